"""The combat environment's step on the native engine: Numba kernels over NumPy states.

:class:`~hybridmarl.envs.combat.env.Combat` is the reference; these kernels give the same env
step (action masks and illegal-action fallback, the decision turn and the enemy-only turns that
follow it, the reward, ``done``) and the same critic features, on the native engine's
structure-of-arrays state (``hybridmarl.engine.native``). They serve the CPU workloads that call
the env step many times from one state, such as Alg. 1's simulation of candidate joint actions
(``hybridmarl.algos.hybrid.brd_native``). The tests hold them equal to the JAX env
(``tests/envs/test_combat_native.py``).

One game's fields are views ``[2, U]`` (``engine.native.kernels.FIELDS`` order) plus the
per-batch ``time``/``turn``/``stale`` ``[B]`` and ``prev_hp_sum`` ``[B, 2]`` arrays indexed by
the game ``g``, as in the engine kernels. The enemy (and a scripted continuation of our side)
is a script code (``engine.native.kernels.SCRIPT_CODES``); the ``random`` script draws from the
native engine's own generator, not JAX's (docs/engine-backends.md).
"""

# ruff: noqa: SIM102, SIM108

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, prange

from hybridmarl.engine.native.kernels import (
    ATTACK_BASE,
    DIR_X,
    FIELDS,
    INF,
    LAST_MOVE,
    MOVE_BASE,
    PASS_ACTION,
    RANDOM,
    RANGE_SQ,
    RELOAD_ACTION,
    SLOT_BITS,
    _d2,
    _rng_base,
    apply_turn,
    choose_actions,
    first_legal_action,
    game_over,
    make_workspace,
    minimum_free_time,
    njit_without_refcount,
    prepare_turn,
    winner,
)
from hybridmarl.envs.combat.observe import HP_SCALE, POS_SCALE, TIME_SCALE
from hybridmarl.envs.combat.view import ATTACK_OFFSET, MOVE_OFFSET, NOOP

#: Critic features per state (``Combat.critic_feature_size``: 2 sides x 17 statistics + 1).
CRITIC_FEATURES = 35

_ENEMY_SALT = np.uint64(0x5555555555555555)

assert DIR_X.shape == (4,)


def state_arrays(states: Any) -> dict[str, np.ndarray]:
    """The kernels' view of a batch of ``CombatState`` (host or device arrays): the unit fields
    (``FIELDS`` order), ``time``/``turn``/``stale``/``prev_hp_sum`` and our side's initial HP
    ``init_hp0`` (the reward's normaliser), as writable int32 copies."""
    g = states.game

    def arr(a: Any) -> np.ndarray:
        return np.array(a, dtype=np.int32, order="C", copy=True)

    return {
        "fields": tuple(arr(getattr(g, f)) for f in FIELDS),  # type: ignore[dict-item]
        "time": arr(g.time),
        "turn": arr(g.turn),
        "stale": arr(g.stale),
        "prev_hp_sum": arr(g.prev_hp_sum),
        "init_hp0": arr(np.asarray(states.init_hp)[:, 0]),
    }  # the four engine moves, env actions MOVE_OFFSET .. MOVE_OFFSET + 3


@njit(cache=True, inline="always")
def enemy_ranks(hp, rank_slot, rank_of_slot):
    """``view.make_view``'s HP ranks of the living enemies (ascending HP, ties to the lower
    slot); returns how many are alive."""
    n = hp.shape[1]
    alive_count = 0
    for j in range(n):
        if hp[1, j] > 0:
            alive_count += 1
    for j in range(n):
        rank_of_slot[j] = -1
        if hp[1, j] > 0:
            key = (hp[1, j] << SLOT_BITS) | j
            r = 0
            for i in range(n):
                if hp[1, i] > 0 and ((hp[1, i] << SLOT_BITS) | i) < key:
                    r += 1
            rank_of_slot[j] = r
            rank_slot[r] = j
    return alive_count


@njit(cache=True, inline="always")
def _env_action_legal(u, a, n_alive, rank_slot, num_actions, utype, ws):
    """``view.action_mask`` at one (agent, action): the env action ``a`` of our unit ``u``."""
    acting, can_atk, move_ok, alive = ws[6], ws[7], ws[8], ws[5]
    if a < 0 or a >= num_actions:
        return False
    if not acting[0, u]:
        return a == NOOP
    if a == NOOP:
        if not can_atk[0, u]:
            return True  # RELOAD is legal
        anything = False
        for d in range(4):
            if move_ok[0, u, d]:
                anything = True
        if not anything:
            rsq = RANGE_SQ[utype[0, u]]
            for j in range(alive.shape[1]):
                if alive[1, j] and rsq >= _d2(ws[0], ws[1], 0, u, j):
                    anything = True
        return not anything  # PASS is legal only if nothing else is
    if a < ATTACK_OFFSET:
        return move_ok[0, u, a - MOVE_OFFSET]
    k = a - ATTACK_OFFSET
    if k >= n_alive or not can_atk[0, u]:
        return False
    j = rank_slot[k]
    return alive[1, j] and RANGE_SQ[utype[0, u]] >= _d2(ws[0], ws[1], 0, u, j)


@njit(cache=True)
def _our_turn(hp, t_move, t_attack):
    p0 = minimum_free_time(hp, t_move, t_attack, 0)
    p1 = minimum_free_time(hp, t_move, t_attack, 1)
    return p0 <= p1 and p0 < INF


@njit(cache=True)
def _hp_diff(hp):
    d = 0
    for s in range(hp.shape[1]):
        d += max(hp[0, s], 0) - max(hp[1, s], 0)
    return d


@njit_without_refcount
def env_step(
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
    actions,
    num_agents,
    num_actions,
    enemy,
    overkill_pass,
    stalemate_limit,
    max_turns,
    init_hp0,
    seed,
    game_id,
    ws,
    rank_slot,
    rank_of_slot,
    prepared,
):
    """``Combat.step`` of game ``g`` (unit-field views ``[2, U]``) with env ``actions``
    ``[num_agents]``, in place. Returns ``(reward, done)``; a finished game is left as it is.

    An illegal action becomes the unit's first legal engine action. The decision turn plays our
    engine actions and the enemy script's, then enemy-only turns follow until one of our units
    acts or the game is over. ``last_actions`` is not kept here
    (:func:`env_step_keeping_last_actions` keeps it).
    ``prepared``: ``ws`` and the ranks already hold this state's turn context (the caller ran
    :func:`script_env_actions` on it just before).

    Compiled without Numba's reference counting (``_nrt=False``), as are the other kernels here
    that allocate nothing: with it, the atomic increments and decrements on every array passed
    down the turn loop took about 80 % of Alg. 1's simulation time.

    Compiled callers pass ``g`` and the flags as runtime values (``np.int64(0)``,
    ``np.bool_(True)``), never as literals: Numba compiles the whole turn loop again for every
    literal argument value it sees (about 25 s of compilation each)."""
    return _env_step(
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
        actions,
        num_agents,
        num_actions,
        enemy,
        overkill_pass,
        stalemate_limit,
        max_turns,
        init_hp0,
        seed,
        game_id,
        ws,
        rank_slot,
        rank_of_slot,
        prepared,
        last,
        np.bool_(False),
    )


@njit_without_refcount
def env_step_keeping_last_actions(
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
    actions,
    num_agents,
    num_actions,
    enemy,
    overkill_pass,
    stalemate_limit,
    max_turns,
    init_hp0,
    seed,
    game_id,
    ws,
    rank_slot,
    rank_of_slot,
    prepared,
    last_actions,
):
    """:func:`env_step` that also keeps ``CombatState.last_actions`` (int32 ``[2, U]``, in
    place): the engine action each unit issued during the step (the latest one if it acted more
    than once), -1 if none; left as it is when the game was already over."""
    return _env_step(
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
        actions,
        num_agents,
        num_actions,
        enemy,
        overkill_pass,
        stalemate_limit,
        max_turns,
        init_hp0,
        seed,
        game_id,
        ws,
        rank_slot,
        rank_of_slot,
        prepared,
        last_actions,
        np.bool_(True),
    )


@njit_without_refcount
def _env_step(
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
    actions,
    num_agents,
    num_actions,
    enemy,
    overkill_pass,
    stalemate_limit,
    max_turns,
    init_hp0,
    seed,
    game_id,
    ws,
    rank_slot,
    rank_of_slot,
    prepared,
    last_actions,
    keep_last_actions,
):
    """The body of :func:`env_step`; with ``keep_last_actions`` it also records every turn's
    actions of the acting units in ``last_actions`` (as ``Combat._turn`` does)."""
    if game_over(utype, hp, stale[g], turn[g], stalemate_limit, max_turns):
        return np.float32(0.0), True
    diff_old = _hp_diff(hp)
    n = hp.shape[1]
    if not prepared:
        prepare_turn(time[g], utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws)
    n_alive = enemy_ranks(hp, rank_slot, rank_of_slot)
    chosen = ws[4]
    for u in range(n):
        chosen[0, u] = PASS_ACTION
    for u in range(num_agents):
        a = actions[u]
        if not _env_action_legal(u, a, n_alive, rank_slot, num_actions, utype, ws):
            chosen[0, u] = first_legal_action(0, u, utype, ws)
        elif a == NOOP:
            chosen[0, u] = PASS_ACTION if ws[7][0, u] else RELOAD_ACTION
        elif a < ATTACK_OFFSET:
            chosen[0, u] = MOVE_BASE + a - MOVE_OFFSET
        else:
            chosen[0, u] = ATTACK_BASE + rank_slot[a - ATTACK_OFFSET]
    if keep_last_actions:
        for p in range(2):
            for u in range(n):
                last_actions[p, u] = -1
    rng = np.uint64(0)
    first = True
    while True:
        if not first:
            prepare_turn(
                time[g], utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws
            )
            for u in range(n):
                chosen[0, u] = PASS_ACTION
        if enemy == RANDOM:  # the native generator, keyed by (seed, game, turn)
            rng = _rng_base(seed, game_id, turn[g]) ^ _ENEMY_SALT
        choose_actions(enemy, 1, utype, x, y, hp, rng, ws)
        if keep_last_actions:
            for p in range(2):
                for u in range(n):
                    if ws[6][p, u]:
                        last_actions[p, u] = ws[4][p, u]
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
        first = False
        if game_over(utype, hp, stale[g], turn[g], stalemate_limit, max_turns):
            break
        if _our_turn(hp, t_move, t_attack):
            break
    reward = np.float32(_hp_diff(hp) - diff_old) / np.float32(max(init_hp0, 1))
    return reward, game_over(utype, hp, stale[g], turn[g], stalemate_limit, max_turns)


@njit_without_refcount
def script_env_actions(
    g,
    utype,
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
    walkable,
    script,
    num_agents,
    stalemate_limit,
    max_turns,
    seed,
    game_id,
    ws,
    rank_slot,
    rank_of_slot,
    out,
):
    """``Combat.script_policy(script)`` at game ``g``: the script's engine actions for our side
    as env actions (noop for units that do not act, and everywhere once the game is over)."""
    for u in range(num_agents):
        out[u] = NOOP
    if game_over(utype, hp, stale[g], turn[g], stalemate_limit, max_turns):
        return
    prepare_turn(time[g], utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws)
    enemy_ranks(hp, rank_slot, rank_of_slot)
    rng = np.uint64(0)
    if script == RANDOM:
        rng = _rng_base(seed, game_id, turn[g])
    choose_actions(script, 0, utype, x, y, hp, rng, ws)
    n = hp.shape[1]
    for u in range(num_agents):
        if not ws[6][0, u]:
            continue
        code = ws[4][0, u]
        if code <= RELOAD_ACTION:
            out[u] = NOOP
        elif code < ATTACK_BASE:
            out[u] = code - MOVE_BASE + MOVE_OFFSET
        else:
            j = min(max(code - ATTACK_BASE, 0), n - 1)
            out[u] = ATTACK_OFFSET + rank_of_slot[j]


@njit(cache=True, inline="always")
def _side_stats(values, hp, p, out, at):
    """mean, variance, min, max of ``values[p]`` over the living units (0s with none)."""
    n = values.shape[1]
    count = 0
    total = np.float32(0.0)
    for s in range(n):
        if hp[p, s] > 0:
            count += 1
            total += values[p, s]
    nf = np.float32(max(count, 1))
    mean = total / nf
    var = np.float32(0.0)
    vmin = np.float32(np.inf)
    vmax = np.float32(-np.inf)
    for s in range(n):
        if hp[p, s] > 0:
            dv = values[p, s] - mean
            var += dv * dv
            vmin = min(vmin, values[p, s])
            vmax = max(vmax, values[p, s])
    out[at] = mean
    out[at + 1] = var / nf
    out[at + 2] = vmin if count > 0 else np.float32(0.0)
    out[at + 3] = vmax if count > 0 else np.float32(0.0)
    return mean


@njit_without_refcount
def critic_features(
    t, x, y, px, py, t_act, last, hp, t_move, t_attack, num_agents, num_enemies, values, out
):
    """``observe.critic_features`` of one game (``values``: float32 ``[2, U]`` scratch). Allocates
    nothing, so it is compiled without reference counting (see ``env_step``)."""
    n = hp.shape[1]
    base = 0
    cx0 = cy0 = cx1 = cy1 = np.float32(0.0)
    alive0 = alive1 = False
    for p in range(2):
        count = 0
        for s in range(n):
            if hp[p, s] > 0:
                count += 1
        if p == 0:
            alive0 = count > 0
        else:
            alive1 = count > 0
        size = num_agents if p == 0 else num_enemies
        out[base] = np.float32(count) / np.float32(size)
        base += 1
        for s in range(n):
            values[p, s] = np.float32(max(hp[p, s], 0)) / np.float32(HP_SCALE)
        _side_stats(values, hp, p, out, base)
        base += 4
        for s in range(n):
            values[p, s] = np.float32(max(t_attack[p, s] - t, 0)) / np.float32(TIME_SCALE)
        _side_stats(values, hp, p, out, base)
        base += 4
        for axis in range(2):
            for s in range(n):
                pos = x[p, s] if axis == 0 else y[p, s]
                prev = px[p, s] if axis == 0 else py[p, s]
                if last[p, s] == LAST_MOVE and t == t_act[p, s]:
                    pos = prev
                elif last[p, s] == LAST_MOVE and t < t_move[p, s]:
                    duration = max(t_move[p, s] - t_act[p, s], 1)
                    ratio = np.float32(t - t_act[p, s]) / np.float32(duration)
                    pos = prev + int(np.float32(pos - prev) * ratio)
                values[p, s] = np.float32(pos) / np.float32(POS_SCALE)
            c = _side_stats(values, hp, p, out, base)
            if p == 0 and axis == 0:
                cx0 = c
            elif p == 0:
                cy0 = c
            elif axis == 0:
                cx1 = c
            else:
                cy1 = c
            base += 4
    dx = cx0 - cx1
    dy = cy0 - cy1
    out[base] = np.sqrt(dx * dx + dy * dy) if (alive0 and alive1) else np.float32(0.0)


__all__ = [
    "CRITIC_FEATURES",
    "critic_features",
    "enemy_ranks",
    "env_step",
    "env_step_keeping_last_actions",
    "play_scripted_episodes",
    "script_env_actions",
    "state_arrays",
    "step_scripted_games",
]


@njit(cache=True, parallel=True)
def play_scripted_episodes(
    fields,
    time,
    turn,
    stale,
    prev_hp_sum,
    init_hp0,
    walkable,
    script,
    enemy,
    num_agents,
    num_actions,
    overkill_pass,
    stalemate_limit,
    max_turns,
    seed,
    n_chunks,
    won,
    lost,
    steps,
    returns,
    terminal,
):
    """Whole episodes of the combat env, our side played by ``script``, every game of the batch
    in place (in parallel over ``n_chunks`` strided chunks): the env's episode metrics, with the
    return summed step by step as the env's evaluation loop sums it."""
    n = fields[8].shape[2]
    for c in prange(n_chunks):
        ws = make_workspace(n)
        ranks = np.empty((2, n), np.int64)
        acts = np.empty(num_agents, np.int64)
        _play_scripted_chunk(
            np.int64(c),
            n_chunks,
            fields,
            time,
            turn,
            stale,
            prev_hp_sum,
            init_hp0,
            walkable,
            script,
            enemy,
            num_agents,
            num_actions,
            overkill_pass,
            stalemate_limit,
            max_turns,
            seed,
            won,
            lost,
            steps,
            returns,
            terminal,
            ws,
            ranks,
            acts,
        )


@njit_without_refcount
def _play_scripted_chunk(
    c,
    n_chunks,
    fields,
    time,
    turn,
    stale,
    prev_hp_sum,
    init_hp0,
    walkable,
    script,
    enemy,
    num_agents,
    num_actions,
    overkill_pass,
    stalemate_limit,
    max_turns,
    seed,
    won,
    lost,
    steps,
    returns,
    terminal,
    ws,
    ranks,
    acts,
):
    """Chunk ``c`` of :func:`play_scripted_episodes`, in the given scratch; allocates nothing,
    so it is compiled without reference counting (see ``env_step``)."""
    utype, uid, x, y, px, py, t_act, last, hp, t_move, t_attack = fields
    b = hp.shape[0]
    rank_slot, rank_of = ranks[0], ranks[1]
    for g in range(c, b, n_chunks):
        ret = np.float32(0.0)
        count = 0
        done = game_over(utype[g], hp[g], stale[g], turn[g], stalemate_limit, max_turns)
        while not done:
            script_env_actions(
                g,
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
                time,
                turn,
                stale,
                walkable,
                script,
                num_agents,
                stalemate_limit,
                max_turns,
                seed,
                g,
                ws,
                rank_slot,
                rank_of,
                acts,
            )
            r, done = env_step(
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
                acts,
                num_agents,
                num_actions,
                enemy,
                overkill_pass,
                stalemate_limit,
                max_turns,
                init_hp0[g],
                seed,
                g,
                ws,
                rank_slot,
                rank_of,
                np.bool_(True),
            )
            ret = ret + r
            count += 1
        w = winner(utype[g], hp[g])
        won[g] = w == 0
        lost[g] = w == 1
        steps[g] = count
        returns[g] = ret
        terminal[g] = np.float32(_hp_diff(hp[g])) / np.float32(max(init_hp0[g], 1))


@njit(cache=True, parallel=True)
def step_scripted_games(
    fields,
    time,
    turn,
    stale,
    prev_hp_sum,
    last_actions,
    steps,
    init_hp0,
    walkable,
    script,
    enemy,
    num_agents,
    num_actions,
    overkill_pass,
    stalemate_limit,
    max_turns,
    seed,
    n_chunks,
    actions,
    reward,
    done,
    won,
    lost,
    terminal,
):
    """One env step of every game of the batch, our side played by ``script``, in place (in
    parallel over ``n_chunks`` strided chunks): the whole ``CombatState`` moves on, including
    ``last_actions`` ``[B, 2, U]`` and ``steps`` ``[B]``, as ``Combat.step`` moves it. Writes the
    script's env actions ``[B, N]`` (``Combat.script_policy``'s), the step's reward and ``done``
    and the env's episode metrics of the new state (``won``/``lost`` where done, ``terminal``:
    the hit-points reward). A game already over is left as it is (noop actions, reward 0, done)."""
    n = fields[8].shape[2]
    # Every chunk's scratch is allocated here, so that the chunk allocates nothing and is
    # compiled without reference counting (see _step_scripted_chunk).
    ranks = np.empty((n_chunks, 2, n), np.int64)
    acts = np.empty((n_chunks, num_agents), np.int64)
    for c in prange(n_chunks):
        _step_scripted_chunk(
            np.int64(c),
            n_chunks,
            fields,
            time,
            turn,
            stale,
            prev_hp_sum,
            last_actions,
            steps,
            init_hp0,
            walkable,
            script,
            enemy,
            num_agents,
            num_actions,
            overkill_pass,
            stalemate_limit,
            max_turns,
            seed,
            actions,
            reward,
            done,
            won,
            lost,
            terminal,
            make_workspace(n),
            ranks[c],
            acts[c],
        )


@njit_without_refcount
def _step_scripted_chunk(
    c,
    n_chunks,
    fields,
    time,
    turn,
    stale,
    prev_hp_sum,
    last_actions,
    steps,
    init_hp0,
    walkable,
    script,
    enemy,
    num_agents,
    num_actions,
    overkill_pass,
    stalemate_limit,
    max_turns,
    seed,
    actions,
    reward,
    done,
    won,
    lost,
    terminal,
    ws,
    ranks,
    acts,
):
    """Chunk ``c`` of :func:`step_scripted_games`, in the given scratch; allocates nothing, so it
    is compiled without reference counting (see ``env_step``)."""
    utype, uid, x, y, px, py, t_act, last, hp, t_move, t_attack = fields
    b = hp.shape[0]
    rank_slot, rank_of = ranks[0], ranks[1]
    for g in range(c, b, n_chunks):
        if game_over(utype[g], hp[g], stale[g], turn[g], stalemate_limit, max_turns):
            r, d = np.float32(0.0), True
            for u in range(num_agents):
                actions[g, u] = NOOP
        else:
            script_env_actions(
                g,
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
                time,
                turn,
                stale,
                walkable,
                script,
                num_agents,
                stalemate_limit,
                max_turns,
                seed,
                g,
                ws,
                rank_slot,
                rank_of,
                acts,
            )
            r, d = env_step_keeping_last_actions(
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
                acts,
                num_agents,
                num_actions,
                enemy,
                overkill_pass,
                stalemate_limit,
                max_turns,
                init_hp0[g],
                seed,
                g,
                ws,
                rank_slot,
                rank_of,
                np.bool_(True),
                last_actions[g],
            )
            steps[g] += 1
            for u in range(num_agents):
                actions[g, u] = acts[u]
        w = winner(utype[g], hp[g])
        reward[g] = r
        done[g] = d
        won[g] = d and w == 0
        lost[g] = d and w == 1
        terminal[g] = np.float32(_hp_diff(hp[g])) / np.float32(max(init_hp0[g], 1))
