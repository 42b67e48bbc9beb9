"""UCT Considering Durations (UCT-CD; Churchill & Buro, CIG 2013; SparCraft ``UCTSearch``).

What it does (docs/baselines.md#uct-cd): a Monte-Carlo tree search over joint moves of one side at a
time. Time jumps to the next decision turn; when both sides can act, the joint move is split into
a **FirstSim** node (the first mover's vector, not applied yet) and a **SecondSim** child that
applies both vectors and then ``finishedMoving``; nodes where one side acts are **Solo** nodes.
The max player moves first at the root; below it the first mover follows the Alternate policy
(the enemy of the node's player). Children: up to ``max_children`` joint moves, the ordering
scripts' moves first (NOKDPS, KiterDPS), then the shuffled odometer (``moves``).

A traversal: at an unvisited node apply its move(s) (a FirstSim leaf applies only its own vector)
and evaluate by a playout (NOKDPS vs NOKDPS, <= 200 turns, ``evalLTD2`` of the end state from
the max player's view, +-100000 if a side of the evaluated state is dead); at a visited node
whose state is terminal take ``eval(LTD2)``; otherwise generate the children once, take the first
unvisited child or the best UCB child (win rate + C sqrt(ln N / n) at max-player nodes, win rate
- ... at min-player nodes) and recurse. Backup: visits + 1, wins + 1 / 0.5 / 0 for a value > 0,
= 0, < 0. The root returns its most visited child (first on ties).

Parameters (``base.UCT_OPTIONS``): time_ms 40, traversals 5000, C 1.6, max_children 20,
ordering nokdps+kiter-dps, playouts nokdps/nokdps, Alternate, no opponent model, most visited.

Deviations from SparCraft
-------------------------
- **Leaf parallelism** (``batch``, default ``auto``: 32 playouts per call up to 12 units a side,
  16 up to 24, 8 up to 40, then 4; see ``base.auto_batch``): each round descends up to ``batch`` times, marking
  every node on a path with a *virtual loss* (one visit, a loss for the player choosing it), and
  evaluates all collected leaves in one batched engine call, then backs the real results up. A
  descent that reaches a node whose evaluation is still in flight ends the round. ``batch=1`` is
  SparCraft's serial algorithm. The root's own first playout joins the first round (its
  children are known before its playout returns because the root state is).
- The traversal budget and the clock are checked after every round (SparCraft: every 5th
  traversal).
- If the root has no children when the search stops (a terminal root state, or a budget spent
  on the root's own playout), the first ordering script's move is returned (SparCraft would
  dereference a null child).
- Move shuffles use the player's seeded NumPy generator (SparCraft: ``random_device``), so a
  deterministic budget with the same seed gives the same decisions.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from hybridmarl.search import kernels as K
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

ROOT, SOLO, FIRST, SECOND = 0, 1, 2, 3


def noop_finish(vec: np.ndarray, num_slots: int) -> np.ndarray:
    """``makeMoves({}); finishedMoving()`` on a decision state, on the host: the time stays (it
    already is the minimum free time), the turn count goes up and the stalemate counter counts
    this turn if the HP sums did not change (they cannot without actions)."""
    out = vec.copy()
    base = len(K.DYNAMIC_FIELDS) * 2 * num_slots
    hp = vec[6 * 2 * num_slots : 7 * 2 * num_slots].reshape(2, num_slots)
    hp_sum = np.maximum(hp, 0).sum(axis=1)
    same = bool(np.all(hp_sum == vec[base + 3 : base + 5]))
    out[base + 1] += 1
    out[base + 2] = vec[base + 2] + 1 if same else 0
    out[base + 3 : base + 5] = hp_sum
    return out


class _Info:
    """A view of one state's node info inside a batch returned by a compiled call."""

    __slots__ = ("batch", "i", "vec")

    def __init__(self, batch: dict[str, np.ndarray], i: int, vec: np.ndarray):
        self.batch = batch
        self.i = i
        self.vec = vec

    def __getitem__(self, k: str) -> Any:
        return self.batch[k][self.i]


class UCTPlayer(SearchPlayer):
    """UCT-CD search player; see the module docstring for the algorithm and its options."""

    algorithm = "uct"

    def __init__(self, options: dict[str, Any], name: str = "uct"):
        super().__init__(options, name)
        o = options
        self.ordering: tuple[str, ...] = o["ordering"]
        self.model: str | None = o["opponent_model"]
        self.info_scripts = unique(self.ordering + ((self.model,) if self.model else ()))
        self.playout = (o["playout0"], o["playout1"])

    def _engine(self, dev: DeviceArgs, stats: SearchStats) -> Engine:
        return Engine(self, dev, self.info_scripts, self.playout, stats)

    def _warmup(self, root: np.ndarray, dev: DeviceArgs) -> None:
        self._engine(dev, SearchStats()).warmup(
            root, [1, resolve_batch(self.options["batch"], dev.num_slots)]
        )

    # -- search ------------------------------------------------------------------------------
    def _search(
        self, root: np.ndarray, dev: DeviceArgs, p: int, stats: SearchStats, t0: float
    ) -> np.ndarray:
        o = self.options
        n = dev.num_slots
        deadline = deadline_from(t0, o["time_ms"])
        c_value = float(o["c"])
        max_trav = int(o["traversals"])
        batch = resolve_batch(o["batch"], n)
        stats.extra["batch"] = batch
        engine = self._engine(dev, stats)
        cap, use_ltd = eval_params(o["eval"])

        # Root: SparCraft applies the root's (empty) move and finishedMoving on every traversal.
        root_post = noop_finish(root, n)
        rinfo = engine.run(
            1,
            root_post[None],
            np.zeros((1, 2, n), np.int32),
            np.zeros((1, 2), bool),
            np.zeros(1, bool),
            p,
            0,
        )
        root_info = _Info(rinfo["info"], 0, root_post)
        fallback = self._fallback(root_info, p)
        if not root_info["movers"][p] or root_info["terminal"]:
            stats.fallback = True
            return fallback

        # Tree as parallel lists (cheap to index from Python).
        parent = [-1]
        player = [-1]
        ntype = [ROOT]
        move: list[np.ndarray | None] = [None]
        visits = [0]
        wins = [0.0]
        vvis = [0]
        vwins = [0.0]
        children: list[list[int] | None] = [None]
        info: list[_Info | None] = [root_info]  # expansion state of each node (None: not yet known)
        depth = [0]
        maxp_node = [True]  # is the node a max-player node (its children are the max player's)

        def expand(node: int) -> None:
            inf = info[node]
            assert inf is not None
            movers = inf["movers"]
            both = bool(movers[0] and movers[1])
            if both:
                if node == 0:
                    ptm = p
                elif ntype[node] == FIRST or o["player_to_move"] == "alternate":
                    ptm = 1 - player[node]
                elif o["player_to_move"] == "not-alternate":
                    ptm = player[node]
                else:
                    ptm = int(self.rng.integers(2))
                ctype = SECOND if ntype[node] == FIRST else FIRST
            else:
                ptm = 0 if movers[0] else 1
                ctype = SOLO
            scripts = inf["scripts"]
            ordered = [scripts[self.info_scripts.index(s), ptm] for s in self.ordering]
            model = (
                scripts[self.info_scripts.index(self.model), ptm]
                if (self.model and ptm != p)
                else None
            )
            vecs = child_moves(
                inf["legal"][ptm],
                inf["acting"][ptm],
                inf["order"][1 - ptm],
                ordered,
                o["max_children"],
                self.rng,
                model_move=model,
            )
            kids = []
            for v in vecs:
                kids.append(len(parent))
                parent.append(node)
                player.append(ptm)
                ntype.append(ctype)
                move.append(v)
                visits.append(0)
                wins.append(0.0)
                vvis.append(0)
                vwins.append(0.0)
                children.append(None)
                # A FirstSim node is expanded from its parent's state (its move is not applied).
                info.append(inf if ctype == FIRST else None)
                depth.append(depth[node] + 1)
                maxp_node.append(False)
            children[node] = kids
            stats.nodes += len(kids)
            # A node is a max-player node if it is the root or its children are the max player's.
            maxp_node[node] = node == 0 or ptm == p
            stats.depth = max(stats.depth, depth[node] + 1)

        def select(node: int) -> int:
            kids = children[node]
            assert kids
            big_n = visits[node] + vvis[node]
            log_n = math.log(big_n) if big_n > 0 else 0.0
            is_max = maxp_node[node]
            best, best_val = kids[0], -math.inf if is_max else math.inf
            for c in kids:
                nc = visits[c] + vvis[c]
                if nc == 0:
                    return c
                wr = (wins[c] + vwins[c]) / nc
                term = c_value * math.sqrt(log_n / nc)
                if is_max:
                    val = wr + term
                    if val > best_val:
                        best, best_val = c, val
                else:
                    val = wr - term
                    if val < best_val:
                        best, best_val = c, val
            return best

        def backup(path: list[int], value: int, virtual: bool) -> None:
            w = 1.0 if value > 0 else (0.5 if value == 0 else 0.0)
            for nd in path:
                if virtual:
                    vvis[nd] -= 1
                    vwins[nd] -= _virtual_loss(nd)
                visits[nd] += 1
                wins[nd] += w

        def _virtual_loss(nd: int) -> float:
            # A loss for whoever chose the node: 0 wins under a max-player parent, 1 under a min one.
            return 0.0 if nd == 0 or maxp_node[parent[nd]] else 1.0

        done = 0
        while done < max_trav:
            leaves: list[tuple[int, list[int]]] = []
            descents = 0
            while descents < batch and done + len(leaves) < max_trav:
                descents += 1
                node, path = 0, [0]
                leaf = -1
                aborted = False
                while True:
                    if visits[node] + vvis[node] == 0:
                        leaf = node
                        break
                    inf = info[node]
                    if inf is None:  # evaluation in flight, state unknown: end the round
                        aborted = True
                        break
                    if ntype[node] != FIRST and inf["terminal"]:
                        break
                    if children[node] is None:
                        expand(node)
                    node = select(node)
                    path.append(node)
                if aborted:
                    break
                if leaf < 0:  # a visited terminal node: eval(LTD2), no playout
                    backup(path, int(info[node]["ev"][p]), virtual=False)  # type: ignore[index]
                    done += 1
                    continue
                for nd in path:
                    vvis[nd] += 1
                    vwins[nd] += _virtual_loss(nd)
                leaves.append((leaf, path))
            if not leaves:
                if time.perf_counter() >= deadline:
                    break
                continue
            results = self._evaluate(
                engine, leaves, parent, player, ntype, move, info, root_post, p, batch, cap, use_ltd
            )
            stats.playouts += len(leaves)
            for j, (leaf, path) in enumerate(leaves):
                if leaf != 0 and ntype[leaf] != FIRST:
                    info[leaf] = _Info(results["info"], j, results["child"][j])
                backup(path, int(results["value"][j]), virtual=True)
            done += len(leaves)
            if time.perf_counter() >= deadline:
                break
        stats.traversals = done

        kids = children[0]
        if not kids:
            stats.fallback = True
            return fallback
        if o["root_select"] == "most-visited":
            best = kids[0]
            for c in kids:
                if visits[c] > visits[best]:
                    best = c
        else:
            log_n = math.log(max(visits[0], 1))
            best, best_val = kids[0], -math.inf
            for c in kids:
                if visits[c] == 0:
                    continue
                val = wins[c] / visits[c] + c_value * math.sqrt(log_n / visits[c])
                if val > best_val:
                    best, best_val = c, val
        stats.extra["root_visits"] = visits[0]
        stats.extra["best_visits"] = visits[best]
        mv = move[best]
        assert mv is not None
        return mv

    def _fallback(self, root_info: _Info, p: int) -> np.ndarray:
        acting = root_info["acting"][p]
        if self.ordering:
            m = root_info["scripts"][self.info_scripts.index(self.ordering[0]), p]
            return np.where(acting, m, 0).astype(np.int32)
        # No ordering script: the first legal action of every unit (SparCraft's index 0).
        legal = root_info["legal"][p]
        return np.where(acting, np.argmax(legal, axis=1), 0).astype(np.int32)

    def _evaluate(
        self,
        engine: Engine,
        leaves,
        parent,
        player,
        ntype,
        move,
        info,
        root_post,
        p: int,
        batch: int,
        cap: int,
        use_ltd: bool,
    ):
        """One batched engine call: apply each leaf's move(s) to its parent's state and evaluate."""
        n = engine.dev.num_slots
        m = len(leaves)
        base = np.empty((m, root_post.shape[0]), np.int32)
        actions = np.zeros((m, 2, n), np.int32)
        mask = np.zeros((m, 2), bool)
        do_step = np.zeros(m, bool)
        for j, (leaf, _) in enumerate(leaves):
            if leaf == 0:
                base[j] = root_post
                continue
            par = parent[leaf]
            base[j] = info[par].vec
            pl = player[leaf]
            actions[j, pl] = move[leaf]
            mask[j, pl] = True
            do_step[j] = True
            if ntype[leaf] == SECOND:
                actions[j, player[par]] = move[par]
                mask[j, player[par]] = True
        return engine.run(batch, base, actions, mask, do_step, p, cap, use_ltd)
