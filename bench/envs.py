"""Environment-layer overheads (prints one JSON object).

(a) ``batched_step``: one batched combat env step against one batched engine turn on the same
    states (``turn_context`` + the enemy script + ``apply_actions``, our side's engine actions
    given), at ``--scenario`` (m30v30) and ``--batch`` (1024), enemy ``attack-weakest``. The env
    step is timed both as ``Combat.batch_step`` (enemy-only turns advanced in compacted
    sub-batches) and as ``jax.vmap(Combat.step)`` (enemy-only turns in lockstep: the batch runs
    as many loop iterations as its slowest game), plus ``vmap(step)`` without the observation
    and the observation alone, to show where the time goes. The states are mid-battle:
    ``--warm-steps`` env steps after reset with attack-closest playing our side. Compile times
    are measured on their own (``lower().compile()``); the candidates are then run interleaved
    (one call + ``block_until_ready`` each, ``--repeats`` rounds), min and median reported.
    ``env_turns`` is the engine turns per env step over the batch (1 + enemy-only turns).
    Target: env step <= 2x an engine turn.
(b) ``pettingzoo_b1``: the PettingZoo adapter's ``step`` at B = 1 against the jitted functional
    ``Combat.step`` at B = 1 (``--pz-scenario``, m5v5), both from the same episodes (every agent
    plays noop; the adapter at its defaults, ``illegal_action="fallback"`` and dict observations,
    and the env's own fallback turn that into the same legal actions); per-step wall time
    including the device-to-host transfer a caller needs (the functional loop reads ``done``).
    Target: overhead <= 30%.

Usage::

    python bench/envs.py [--scenario m30v30] [--batch 1024] [--repeats 7] [--pz-steps 300]

XLA sees one CPU device (no ``pmap``); set ``XLA_FLAGS`` to change that.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.engine import rules as R
from hybridmarl.engine.scripts import get_script
from hybridmarl.envs.combat import Combat
from hybridmarl.envs.pettingzoo import PettingZooAdapter


def _timed_together(
    fns: dict, repeats: int
) -> tuple[dict, dict[str, float], dict[str, list[float]]]:
    """Compile each ``name: (fn, args)`` on its own (timed), then run them interleaved, so that
    load changes on a shared machine hit every candidate alike."""
    compiled, compile_s = {}, {}
    for name, (fn, args) in fns.items():
        t0 = time.perf_counter()
        compiled[name] = jax.jit(fn).lower(*args).compile()
        compile_s[name] = time.perf_counter() - t0
        jax.block_until_ready(compiled[name](*args))  # warm-up
    runs: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, (_, args) in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(compiled[name](*args))
            runs[name].append(time.perf_counter() - t)
    return compiled, compile_s, runs


def _stats(runs: list[float]) -> dict[str, float]:
    return {"min": round(min(runs) * 1e3, 3), "median": round(statistics.median(runs) * 1e3, 3)}


def bench_batched(scenario: str, batch: int, warm_steps: int, repeats: int, seed: int) -> dict:
    env = Combat(scenario, enemy="attack-weakest")
    ours = get_script("attack-closest")
    policy = env.script_policy(ours)

    @jax.jit
    def warm(keys):
        _, st = jax.vmap(env.reset)(keys)

        def body(st, k):
            ka = jax.random.split(k, keys.shape[0])
            acts = jax.vmap(policy)(ka, st)
            _, st, _, _, _ = jax.vmap(env.step)(ka, st, acts)
            return st, None

        st, _ = jax.lax.scan(body, st, jax.random.split(keys[0], warm_steps))
        return st

    keys = jax.random.split(jax.random.key(seed), batch)
    t0 = time.perf_counter()
    states = jax.block_until_ready(warm(keys))
    warm_s = time.perf_counter() - t0
    actions = jax.jit(jax.vmap(policy))(keys, states)
    games = states.game
    ours_engine = jax.jit(jax.vmap(lambda k, g: ours(k, g, R.turn_context(g, env.rules), 0)))(
        keys, games
    )
    done = np.asarray(jax.vmap(env.is_done)(states))

    def env_step(k, s, a):
        return env.batch_step(k, s, a)

    def env_step_vmap(k, s, a):
        return jax.vmap(env.step)(k, s, a)

    def env_core(k, s, a):  # vmap(step) without the observation
        return jax.vmap(env._step_core)(k, s, a)

    def observe(s):
        return jax.vmap(env.observe)(s)

    def engine_turn(k, g, a0):
        def one(k, g, a0):
            ctx = R.turn_context(g, env.rules)
            a1 = env.enemy(k, g, ctx, 1)
            return R.apply_actions(g, ctx, jnp.stack([a0, a1]), env.rules)

        return jax.vmap(one)(k, g, a0)

    compiled, compile_s, runs = _timed_together(
        {
            "engine_turn": (engine_turn, (keys, games, ours_engine)),
            "env_batch_step": (env_step, (keys, states, actions)),
            "env_vmap_step": (env_step_vmap, (keys, states, actions)),
            "env_vmap_step_without_obs": (env_core, (keys, states, actions)),
            "observe": (observe, (states,)),
        },
        repeats,
    )
    info = compiled["env_batch_step"](keys, states, actions)[4]
    turns = np.asarray(info["engine_turns"])[~done]
    r_eng = runs["engine_turn"]

    def ratio(name: str) -> dict[str, float]:
        r = runs[name]
        return {
            "min": round(min(r) / min(r_eng), 3),
            "median": round(statistics.median(r) / statistics.median(r_eng), 3),
        }

    return {
        "scenario": scenario,
        "batch": batch,
        "enemy": env.enemy_name,
        "warm_steps": warm_steps,
        "warm_s": round(warm_s, 2),
        "games_done_at_snapshot": int(done.sum()),
        "env_turns": {
            "mean": round(float(turns.mean()), 3) if turns.size else 0.0,
            "max": int(turns.max()) if turns.size else 0,
        },
        "ms": {name: _stats(r) for name, r in runs.items()},
        "compile_s": {name: round(c, 2) for name, c in compile_s.items()},
        "ratio_over_engine_turn": {name: ratio(name) for name in runs if name != "engine_turn"},
        "target_ratio": 2.0,
    }


def bench_pettingzoo(scenario: str, steps: int, seed: int) -> dict:
    env = Combat(scenario, enemy="attack-weakest")
    n = env.num_agents
    # Functional loop: jitted reset/step, keys split outside the timing, noop actions (the env's
    # fallback makes them legal), reading `done` back to the host as a caller must.
    reset = jax.jit(env.reset)
    step = jax.jit(env.step)
    zeros = jnp.zeros((n,), jnp.int32)
    keys = list(jax.random.split(jax.random.key(seed), 2 * steps + 64))
    _, st = reset(keys.pop())
    jax.block_until_ready(step(keys[0], st, zeros))  # compile
    pz = PettingZooAdapter(env)  # defaults: illegal actions replaced by the fallback
    pz.reset(seed=seed)
    pz.step(dict.fromkeys(pz.agents, 0))  # compile
    pz.reset(seed=seed)
    functional, adapter = [], []
    # Interleaved, so that load changes on a shared machine hit both alike.
    for i in range(steps):
        t = time.perf_counter()
        _, st, _, d, _ = step(keys[i], st, zeros)
        done = bool(d)
        functional.append(time.perf_counter() - t)
        if done:
            _, st = reset(keys.pop())
        actions = dict.fromkeys(pz.agents, 0)
        t = time.perf_counter()
        pz.step(actions)
        adapter.append(time.perf_counter() - t)
        if not pz.agents:
            pz.reset()
    f_med, a_med = statistics.median(functional), statistics.median(adapter)
    return {
        "scenario": scenario,
        "steps": steps,
        "functional_step_ms": _stats(functional),
        "adapter_step_ms": _stats(adapter),
        "overhead_median": round(a_med / f_med - 1.0, 3),
        "overhead_min": round(min(adapter) / min(functional) - 1.0, 3),
        "target_overhead": 0.3,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="m30v30")
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--warm-steps", type=int, default=25)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--pz-scenario", default="m5v5")
    ap.add_argument("--pz-steps", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-batched", action="store_true")
    args = ap.parse_args()
    out = {
        "benchmark": "envs",
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.local_devices()],
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "jax": jax.__version__,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "load_avg_1m": round(os.getloadavg()[0], 2),
    }
    if not args.skip_batched:
        out["batched_step"] = bench_batched(
            args.scenario, args.batch, args.warm_steps, args.repeats, args.seed
        )
    out["pettingzoo_b1"] = bench_pettingzoo(args.pz_scenario, args.pz_steps, args.seed)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
