"""SparCraft's scripted players as batched pure functions (docs/engine.md#scripts).

A script maps ``(key, state, ctx, p)`` to one action code per unit slot of player ``p`` (see
``rules``); only the acting units' entries are used. Every tie-break is SparCraft's:

- the closest enemy is the one at the smallest squared distance (current, interpolated positions),
  ties to the lower unit id; only enemies within 1000 px count (``getClosestEnemyUnit`` starts from
  minDist = 1,000,000) and with none that close it is the first enemy in SparCraft's unit order;
- attack candidates are scanned in the enemy's unit order (alive, free time, id) with strict
  comparisons, so the first one wins ties;
- "move toward X" scores each legal MOVE by the unit's stored position plus the unit direction
  vector, keeping the first of left, right, down, up on ties ("move away": the first maximum);
- a script with nothing to choose falls back to the first action of the legal-action list.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from hybridmarl.engine import units as U
from hybridmarl.engine.rules import (
    ATTACK_BASE,
    DIR_X,
    DIR_Y,
    MOVE_ACTIONS,
    ORDER_BITS,
    RELOAD_ACTION,
    SLOT_BITS,
    SLOT_MASK,
    TurnContext,
    first_in_order,
    first_legal_action,
    legal_actions,
)
from hybridmarl.engine.state import GameState

Script = Callable[[jax.Array, GameState, TurnContext, int], jax.Array]

_BIG = jnp.iinfo(jnp.int32).max
_CLOSEST_LIMIT = 1_000_000
_DIRS = jnp.arange(4, dtype=jnp.int32)[None, :]


def _select_min(mask: jax.Array, score: jax.Array, order: jax.Array) -> jax.Array:
    """Among ``mask`` candidates ([U, M]), the smallest int ``score`` (< 2^16); ties to the first
    in ``order`` ([M]). One packed min-reduction."""
    key = jnp.where(mask, (score << ORDER_BITS) | order[None, :], _BIG)
    return (jnp.min(key, axis=1) & SLOT_MASK).astype(jnp.int32)


def _select_max_float(mask: jax.Array, value: jax.Array, order: jax.Array) -> jax.Array:
    """Among ``mask`` candidates, the largest float ``value`` (strictly positive); ties to the
    first in ``order``."""
    v = jnp.where(mask, value, -1.0)
    best = jnp.max(v, axis=-1, keepdims=True)
    return first_in_order(mask & (v == best), order)[0]


def closest_enemy(state: GameState, ctx: TurnContext, p: int) -> jax.Array:
    """int32 [U]: enemy slot of each unit's closest enemy (``GameState::getClosestEnemyUnit``)."""
    q = 1 - p
    d2 = ctx.enemy_d2(p)
    cand = ctx.alive[q][None, :] & (d2 <= _CLOSEST_LIMIT)
    # Lexicographic (distance, id) as distance << 9 | slot (slot order is id order; d2 < 2^20).
    slot = jnp.arange(d2.shape[1], dtype=jnp.int32)
    k = jnp.min(jnp.where(cand, (d2 << SLOT_BITS) | slot[None, :], _BIG), axis=1)
    first = jnp.min(ctx.order[q]) & SLOT_MASK
    return jnp.where(k < _BIG, k & SLOT_MASK, first).astype(jnp.int32)


def _gather_rows(m: jax.Array, idx: jax.Array) -> jax.Array:
    return jnp.take_along_axis(m, idx[:, None], axis=1)[:, 0]


def in_own_range(state: GameState, ctx: TurnContext, p: int, target: jax.Array) -> jax.Array:
    """bool [U]: ``canAttackTarget``: the enemy slot ``target`` is within the unit's range now."""
    range_sq = jnp.asarray(U.TABLES.range_sq)[state.utype[p]]
    return range_sq >= _gather_rows(ctx.enemy_d2(p), target)


def _move_scores(
    state: GameState, ctx: TurnContext, p: int, tx: jax.Array, ty: jax.Array
) -> jax.Array:
    """int32 [U, 4]: squared distance from (tx, ty) to stored position + unit direction vector."""
    nx = state.x[p][:, None] + jnp.asarray(DIR_X, jnp.int32)[None, :]
    ny = state.y[p][:, None] + jnp.asarray(DIR_Y, jnp.int32)[None, :]
    dx = nx - tx[:, None]
    dy = ny - ty[:, None]
    return dx * dx + dy * dy


def move_toward(
    state: GameState, ctx: TurnContext, p: int, tx: jax.Array, ty: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """(action code [U], any legal move [U]) of the legal MOVE closest to (tx, ty)."""
    ok = ctx.move_ok[p]
    k = jnp.min(jnp.where(ok, (_move_scores(state, ctx, p, tx, ty) << 2) | _DIRS, _BIG), axis=1)
    return ((k & 3) + MOVE_ACTIONS[0]).astype(jnp.int32), k < _BIG


def move_away(
    state: GameState, ctx: TurnContext, p: int, tx: jax.Array, ty: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """(action code [U], any candidate [U]) of the legal MOVE furthest from (tx, ty), strict > 0."""
    ok = ctx.move_ok[p]
    # First maximum: max of score << 2 | (3 - dir).
    k = jnp.max(jnp.where(ok, (_move_scores(state, ctx, p, tx, ty) << 2) | (3 - _DIRS), -1), axis=1)
    return ((3 - (k & 3)) + MOVE_ACTIONS[0]).astype(jnp.int32), (k >> 2) > 0


def _enemy_pos(ctx: TurnContext, q: int, j: jax.Array) -> tuple[jax.Array, jax.Array]:
    return ctx.cx[q][j], ctx.cy[q][j]


def _approach_or_reload(state: GameState, ctx: TurnContext, p: int) -> jax.Array:
    """The shared non-attack branch of the Attack* scripts and NOKDPS: RELOAD if in cooldown and
    the closest enemy is in range, else the move toward the closest enemy, else the first legal."""
    q = 1 - p
    closest = closest_enemy(state, ctx, p)
    tx, ty = _enemy_pos(ctx, q, closest)
    toward, has_move = move_toward(state, ctx, p, tx, ty)
    reload = ~ctx.can_attack_now[p] & in_own_range(state, ctx, p, closest)
    fallback = first_legal_action(ctx, p)
    return jnp.where(reload, RELOAD_ACTION, jnp.where(has_move, toward, fallback)).astype(jnp.int32)


def _kite(state: GameState, ctx: TurnContext, p: int) -> jax.Array:
    """Kiter's non-attack branch: move away from the closest enemy if it is in range, else toward."""
    q = 1 - p
    closest = closest_enemy(state, ctx, p)
    tx, ty = _enemy_pos(ctx, q, closest)
    toward, has_toward = move_toward(state, ctx, p, tx, ty)
    away, has_away = move_away(state, ctx, p, tx, ty)
    fallback = first_legal_action(ctx, p)
    in_range = in_own_range(state, ctx, p, closest)
    return jnp.where(
        in_range,
        jnp.where(has_away, away, fallback),
        jnp.where(has_toward, toward, fallback),
    ).astype(jnp.int32)


def _attack_mask(ctx: TurnContext, p: int) -> jax.Array:
    return ctx.in_range[p] & ctx.can_attack_now[p][:, None]


def _dpf_per_hp(state: GameState, q: int, hp: jax.Array) -> jax.Array:
    """float32 [.., M]: target dpf / target HP, in float like SparCraft (float / int)."""
    dpf = jnp.asarray(U.TABLES.dpf)[state.utype[q]]
    return dpf / jnp.maximum(hp, 1).astype(jnp.float32)


def _with_attack(
    target_choice: Callable[[GameState, TurnContext, int, jax.Array], jax.Array], otherwise
) -> Script:
    def script(key: jax.Array, state: GameState, ctx: TurnContext, p: int) -> jax.Array:
        del key
        mask = _attack_mask(ctx, p)
        target = target_choice(state, ctx, p, mask)
        return jnp.where(mask.any(axis=1), ATTACK_BASE + target, otherwise(state, ctx, p)).astype(
            jnp.int32
        )

    return script


def _target_closest(state: GameState, ctx: TurnContext, p: int, mask: jax.Array) -> jax.Array:
    return _select_min(mask, ctx.enemy_d2(p), ctx.order[1 - p])


def _target_weakest(state: GameState, ctx: TurnContext, p: int, mask: jax.Array) -> jax.Array:
    q = 1 - p
    return _select_min(mask, jnp.broadcast_to(state.hp[q][None, :], mask.shape), ctx.order[q])


def _target_dps(state: GameState, ctx: TurnContext, p: int, mask: jax.Array) -> jax.Array:
    q = 1 - p
    value = jnp.broadcast_to(_dpf_per_hp(state, q, state.hp[q])[None, :], mask.shape)
    return _select_max_float(mask, value, ctx.order[q])


attack_closest: Script = _with_attack(_target_closest, _approach_or_reload)
attack_weakest: Script = _with_attack(_target_weakest, _approach_or_reload)
attack_dps: Script = _with_attack(_target_dps, _approach_or_reload)
kiter: Script = _with_attack(_target_closest, _kite)
kiter_dps: Script = _with_attack(_target_dps, _kite)


def _nok_targets(state: GameState, ctx: TurnContext, p: int) -> tuple[jax.Array, jax.Array]:
    """NOKDPS's sequential no-overkill targeting: each acting unit in unit order picks the in-range
    enemy with remaining HP > 0 maximising dpf / remaining HP, then reserves its raw damage()."""
    q = 1 - p
    mask = _attack_mask(ctx, p)
    order = ctx.order[q]
    dpf = jnp.asarray(U.TABLES.dpf)[state.utype[q]]
    my_damage = jnp.asarray(U.TABLES.script_damage)[state.utype[p]]
    n = mask.shape[0]
    # Acting units share one free time, so SparCraft's unit order among them is slot (id) order.

    def body(hp_rem, u):
        cand = mask[u] & (hp_rem > 0) & ctx.acting[p][u]
        value = dpf / jnp.maximum(hp_rem, 1).astype(jnp.float32)
        j = _select_max_float(cand, value, order)
        found = cand.any()
        hp_rem = hp_rem.at[j].add(jnp.where(found, -my_damage[u], 0))
        return hp_rem, (j, found)

    _, (target, found) = jax.lax.scan(body, state.hp[q], jnp.arange(n))
    return target, found


def nokdps(key: jax.Array, state: GameState, ctx: TurnContext, p: int) -> jax.Array:
    del key
    target, found = _nok_targets(state, ctx, p)
    return jnp.where(found, ATTACK_BASE + target, _approach_or_reload(state, ctx, p)).astype(
        jnp.int32
    )


def kiter_nokdps(key: jax.Array, state: GameState, ctx: TurnContext, p: int) -> jax.Array:
    """NOKDPS targeting with kiting; in cooldown with the closest enemy in range the scan stops at
    RELOAD before any MOVE is scored, so it RELOADs instead of retreating (docs/engine.md#scripts)."""
    del key
    target, found = _nok_targets(state, ctx, p)
    closest = closest_enemy(state, ctx, p)
    in_range = in_own_range(state, ctx, p, closest)
    reload = ~ctx.can_attack_now[p] & in_range
    kite = _kite(state, ctx, p)
    return jnp.where(found, ATTACK_BASE + target, jnp.where(reload, RELOAD_ACTION, kite)).astype(
        jnp.int32
    )


def cluster(key: jax.Array, state: GameState, ctx: TurnContext, p: int) -> jax.Array:
    """Move toward the centroid of our living units' stored positions (float scale, truncated)."""
    del key
    alive = ctx.alive[p]
    n = jnp.maximum(jnp.sum(alive), 1)
    inv = jnp.float32(1.0) / n.astype(jnp.float32)
    sx = jnp.sum(jnp.where(alive, state.x[p], 0))
    sy = jnp.sum(jnp.where(alive, state.y[p], 0))
    cx = (inv * sx.astype(jnp.float32)).astype(jnp.int32)
    cy = (inv * sy.astype(jnp.float32)).astype(jnp.int32)
    size = state.x.shape[-1]
    toward, has_move = move_toward(state, ctx, p, jnp.full(size, cx), jnp.full(size, cy))
    return jnp.where(has_move, toward, first_legal_action(ctx, p)).astype(jnp.int32)


def random_script(key: jax.Array, state: GameState, ctx: TurnContext, p: int) -> jax.Array:
    """A uniformly random legal action per unit."""
    del state
    legal = legal_actions(ctx, p)
    logits = jnp.where(legal, 0.0, -jnp.inf)
    choice = jax.random.categorical(key, logits, axis=-1).astype(jnp.int32)
    return jnp.where(legal.any(axis=1), choice, first_legal_action(ctx, p)).astype(jnp.int32)


def attack_weakest_global(key: jax.Array, state: GameState, ctx: TurnContext, p: int) -> jax.Array:
    """The paper's "w" heuristic read without "in range": target the weakest living enemy overall
    (lowest HP, ties to the lowest id); attack it if in range and able to fire, RELOAD if in range
    but in cooldown, otherwise step toward it."""
    del key
    q = 1 - p
    alive = ctx.alive[q]
    slot = jnp.arange(alive.shape[0], dtype=jnp.int32)
    target = (
        jnp.min(jnp.where(alive, (state.hp[q] << SLOT_BITS) | slot, _BIG)) & SLOT_MASK
    ).astype(jnp.int32)
    size = state.x.shape[-1]
    targets = jnp.full(size, target)
    in_range = in_own_range(state, ctx, p, targets)
    tx, ty = _enemy_pos(ctx, q, targets)
    toward, has_move = move_toward(state, ctx, p, tx, ty)
    fallback = first_legal_action(ctx, p)
    return jnp.where(
        in_range & ctx.can_attack_now[p],
        ATTACK_BASE + targets,
        jnp.where(in_range, RELOAD_ACTION, jnp.where(has_move, toward, fallback)),
    ).astype(jnp.int32)


SCRIPTS: dict[str, Script] = {
    "attack-closest": attack_closest,
    "attack-weakest": attack_weakest,
    "attack-dps": attack_dps,
    "nokdps": nokdps,
    "kiter": kiter,
    "kiter-dps": kiter_dps,
    "kiter-nokdps": kiter_nokdps,
    "cluster": cluster,
    "random": random_script,
    "attack-weakest-global": attack_weakest_global,
}

#: SparCraft's own player names, accepted as aliases.
ALIASES: dict[str, str] = {
    "attackclosest": "attack-closest",
    "attackweakest": "attack-weakest",
    "attackdps": "attack-dps",
    "kiterdps": "kiter-dps",
    "kiter_nokdps": "kiter-nokdps",
    "kiternokdps": "kiter-nokdps",
    "attackweakestglobal": "attack-weakest-global",
}


def canonical_name(name: str) -> str:
    """Canonical script name for a user-given name (case-insensitive, SparCraft names accepted)."""
    key = name.strip().lower()
    if key in SCRIPTS:
        return key
    key2 = key.replace("_", "-")
    if key2 in SCRIPTS:
        return key2
    if key.replace("-", "").replace("_", "") in ALIASES:
        return ALIASES[key.replace("-", "").replace("_", "")]
    if key in ALIASES:
        return ALIASES[key]
    known = ", ".join(SCRIPTS)
    raise KeyError(f"unknown script {name!r} (known: {known})")


def get_script(name: str) -> Script:
    return SCRIPTS[canonical_name(name)]
