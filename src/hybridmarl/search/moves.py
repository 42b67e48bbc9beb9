"""Host-side move generation shared by UCT-CD and ABCD (``MoveArray`` + ``generateOrderedMoves``).

A *move* of a player is one action code per acting unit (a joint vector). A node's children are,
in order (docs/baselines.md#abcd):

1. the ordering scripts' moves (ScriptFirst: NOKDPS, then KiterDPS by default), duplicates kept;
2. then the cartesian product of the units' legal-action lists in odometer order, unit 0 (the
   first acting unit in SparCraft's order) varying fastest, starting from all-first actions,

until ``max_children`` vectors. With an opponent model for the player to move there is exactly
one child: the model script's move.

Each unit's legal-action list is in ``generateMoves`` order: ATTACK per enemy in the enemy's
sorted order, RELOAD, MOVE left/right/down/up, or PASS alone. Before enumeration the list is
shuffled as ``MoveArray::shuffleMoveActions`` does it, quirk included: ``std::shuffle`` over
``[moveBegin, moveEnd)`` where ``moveEnd`` is the index of the *last* MOVE (so the last MOVE keeps
its place) and ``moveBegin`` is the index of the last non-MOVE action before the MOVE block (so
that action takes part in the shuffle), or 0 when the list starts with MOVEs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hybridmarl.engine.rules import ATTACK_BASE, MOVE_ACTIONS, PASS_ACTION, RELOAD_ACTION


def unit_action_lists(
    legal: np.ndarray, acting: np.ndarray, enemy_order: np.ndarray
) -> list[np.ndarray]:
    """Per acting unit (slot order), its legal action codes in SparCraft's generation order.

    ``legal``: bool [U, 6 + U]; ``acting``: bool [U]; ``enemy_order``: int [U] sort keys of the
    enemy's units (smaller = earlier).
    """
    n = legal.shape[0]
    num_codes = legal.shape[1]
    # Rank of every action code in generation order: attacks by the target's place in the
    # enemy's unit order, then RELOAD, the four MOVEs, and PASS.
    enemy_rank = np.empty(n, np.int64)
    enemy_rank[np.argsort(enemy_order, kind="stable")] = np.arange(n)
    rank = np.empty(num_codes, np.int64)
    rank[ATTACK_BASE:] = enemy_rank
    rank[RELOAD_ACTION] = n
    for d, code in enumerate(MOVE_ACTIONS):
        rank[code] = n + 1 + d
    rank[PASS_ACTION] = n + 5
    order = np.argsort(rank, kind="stable")
    out = []
    for u in np.flatnonzero(acting):
        codes = order[legal[u][order]]
        out.append(codes.astype(np.int32))
    return out


def shuffle_move_actions(lists: list[np.ndarray], rng: np.random.Generator) -> list[np.ndarray]:
    """``MoveArray::shuffleMoveActions`` with a seeded generator (see the module docstring)."""
    lo, hi = MOVE_ACTIONS[0], MOVE_ACTIONS[-1]
    out = []
    for codes in lists:
        cl = codes.tolist()
        move_end = -1
        for i in range(len(cl) - 1, -1, -1):
            if lo <= cl[i] <= hi:
                move_end = i
                break
        if move_end < 0:
            out.append(codes)
            continue
        # moveBegin: the last non-MOVE index before moveEnd, or 0 when every earlier action is a
        # MOVE (the MOVE block is contiguous and last but for PASS).
        move_begin = 0
        for i in range(move_end - 1, -1, -1):
            if not lo <= cl[i] <= hi:
                move_begin = i
                break
        if move_end != move_begin:
            codes = codes.copy()
            seg = codes[move_begin:move_end].copy()
            rng.shuffle(seg)
            codes[move_begin:move_end] = seg
        out.append(codes)
    return out


def _odometer_rows(lists: Sequence[np.ndarray], count: int) -> list[list[int]]:
    """The first ``count`` vectors of the cartesian product as Python lists (unit 0 fastest)."""
    sizes = [len(c) for c in lists]
    total = 1
    for s in sizes:
        total *= s
        if total >= count:
            break
    count = min(count, total)
    codes = [c.tolist() for c in lists]
    units = range(len(codes))
    out = []
    idx = [0] * len(codes)
    for _ in range(count):
        out.append([codes[u][idx[u]] for u in units])
        for u in units:
            idx[u] += 1
            if idx[u] < sizes[u]:
                break
            idx[u] = 0
    return out


def odometer_vectors(lists: Sequence[np.ndarray], count: int) -> list[np.ndarray]:
    """The first ``count`` vectors of the cartesian product (unit 0 fastest), fewer if the
    product is smaller."""
    return [np.array(r, np.int32) for r in _odometer_rows(lists, count)]


def scatter(vec: np.ndarray, acting: np.ndarray, num_slots: int) -> np.ndarray:
    """A per-acting-unit vector as an int32 [U] row of action codes (0 for the other slots)."""
    row = np.zeros(num_slots, np.int32)
    row[np.flatnonzero(acting)] = vec
    return row


def child_moves(
    legal: np.ndarray,
    acting: np.ndarray,
    enemy_order: np.ndarray,
    ordered: Sequence[np.ndarray],
    max_children: int,
    rng: np.random.Generator,
    *,
    model_move: np.ndarray | None = None,
    only_first: bool = False,
) -> list[np.ndarray]:
    """The children of a node for the player to move, as int32 [U] rows (only acting slots set).

    ``ordered``: full [U] rows of the ordering scripts' moves (ScriptFirst), in order.
    ``model_move``: the opponent-model script's [U] row: if given, it is the only child.
    ``only_first``: stop after the first child (AB's transposition-table rule, see ``abcd``).
    The legal lists are always generated and shuffled first, as SparCraft does, so the random
    stream does not depend on how many children are used.
    """
    n = legal.shape[0]
    lists = shuffle_move_actions(unit_action_lists(legal, acting, enemy_order), rng)
    if model_move is not None:
        return [np.where(acting, model_move, 0).astype(np.int32)]
    limit = 1 if only_first else max_children
    out = [np.where(acting, m, 0).astype(np.int32) for m in ordered[:limit]]
    if len(out) < limit:
        rows = _odometer_rows(lists, limit - len(out))
        if rows:
            block = np.zeros((len(rows), n), np.int32)
            block[:, np.flatnonzero(acting)] = np.array(rows, np.int32).reshape(len(rows), -1)
            out += list(block)
    return out
