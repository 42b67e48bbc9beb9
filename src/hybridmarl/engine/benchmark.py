"""Engine throughput benchmark: full scripted games per second and unit-actions per second.

Used by ``hybridmarl bench engine`` and ``bench/engine.py``. For every (scenario, batch size):
compile time is measured once, on its own (``jit(...).lower(...).compile()``); then ``repeats``
timed runs each play at least ``min_games`` games, and the minimum and median of games/s and
unit-actions/s are reported. Batch size B means B concurrent games: a pool of B games that is
refilled as games end (``game.play_pool``), split across the host devices JAX sees.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Sequence

import jax
import numpy as np

from hybridmarl.engine import game
from hybridmarl.engine.battle import pad_states
from hybridmarl.engine.scenarios import named_scenario
from hybridmarl.engine.scripts import canonical_name
from hybridmarl.engine.state import make_rules


def bench_engine(
    scenarios: Sequence[str] = ("m5v5-apart", "m30v30-apart"),
    batch_sizes: Sequence[int] = (1, 64, 1024, 4096),
    p0: str = "attack-closest",
    p1: str = "attack-weakest",
    repeats: int = 5,
    min_games: int = 256,
    seed: int = 0,
) -> dict:
    rules = make_rules()
    p0c, p1c = canonical_name(p0), canonical_name(p1)
    devices = jax.local_device_count()
    rows = []
    for sc_name in scenarios:
        sc = named_scenario(sc_name)
        for b in batch_sizes:
            per_dev_pool = max(1, b // devices) if b >= devices else b
            use_dev = devices if b >= devices else 1
            pool = per_dev_pool
            n_games = max(min_games, b)
            n_games = int(np.ceil(n_games / (pool * use_dev)) * pool * use_dev)
            states = sc.generate(n_games, seed)
            stacked, _ = pad_states(states)
            keys = jax.random.split(jax.random.PRNGKey(seed), n_games)
            fn = game.pooled_player(p0c, p1c, game.rules_static(rules), pool, use_dev)
            t0 = time.perf_counter()
            if use_dev == 1:
                compiled = jax.jit(fn).lower(keys, stacked, rules.walkable).compile()
                run = compiled
            else:
                res = fn(keys, stacked, rules.walkable)  # pmap compiles on first call
                jax.block_until_ready(res)
                run = fn
            compile_s = time.perf_counter() - t0
            gps, aps = [], []
            res = None
            for _ in range(repeats):
                t = time.perf_counter()
                res = run(keys, stacked, rules.walkable)
                jax.block_until_ready(res)
                dt = time.perf_counter() - t
                gps.append(n_games / dt)
                aps.append(float(np.asarray(res.unit_actions).sum()) / dt)
            assert res is not None
            turns = np.asarray(res.turns)
            winner = np.asarray(res.winner)
            rows.append(
                {
                    "scenario": sc_name,
                    "batch_size": b,
                    "devices": use_dev,
                    "games_per_run": n_games,
                    "compile_s": round(compile_s, 3),
                    "games_per_s": {"min": round(min(gps), 1), "median": round(statistics.median(gps), 1)},
                    "unit_actions_per_s": {"min": round(min(aps), 1), "median": round(statistics.median(aps), 1)},
                    "mean_turns": round(float(turns.mean()), 2),
                    "mean_unit_actions": round(float(np.asarray(res.unit_actions).mean()), 2),
                    "mean_final_time": round(float(np.asarray(res.final_time).mean()), 2),
                    "p0_win_rate": round(float((winner == 0).mean()), 4),
                }
            )
    return {
        "benchmark": "engine",
        "p0": p0c,
        "p1": p1c,
        "repeats": repeats,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.local_devices()],
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "jax": jax.__version__,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "results": rows,
    }
