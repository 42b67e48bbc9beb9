"""Differential checking of the native engine against the JAX engine (tests and
``bench/engine_parity.py``).

The JAX side here plays a batch in which every game has its own pair of deterministic scripts:
each policy evaluates all of them and keeps the one indexed by the game's script number, so one
compiled program covers every match-up (per overkill mode and slot count). Games run either turn
by turn in lockstep with the native engine (``lockstep``, reporting the first differing turn and
field) or to the end (``jax_play``).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.engine import game
from hybridmarl.engine import rules as R
from hybridmarl.engine import units as U
from hybridmarl.engine.native.play import advance, play
from hybridmarl.engine.native.state import NativeStates, from_jax, to_jax
from hybridmarl.engine.scripts import SCRIPTS, get_script
from hybridmarl.engine.state import GameState, Rules, UnitSpec, is_walkable_np

#: Every script whose play is deterministic (the random script draws from JAX's PRNG).
DETERMINISTIC_SCRIPTS: tuple[str, ...] = tuple(n for n in SCRIPTS if n != "random")


def _indexed_policy(index_of_player: int):
    scripts = [get_script(n) for n in DETERMINISTIC_SCRIPTS]

    def policy(key, state, ctx, p, choice):
        outs = jnp.stack([s(key, state, ctx, p) for s in scripts])
        return outs[choice]

    del index_of_player
    return policy


@functools.lru_cache(maxsize=16)
def _jax_turn(rules_static: tuple):
    """Jitted ``(states [B], choice0 [B], choice1 [B], walkable) -> (states, acting count [B])``:
    one turn of every game that is not over (finished games are left as they are)."""
    stalemate_limit, overkill, max_turns = rules_static
    policy = _indexed_policy(0)

    def one(state, c0, c1, walkable):
        rules = Rules(
            walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=max_turns
        )
        ctx = R.turn_context(state, rules)
        key = jax.random.PRNGKey(0)
        actions = jnp.stack([policy(key, state, ctx, 0, c0), policy(key, state, ctx, 1, c1)])
        new = R.apply_actions(state, ctx, actions, rules)
        over = R.game_over(state, rules)
        kept = jax.tree.map(lambda a, b: jnp.where(over, a, b), state, new)
        return kept, jnp.where(over, 0, jnp.sum(ctx.acting)).astype(jnp.int32)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, None)))


@functools.lru_cache(maxsize=16)
def _jax_game(rules_static: tuple):
    """Jitted whole games (``game.play_game``) with per-game script choices; returns the final
    states and ``game.GameResult``."""
    stalemate_limit, overkill, max_turns = rules_static
    policy = _indexed_policy(0)

    def one(state, c0, c1, walkable):
        rules = Rules(
            walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=max_turns
        )
        final, n = game.play_game(
            jax.random.PRNGKey(0),
            state,
            rules,
            lambda k, s, c, p: policy(k, s, c, p, c0),
            lambda k, s, c, p: policy(k, s, c, p, c1),
        )
        return final, game.result_of(final, n)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, None)))


def script_choices(names: Sequence[str]) -> np.ndarray:
    return np.array([DETERMINISTIC_SCRIPTS.index(n) for n in names], np.int32)


def first_difference(ours: NativeStates, ref: NativeStates) -> str | None:
    """Where two batches first differ ("game g field f"), or None if they are equal."""
    for f in NativeStates._fields:
        a, b = getattr(ours, f), getattr(ref, f)
        if a.shape != b.shape:
            return f"field {f}: shape {a.shape} vs {b.shape}"
        diff = np.argwhere(a != b)
        if len(diff):
            g = int(diff[0][0])
            return f"game {g} field {f}: native {a[g].tolist()} vs jax {b[g].tolist()}"
    return None


def lockstep(
    states: NativeStates,
    rules: Rules,
    p0: Sequence[str],
    p1: Sequence[str],
    max_turns: int | None = None,
) -> tuple[NativeStates, int]:
    """Play both engines one turn at a time from the same states until every game is over (or
    ``max_turns`` turns), comparing the whole state after each turn. Raises ``AssertionError``
    naming the first differing turn and field. Returns the final native states and the turns."""
    fn = _jax_turn(game.rules_static(rules))
    c0, c1 = jnp.asarray(script_choices(p0)), jnp.asarray(script_choices(p1))
    ref = to_jax(states)
    ours = states
    step = 0
    while max_turns is None or step < max_turns:
        if games_over(ours, rules).all():
            break
        ref, _ = fn(ref, c0, c1, rules.walkable)
        ours = advance(ours, rules, list(p0), list(p1), 1)
        step += 1
        where = first_difference(ours, from_jax(ref))
        if where is not None:
            raise AssertionError(f"native and JAX engines differ after turn {step}: {where}")
    return ours, step


def games_over(states: NativeStates, rules: Rules) -> np.ndarray:
    """bool [B]: ``rules.game_over`` of every game, in NumPy."""
    can_hurt = (states.hp > 0) & (U.TABLES.script_damage[states.utype.clip(0, U.NUM_TYPES - 1)] > 0)
    dead: np.ndarray = ~np.any(can_hurt, axis=2)
    return (
        np.any(dead, axis=1)
        | (states.stale > rules.stalemate_limit)
        | (states.turn >= rules.max_turns)
    )


@dataclass
class GameComparison:
    games: int
    mismatches: int
    first_mismatch: str | None
    #: Games whose LTD2 evaluation differs by 1 or 2 (not mismatches): the native engine sums a
    #: side's sqrt(HP) * dpf in float32 unit by unit like SparCraft, XLA's reduction may sum in
    #: another order (it even depends on the batch size), so each side's int(1000 * sum / total)
    #: can land one lower or higher, and the evaluation is the difference of the two sides.
    ltd2_rounding: int = 0


def compare_whole_games(
    states: NativeStates, rules: Rules, p0: Sequence[str], p1: Sequence[str]
) -> GameComparison:
    """Play every game to its end on both engines; compare the final states and results
    (winner, final frame, turns, HP, unit actions exactly; LTD2 evaluation within 2, i.e.
    each side's LTD2 within 1)."""
    final_ref, res_ref = _jax_game(game.rules_static(rules))(
        to_jax(states),
        jnp.asarray(script_choices(p0)),
        jnp.asarray(script_choices(p1)),
        rules.walkable,
    )
    ref = from_jax(final_ref)
    final, res = play(states, rules, list(p0), list(p1))
    bad = np.zeros(states.batch_size, bool)
    for f in NativeStates._fields:
        a, b = getattr(final, f), getattr(ref, f)
        bad |= (a != b).reshape(states.batch_size, -1).any(axis=1)
    for name in ("winner", "final_time", "turns", "unit_actions"):
        bad |= np.asarray(getattr(res, name)) != np.asarray(getattr(res_ref, name))
    ltd2_gap = np.abs(np.asarray(res.ltd2_eval, np.int64) - np.asarray(res_ref.ltd2_eval, np.int64))
    bad |= ltd2_gap > 2
    first = None
    if bad.any():
        g = int(np.argmax(bad))
        sub = states.take(g)
        first = f"game {g} ({p0[g]} vs {p1[g]}): "
        try:
            lockstep(sub, rules, [p0[g]], [p1[g]])
            first += "final results differ, states equal turn by turn"
        except AssertionError as e:
            first += str(e)
    return GameComparison(
        states.batch_size, int(bad.sum()), first, int(((ltd2_gap >= 1) & (ltd2_gap <= 2)).sum())
    )


def random_walkable(
    rng: np.random.Generator, width: int = 64, height: int = 40, walls: int = 6
) -> np.ndarray:
    """A walk-tile grid with a few random rectangular walls."""
    grid = np.ones((height, width), bool)
    for _ in range(walls):
        w, h = rng.integers(2, 12), rng.integers(2, 12)
        x0, y0 = rng.integers(0, width - w), rng.integers(0, height - h)
        grid[y0 : y0 + h, x0 : x0 + w] = False
    return grid


def random_states(
    rng: np.random.Generator,
    n: int,
    max_side: int,
    walkable: np.ndarray,
    *,
    types: Sequence[str] | None = None,
) -> list[list[UnitSpec]]:
    """``n`` start states with 1..``max_side`` units of random types per side, P0 around a point
    left of the map's middle and P1 right of it (sometimes overlapping), on walkable pixels."""
    names = list(U.TYPE_NAMES if types is None else types)
    h, w = walkable.shape[0] * 8, walkable.shape[1] * 8
    out = []
    for _ in range(n):
        sizes = rng.integers(1, max_side + 1, size=2)
        gap = int(rng.integers(0, w // 2))
        centres = ((w // 2 - gap // 2, h // 2), (w // 2 + gap // 2, h // 2))
        units = []
        for p in (0, 1):
            for _k in range(int(sizes[p])):
                for _try in range(100):
                    x = int(centres[p][0] + rng.integers(-120, 121))
                    y = int(centres[p][1] + rng.integers(-120, 121))
                    if is_walkable_np(walkable, x, y):
                        break
                units.append(UnitSpec(names[int(rng.integers(len(names)))], p, x, y))
        order = rng.permutation(len(units))
        out.append([units[i] for i in order])
    return out


def all_pairs() -> tuple[list[str], list[str]]:
    p0 = [a for a in DETERMINISTIC_SCRIPTS for _ in DETERMINISTIC_SCRIPTS]
    p1 = [b for _ in DETERMINISTIC_SCRIPTS for b in DETERMINISTIC_SCRIPTS]
    return p0, p1


__all__ = [
    "DETERMINISTIC_SCRIPTS",
    "GameComparison",
    "GameState",
    "all_pairs",
    "compare_whole_games",
    "first_difference",
    "lockstep",
    "random_states",
    "random_walkable",
]
