"""SparCraft's combat rules (DC-HEAD semantics) as pure JAX functions over ``GameState``.

One decision turn (docs/engine.md#turn-structure):

1. ``turn_context(state)``: who moves (the side(s) whose first unit in SparCraft's sort order has
   the smallest free time), which units act (the leading block: every living unit of a moving side
   whose free time equals that minimum), interpolated positions, distances, ranges and the legal
   actions. Both sides decide from this one context.
2. A policy (script, search or network) picks one action code per acting unit.
3. ``apply_actions(state, ctx, actions)``: P1's actions then P0's, damage applied at once, a unit
   killed earlier in the turn still acts, an attack on a target killed earlier in the turn becomes a
   PASS; then ``finishedMoving``: time jumps to the next minimum free time and the stalemate
   counter is updated.

Action codes, per unit: ``PASS=0, RELOAD=1, MOVE_LEFT=2, MOVE_RIGHT=3, MOVE_DOWN=4 (+y),
MOVE_UP=5 (-y), ATTACK(j)=6+j`` where ``j`` is the target's slot in the enemy row of the state.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct
from jax import lax

from hybridmarl.engine import units as U
from hybridmarl.engine.state import ATTACK, MOVE, PASS, RELOAD, WALK_TILE, GameState, Rules

PASS_ACTION, RELOAD_ACTION = 0, 1
MOVE_ACTIONS = (2, 3, 4, 5)
ATTACK_BASE = 6
#: SparCraft ``Constants::Move_Dir``: left, right, down (+y), up (-y) — also the tie-break order.
DIR_X = (-1, 1, 0, 0)
DIR_Y = (0, 0, 1, -1)

_INF = jnp.iinfo(jnp.int32).max
#: Selections are single min-reductions over packed int32 keys (value << bits | index), which
#: XLA's CPU backend vectorises far better than argmin's variadic reduce. Slots fit in 9 bits.
SLOT_BITS = 9
SLOT_MASK = (1 << SLOT_BITS) - 1
#: SparCraft's unit order packed as (free time - now) << 9 | slot. Free times of living units lie
#: within 34 frames of now for every supported unit (cooldown + move penalty), so 6 bits suffice.
ORDER_BITS = 6 + SLOT_BITS


def num_actions(num_slots: int) -> int:
    return ATTACK_BASE + num_slots


@struct.dataclass
class TurnContext:
    """Everything both sides' policies see at a decision turn (computed once per turn)."""

    time: jnp.ndarray  # int32 []
    alive: jnp.ndarray  # bool [2, U]
    cx: jnp.ndarray  # int32 [2, U] current positions (mid-move units interpolated)
    cy: jnp.ndarray  # int32 [2, U]
    movers: jnp.ndarray  # bool [2]
    acting: jnp.ndarray  # bool [2, U]
    order: jnp.ndarray  # int32 [2, U] SparCraft sort key (alive, free time, id); smaller = earlier
    d2: jnp.ndarray  # int32 [U, U] squared distance, P0 slot i to P1 slot j
    can_attack_now: jnp.ndarray  # bool [2, U]
    in_range: jnp.ndarray  # bool [2, U, U] [p, own slot, enemy slot]: enemy alive and in range
    move_dist: jnp.ndarray  # int32 [2, U] length of a move generated now
    move_ok: jnp.ndarray  # bool [2, U, 4] MOVE destination walkable (L, R, D, U)

    def enemy_d2(self, p: int) -> jnp.ndarray:
        """[own slot, enemy slot] squared distances for player ``p``."""
        return self.d2 if p == 0 else self.d2.T


def alive_mask(state: GameState) -> jnp.ndarray:
    return state.hp > 0


def free_time(state: GameState) -> jnp.ndarray:
    return jnp.minimum(state.t_move, state.t_attack)


def current_positions(state: GameState, t: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Positions at frame ``t`` (``Unit::currentPosition``): a unit in the middle of a MOVE is at
    prev + trunc((dest - prev) * ratio), ratio = float32((t - start) / duration)."""
    moving = (state.last == MOVE) & (t < state.t_move)
    at_start = (state.last == MOVE) & (t == state.t_act)
    duration = jnp.maximum(state.t_move - state.t_act, 1)
    ratio = (t - state.t_act).astype(jnp.float32) / duration.astype(jnp.float32)
    ix = state.px + ((state.x - state.px).astype(jnp.float32) * ratio).astype(jnp.int32)
    iy = state.py + ((state.y - state.py).astype(jnp.float32) * ratio).astype(jnp.int32)
    cx = jnp.where(at_start, state.px, jnp.where(moving, ix, state.x))
    cy = jnp.where(at_start, state.py, jnp.where(moving, iy, state.y))
    return cx, cy


def walkable_at(walkable: jnp.ndarray, x: jnp.ndarray, y: jnp.ndarray) -> jnp.ndarray:
    """Walkability of pixel destinations; C truncating division, off-map tiles are not walkable."""
    tx = lax.div(x, jnp.int32(WALK_TILE))
    ty = lax.div(y, jnp.int32(WALK_TILE))
    h, w = walkable.shape
    inside = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
    return inside & walkable[jnp.clip(ty, 0, h - 1), jnp.clip(tx, 0, w - 1)]


def player_minimum_free_time(state: GameState) -> jnp.ndarray:
    """int32 [2]: each side's smallest free time over living units (INT_MAX for an empty side)."""
    return jnp.min(jnp.where(alive_mask(state), free_time(state), _INF), axis=1)


def order_keys(state: GameState, alive: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
    """SparCraft's unit order (alive first, then free time, then id) as one int32 key per unit;
    within a player, slot order is id order. Dead units get INT_MAX."""
    rel = jnp.clip(free_time(state) - t, 0, (1 << (ORDER_BITS - SLOT_BITS)) - 1)
    slot = jnp.arange(state.hp.shape[-1], dtype=jnp.int32)
    return jnp.where(alive, (rel << SLOT_BITS) | slot, _INF)


def first_in_order(mask: jnp.ndarray, order: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(slot, found) of the candidate (mask [..., M]) that comes first in ``order`` ([M])."""
    k = jnp.min(jnp.where(mask, order, _INF), axis=-1)
    return (k & SLOT_MASK).astype(jnp.int32), k < _INF


def turn_context(state: GameState, rules: Rules) -> TurnContext:
    t = state.time
    alive = alive_mask(state)
    cx, cy = current_positions(state, t)
    pmin = player_minimum_free_time(state)
    movers = jnp.stack([pmin[0] <= pmin[1], pmin[1] <= pmin[0]]) & (pmin < _INF)
    acting = alive & movers[:, None] & (free_time(state) == pmin[:, None])

    dx = cx[0][:, None] - cx[1][None, :]
    dy = cy[0][:, None] - cy[1][None, :]
    d2 = dx * dx + dy * dy
    range_sq = jnp.asarray(U.TABLES.range_sq)[state.utype]
    in_range = jnp.stack(
        [
            (range_sq[0][:, None] >= d2) & alive[1][None, :],
            (range_sq[1][:, None] >= d2.T) & alive[0][None, :],
        ]
    )
    can_attack_now = state.t_attack <= state.t_move

    t_atk = jnp.clip(state.t_attack - t, 0, U.MAX_T_ATK)
    move_dist = jnp.asarray(U.TABLES.move_dist)[state.utype, t_atk]
    dest_x = state.x[..., None] + move_dist[..., None] * jnp.asarray(DIR_X, jnp.int32)
    dest_y = state.y[..., None] + move_dist[..., None] * jnp.asarray(DIR_Y, jnp.int32)
    move_ok = walkable_at(rules.walkable, dest_x, dest_y)

    return TurnContext(
        time=t,
        alive=alive,
        cx=cx,
        cy=cy,
        movers=movers,
        acting=acting,
        order=order_keys(state, alive, t),
        d2=d2,
        can_attack_now=can_attack_now,
        in_range=in_range,
        move_dist=move_dist,
        move_ok=move_ok,
    )


def legal_actions(ctx: TurnContext, p: int) -> jnp.ndarray:
    """bool [U, 6 + U]: SparCraft's legal actions (``GameState::generateMoves``) for player ``p``.

    ATTACK per living enemy in range if the unit can attack now, else RELOAD; MOVE in each
    direction whose destination is walkable; PASS only if nothing else. Non-acting units: none.
    """
    can_atk = ctx.can_attack_now[p]
    attacks = ctx.in_range[p] & can_atk[:, None]
    reload = ~can_atk
    moves = ctx.move_ok[p]
    anything = attacks.any(axis=1) | reload | moves.any(axis=1)
    mask = jnp.concatenate([(~anything)[:, None], reload[:, None], moves, attacks], axis=1)
    return mask & ctx.acting[p][:, None]


def first_legal_action(ctx: TurnContext, p: int) -> jnp.ndarray:
    """int32 [U]: the first action of SparCraft's legal-action list (scripts' fallback index 0):
    the first attack in enemy order, else RELOAD, else the first walkable move, else PASS."""
    q = 1 - p
    attacks = ctx.in_range[p] & ctx.can_attack_now[p][:, None]
    first_target, any_attack = first_in_order(attacks, ctx.order[q][None, :])
    moves = ctx.move_ok[p]
    first_move = (
        jnp.min(jnp.where(moves, jnp.arange(4, dtype=jnp.int32), 4), axis=1) + MOVE_ACTIONS[0]
    )
    return jnp.where(
        any_attack,
        ATTACK_BASE + first_target,
        jnp.where(
            ~ctx.can_attack_now[p],
            RELOAD_ACTION,
            jnp.where(moves.any(axis=1), first_move, PASS_ACTION),
        ),
    ).astype(jnp.int32)


def _apply_player(
    state: GameState, ctx: TurnContext, p: int, actions: jnp.ndarray, rules: Rules
) -> tuple[dict[str, jnp.ndarray], jnp.ndarray]:
    """New per-unit fields of player ``p`` after its actions, and the damage it deals per enemy slot."""
    q = 1 - p
    t = ctx.time
    n = state.hp.shape[-1]
    acting = ctx.acting[p]
    code = actions.astype(jnp.int32)
    is_attack = acting & (code >= ATTACK_BASE)
    is_move = acting & (code >= MOVE_ACTIONS[0]) & (code <= MOVE_ACTIONS[-1])
    is_reload = acting & (code == RELOAD_ACTION)
    is_pass = acting & (code == PASS_ACTION)
    target = jnp.clip(code - ATTACK_BASE, 0, n - 1)

    # Damage: attacks of one side are applied in unit order; an attack deals damage only if its
    # target is still alive when it executes (damage before it on the same target < target HP).
    utype = state.utype[p]
    dmg = jnp.asarray(U.TABLES.damage)[utype, state.utype[q][target]]
    uid = state.uid[p]
    earlier_same_target = (
        (target[:, None] == target[None, :]) & is_attack[None, :] & (uid[None, :] < uid[:, None])
    )
    prior = jnp.sum(jnp.where(earlier_same_target, dmg[None, :], 0), axis=1)
    effective = is_attack & (state.hp[q][target] - prior > 0)
    hits = (target[:, None] == jnp.arange(n)[None, :]) & effective[:, None]
    damage_to_enemy = jnp.sum(jnp.where(hits, dmg[:, None], 0), axis=0)

    if rules.overkill == "pass":  # DC-HEAD: the attacker does a PASS instead
        attack_timing = effective
        as_pass = is_pass | (is_attack & ~effective)
    else:  # DC-CLASSIC: cooldown consumed, no damage
        attack_timing = is_attack
        as_pass = is_pass

    tm, ta = state.t_move[p], state.t_attack[p]
    last = state.last[p]
    cooldown = jnp.asarray(U.TABLES.cooldown)[utype]
    first = jnp.asarray(U.TABLES.anim_first)[utype]
    repeat = jnp.asarray(U.TABLES.anim_repeat)[utype]
    is_repeat = (last == ATTACK) | (last == RELOAD)
    after_move = last == MOVE
    atk_tm = jnp.where(is_repeat, t + repeat, t + first + 2)
    atk_ta = t + cooldown + jnp.where(after_move & ~is_repeat, U.MOVE_PENALTY, 0)

    d = jnp.clip(code - MOVE_ACTIONS[0], 0, 3)
    dist = ctx.move_dist[p]
    dest_x = state.x[p] + dist * jnp.asarray(DIR_X, jnp.int32)[d]
    dest_y = state.y[p] + dist * jnp.asarray(DIR_Y, jnp.int32)[d]
    t_atk = jnp.clip(ta - t, 0, U.MAX_T_ATK)
    duration = jnp.asarray(U.TABLES.move_dur)[utype, t_atk]
    mv_tm = t + duration
    mv_ta = jnp.maximum(ta, mv_tm)

    new_tm = jnp.where(
        attack_timing,
        atk_tm,
        jnp.where(
            is_move, mv_tm, jnp.where(is_reload, ta, jnp.where(as_pass, t + U.PASS_DURATION, tm))
        ),
    )
    new_ta = jnp.where(
        attack_timing,
        atk_ta,
        jnp.where(is_move, mv_ta, jnp.where(as_pass, t + U.PASS_DURATION, ta)),
    )
    # An overkill PASS keeps the ATTACK as the unit's previous action (HEAD calls Unit::pass with
    # the attack action), so the unit's next shot is timed as a repeat shot (reference traces).
    new_last = jnp.where(
        attack_timing | is_attack,
        ATTACK,
        jnp.where(is_move, MOVE, jnp.where(is_reload, RELOAD, jnp.where(as_pass, PASS, last))),
    )
    fields = {
        "x": jnp.where(is_move, dest_x, state.x[p]),
        "y": jnp.where(is_move, dest_y, state.y[p]),
        "px": jnp.where(is_move, state.x[p], state.px[p]),
        "py": jnp.where(is_move, state.y[p], state.py[p]),
        "t_act": jnp.where(acting, t, state.t_act[p]),
        "last": new_last.astype(jnp.int32),
        "t_move": new_tm.astype(jnp.int32),
        "t_attack": new_ta.astype(jnp.int32),
    }
    return fields, damage_to_enemy


def apply_actions(
    state: GameState, ctx: TurnContext, actions: jnp.ndarray, rules: Rules
) -> GameState:
    """Play one decision turn: apply ``actions`` (int32 [2, U]; only acting units' entries are read)
    and advance time (``GameState::makeMoves`` for P1 then P0, then ``finishedMoving``)."""
    f0, dmg_to_1 = _apply_player(state, ctx, 0, actions[0], rules)
    f1, dmg_to_0 = _apply_player(state, ctx, 1, actions[1], rules)
    hp = jnp.maximum(state.hp - jnp.stack([dmg_to_0, dmg_to_1]), 0)
    new = dataclasses.replace(
        state,
        **{k: jnp.stack([f0[k], f1[k]]) for k in f0},
        hp=hp,
    )
    return finish_turn(new, rules)


def finish_turn(state: GameState, rules: Rules) -> GameState:
    """``GameState::finishedMoving``: next decision time, turn count and stalemate counter.

    A side with no living unit never moves; with no living unit at all the time stays put.
    """
    del rules
    pmin = player_minimum_free_time(state)
    nxt = jnp.min(pmin)
    time = jnp.where(nxt < _INF, nxt, state.time)
    hp_sum = jnp.sum(jnp.where(state.hp > 0, state.hp, 0), axis=1).astype(jnp.int32)
    same = jnp.all(hp_sum == state.prev_hp_sum)
    return dataclasses.replace(
        state,
        time=time.astype(jnp.int32),
        turn=state.turn + 1,
        stale=jnp.where(same, state.stale + 1, 0).astype(jnp.int32),
        prev_hp_sum=hp_sum,
    )


def player_dead(state: GameState) -> jnp.ndarray:
    """bool [2]: a side is dead with no living unit that can deal damage (``playerDead``)."""
    can_hurt = (state.hp > 0) & (jnp.asarray(U.TABLES.script_damage)[state.utype] > 0)
    return ~can_hurt.any(axis=1)


def is_terminal(state: GameState, rules: Rules) -> jnp.ndarray:
    """Game over: a side dead, or more than ``stalemate_limit`` turns with no HP change.

    (SparCraft's third condition, every unit immobile and nobody in range, cannot hold for the
    supported unit types, which are all mobile attackers.)
    """
    return player_dead(state).any() | (state.stale > rules.stalemate_limit)


def game_over(state: GameState, rules: Rules) -> jnp.ndarray:
    """Terminal, or the turn cap reached (``Game::play``)."""
    return is_terminal(state, rules) | (state.turn >= rules.max_turns)


def ltd(state: GameState) -> jnp.ndarray:
    """float/int32 [2]: LTD per player, int(1000 * sum_alive hp*dpf / sum maxHP*dpf)."""
    dpf = jnp.asarray(U.TABLES.dpf)[state.utype]
    alive = state.hp > 0
    s = jnp.sum(jnp.where(alive, state.hp.astype(jnp.float32) * dpf, 0.0), axis=1)
    val = (1000.0 * s / jnp.where(state.ltd_total > 0, state.ltd_total, 1.0)).astype(jnp.int32)
    return jnp.where(alive.any(axis=1) & (state.ltd_total > 0), val, 0)


def ltd2(state: GameState) -> jnp.ndarray:
    """int32 [2]: LTD2 per player, int(1000 * sum_alive sqrt(hp)*dpf / sum sqrt(maxHP)*dpf)."""
    dpf = jnp.asarray(U.TABLES.dpf)[state.utype]
    alive = state.hp > 0
    s = jnp.sum(jnp.where(alive, jnp.sqrt(state.hp.astype(jnp.float32)) * dpf, 0.0), axis=1)
    val = (1000.0 * s / jnp.where(state.ltd2_total > 0, state.ltd2_total, 1.0)).astype(jnp.int32)
    return jnp.where(alive.any(axis=1) & (state.ltd2_total > 0), val, 0)


def evaluate(state: GameState, p: int, method: str = "ltd2") -> jnp.ndarray:
    """``GameState::eval(p, LTD|LTD2)``: score difference plus +-100000 if exactly one side is dead
    (0 if both are)."""
    score = ltd2(state) if method == "ltd2" else ltd(state)
    dead = player_dead(state)
    value = score[p] - score[1 - p]
    bonus = jnp.where(dead[1 - p] & ~dead[p], 100000, jnp.where(dead[p] & ~dead[1 - p], -100000, 0))
    return jnp.where(dead.all(), 0, value + bonus).astype(jnp.int32)


def winner(state: GameState) -> jnp.ndarray:
    """int32: 0 or 1 if that side has survivors and the other has none, -1 otherwise (draw)."""
    dead = player_dead(state)
    return jnp.where(dead[1] & ~dead[0], 0, jnp.where(dead[0] & ~dead[1], 1, -1)).astype(jnp.int32)


def hp_sums(state: GameState) -> jnp.ndarray:
    return jnp.sum(jnp.maximum(state.hp, 0), axis=1)


__all__ = [
    "ATTACK_BASE",
    "MOVE_ACTIONS",
    "PASS_ACTION",
    "RELOAD_ACTION",
    "TurnContext",
    "apply_actions",
    "evaluate",
    "first_legal_action",
    "game_over",
    "is_terminal",
    "legal_actions",
    "ltd",
    "ltd2",
    "turn_context",
    "winner",
    "jax",
]
