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
        rules = Rules(
            walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=max_turns
        )
        final, n = play_game(key, state, rules, s0, s1)
        return result_of(final, n)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, None)))


def rules_static(rules: Rules) -> tuple:
    return (rules.stalemate_limit, rules.overkill, rules.max_turns)


def play_batch(keys: jax.Array, states: GameState, rules: Rules, p0: str, p1: str) -> GameResult:
    """Play a batch of games (leading axis B on ``keys`` and every state leaf) with named scripts."""
    fn = batched_player(p0, p1, rules_static(rules))
    return fn(keys, states, rules.walkable)


def play_pool(
    keys: jax.Array,
    states: GameState,
    rules: Rules,
    policy0: Script,
    policy1: Script,
    pool_size: int,
) -> GameResult:
    """Play N games (leading axis of ``keys`` and ``states``) through a pool of ``pool_size``
    concurrent games; a slot whose game ends is refilled with the next unplayed game at once.

    Plain ``vmap(play_game)`` runs every game for as many turns as the longest one; the pool keeps
    the batch busy, so it costs about N * mean turns rather than N * max turns turn-steps.
    Results come back in input order, exactly as ``vmap(play_game)`` would give them.
    """
    n = keys.shape[0]
    b = min(pool_size, n)
    first = jax.tree.map(lambda a: a[:b], states)
    slots = jnp.arange(b, dtype=jnp.int32)
    hp_shape = states.hp.shape[1:]

    results = GameResult(
        winner=jnp.zeros(n, jnp.int32),
        final_time=jnp.zeros(n, jnp.int32),
        turns=jnp.zeros(n, jnp.int32),
        hp=jnp.zeros((n, *hp_shape), jnp.int32),
        ltd2_eval=jnp.zeros(n, jnp.int32),
        unit_actions=jnp.zeros(n, jnp.int32),
    )
    turn = jax.vmap(lambda k, s: play_turn(k, s, rules, policy0, policy1))
    over = jax.vmap(lambda s: R.game_over(s, rules))
    result_one = jax.vmap(result_of)

    def cond(carry):
        _, _, game_idx, _, _, _ = carry
        return jnp.any(game_idx < n)

    def body(carry):
        pool, pkeys, game_idx, nxt, counts, res = carry
        active = game_idx < n
        done = over(pool) & active
        # Record finished games (inactive/unfinished slots scatter out of bounds and are dropped).
        out = result_one(pool, counts)
        where = jnp.where(done, game_idx, n)
        res = jax.tree.map(lambda r, o: r.at[where].set(o, mode="drop"), res, out)
        # Refill finished slots with the next games, in order.
        rank = jnp.cumsum(done.astype(jnp.int32)) - 1
        new_idx = jnp.where(done, nxt + rank, game_idx)
        nxt = nxt + jnp.sum(done.astype(jnp.int32))
        load = done & (new_idx < n)
        src = jnp.clip(new_idx, 0, n - 1)
        fresh = jax.tree.map(lambda a: a[src], states)
        sel = sel_mask(load)
        pool = jax.tree.map(sel, fresh, pool)
        pkeys = sel(keys[src], pkeys)
        counts = jnp.where(load, 0, counts)
        game_idx = jnp.where(done & ~load, n, new_idx)
        # One turn for every live slot.
        live = (game_idx < n) & ~over(pool)
        split = jax.vmap(jax.random.split)(pkeys)
        stepped, _, ctx = turn(split[:, 1], pool)
        pool = jax.tree.map(sel_mask(live), stepped, pool)
        pkeys = split[:, 0]
        counts = counts + jnp.where(live, jnp.sum(ctx.acting, axis=(1, 2)), 0).astype(jnp.int32)
        return pool, pkeys, game_idx, nxt, counts, res

    carry = (first, keys[:b], slots, jnp.int32(b), jnp.zeros(b, jnp.int32), results)
    carry = jax.lax.while_loop(cond, body, carry)
    return carry[-1]


def sel_mask(mask: jax.Array):
    def sel(new, old):
        return jnp.where(mask.reshape(mask.shape + (1,) * (new.ndim - 1)), new, old)

    return sel


@functools.lru_cache(maxsize=64)
def pooled_player(
    p0: str, p1: str, rules_static: tuple, pool_size: int, devices: int = 1
) -> Callable:
    """Jitted ``(keys [N], states [N], walkable) -> GameResult [N]`` over a refilling pool.

    With ``devices > 1`` the games are split evenly across that many (host) devices with ``pmap``
    (N must be a multiple of ``devices``): each device runs its own pool of ``pool_size``.
    """
    stalemate_limit, overkill, max_turns = rules_static
    s0, s1 = get_script(p0), get_script(p1)

    def run(keys, states, walkable):
        rules = Rules(
            walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=max_turns
        )
        return play_pool(keys, states, rules, s0, s1, pool_size)

    if devices <= 1:
        return jax.jit(run)
    pm = jax.pmap(run, in_axes=(0, 0, None))

    def split_run(keys, states, walkable):
        shard = lambda a: a.reshape((devices, a.shape[0] // devices) + a.shape[1:])  # noqa: E731
        out = pm(shard(keys), jax.tree.map(shard, states), walkable)
        return jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), out)

    return split_run
