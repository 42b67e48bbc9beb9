"""Scripted battle series: the Python API behind ``hybridmarl battle``.

>>> from hybridmarl.engine.battle import run_battles
>>> from hybridmarl.engine.scenarios import named_scenario
>>> states = named_scenario("m5v5").generate(100, seed=0)
>>> res = run_battles(states, "attack-closest", "attack-weakest", progress=False)
>>> res.summary()["p0_win_rate"]  # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.engine import game
from hybridmarl.engine.scenarios import InputError
from hybridmarl.engine.scripts import canonical_name
from hybridmarl.engine.state import (
    GameState,
    Rules,
    UnitSpec,
    build_batch,
    make_rules,
)

#: Engine backends ``run_battles`` can play on (``docs/engine-backends.md``).
ENGINES = ("jax", "native")


@dataclass
class BattleResults:
    """Per-battle outcomes, in input order."""

    p0: str
    p1: str
    winner: np.ndarray  # int [N]: 0, 1, or -1 for a draw
    final_time: np.ndarray  # int [N]
    turns: np.ndarray  # int [N]
    unit_hp: list[list[int]]  # final HP per unit id (0 if dead)
    ltd2_eval: np.ndarray  # int [N]
    unit_actions: np.ndarray  # int [N]

    def __len__(self) -> int:
        return len(self.winner)

    def summary(self) -> dict:
        n = max(len(self), 1)
        return {
            "battles": len(self),
            "p0": self.p0,
            "p1": self.p1,
            "p0_wins": int((self.winner == 0).sum()),
            "p1_wins": int((self.winner == 1).sum()),
            "draws": int((self.winner == -1).sum()),
            "p0_win_rate": float((self.winner == 0).sum() / n),
            "p1_win_rate": float((self.winner == 1).sum() / n),
            "draw_rate": float((self.winner == -1).sum() / n),
            "mean_final_time": float(self.final_time.mean()) if len(self) else 0.0,
            "mean_turns": float(self.turns.mean()) if len(self) else 0.0,
        }

    def to_document(self) -> dict:
        return {
            "results": [
                {
                    "winner": None if int(w) < 0 else int(w),
                    "final_time": int(t),
                    "turns": int(k),
                    "unit_hp": [int(h) for h in hp],
                }
                for w, t, k, hp in zip(
                    self.winner, self.final_time, self.turns, self.unit_hp, strict=True
                )
            ],
            "summary": self.summary(),
        }


def pad_states(states: Sequence[Sequence[UnitSpec]]) -> tuple[GameState, int]:
    """Build and stack states, all padded to the largest side of any of them (built in NumPy in
    one pass; equal to ``stack_states`` of ``build_state`` per state)."""
    slots = max(max(sum(1 for u in s if u.player == p) for p in (0, 1)) for s in states)
    return build_batch(states, slots), slots


def run_battles(
    states: Sequence[Sequence[UnitSpec]],
    p0: str,
    p1: str,
    *,
    seed: int = 0,
    rules: Rules | None = None,
    batch_size: int = 1024,
    progress: bool = True,
    engine: str = "jax",
) -> BattleResults:
    """Play every start state once, ``p0`` as player 0 and ``p1`` as player 1.

    Games run in batches of ``batch_size`` through one compiled program (``game.play_batch``);
    ``seed`` only matters for the ``random`` script (combat itself is deterministic).
    ``engine="native"`` plays on the Numba backend (``engine.native.run_battles``): the same
    results, except the ``random`` script's draws.
    """
    if engine == "native":
        from hybridmarl.engine import native

        return native.run_battles(states, p0, p1, seed=seed, rules=rules, progress=progress)
    if engine != "jax":
        raise InputError(f"unknown engine {engine!r} (known: {', '.join(ENGINES)})")
    try:
        p0c, p1c = canonical_name(p0), canonical_name(p1)
    except KeyError as e:
        raise InputError(str(e.args[0])) from None
    if not states:
        raise InputError("no start states to play")
    rules = make_rules() if rules is None else rules
    stacked, slots = pad_states(states)
    n = len(states)
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    outs: list[game.GameResult] = []
    bar = _progress(progress, n, f"{p0c} vs {p1c}")
    for start in range(0, n, batch_size):
        stop = min(start + batch_size, n)
        chunk = jax.tree.map(lambda a, s=start, e=stop: a[s:e], stacked)
        # Pad the last chunk to the batch size so every chunk reuses one compiled program.
        m = stop - start
        if n > batch_size and m < batch_size:
            chunk = jax.tree.map(
                lambda a, m=m: np.concatenate([a, np.repeat(a[-1:], batch_size - m, 0)]), chunk
            )
            kchunk = np.concatenate(
                [
                    np.asarray(keys[start:stop]),
                    np.repeat(np.asarray(keys[stop - 1 : stop]), batch_size - m, 0),
                ]
            )
        else:
            kchunk = keys[start:stop]
        res = game.play_batch(jnp.asarray(kchunk), chunk, rules, p0c, p1c)
        res = jax.tree.map(lambda a, m=m: np.asarray(a)[:m], res)
        outs.append(res)
        if bar is not None:
            bar[0].update(bar[1], advance=m)
    if bar is not None:
        bar[0].stop()
    cat = jax.tree.map(lambda *xs: np.concatenate(xs), *outs)
    unit_hp = []
    uid = np.asarray(stacked.uid)
    for i, s in enumerate(states):
        hp = np.zeros(len(s), np.int64)
        u = uid[i].ravel()
        h = np.maximum(cat.hp[i].ravel(), 0)
        keep = u < len(s)
        hp[u[keep]] = h[keep]
        unit_hp.append(hp.tolist())
    del slots
    return BattleResults(
        p0=p0c,
        p1=p1c,
        winner=cat.winner,
        final_time=cat.final_time,
        turns=cat.turns,
        unit_hp=unit_hp,
        ltd2_eval=cat.ltd2_eval,
        unit_actions=cat.unit_actions,
    )


def _progress(enabled: bool, total: int, label: str):
    if not enabled:
        return None
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    prog = Progress(
        TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), transient=False
    )
    prog.start()
    task = prog.add_task(label, total=total)
    return prog, task
