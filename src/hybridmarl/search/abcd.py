"""Alpha-Beta Considering Durations (ABCD; Churchill, Saffidine & Buro, AIIDE 2012; SparCraft
``AlphaBetaSearch`` with ``IDAlphaBeta``).

What it does (docs/baselines.md#abcd): iterative deepening alpha-beta, depths 1, 2, ... up to 50, over
joint moves of one side at a time; the result is the best root move of the last completed depth,
or the fallback script's (NOKDPS) move if depth 1 does not complete in the budget.

- **Player to move**: whoever can act; when both can, the max player at the root and the enemy
  of the last mover elsewhere (Alternate). A simultaneous pair takes two plies: at a both-can-move
  node with depth != 1 the first mover's vector is *not* applied but passed down (depth - 1); the
  second mover then enumerates its vectors and each child applies both vectors, then
  ``finishedMoving``. At depth 1 the first mover's vector is applied alone.
- **Children**: the ordering scripts' moves (NOKDPS, KiterDPS), then the shuffled odometer, at
  most ``max_children`` (``moves``); an opponent model gives its player exactly one child.
- **Leaves** (depth 0 or a terminal state): ``eval(max player, Playout)``: a NOKDPS vs NOKDPS
  playout of <= 200 turns scored by evalLTD2 of its end state, +-100000 if a side of the leaf
  state is dead, 0 if both are. Scores compare by value, then by fewer MOVE actions of the max
  player (``StateEvalScore``); a leaf's move count is twice the MOVEs on the path from the root
  plus the playout's (SparCraft adds the state's count to the playout's cumulative count).
- **Transposition table** (non-second-simultaneous nodes only): two 32-bit hashes of the living
  units' current positions, relative timers, HP and type in unit order; 100,000 entries, a linear
  scan of 10 slots; an entry is used for a cut only at equal depth (UPPER / LOWER / ACCURATE
  bounds). Its stored best move is returned on a cut; when an entry of at least the node's depth
  with a valid move exists, only the node's first child is searched (SparCraft's
  ``getNextMoveVec`` rule). The table lives across the decisions of a game (``reset`` clears it).
- Initial window +-10,000,000.

Parameters (``base.ABCD_OPTIONS``): time_ms 40, max_depth 50, max_children 20, ordering
nokdps+kiter-dps, playouts nokdps/nokdps, Alternate, no opponent model, fallback nokdps.

Deviations from SparCraft
-------------------------
- **Young-brothers-wait leaf batching**: at a node whose children are leaves the eldest child is
  evaluated alone, then the rest in batches of ``batch`` (one engine call each; ``auto``: as
  UCT's, at most ``max_children``), before the
  alpha-beta loop consumes them in order. Values, cuts, best moves and the node count are those
  of the serial search; only playouts of children after a cut are wasted (``stats.playouts``
  counts every playout run). Children that are inner nodes are generated in one batched call.
- The budget is tested at every node (SparCraft: every 50th node, which overshoots 40 ms by up
  to 2x); a node budget (``nodes``) gives reproducible searches.
- The hash is BLAKE2b over the same unit fields (SparCraft: Zobrist tables); the leaf move count
  leaves out the MOVEs made before the root (a constant for all leaves but both-dead ones).
- If the completed iteration has no valid root move (a table cut without a stored move), the
  previous iteration's move is kept.
"""

from __future__ import annotations

import hashlib
import time
from typing import Any

import numpy as np

from hybridmarl.search.base import (
    DeviceArgs,
    Engine,
    SearchPlayer,
    SearchStats,
    deadline_from,
    eval_params,
    resolve_batch,
    unique,
)
from hybridmarl.search.moves import child_moves

NONE, UPPER, LOWER, ACCURATE = 0, 1, 2, 3
ALPHA0 = (-10_000_000, -999_999)  # StateEvalScore(-1e7, 999999) as a (value, -moves) key
BETA0 = (10_000_000, -999_999)
TT_SCAN = 10

Score = tuple[int, int]  # (value, -moves): larger is better for the max player
LeafValue = tuple[int, bool, int, int]  # value, both dead, path MOVEs, playout MOVEs


class _Timeout(Exception):
    pass


class TTEntry:
    __slots__ = ("h2", "score", "depth", "kind", "best")

    def __init__(
        self,
        h2: int,
        score: Score,
        depth: int,
        kind: int,
        first_player: int,
        best_first,
        best_second,
    ):
        self.h2 = h2
        self.score = score
        self.depth = depth
        self.kind = kind
        self.best: list[tuple[Any, Any]] = [(None, None), (None, None)]
        self.best[first_player] = (best_first, best_second)

    def move_for(self, player: int) -> np.ndarray | None:
        """``getAlphaBetaMove``: this player's first move, else the enemy entry's response."""
        first = self.best[player][0]
        return first if first is not None else self.best[1 - player][1]


class TranspositionTable:
    """SparCraft's table: ``size`` slots, entry i at hash1 % size, linear scan of 10 slots."""

    def __init__(self, size: int):
        self.size = size
        self.slots: list[TTEntry | None] = [None] * size

    def lookup(self, h1: int, h2: int) -> TTEntry | None:
        start = h1 % self.size
        for i in range(start, min(start + TT_SCAN, self.size)):
            e = self.slots[i]
            if e is not None and e.h2 == h2:
                return e
        return None

    def _save_index(self, start: int, h2: int, depth: int) -> int:
        worst_depth, worst = 1000, start
        for i in range(start, min(start + TT_SCAN, self.size)):
            e = self.slots[i]
            if e is not None and e.h2 == h2 and e.depth < depth:
                return i
            if e is None:
                return i
            if e.h2 != h2 and e.depth < worst_depth:
                worst_depth, worst = e.depth, i
        return worst

    def save(self, h1: int, entry: TTEntry) -> None:
        self.slots[self._save_index(h1 % self.size, entry.h2, entry.depth)] = entry


class _Node:
    """A search state: packed vector, its node info, and the max player's MOVEs from the root."""

    __slots__ = ("vec", "info", "i", "path_moves", "_hash")

    def __init__(self, vec: np.ndarray, info: dict[str, np.ndarray], i: int, path_moves: int):
        self.vec = vec
        self.info = info
        self.i = i
        self.path_moves = path_moves
        self._hash: tuple[int, int] | None = None

    def __getitem__(self, k: str) -> Any:
        return self.info[k][self.i]

    def hash(self) -> tuple[int, int]:
        if self._hash is None:
            d = hashlib.blake2b(
                np.ascontiguousarray(self["hash"]).tobytes(), digest_size=8
            ).digest()
            self._hash = (int.from_bytes(d[:4], "little"), int.from_bytes(d[4:], "little"))
        return self._hash


class ABCDPlayer(SearchPlayer):
    """ABCD search player; see the module docstring for the algorithm and its options."""

    algorithm = "abcd"

    def __init__(self, options: dict[str, Any], name: str = "abcd"):
        super().__init__(options, name)
        o = options
        self.ordering: tuple[str, ...] = o["ordering"]
        self.model: str | None = o["opponent_model"]
        self.fallback_script: str = o["fallback"]
        self.info_scripts = unique(
            self.ordering + ((self.model,) if self.model else ()) + (self.fallback_script,)
        )
        self.playout = (o["playout0"], o["playout1"])
        self.tt = TranspositionTable(o["tt_size"]) if o["tt"] else None
        #: Prefetch the eldest leaves of depth-2 nodes (``_Search._prefetch_eldest``); switching
        #: it off changes the engine calls made, never the decisions.
        self.prefetch = True

    def reset(self, seed: int) -> None:
        super().reset(seed)
        self.tt = TranspositionTable(self.options["tt_size"]) if self.options["tt"] else None

    def _engine(self, dev: DeviceArgs, stats: SearchStats) -> Engine:
        return Engine(self, dev, self.info_scripts, self.playout, stats)

    def _warmup(self, root: np.ndarray, dev: DeviceArgs) -> None:
        o = self.options
        self._engine(dev, SearchStats()).warmup(
            root,
            [1, resolve_batch(o["batch"], dev.num_slots, o["max_children"]), o["max_children"]],
        )

    # -- search ------------------------------------------------------------------------------
    def _search(
        self, root: np.ndarray, dev: DeviceArgs, p: int, stats: SearchStats, t0: float
    ) -> np.ndarray:
        o = self.options
        n = dev.num_slots
        engine = self._engine(dev, stats)
        rinfo = engine.run(
            1,
            root[None],
            np.zeros((1, 2, n), np.int32),
            np.zeros((1, 2), bool),
            np.zeros(1, bool),
            p,
            0,
        )
        root_node = _Node(root, rinfo["info"], 0, 0)
        acting = root_node["acting"][p]
        fb = root_node["scripts"][self.info_scripts.index(self.fallback_script), p]
        fallback = np.where(acting, fb, 0).astype(np.int32)
        if not root_node["movers"][p] or root_node["terminal"]:
            stats.fallback = True
            return fallback

        search = _Search(self, engine, p, stats, deadline_from(t0, o["time_ms"]), int(o["nodes"]))
        best: np.ndarray | None = None
        for d in range(1, int(o["max_depth"]) + 1):
            search.root_depth = d
            try:
                _, mv = search.alpha_beta(root_node, d, -1, None, ALPHA0, BETA0)
            except _Timeout:
                break
            if mv is not None:
                best = mv
            stats.depth = d
        stats.extra["tt_cuts"] = search.tt_cuts
        if best is None:
            stats.fallback = True
            return fallback
        return best


class _Search:
    """One decision's alpha-beta state (counters, budget, compiled calls)."""

    def __init__(
        self,
        player: ABCDPlayer,
        engine: Engine,
        p: int,
        stats: SearchStats,
        deadline: float,
        max_nodes: int,
    ):
        self.pl = player
        self.o = player.options
        self.engine = engine
        self.dev = engine.dev
        self.p = p
        self.stats = stats
        self.deadline = deadline
        self.max_nodes = max_nodes
        self.root_depth = 1
        self.tt_cuts = 0
        self.cap, self.use_ltd = eval_params(self.o["eval"])
        self.batch = resolve_batch(self.o["batch"], engine.dev.num_slots, self.o["max_children"])
        stats.extra["batch"] = self.batch

    def _enter(self) -> None:
        """``nodesExpanded++`` and the budget test at every node."""
        self.stats.nodes += 1
        if (
            self.max_nodes and self.stats.nodes > self.max_nodes
        ) or time.perf_counter() >= self.deadline:
            raise _Timeout

    def _player_to_move(self, node: _Node, depth: int, last: int, first_sim: bool) -> int:
        movers = node["movers"]
        if movers[0] and movers[1]:
            if not first_sim:
                return 1 - last
            if depth == self.root_depth:
                return self.p
            policy = self.o["player_to_move"]
            if policy == "alternate":
                return 1 - last
            if policy == "not-alternate":
                return last
            return int(self.pl.rng.integers(2))
        return 0 if movers[0] else 1

    def _call(
        self, k: int, node: _Node, rows: list[tuple[np.ndarray, np.ndarray]], cap: int
    ) -> dict[str, Any]:
        """Apply each (actions [2, U], mask [2]) to ``node``'s state in one call of batch ``k``."""
        actions = np.stack([a for a, _ in rows])
        mask = np.stack([mk for _, mk in rows])
        return self.engine.run(
            k, node.vec, actions, mask, np.ones(len(rows), bool), self.p, cap, self.use_ltd
        )

    def _score(self, value: int, both_dead: bool, path_moves: int, playout_moves: int) -> Score:
        if both_dead:
            return (0, -path_moves)
        if self.o["eval"] == "playout":
            return (int(value), -(2 * path_moves + int(playout_moves)))
        return (int(value), -path_moves)

    def alpha_beta(
        self,
        node: _Node,
        depth: int,
        last: int,
        prev_sim: np.ndarray | None,
        alpha: Score,
        beta: Score,
        eldest: tuple[np.ndarray, LeafValue] | None = None,
    ) -> tuple[Score, np.ndarray | None]:
        """SparCraft's ``alphaBeta``. ``eldest``: a prefetched (move, value) of this node's first
        child when that child is a leaf (see ``_prefetch_eldest``)."""
        self._enter()
        p = self.p
        movers = node["movers"]
        both = bool(movers[0] and movers[1])
        ptm = self._player_to_move(node, depth, last, prev_sim is None)
        is_max = ptm == p
        tt = self.pl.tt
        tt_state = (not both) or prev_sim is None
        entry: TTEntry | None = None
        if tt is not None and tt_state:
            h1, h2 = node.hash()
            entry = tt.lookup(h1, h2)
            if entry is not None and entry.depth == depth:
                if entry.kind == LOWER:
                    alpha = max(alpha, entry.score)
                elif entry.kind == UPPER:
                    beta = min(beta, entry.score)
                else:
                    alpha = beta = entry.score
                if alpha >= beta:
                    self.tt_cuts += 1
                    return entry.score, entry.move_for(ptm)
        orig_alpha, orig_beta = alpha, beta
        only_first = entry is not None and entry.depth >= depth and entry.move_for(ptm) is not None

        scripts = node["scripts"]
        ordered = [scripts[self.pl.info_scripts.index(s), ptm] for s in self.pl.ordering]
        model = (
            scripts[self.pl.info_scripts.index(self.pl.model), ptm]
            if (self.pl.model and ptm != p)
            else None
        )
        vecs = child_moves(
            node["legal"][ptm],
            node["acting"][ptm],
            node["order"][1 - ptm],
            ordered,
            self.o["max_children"],
            self.pl.rng,
            model_move=model,
            only_first=only_first,
        )

        best_move: np.ndarray | None = None
        best_response: np.ndarray | None = None

        def update(val: Score, vec: np.ndarray, response: np.ndarray | None) -> None:
            nonlocal alpha, beta, best_move, best_response
            if is_max and val > alpha:
                alpha = val
                best_move = vec
                if both and prev_sim is None:
                    best_response = response
            elif not is_max and val < beta:
                beta = val
                best_move = vec
                if both and prev_sim is not None:
                    best_response = response

        if both and prev_sim is None and depth != 1:
            # First mover of a simultaneous pair: pass the vector down without applying it.
            pre = self._prefetch_eldest([(node, ptm, v) for v in vecs]) if depth == 2 else {}
            for i, vec in enumerate(vecs):
                val, resp = self.alpha_beta(node, depth - 1, ptm, vec, alpha, beta, pre.get(i))
                update(val, vec, resp)
                if alpha >= beta:
                    break
        else:
            rows = self._leaf_rows(vecs, ptm, prev_sim)
            if depth - 1 <= 0:
                self._leaf_loop(node, vecs, rows, update, lambda: alpha >= beta, eldest)
            else:
                out = self._call(self.o["max_children"], node, rows, 0)
                kids = [
                    _Node(
                        out["child"][i],
                        out["info"],
                        i,
                        node.path_moves + int(out["step_moves"][i, p]),
                    )
                    for i in range(len(vecs))
                ]
                pre = self._prefetch_eldest([(c, ptm, None) for c in kids]) if depth == 2 else {}
                for i, vec in enumerate(vecs):
                    child = kids[i]
                    if child["terminal"]:
                        # A terminal child is a leaf: its playout plays no turn.
                        self._enter()
                        ev = int(child["ev"][p])
                        both_dead = _both_dead(child, ev)
                        val = self._score(ev, both_dead, child.path_moves, 0)
                        resp = None
                    else:
                        val, resp = self.alpha_beta(
                            child, depth - 1, ptm, None, alpha, beta, pre.get(i)
                        )
                    update(val, vec, resp)
                    if alpha >= beta:
                        break

        if tt is not None and tt_state:
            value = alpha if is_max else beta
            h1, h2 = node.hash()
            old = tt.lookup(h1, h2)
            if not (old is not None and old.depth > depth):
                kind = UPPER if value <= orig_alpha else (LOWER if value >= orig_beta else ACCURATE)
                tt.save(h1, TTEntry(h2, value, depth, kind, ptm, best_move, best_response))
        return (alpha if is_max else beta), best_move

    def _leaf_rows(
        self, vecs: list[np.ndarray], ptm: int, prev_sim: np.ndarray | None
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        rows = []
        for vec in vecs:
            a = np.zeros((2, self.dev.num_slots), np.int32)
            mk = np.zeros(2, bool)
            a[ptm], mk[ptm] = vec, True
            if prev_sim is not None:
                a[1 - ptm], mk[1 - ptm] = prev_sim, True
            rows.append((a, mk))
        return rows

    def _leaf_values(
        self,
        bases: list[np.ndarray],
        rows: list[tuple[np.ndarray, np.ndarray]],
        path_moves: list[int],
        k: int,
    ) -> list[LeafValue]:
        """Evaluate leaves (base state, joint action) in one engine call of batch ``k``."""
        base = np.stack(bases) if len(bases) > 1 else bases[0]  # one [L] state: shared by all rows
        actions = np.stack([a for a, _ in rows])
        mask = np.stack([mk for _, mk in rows])
        out = self.engine.run(
            k, base, actions, mask, np.ones(len(rows), bool), self.p, self.cap, self.use_ltd
        )
        if self.o["eval"] == "playout":
            self.stats.playouts += len(rows)
        return [
            (
                int(out["value"][j]),
                bool(out["both_dead"][j]),
                path_moves[j] + int(out["step_moves"][j, self.p]),
                int(out["playout_moves"][j]),
            )
            for j in range(len(rows))
        ]

    def _prefetch_eldest(
        self, kids: list[tuple[_Node, int, np.ndarray | None]]
    ) -> dict[int, tuple[np.ndarray, LeafValue]]:
        """Young brothers wait, one level up: before a depth-2 node searches its children, the
        first (eldest) leaf of every child is evaluated in one batched call.

        ``kids``: (state, the parent's player to move, the parent's vector passed down when the
        child is the second mover of a simultaneous pair, else None). Only when a child's first
        child is known without drawing random numbers: it is the first ordering script's (or
        the opponent model's) move, which SparCraft puts first whatever the shuffle and the
        transposition table say. Values are those the serial search would compute; a prefetched
        leaf whose parent is cut off or answered from the table is wasted work only.
        """
        if (
            not self.pl.prefetch
            or not (self.pl.ordering or self.pl.model)
            or self.o["player_to_move"] == "random"
        ):
            return {}
        want: list[tuple[int, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray], int]] = []
        for i, (child, last, prev_sim) in enumerate(kids):
            if child["terminal"]:
                continue
            ptm = self._player_to_move(child, 1, last, prev_sim is None)
            scripts = child["scripts"]
            if self.pl.model and ptm != self.p:
                first = scripts[self.pl.info_scripts.index(self.pl.model), ptm]
            else:
                first = scripts[self.pl.info_scripts.index(self.pl.ordering[0]), ptm]
            first = np.where(child["acting"][ptm], first, 0).astype(np.int32)
            row = self._leaf_rows([first], ptm, prev_sim)[0]
            want.append((i, first, child.vec, row, child.path_moves))
        if len(want) < 2:
            return {}
        k = self.o["max_children"]
        vals = self._leaf_values(
            [w[2] for w in want], [w[3] for w in want], [w[4] for w in want], k
        )
        return {w[0]: (w[1], v) for w, v in zip(want, vals, strict=True)}

    def _leaf_loop(
        self, node: _Node, vecs, rows, update, cut, eldest: tuple[np.ndarray, LeafValue] | None
    ) -> None:
        """Children that are leaves: eldest alone (or prefetched), then the rest in batches,
        consumed in order with SparCraft's node count and budget test."""
        batch = self.batch
        values: list[LeafValue | None] = [None] * len(vecs)
        if eldest is not None and np.array_equal(eldest[0], vecs[0]):
            values[0] = eldest[1]

        def fill(i: int) -> None:
            if i == 0 or batch == 1:
                idx, k = [i], 1
            else:
                idx, k = list(range(i, min(i + batch, len(vecs)))), batch
            vals = self._leaf_values(
                [node.vec], [rows[j] for j in idx], [node.path_moves] * len(idx), k
            )
            for j, v in zip(idx, vals, strict=True):
                values[j] = v

        for i, vec in enumerate(vecs):
            self._enter()
            if values[i] is None:
                fill(i)
            v = values[i]
            assert v is not None
            update(self._score(*v), vec, None)
            if cut():
                break


def _both_dead(child: _Node, ev: int) -> bool:
    """Whether both sides of a terminal child are dead (its eval is then 0 with no bonus): every
    living unit's HP row is empty for both players in the hash material."""
    mat = child["hash"]  # [2, U, 6]; column 4 is HP, zero for dead units
    return ev == 0 and not (mat[0, :, 4] > 0).any() and not (mat[1, :, 4] > 0).any()
