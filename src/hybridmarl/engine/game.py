"""Playing games: one turn, a whole game under ``lax.while_loop``, and batches under ``vmap``.

A *policy* has the script signature ``(key, state, ctx, p) -> int32 [U]`` (see ``scripts``), so
scripts, search players and trained networks are interchangeable wherever a player is expected.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from hybridmarl.engine import rules as R
from hybridmarl.engine.scripts import Script, get_script
from hybridmarl.engine.state import GameState, Rules


def play_turn(
    key: jax.Array, state: GameState, rules: Rules, policy0: Script, policy1: Script
) -> tuple[GameState, jax.Array, R.TurnContext]:
    """One decision turn. Returns the new state, the actions [2, U] and the context they saw."""
    k0, k1 = jax.random.split(key)
    ctx = R.turn_context(state, rules)
    a0 = policy0(k0, state, ctx, 0)
    a1 = policy1(k1, state, ctx, 1)
    actions = jnp.stack([a0, a1])
    return R.apply_actions(state, ctx, actions, rules), actions, ctx


class GameResult(NamedTuple):
    """Outcome of one game (fields get a leading batch axis when batched)."""

    winner: jax.Array  # int32: 0, 1, or -1 for a draw / unfinished
    final_time: jax.Array  # int32 frames
    turns: jax.Array  # int32 decision turns
    hp: jax.Array  # int32 [2, U] final HP per slot
    ltd2_eval: jax.Array  # int32 eval(P0, LTD2) with the +-100000 bonus
    unit_actions: jax.Array  # int32 unit actions issued (acting units summed over turns)


def play_game(
    key: jax.Array, state: GameState, rules: Rules, policy0: Script, policy1: Script
) -> tuple[GameState, jax.Array]:
    """Play until the game is over (``Game::play``). Returns the final state and the number of
    unit actions issued."""

    def cond(carry):
        _, s, _ = carry
        return ~R.game_over(s, rules)

    def body(carry):
        k, s, n = carry
        k, sub = jax.random.split(k)
        s2, _, ctx = play_turn(sub, s, rules, policy0, policy1)
        return k, s2, n + jnp.sum(ctx.acting).astype(jnp.int32)

    _, final, n_actions = jax.lax.while_loop(cond, body, (key, state, jnp.int32(0)))
    return final, n_actions


def result_of(final: GameState, n_actions: jax.Array) -> GameResult:
    return GameResult(
        winner=R.winner(final),
        final_time=final.time,
        turns=final.turn,
        hp=final.hp,
        ltd2_eval=R.evaluate(final, 0, "ltd2"),
        unit_actions=n_actions,
    )


@functools.lru_cache(maxsize=64)
def batched_player(p0: str, p1: str, rules_static: tuple) -> Callable:
    """A jitted ``(keys [B], states [B], walkable) -> GameResult [B]`` for a pair of named scripts.

    Cached per (scripts, static rules) so repeated calls reuse one compiled program.
    """
    stalemate_limit, overkill, max_turns = rules_static
    s0, s1 = get_script(p0), get_script(p1)

    def one(key, state, walkable):
        rules = Rules(walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=max_turns)
        final, n = play_game(key, state, rules, s0, s1)
        return result_of(final, n)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, None)))


def rules_static(rules: Rules) -> tuple:
    return (rules.stalemate_limit, rules.overkill, rules.max_turns)


def play_batch(keys: jax.Array, states: GameState, rules: Rules, p0: str, p1: str) -> GameResult:
    """Play a batch of games (leading axis B on ``keys`` and every state leaf) with named scripts."""
    fn = batched_player(p0, p1, rules_static(rules))
    return fn(keys, states, rules.walkable)
