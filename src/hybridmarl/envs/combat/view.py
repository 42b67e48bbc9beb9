"""What a decision point looks like from our side: HP ranks, legal-action masks, and the maps
between env actions and the engine's action codes (layout in :mod:`hybridmarl.envs.combat`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from hybridmarl.engine import rules as R
from hybridmarl.engine.state import GameState, Rules
from hybridmarl.envs.combat.state import INT32_MAX

__all__ = [
    "ATTACK_OFFSET",
    "MOVE_OFFSET",
    "NOOP",
    "View",
    "action_mask",
    "engine_to_env",
    "env_to_engine",
    "make_view",
]

NOOP = 0
#: Env actions 1..4 are the engine's MOVE 2..5 (left, right, down, up).
MOVE_OFFSET = 1
#: Env action ``5 + k`` attacks the k-th living enemy by ascending HP.
ATTACK_OFFSET = 5


class View(struct.PyTreeNode):
    """Per-decision-point quantities shared by masks, action conversion and observations."""

    ctx: R.TurnContext
    legal: jax.Array  # bool [U, 6 + U] engine legal actions of player 0
    rank_slot: jax.Array  # int32 [U] enemy slot of HP rank k (valid where rank_valid)
    rank_valid: jax.Array  # bool [U]
    rank_of_slot: jax.Array  # int32 [U] HP rank of each enemy slot (meaningless if dead)
    over: jax.Array  # bool [] game over


def make_view(game: GameState, rules: Rules) -> View:
    """The turn context of ``game`` and the HP ranks of the living enemies (ascending HP, ties
    to the lower slot, which is the lower unit id)."""
    ctx = R.turn_context(game, rules)
    u = game.hp.shape[-1]
    slot = jnp.arange(u, dtype=jnp.int32)
    alive1 = ctx.alive[1]
    keys = jnp.where(alive1, (jnp.maximum(game.hp[1], 0) << R.SLOT_BITS) | slot, INT32_MAX)
    # Ranks by counting (no sort): rank = number of living enemies with a smaller key.
    rank_of_slot = jnp.sum(keys[None, :] < keys[:, None], axis=1).astype(jnp.int32)
    hit = (rank_of_slot[None, :] == slot[:, None]) & alive1[None, :]  # [k, slot]
    rank_slot = jnp.sum(jnp.where(hit, slot[None, :], 0), axis=1).astype(jnp.int32)
    rank_valid = slot < jnp.sum(alive1)
    return View(
        ctx=ctx,
        legal=R.legal_actions(ctx, 0),
        rank_slot=rank_slot,
        rank_valid=rank_valid,
        rank_of_slot=rank_of_slot,
        over=R.game_over(game, rules),
    )


def action_mask(view: View, num_agents: int, num_enemies: int) -> jax.Array:
    """bool ``[n0, 5 + M]``: the engine's legal actions of our units, as env actions."""
    n0, m = num_agents, num_enemies
    legal = view.legal[:n0]
    acting = view.ctx.acting[0, :n0]
    noop = ~acting | legal[:, R.PASS_ACTION] | legal[:, R.RELOAD_ACTION]
    moves = legal[:, R.MOVE_ACTIONS[0] : R.MOVE_ACTIONS[-1] + 1]
    by_slot = legal[:, R.ATTACK_BASE :]
    attacks = by_slot[:, view.rank_slot[:m]] & view.rank_valid[:m][None, :]
    live = jnp.concatenate([moves, attacks], axis=1) & ~view.over
    noop = noop | view.over
    return jnp.concatenate([noop[:, None], live], axis=1)


def env_to_engine(view: View, actions: jax.Array, num_agents: int, num_enemies: int) -> jax.Array:
    """int32 ``[n0]`` engine codes of env ``actions`` (no legality check): noop is RELOAD in
    cooldown and PASS otherwise."""
    can_fire = view.ctx.can_attack_now[0, :num_agents]
    noop = jnp.where(can_fire, R.PASS_ACTION, R.RELOAD_ACTION)
    move = actions - MOVE_OFFSET + R.MOVE_ACTIONS[0]
    target = view.rank_slot[jnp.clip(actions - ATTACK_OFFSET, 0, num_enemies - 1)]
    return jnp.where(
        actions < MOVE_OFFSET,
        noop,
        jnp.where(actions < ATTACK_OFFSET, move, R.ATTACK_BASE + target),
    ).astype(jnp.int32)


def engine_to_env(view: View, codes: jax.Array, num_agents: int) -> jax.Array:
    """int32 ``[n0]`` env actions of player 0's engine ``codes`` (``[U]`` or ``[n0]``)."""
    codes = codes[:num_agents].astype(jnp.int32)
    u = view.rank_of_slot.shape[-1]
    move = codes - R.MOVE_ACTIONS[0] + MOVE_OFFSET
    attack = ATTACK_OFFSET + view.rank_of_slot[jnp.clip(codes - R.ATTACK_BASE, 0, u - 1)]
    return jnp.where(
        codes <= R.RELOAD_ACTION, NOOP, jnp.where(codes < R.ATTACK_BASE, move, attack)
    ).astype(jnp.int32)
