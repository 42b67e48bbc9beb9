"""Native kernels of the search players (``hybridmarl.search``): the CPU counterparts of
``search.kernels.search_fn`` and ``search.kernels.pgs_fn``, built on the engine kernels of
``engine.native.kernels`` and returning the same arrays.

States travel in the search's packed form: one int32 vector per state, the nine per-unit fields
that change during a game (``x, y, px, py, t_act, last, hp, t_move, t_attack``, [2, U] each,
flattened) and five scalars (time, turn, stale, prev_hp_sum[0], prev_hp_sum[1]); the fixed
fields (unit types, ids, LTD / LTD2 denominators) come separately.

- :func:`search_batch`: apply a joint action to each base state (the sides selected by a mask,
  then ``finishedMoving``), the child's node info (movers, acting units, legal actions, unit
  order keys, the info scripts' moves for both sides, terminal, ``eval(p, LTD2)`` of both sides,
  the transposition-table key material) and its leaf value (a script playout of at most ``cap``
  turns scored by LTD2 or LTD, the +-100000 bonus of the child; ``cap`` 0: the child itself).
- :func:`pgs_batch`: Portfolio Greedy Search playouts where each unit plays its own script
  (``Game::playIndividualScripts``), scored by ``eval(player, LTD2)`` of the final state.

LTD and LTD2 sum the units' terms in float32 in slot order, as the JAX search kernels do
(``search.kernels.ltd_scores``), so both paths give equal values.

The ``random`` script draws from the native engine's own generator (docs/engine-backends.md),
so searches whose ordering, playout or portfolio scripts include it are reproducible per seed
but do not equal the JAX path's.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from hybridmarl.engine.native.kernels import (
    ATTACK_BASE,
    INF,
    MOVE_BASE,
    PASS_ACTION,
    RANGE_SQ,
    RELOAD_ACTION,
    _rng_base,
    apply_turn,
    choose_actions,
    evaluate,
    make_workspace,
    njit_without_refcount,
    player_dead,
    prepare_turn,
    side_scores,
)

NUM_DYNAMIC = 9  # x, y, px, py, t_act, last, hp, t_move, t_attack
HP_FIELD = 6
NUM_CODES_EXTRA = ATTACK_BASE  # legal-action codes per unit: 6 + U


@njit(cache=True, inline="always")
def _unpack(vec, st, sc, prev):
    """Packed vector -> per-unit fields ``st`` [9, 2, U] and scalars (time, turn, stale in
    ``sc`` [3, 1], prev_hp_sum in ``prev`` [1, 2])."""
    n = st.shape[2]
    i = 0
    for f in range(NUM_DYNAMIC):
        for p in range(2):
            for s in range(n):
                st[f, p, s] = vec[i]
                i += 1
    sc[0, 0] = vec[i]
    sc[1, 0] = vec[i + 1]
    sc[2, 0] = vec[i + 2]
    prev[0, 0] = vec[i + 3]
    prev[0, 1] = vec[i + 4]


@njit(cache=True, inline="always")
def _pack(st, sc, prev, out):
    n = st.shape[2]
    i = 0
    for f in range(NUM_DYNAMIC):
        for p in range(2):
            for s in range(n):
                out[i] = st[f, p, s]
                i += 1
    out[i] = sc[0, 0]
    out[i + 1] = sc[1, 0]
    out[i + 2] = sc[2, 0]
    out[i + 3] = prev[0, 0]
    out[i + 4] = prev[0, 1]


@njit(cache=True, inline="always")
def _terminal(utype, hp, stale, stalemate_limit):
    """``rules.is_terminal``: a side dead or more than ``stalemate_limit`` turns without HP change."""
    return player_dead(utype, hp, 0) or player_dead(utype, hp, 1) or stale > stalemate_limit


@njit(cache=True, inline="always")
def _is_move(code):
    return MOVE_BASE <= code < ATTACK_BASE


# The engine's turn functions are inlined into their callers (``inline="always"``); the search
# kernels call them from several places, so each is wrapped once in a plain function here, which
# keeps the kernels' compile time down (one copy of each instead of one per call site).
# Functions that allocate nothing are compiled without Numba's reference counting
# (``_nrt=False``): otherwise every array passed down the turn loop costs an atomic increment
# and decrement, which took most of a playout's time.


@njit_without_refcount
def _prepare(t, utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws):
    return prepare_turn(t, utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws)


@njit_without_refcount
def _choose(script, p, utype, x, y, hp, rng_base, ws):
    choose_actions(script, p, utype, x, y, hp, rng_base, ws)


@njit_without_refcount
def _apply(
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
    prev,
    overkill_pass,
    ws,
):
    apply_turn(
        0,
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
        prev,
        overkill_pass,
        ws,
    )


@njit_without_refcount
def _search_one(
    k,
    vecs,
    actions,
    mask,
    do_step,
    player,
    cap,
    use_ltd,
    utype,
    uid,
    ltd_total,
    ltd2_total,
    walkable,
    info_scripts,
    playout0,
    playout1,
    overkill_pass,
    stalemate_limit,
    seed,
    ws,
    st,
    sc,
    prev,
    child_out,
    step_moves,
    movers_out,
    acting_out,
    legal_out,
    order_out,
    scripts_out,
    terminal_out,
    ev_out,
    hash_out,
    value_out,
    pmoves_out,
    both_dead_out,
):
    n = st.shape[2]
    x, y, px, py, t_act, last, hp, t_move, t_attack = (
        st[0],
        st[1],
        st[2],
        st[3],
        st[4],
        st[5],
        st[6],
        st[7],
        st[8],
    )
    time, turn, stale = sc[0], sc[1], sc[2]
    _unpack(vecs[k], st, sc, prev)
    # 1. The child: the joint action for the masked sides, then finishedMoving.
    step_moves[k, 0] = 0
    step_moves[k, 1] = 0
    if do_step[k]:
        _prepare(time[0], utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws)
        acts, acting = ws[4], ws[6]
        for p in range(2):
            for s in range(n):
                a = acting[p, s] and mask[k, p]
                acting[p, s] = a
                acts[p, s] = actions[k, p, s]
                if a and _is_move(actions[k, p, s]):
                    step_moves[k, p] += 1
        _apply(
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
            prev,
            overkill_pass,
            ws,
        )
    _pack(st, sc, prev, child_out[k])
    # 2. The child's node info.
    _prepare(time[0], utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws)
    cx, cy, order, acting, can_atk, move_ok, alive = ws[0], ws[1], ws[2], ws[6], ws[7], ws[8], ws[5]
    for p in range(2):
        movers_out[k, p] = ws[12][p]
        q = 1 - p
        for s in range(n):
            acting_out[k, p, s] = acting[p, s]
            order_out[k, p, s] = order[p, s]
            row = legal_out[k, p, s]
            for c in range(row.shape[0]):
                row[c] = False
            if acting[p, s]:
                anything = False
                if can_atk[p, s]:
                    rsq = RANGE_SQ[utype[p, s]]
                    for j in range(n):
                        if alive[q, j]:
                            dx = cx[p, s] - cx[q, j]
                            dy = cy[p, s] - cy[q, j]
                            if rsq >= dx * dx + dy * dy:
                                row[ATTACK_BASE + j] = True
                                anything = True
                else:
                    row[RELOAD_ACTION] = True
                    anything = True
                for d in range(4):
                    if move_ok[p, s, d]:
                        row[MOVE_BASE + d] = True
                        anything = True
                if not anything:
                    row[PASS_ACTION] = True
    salt1 = np.uint64(0x5555555555555555)
    rng = _rng_base(seed, k, turn[0])
    for i in range(info_scripts.shape[0]):
        for p in range(2):
            _choose(
                info_scripts[i], p, utype, x, y, hp, rng ^ (salt1 if p == 1 else np.uint64(0)), ws
            )
            for s in range(n):
                scripts_out[k, i, p, s] = ws[4][p, s]
    terminal_out[k] = _terminal(utype, hp, stale[0], stalemate_limit)
    ev_out[k, 0] = evaluate(utype, hp, ltd2_total, False, 0)
    ev_out[k, 1] = evaluate(utype, hp, ltd2_total, False, 1)
    # Transposition-table key material: living units in unit order (cx, cy, t_attack - time,
    # t_move - time, hp, type); dead units are rows of zeros after them.
    t = time[0]
    for p in range(2):
        r = 0
        # Living units: ascending order keys (unique: the slot is in the low bits).
        last_key = -1
        while True:
            best = INF
            best_s = -1
            for s in range(n):
                if alive[p, s] and order[p, s] > last_key and order[p, s] < best:
                    best = order[p, s]
                    best_s = s
            if best_s < 0:
                break
            last_key = best
            h = hash_out[k, p, r]
            h[0] = cx[p, best_s]
            h[1] = cy[p, best_s]
            h[2] = t_attack[p, best_s] - t
            h[3] = t_move[p, best_s] - t
            h[4] = hp[p, best_s]
            h[5] = utype[p, best_s]
            r += 1
        while r < n:
            for c in range(6):
                hash_out[k, p, r, c] = 0
            r += 1
    # 3. The leaf value: a playout of at most ``cap`` turns from the child.
    d0 = player_dead(utype, hp, 0)
    d1 = player_dead(utype, hp, 1)
    me_dead = d0 if player[k] == 0 else d1
    en_dead = d1 if player[k] == 0 else d0
    bonus = 100000 if (en_dead and not me_dead) else (-100000 if (me_dead and not en_dead) else 0)
    moves = 0
    played = 0
    while played < cap and not _terminal(utype, hp, stale[0], stalemate_limit):
        _prepare(time[0], utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws)
        rng = _rng_base(seed, k + 7919 * (played + 1), turn[0])
        _choose(playout0, np.int64(0), utype, x, y, hp, rng, ws)
        _choose(playout1, np.int64(1), utype, x, y, hp, rng ^ salt1, ws)
        pl = player[k]
        for s in range(n):
            if ws[6][pl, s] and _is_move(ws[4][pl, s]):
                moves += 1
        _apply(
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
            prev,
            overkill_pass,
            ws,
        )
        played += 1
    totals = ltd_total if use_ltd else ltd2_total
    s0, s1 = side_scores(utype, hp, totals, use_ltd)
    diff = s0 - s1 if player[k] == 0 else s1 - s0
    if d0 and d1:
        value_out[k] = 0
        pmoves_out[k] = 0
        both_dead_out[k] = True
    else:
        value_out[k] = diff + bonus
        pmoves_out[k] = moves
        both_dead_out[k] = False


@njit(cache=True, parallel=True)
def search_batch(
    vecs,
    actions,
    mask,
    do_step,
    player,
    cap,
    use_ltd,
    utype,
    uid,
    ltd_total,
    ltd2_total,
    walkable,
    info_scripts,
    playout0,
    playout1,
    overkill_pass,
    stalemate_limit,
    seed,
    n_chunks,
    child_out,
    step_moves,
    movers_out,
    acting_out,
    legal_out,
    order_out,
    scripts_out,
    terminal_out,
    ev_out,
    hash_out,
    value_out,
    pmoves_out,
    both_dead_out,
):
    """Every entry ``k`` of the batch (see the module docstring), in parallel over ``n_chunks``
    strided chunks. Outputs are written in place."""
    n = utype.shape[1]
    m = vecs.shape[0]
    for c in prange(n_chunks):
        ws = make_workspace(n)
        st = np.zeros((NUM_DYNAMIC, 2, n), np.int32)
        sc = np.zeros((3, 1), np.int32)
        prev = np.zeros((1, 2), np.int32)
        for k in range(c, m, n_chunks):
            _search_one(
                k,
                vecs,
                actions,
                mask,
                do_step,
                player,
                cap,
                use_ltd,
                utype,
                uid,
                ltd_total,
                ltd2_total,
                walkable,
                info_scripts,
                playout0,
                playout1,
                overkill_pass,
                stalemate_limit,
                seed,
                ws,
                st,
                sc,
                prev,
                child_out,
                step_moves,
                movers_out,
                acting_out,
                legal_out,
                order_out,
                scripts_out,
                terminal_out,
                ev_out,
                hash_out,
                value_out,
                pmoves_out,
                both_dead_out,
            )


@njit_without_refcount
def _pgs_one(
    k,
    vec,
    assign,
    player,
    turns,
    utype,
    uid,
    ltd2_total,
    walkable,
    scripts,
    overkill_pass,
    stalemate_limit,
    seed,
    ws,
    st,
    sc,
    prev,
    used,
    per_script,
):
    n = st.shape[2]
    x, y, px, py, t_act, last, hp, t_move, t_attack = (
        st[0],
        st[1],
        st[2],
        st[3],
        st[4],
        st[5],
        st[6],
        st[7],
        st[8],
    )
    time, turn, stale = sc[0], sc[1], sc[2]
    _unpack(vec, st, sc, prev)
    ns = scripts.shape[0]
    salt1 = np.uint64(0x5555555555555555)
    played = 0
    while played <= turns and not _terminal(utype, hp, stale[0], stalemate_limit):
        _prepare(time[0], utype, x, y, px, py, t_act, last, hp, t_move, t_attack, walkable, ws)
        rng = _rng_base(seed, k + 7919 * (played + 1), turn[0])
        acting = ws[6]
        for p in range(2):
            for i in range(ns):
                used[i] = False
            for s in range(n):
                if acting[p, s]:
                    used[assign[k, p, s]] = True
            # Each script the side uses runs for the whole side (NOKDPS's overkill bookkeeping
            # sees every acting unit); each unit then takes its own script's action.
            for i in range(ns):
                if used[i]:
                    _choose(
                        scripts[i],
                        p,
                        utype,
                        x,
                        y,
                        hp,
                        rng ^ (salt1 if p == 1 else np.uint64(0)),
                        ws,
                    )
                    for s in range(n):
                        per_script[i, s] = ws[4][p, s]
            for s in range(n):
                ws[4][p, s] = per_script[assign[k, p, s], s] if acting[p, s] else PASS_ACTION
        _apply(
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
            prev,
            overkill_pass,
            ws,
        )
        played += 1
    return evaluate(utype, hp, ltd2_total, False, player[k])


@njit(cache=True, parallel=True)
def pgs_batch(
    vec,
    assign,
    player,
    turns,
    utype,
    uid,
    ltd2_total,
    walkable,
    scripts,
    overkill_pass,
    stalemate_limit,
    seed,
    n_chunks,
    value_out,
):
    """Per-unit script playouts from one packed state ``vec``: entry ``k`` plays unit (p, s) with
    script ``scripts[assign[k, p, s]]`` while the state is not terminal and rounds <= ``turns``,
    and scores ``eval(player[k], LTD2)`` of the final state."""
    n = utype.shape[1]
    m = assign.shape[0]
    for c in prange(n_chunks):
        ws = make_workspace(n)
        st = np.zeros((NUM_DYNAMIC, 2, n), np.int32)
        sc = np.zeros((3, 1), np.int32)
        prev = np.zeros((1, 2), np.int32)
        used = np.zeros(scripts.shape[0], np.bool_)
        per_script = np.zeros((scripts.shape[0], n), np.int64)
        for k in range(c, m, n_chunks):
            value_out[k] = _pgs_one(
                k,
                vec,
                assign,
                player,
                turns,
                utype,
                uid,
                ltd2_total,
                walkable,
                scripts,
                overkill_pass,
                stalemate_limit,
                seed,
                ws,
                st,
                sc,
                prev,
                used,
                per_script,
            )
