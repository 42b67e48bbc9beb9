"""Numba kernels of the native engine: SparCraft turn resolution and the scripted players.

Everything here mirrors ``engine.rules`` and ``engine.scripts`` operation by operation (same
packed sort keys, same float32 arithmetic, same fallbacks), so a game played here ends exactly
as the JAX engine ends it. The state is NumPy structure-of-arrays: eleven int32 per-unit fields
of shape ``[B, 2, U]`` in ``FIELDS`` order, plus ``time``/``turn``/``stale`` (int32 ``[B]``) and
``prev_hp_sum`` (int32 ``[B, 2]``). Kernels update the arrays in place.

Per turn the kernels only compute what an acting unit needs (its moves, its targets), instead of
the full ``[U, U]`` matrices the array program builds: the results are the same values.

Script codes (``SCRIPT_CODES``) select a player at run time, so one compiled program serves every
pair of scripts and both overkill modes.
"""

# The kernels keep explicit loops and == chains: Numba compiles them to plain branches, while
# generator expressions (all/any) and tuple membership are slower or unsupported in nopython code.
# ruff: noqa: SIM102, SIM109, SIM110

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, prange

from hybridmarl.engine import units as U

# Field order of the per-unit arrays (the GameState fields of shape [2, U]).
FIELDS = ("utype", "uid", "x", "y", "px", "py", "t_act", "last", "hp", "t_move", "t_attack")

# Previous-action kinds (engine.state) and action codes (engine.rules).
LAST_ATTACK, LAST_RELOAD, LAST_MOVE, LAST_PASS = 1, 2, 3, 4
PASS_ACTION, RELOAD_ACTION, MOVE_BASE, ATTACK_BASE = 0, 1, 2, 6

INF = 2147483647  # int32 max: the JAX engine's "no candidate" key
SLOT_BITS = 9
SLOT_MASK = (1 << SLOT_BITS) - 1
ORDER_BITS = 6 + SLOT_BITS
ORDER_REL_MAX = (1 << (ORDER_BITS - SLOT_BITS)) - 1
CLOSEST_LIMIT = 1_000_000
WALK_TILE = 8
MAX_T_ATK = U.MAX_T_ATK
MOVE_PENALTY = U.MOVE_PENALTY
PASS_DURATION = U.PASS_DURATION

DIR_X = np.array([-1, 1, 0, 0], np.int64)
DIR_Y = np.array([0, 0, 1, -1], np.int64)

MAX_HP = U.TABLES.max_hp.astype(np.int64)
RANGE_SQ = U.TABLES.range_sq.astype(np.int64)
COOLDOWN = U.TABLES.cooldown.astype(np.int64)
ANIM_FIRST = U.TABLES.anim_first.astype(np.int64)
ANIM_REPEAT = U.TABLES.anim_repeat.astype(np.int64)
SCRIPT_DAMAGE = U.TABLES.script_damage.astype(np.int64)
DPF = U.TABLES.dpf.astype(np.float32)
DAMAGE = U.TABLES.damage.astype(np.int64)
MOVE_DIST = U.TABLES.move_dist.astype(np.int64)
MOVE_DUR = U.TABLES.move_dur.astype(np.int64)

# Scripted players, by run-time code.
ATTACK_CLOSEST, ATTACK_WEAKEST, ATTACK_DPS, NOKDPS = 0, 1, 2, 3
KITER, KITER_DPS, KITER_NOKDPS, CLUSTER, RANDOM, ATTACK_WEAKEST_GLOBAL = 4, 5, 6, 7, 8, 9
SCRIPT_CODES = {
    "attack-closest": ATTACK_CLOSEST,
    "attack-weakest": ATTACK_WEAKEST,
    "attack-dps": ATTACK_DPS,
    "nokdps": NOKDPS,
    "kiter": KITER,
    "kiter-dps": KITER_DPS,
    "kiter-nokdps": KITER_NOKDPS,
    "cluster": CLUSTER,
    "random": RANDOM,
    "attack-weakest-global": ATTACK_WEAKEST_GLOBAL,
}
#: Placeholder script code for a side whose actions come from the caller (search, networks).
EXTERNAL = -1


def njit_without_refcount(fn: Any) -> Any:
    """``njit(cache=True)`` for a kernel that allocates nothing, compiled without Numba's
    reference counting (its NRT is off: ``_nrt=False``). With it, every array passed down a
    turn loop costs an atomic increment and decrement, and those took about 80 % of a playout's
    or Alg. 1 simulation's time. Such a kernel may take and index arrays and views of them, but
    not create arrays (no ``np.empty``, no slice assignment; Numba refuses to compile those)."""
    options: dict[str, Any] = {"cache": True, "_nrt": False}
    return njit(**options)(fn)


# ----------------------------------------------------------------------------- workspace


@njit(cache=True)
def make_workspace(n):
    """Per-thread scratch for one game of ``n`` slots (reused from game to game)."""
    return (
        np.zeros((2, n), np.int64),  # 0 cx: current (interpolated) x
        np.zeros((2, n), np.int64),  # 1 cy
        np.zeros((2, n), np.int64),  # 2 order: SparCraft sort key, INF for dead units
        np.zeros((2, n), np.int64),  # 3 move_dist of a move generated now
        np.zeros((2, n), np.int64),  # 4 actions chosen this turn
        np.zeros((2, n), np.bool_),  # 5 alive
        np.zeros((2, n), np.bool_),  # 6 acting
        np.zeros((2, n), np.bool_),  # 7 can_attack_now
        np.zeros((2, n, 4), np.bool_),  # 8 move_ok (L, R, D, U)
        np.zeros(n, np.int64),  # 9 NOKDPS remaining HP
        np.zeros(n, np.int64),  # 10 NOKDPS target per unit (-1: none)
        np.zeros((2, n), np.int64),  # 11 damage taken this turn
        np.zeros(2, np.bool_),  # 12 movers
    )


# ----------------------------------------------------------------------------- helpers


@njit(cache=True, inline="always")
def _trunc_div(a, b):
    """C integer division (truncates toward zero), as SparCraft's and lax.div's."""
    if a >= 0:
        return a // b
    return -((-a) // b)


@njit(cache=True, inline="always")
def _walkable(walkable, x, y):
    tx = _trunc_div(x, WALK_TILE)
    ty = _trunc_div(y, WALK_TILE)
    h, w = walkable.shape
    return 0 <= tx < w and 0 <= ty < h and walkable[ty, tx]


@njit(cache=True, inline="always")
def _clip(v, lo, hi):
    return lo if v < lo else (hi if v > hi else v)


@njit(cache=True, inline="always")
def minimum_free_time(hp, t_move, t_attack, p):
    """A side's smallest free time over living units (INF with none alive)."""
    best = INF
    for s in range(hp.shape[1]):
        if hp[p, s] > 0:
            ft = min(t_move[p, s], t_attack[p, s])
            if ft < best:
                best = ft
    return best


# ----------------------------------------------------------------------------- turn context


@njit(cache=True, inline="always")
def prepare_turn(t, utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws):
    """``rules.turn_context``: movers, acting units, current positions, order keys, and the move
    lengths / walkable directions / attack readiness of the acting units. Returns the count of
    acting units."""
    cx, cy, order, mdist = ws[0], ws[1], ws[2], ws[3]
    alive, acting, can_atk, move_ok, movers = ws[5], ws[6], ws[7], ws[8], ws[12]
    n = hp.shape[1]
    pmin0 = minimum_free_time(hp, t_move, t_attack, 0)
    pmin1 = minimum_free_time(hp, t_move, t_attack, 1)
    movers[0] = pmin0 <= pmin1 and pmin0 < INF
    movers[1] = pmin1 <= pmin0 and pmin1 < INF
    n_acting = 0
    for p in range(2):
        pmin = pmin0 if p == 0 else pmin1
        for s in range(n):
            a = hp[p, s] > 0
            alive[p, s] = a
            if last[p, s] == LAST_MOVE and t == t_act[p, s]:
                cx[p, s] = px[p, s]
                cy[p, s] = py[p, s]
            elif last[p, s] == LAST_MOVE and t < t_move[p, s]:
                duration = max(t_move[p, s] - t_act[p, s], 1)
                ratio = np.float32(t - t_act[p, s]) / np.float32(duration)
                cx[p, s] = px[p, s] + int(np.float32(x[p, s] - px[p, s]) * ratio)
                cy[p, s] = py[p, s] + int(np.float32(y[p, s] - py[p, s]) * ratio)
            else:
                cx[p, s] = x[p, s]
                cy[p, s] = y[p, s]
            ft = min(t_move[p, s], t_attack[p, s])
            if a:
                order[p, s] = (_clip(ft - t, 0, ORDER_REL_MAX) << SLOT_BITS) | s
            else:
                order[p, s] = INF
            act = a and movers[p] and ft == pmin
            acting[p, s] = act
            if act:
                n_acting += 1
                can_atk[p, s] = t_attack[p, s] <= t_move[p, s]
                ut = utype[p, s]
                md = MOVE_DIST[ut, _clip(t_attack[p, s] - t, 0, MAX_T_ATK)]
                mdist[p, s] = md
                for d in range(4):
                    move_ok[p, s, d] = _walkable(
                        walkable, x[p, s] + md * DIR_X[d], y[p, s] + md * DIR_Y[d]
                    )
    return n_acting


@njit(cache=True, inline="always")
def _d2(cx, cy, p, u, j):
    """Squared distance from player p's unit u to its enemy j (current positions)."""
    q = 1 - p
    dx = cx[p, u] - cx[q, j]
    dy = cy[p, u] - cy[q, j]
    return dx * dx + dy * dy


@njit(cache=True, inline="always")
def first_legal_action(p, u, utype, ws):
    """The first entry of SparCraft's legal-action list: first attack in enemy order, else
    RELOAD, else the first walkable move, else PASS."""
    cx, cy, order = ws[0], ws[1], ws[2]
    alive, can_atk, move_ok = ws[5], ws[7], ws[8]
    q = 1 - p
    n = alive.shape[1]
    if can_atk[p, u]:
        rsq = RANGE_SQ[utype[p, u]]
        best = INF
        for j in range(n):
            if alive[q, j] and rsq >= _d2(cx, cy, p, u, j) and order[q, j] < best:
                best = order[q, j]
        if best < INF:
            return ATTACK_BASE + (best & SLOT_MASK)
    else:
        return RELOAD_ACTION
    for d in range(4):
        if move_ok[p, u, d]:
            return MOVE_BASE + d
    return PASS_ACTION


@njit(cache=True, inline="always")
def closest_enemy(p, u, ws):
    """``getClosestEnemyUnit``: smallest squared distance within 1000 px, ties to the lower slot;
    with none that close, the first enemy in unit order (clamped like an XLA gather)."""
    cx, cy, order, alive = ws[0], ws[1], ws[2], ws[5]
    q = 1 - p
    n = alive.shape[1]
    best = INF
    for j in range(n):
        if alive[q, j]:
            d = _d2(cx, cy, p, u, j)
            if d <= CLOSEST_LIMIT:
                k = (d << SLOT_BITS) | j
                if k < best:
                    best = k
    if best < INF:
        return best & SLOT_MASK
    first = INF
    for j in range(n):
        if order[q, j] < first:
            first = order[q, j]
    return min(first & SLOT_MASK, n - 1)


@njit(cache=True, inline="always")
def _in_own_range(p, u, j, utype, ws):
    return RANGE_SQ[utype[p, u]] >= _d2(ws[0], ws[1], p, u, j)


@njit(cache=True, inline="always")
def best_move(away, p, u, tx, ty, x, y, move_ok):
    """(action code, found) of the walkable MOVE whose unit step from the stored position is
    closest to (tx, ty), ties to the first of left, right, down, up; with ``away`` the furthest
    (first maximum), found only with a strictly positive score."""
    best = -1 if away else INF
    for d in range(4):
        if move_ok[p, u, d]:
            dx = x[p, u] + DIR_X[d] - tx
            dy = y[p, u] + DIR_Y[d] - ty
            score = (dx * dx + dy * dy) << 2
            if away:
                k = score | (3 - d)
                if k > best:
                    best = k
            else:
                k = score | d
                if k < best:
                    best = k
    if away:
        return MOVE_BASE + (3 - (best & 3)), (best >> 2) > 0
    return MOVE_BASE + (best & 3), best < INF


@njit(cache=True, inline="always")
def _attack_target(kind, p, u, utype, hp, ws):
    """Attack target of an Attack*/Kiter* script (-1 if the unit cannot attack anyone now).
    kind 0: closest, 1: weakest (lowest HP), 2: highest dpf / HP; ties to the enemy order."""
    cx, cy, order, alive, can_atk = ws[0], ws[1], ws[2], ws[5], ws[7]
    if not can_atk[p, u]:
        return -1
    q = 1 - p
    n = alive.shape[1]
    rsq = RANGE_SQ[utype[p, u]]
    best_key = INF
    best_val = np.float32(-1.0)
    best_j = -1
    for j in range(n):
        if not alive[q, j]:
            continue
        d = _d2(cx, cy, p, u, j)
        if rsq < d:
            continue
        if kind == 2:
            v = DPF[utype[q, j]] / np.float32(max(hp[q, j], 1))
            if v > best_val or (v == best_val and order[q, j] < order[q, best_j]):
                best_val = v
                best_j = j
        else:
            score = d if kind == 0 else hp[q, j]
            k = (score << ORDER_BITS) | order[q, j]
            if k < best_key:
                best_key = k
                best_j = j
    return best_j


@njit(cache=True, inline="always")
def _nok_targets(p, utype, hp, ws):
    """NOKDPS's sequential no-overkill targeting over the acting units in slot (= id) order:
    each picks the in-range enemy with HP left maximising dpf / HP left, then reserves its damage."""
    order, alive, acting, can_atk = ws[2], ws[5], ws[6], ws[7]
    hp_rem, target = ws[9], ws[10]
    q = 1 - p
    n = alive.shape[1]
    for j in range(n):
        hp_rem[j] = hp[q, j]
    for u in range(n):
        target[u] = -1
        if not (acting[p, u] and can_atk[p, u]):
            continue
        rsq = RANGE_SQ[utype[p, u]]
        best_val = np.float32(-1.0)
        best_j = -1
        for j in range(n):
            if not alive[q, j] or hp_rem[j] <= 0 or rsq < _d2(ws[0], ws[1], p, u, j):
                continue
            v = DPF[utype[q, j]] / np.float32(max(hp_rem[j], 1))
            if v > best_val or (v == best_val and order[q, j] < order[q, best_j]):
                best_val = v
                best_j = j
        if best_j >= 0:
            target[u] = best_j
            hp_rem[best_j] -= SCRIPT_DAMAGE[utype[p, u]]


@njit(cache=True, inline="always")
def _mix(h):
    """splitmix64 finaliser (the native random script's counter-based generator)."""
    h = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    h = (h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return h ^ (h >> np.uint64(31))


@njit(cache=True, inline="always")
def _random_action(p, u, utype, draw, ws):
    """A uniformly random legal action, drawn from the 64-bit value ``draw``."""
    cx, cy, alive, can_atk, move_ok = ws[0], ws[1], ws[5], ws[7], ws[8]
    q = 1 - p
    n = alive.shape[1]
    count = 0
    if can_atk[p, u]:
        rsq = RANGE_SQ[utype[p, u]]
        for j in range(n):
            if alive[q, j] and rsq >= _d2(cx, cy, p, u, j):
                count += 1
    else:
        count += 1
    for d in range(4):
        if move_ok[p, u, d]:
            count += 1
    if count == 0:
        return PASS_ACTION
    pick = np.int64(draw % np.uint64(count))
    if not can_atk[p, u]:
        if pick == 0:
            return RELOAD_ACTION
        pick -= 1
    for d in range(4):
        if move_ok[p, u, d]:
            if pick == 0:
                return MOVE_BASE + d
            pick -= 1
    rsq = RANGE_SQ[utype[p, u]]
    for j in range(n):
        if alive[q, j] and rsq >= _d2(cx, cy, p, u, j):
            if pick == 0:
                return ATTACK_BASE + j
            pick -= 1
    return PASS_ACTION


@njit(cache=True, inline="always")
def choose_actions(script, p, utype, x, y, hp, rng_base, ws):
    """Fill ``ws`` actions row ``p`` with the script's action for every acting unit."""
    cx, cy, alive, acting, can_atk = ws[0], ws[1], ws[5], ws[6], ws[7]
    actions, nok = ws[4], ws[10]
    q = 1 - p
    n = alive.shape[1]
    if script == NOKDPS or script == KITER_NOKDPS:
        _nok_targets(p, utype, hp, ws)
    cluster_x = 0
    cluster_y = 0
    if script == CLUSTER:
        count = 0
        sx = 0
        sy = 0
        for s in range(n):
            if alive[p, s]:
                count += 1
                sx += x[p, s]
                sy += y[p, s]
        inv = np.float32(1.0) / np.float32(max(count, 1))
        cluster_x = int(inv * np.float32(sx))
        cluster_y = int(inv * np.float32(sy))
    weakest = 0
    if script == ATTACK_WEAKEST_GLOBAL:
        best = INF
        for j in range(n):
            if alive[q, j]:
                k = (hp[q, j] << SLOT_BITS) | j
                if k < best:
                    best = k
        weakest = min(best & SLOT_MASK, n - 1)
    attack_family = script <= ATTACK_DPS or script == KITER or script == KITER_DPS
    kind = (
        0
        if (script == ATTACK_CLOSEST or script == KITER)
        else (1 if script == ATTACK_WEAKEST else 2)
    )
    kites = script == KITER or script == KITER_DPS or script == KITER_NOKDPS
    # Each helper has one call site below, so inlining them all keeps the kernel small.
    for u in range(n):
        if not acting[p, u]:
            actions[p, u] = PASS_ACTION
            continue
        a = -1
        if attack_family:
            j = _attack_target(kind, p, u, utype, hp, ws)
            if j >= 0:
                a = ATTACK_BASE + j
        elif script == NOKDPS or script == KITER_NOKDPS:
            if nok[u] >= 0:
                a = ATTACK_BASE + nok[u]
        elif script == RANDOM:
            draw = _mix(rng_base + np.uint64(p * 1024 + u + 1) * np.uint64(0x9E3779B97F4A7C15))
            a = _random_action(p, u, utype, draw, ws)
        if a >= 0:
            actions[p, u] = a
            continue
        # No attack: RELOAD, or a move toward (or, kiting, away from) a point, else the first
        # legal action.
        away = False
        if script == CLUSTER:
            tx, ty = cluster_x, cluster_y
        else:
            c = weakest if script == ATTACK_WEAKEST_GLOBAL else closest_enemy(p, u, ws)
            in_range = _in_own_range(p, u, c, utype, ws)
            tx, ty = cx[q, c], cy[q, c]
            if script == ATTACK_WEAKEST_GLOBAL:
                if in_range:
                    a = ATTACK_BASE + c if can_atk[p, u] else RELOAD_ACTION
            elif kites:
                if script == KITER_NOKDPS and in_range and not can_atk[p, u]:
                    a = RELOAD_ACTION
                away = in_range
            elif in_range and not can_atk[p, u]:
                a = RELOAD_ACTION
        if a < 0:
            code, found = best_move(away, p, u, tx, ty, x, y, ws[8])
            a = code if found else first_legal_action(p, u, utype, ws)
        actions[p, u] = a


# ----------------------------------------------------------------------------- applying a turn


@njit(cache=True, inline="always")
def _apply_player(
    p, t, utype, uid, x, y, px, py, t_act, last, hp, t_move, t_attack, overkill_pass, ws
):
    """``GameState::makeMoves`` for one side: timers, moves, and the damage it deals (added to
    ws damage-taken of the enemy; HP changes wait until both sides have acted)."""
    mdist, actions, acting, damage_taken = ws[3], ws[4], ws[6], ws[11]
    q = 1 - p
    n = hp.shape[1]
    for u in range(n):
        if not acting[p, u]:
            continue
        code = actions[p, u]
        is_attack = code >= ATTACK_BASE
        is_move = MOVE_BASE <= code < ATTACK_BASE
        is_reload = code == RELOAD_ACTION
        is_pass = code == PASS_ACTION
        ut = utype[p, u]
        effective = False
        if is_attack:
            j = _clip(code - ATTACK_BASE, 0, n - 1)
            dmg = DAMAGE[ut, utype[q, j]]
            # Attacks apply in unit (id) order: damage of earlier attacks on the same target,
            # whether or not they landed, counts against the target's HP at the turn's start.
            prior = 0
            for v in range(n):
                cv = actions[p, v]
                if acting[p, v] and cv >= ATTACK_BASE and uid[p, v] < uid[p, u]:
                    if _clip(cv - ATTACK_BASE, 0, n - 1) == j:
                        prior += DAMAGE[utype[p, v], utype[q, j]]
            effective = hp[q, j] - prior > 0
            if effective:
                damage_taken[q, j] += dmg
        attack_timing = effective if overkill_pass else is_attack
        as_pass = is_pass or (overkill_pass and is_attack and not effective)
        tm = t_move[p, u]
        ta = t_attack[p, u]
        prev = last[p, u]
        if attack_timing:
            is_repeat = prev == LAST_ATTACK or prev == LAST_RELOAD
            new_tm = t + ANIM_REPEAT[ut] if is_repeat else t + ANIM_FIRST[ut] + 2
            penalty = MOVE_PENALTY if (prev == LAST_MOVE and not is_repeat) else 0
            new_ta = t + COOLDOWN[ut] + penalty
        elif is_move:
            dur = MOVE_DUR[ut, _clip(ta - t, 0, MAX_T_ATK)]
            new_tm = t + dur
            new_ta = max(ta, new_tm)
        elif is_reload:
            new_tm = ta
            new_ta = ta
        elif as_pass:
            new_tm = t + PASS_DURATION
            new_ta = t + PASS_DURATION
        else:
            new_tm = tm
            new_ta = ta
        if attack_timing or is_attack:
            last[p, u] = LAST_ATTACK
        elif is_move:
            last[p, u] = LAST_MOVE
        elif is_reload:
            last[p, u] = LAST_RELOAD
        elif as_pass:
            last[p, u] = LAST_PASS
        if is_move:
            d = _clip(code - MOVE_BASE, 0, 3)
            px[p, u] = x[p, u]
            py[p, u] = y[p, u]
            x[p, u] = x[p, u] + mdist[p, u] * DIR_X[d]
            y[p, u] = y[p, u] + mdist[p, u] * DIR_Y[d]
        t_act[p, u] = t
        t_move[p, u] = new_tm
        t_attack[p, u] = new_ta


@njit(cache=True, inline="always")
def apply_turn(
    g,
    utype,
    uid,
    x,
    y,
    px,
    py,
    t_act,
    last,
    hp,
    t_move,
    t_attack,
    time,
    turn,
    stale,
    prev_hp_sum,
    overkill_pass,
    ws,
):
    """``apply_actions`` + ``finish_turn`` for game ``g`` (views [2, U] of its unit fields), with
    the actions in ``ws`` and the context from ``prepare_turn``."""
    damage_taken = ws[11]
    n = hp.shape[1]
    t = time[g]
    for p in range(2):
        for s in range(n):
            damage_taken[p, s] = 0
    _apply_player(
        1, t, utype, uid, x, y, px, py, t_act, last, hp, t_move, t_attack, overkill_pass, ws
    )
    _apply_player(
        0, t, utype, uid, x, y, px, py, t_act, last, hp, t_move, t_attack, overkill_pass, ws
    )
    same = True
    for p in range(2):
        total = 0
        for s in range(n):
            h = max(hp[p, s] - damage_taken[p, s], 0)
            hp[p, s] = h
            total += h
        if total != prev_hp_sum[g, p]:
            same = False
        prev_hp_sum[g, p] = total
    nxt = min(
        minimum_free_time(hp, t_move, t_attack, 0), minimum_free_time(hp, t_move, t_attack, 1)
    )
    if nxt < INF:
        time[g] = nxt
    turn[g] += 1
    stale[g] = stale[g] + 1 if same else 0


@njit(cache=True, inline="always")
def player_dead(utype, hp, p):
    for s in range(hp.shape[1]):
        if hp[p, s] > 0 and SCRIPT_DAMAGE[utype[p, s]] > 0:
            return False
    return True


@njit(cache=True, inline="always")
def game_over(utype, hp, stale, turn, stalemate_limit, max_turns):
    """A side dead, more than ``stalemate_limit`` turns without HP change, or the turn cap."""
    return (
        player_dead(utype, hp, 0)
        or player_dead(utype, hp, 1)
        or stale > stalemate_limit
        or turn >= max_turns
    )


@njit(cache=True)
def winner(utype, hp):
    d0 = player_dead(utype, hp, 0)
    d1 = player_dead(utype, hp, 1)
    if d1 and not d0:
        return 0
    if d0 and not d1:
        return 1
    return -1


@njit(cache=True, inline="always")
def side_scores(utype, hp, totals, use_ltd):
    """LTD2 (or LTD) of both sides: int(1000 * sum / total), the sum in float32 in slot order;
    0 for a side with no living unit or a zero total (``rules.ltd2`` / ``rules.ltd``)."""
    s0 = 0
    s1 = 0
    for p in range(2):
        acc = np.float32(0.0)
        any_alive = False
        for s in range(hp.shape[1]):
            if hp[p, s] > 0:
                any_alive = True
                if use_ltd:
                    acc = acc + np.float32(hp[p, s]) * DPF[utype[p, s]]
                else:
                    acc = acc + np.sqrt(np.float32(hp[p, s])) * DPF[utype[p, s]]
        total = totals[p]
        v = 0
        if any_alive and total > 0:
            v = int(np.float32(1000.0) * acc / total)
        if p == 0:
            s0 = v
        else:
            s1 = v
    return s0, s1


@njit(cache=True, inline="always")
def evaluate(utype, hp, totals, use_ltd, p):
    """``rules.evaluate(state, p)``: score difference plus the +-100000 bonus, 0 if both are dead."""
    s0, s1 = side_scores(utype, hp, totals, use_ltd)
    d0 = player_dead(utype, hp, 0)
    d1 = player_dead(utype, hp, 1)
    if d0 and d1:
        return 0
    v = s0 - s1 if p == 0 else s1 - s0
    mine = d0 if p == 0 else d1
    theirs = d1 if p == 0 else d0
    if theirs and not mine:
        v += 100000
    elif mine and not theirs:
        v -= 100000
    return v


# ----------------------------------------------------------------------------- whole turns, games


@njit(cache=True)
def _rng_base(seed, game_id, turn):
    return _mix(_mix(np.uint64(seed) ^ _mix(np.uint64(game_id) + np.uint64(1))) + np.uint64(turn))


@njit_without_refcount
def play_game(
    g,
    utype,
    uid,
    x,
    y,
    px,
    py,
    t_act,
    last,
    hp,
    t_move,
    t_attack,
    time,
    turn,
    stale,
    prev_hp_sum,
    walkable,
    script0,
    script1,
    overkill_pass,
    stalemate_limit,
    max_turns,
    turn_budget,
    seed,
    game_id,
    ws,
):
    """Play game ``g`` (views [2, U] of its unit fields) until it is over or has played
    ``turn_budget`` turns (-1: no budget). Returns the number of unit actions issued.

    Compiled without Numba's reference counting (``_nrt=False``): it allocates nothing, and the
    atomic reference-count updates on the arrays passed down the turn loop cost more than the
    rules themselves."""
    n_actions = 0
    played = 0
    while not game_over(utype, hp, stale[g], turn[g], stalemate_limit, max_turns):
        if turn_budget >= 0 and played >= turn_budget:
            break
        n_actions += prepare_turn(
            time[g], utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws
        )
        rng_base = np.uint64(0)
        if script0 == RANDOM or script1 == RANDOM:
            rng_base = _rng_base(seed, game_id, turn[g])
        choose_actions(script0, 0, utype, x, y, hp, rng_base, ws)
        choose_actions(script1, 1, utype, x, y, hp, rng_base ^ np.uint64(0x5555555555555555), ws)
        apply_turn(
            g,
            utype,
            uid,
            x,
            y,
            px,
            py,
            t_act,
            last,
            hp,
            t_move,
            t_attack,
            time,
            turn,
            stale,
            prev_hp_sum,
            overkill_pass,
            ws,
        )
        played += 1
    return n_actions


@njit(cache=True, parallel=True)
def play_games(
    fields,
    time,
    turn,
    stale,
    prev_hp_sum,
    ltd2_total,
    walkable,
    script0,
    script1,
    overkill_pass,
    stalemate_limit,
    max_turns,
    turn_budget,
    seed,
    game_ids,
    n_chunks,
    winner_out,
    ltd2_out,
    actions_out,
):
    """Play every game of the batch until it is over or has played ``turn_budget`` more turns
    (-1: no budget), game ``g`` with script codes ``script0[g]`` and ``script1[g]``, in parallel
    over ``n_chunks`` strided chunks of games. Writes the winner and the final LTD2 evaluation
    and adds the unit actions issued to the outputs."""
    utype, uid, x, y, px, py, t_act, last, hp, t_move, t_attack = fields
    n_games = hp.shape[0]
    n_slots = hp.shape[2]
    for c in prange(n_chunks):
        ws = make_workspace(n_slots)
        for g in range(c, n_games, n_chunks):
            actions_out[g] += play_game(
                g,
                utype[g],
                uid[g],
                x[g],
                y[g],
                px[g],
                py[g],
                t_act[g],
                last[g],
                hp[g],
                t_move[g],
                t_attack[g],
                time,
                turn,
                stale,
                prev_hp_sum,
                walkable,
                script0[g],
                script1[g],
                overkill_pass,
                stalemate_limit,
                max_turns,
                turn_budget,
                seed,
                game_ids[g],
                ws,
            )
            winner_out[g] = winner(utype[g], hp[g])
            ltd2_out[g] = evaluate(utype[g], hp[g], ltd2_total[g], False, 0)


@njit(cache=True)
def step_one(
    g,
    fields,
    time,
    turn,
    stale,
    prev_hp_sum,
    walkable,
    script0,
    script1,
    overkill_pass,
    seed,
    game_id,
    actions,
    acting,
    movers,
):
    """One turn of game ``g``; a side with script code EXTERNAL plays ``actions`` (int [2, U])
    instead. Writes the actions played, the acting mask and the movers; returns acting count."""
    n = fields[8].shape[2]
    ws = make_workspace(n)
    utype, uid, x, y, px, py, t_act, last, hp, t_move, t_attack = fields
    n_acting = prepare_turn(
        time[g],
        utype[g],
        x[g],
        y[g],
        px[g],
        py[g],
        t_act[g],
        last[g],
        hp[g],
        t_move[g],
        t_attack[g],
        walkable,
        ws,
    )
    rng_base = _rng_base(seed, game_id, turn[g])
    scripts = (script0, script1)
    for p in range(2):
        if scripts[p] >= 0:
            salt = np.uint64(0) if p == 0 else np.uint64(0x5555555555555555)
            choose_actions(scripts[p], p, utype[g], x[g], y[g], hp[g], rng_base ^ salt, ws)
        else:
            for s in range(n):
                ws[4][p, s] = actions[p, s]
    for p in range(2):
        movers[p] = ws[12][p]
        for s in range(n):
            actions[p, s] = ws[4][p, s]
            acting[p, s] = ws[6][p, s]
    apply_turn(
        g,
        utype[g],
        uid[g],
        x[g],
        y[g],
        px[g],
        py[g],
        t_act[g],
        last[g],
        hp[g],
        t_move[g],
        t_attack[g],
        time,
        turn,
        stale,
        prev_hp_sum,
        overkill_pass,
        ws,
    )
    return n_acting
