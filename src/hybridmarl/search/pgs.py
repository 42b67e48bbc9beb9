"""Portfolio Greedy Search (PGS; Churchill & Buro, CIG 2013; SparCraft ``PortfolioGreedySearch``).

What it does (docs/baselines.md#pgs): searches over assignments of *scripts to units* by greedy
hill-climbing with playout evaluation.

1. **Seed**: for our side, try each portfolio script as the script of all our units, with every
   enemy unit on the enemy seed script (NOKDPS); keep the best playout (ties: first script). The
   enemy's seed is found the same way from the enemy's side (our units on NOKDPS).
2. **Improve(side)**, ``iterations`` times: for each of the side's living units in SparCraft's
   unit order, try each portfolio script for that unit alone (all other assignments fixed), play
   out each, keep the best (ties: first) and assign it. The clock is checked before each unit.
3. Improve(self), then ``responses`` x [Improve(enemy), Improve(self)].
4. Output: for each of our acting units, the action its assigned script chooses in the root state.

A **playout** plays every unit with its own script (``Game::playIndividualScripts``): each turn
every script of the assignment is computed for the whole side (so NOKDPS's overkill bookkeeping
sees all acting units, as ``UnitScriptData::calculateMoves`` does) and each unit takes its own
script's action; it runs while the state is not terminal and rounds <= 100 (so up to 101 turns)
and scores ``eval(side, LTD2)`` of the final state, +-100000 win bonus included.

Playouts per decision with I = 1, R = 0: 2 |P| seed playouts + n |P| improvement playouts, i.e.
4 + 2n for n living units and the default portfolio {NOKDPS, KiterDPS}.

Parameters (``base.PGS_OPTIONS``): time_ms 40 (0 = none, SparCraft's sample config), portfolio
nokdps+kiter-dps, enemy seed nokdps, I = 1, R = 0, playout cap 100.

Deviations from SparCraft
-------------------------
- The candidate playouts of one step (the |P| seeds of a side, or the |P| scripts of one unit)
  run as one batched engine call. With ``lookahead=2`` units are taken in pairs (u1, u2): u1's |P| candidates and u2's |P| candidates for each of u1's
  possible choices (|P| + |P|^2 playouts) run in one call, and the choices are read off as the
  serial search makes them, so the assignment is the same; ``stats.playouts`` counts the
  serial search's playouts (4 + 2n), ``stats.extra["playouts_run"]`` what actually ran. The two
  sides' seed candidates then share one call too. It is off by default: a batch of 6 playouts
  costs about as much as two batches of 2 here (measured: equal at 8v8, ~10% faster at 32v32).
- The time budget counts from the start of the decision (seeds included); SparCraft restarts the
  timer in every ``doPortfolioSearch`` pass and does not count the seeds. A deterministic budget
  (``playouts``) stops the improvement passes once that many playouts ran.
"""

from __future__ import annotations

import time
from typing import Any

import jax
import numpy as np

from hybridmarl.search import kernels as K
from hybridmarl.search.base import (
    DeviceArgs,
    Engine,
    SearchPlayer,
    SearchStats,
    deadline_from,
    unique,
)


class PGSPlayer(SearchPlayer):
    """Portfolio Greedy Search player; see the module docstring."""

    algorithm = "pgs"

    def __init__(self, options: dict[str, Any], name: str = "pgs"):
        super().__init__(options, name)
        self.portfolio: tuple[str, ...] = options["portfolio"]
        self.enemy_seed: str = options["enemy_seed"]
        self.scripts = unique(self.portfolio + (self.enemy_seed,))

    def _lookahead(self, num_slots: int) -> int:
        del num_slots
        return int(self.options["lookahead"])

    def _batch(self, num_slots: int) -> int:
        """Playouts per call: |P| (one unit's candidates), or |P| + |P|^2 with lookahead 2
        (which also holds both sides' |P| seed candidates)."""
        k = len(self.portfolio)
        return k + k * k if self._lookahead(num_slots) == 2 else k

    def _fn(self, dev: DeviceArgs):
        return K.pgs_fn(
            dev.num_slots,
            self._batch(dev.num_slots),
            self.scripts,
            int(self.options["playout_turns"]),
            dev.rules_key,
        )

    def _engine(self, dev: DeviceArgs, stats: SearchStats) -> Engine:
        # Only the root's node info (this portfolio's moves, unit order) comes from the search
        # program; its playout scripts are the UCT/ABCD defaults so the program is shared.
        return Engine(self, dev, self.scripts, ("nokdps", "nokdps"), stats)

    def _warmup(self, root: np.ndarray, dev: DeviceArgs) -> None:
        k = self._batch(dev.num_slots)
        self._engine(dev, SearchStats()).warmup(root, [1])
        if dev.native is not None:
            return
        out = self._fn(dev)(
            self.key(),
            root,
            np.zeros((k, 2, dev.num_slots), np.int32),
            np.zeros(k, np.int32),
            *dev.args,
        )
        jax.block_until_ready(out)

    def _search(
        self, root: np.ndarray, dev: DeviceArgs, p: int, stats: SearchStats, t0: float
    ) -> np.ndarray:
        o = self.options
        info = self._engine(dev, stats).info(root)
        acting = info["acting"][p]
        s_moves = info["scripts"]  # [S, 2, U]
        pidx = np.array([self.scripts.index(s) for s in self.portfolio], np.int32)
        eidx = self.scripts.index(self.enemy_seed)
        if not info["movers"][p]:
            return np.zeros(dev.num_slots, np.int32)

        fn = self._fn(dev) if dev.native is None else None
        deadline = deadline_from(t0, o["time_ms"])
        budget = int(o["playouts"])
        k = len(self.portfolio)
        n = dev.num_slots
        e = 1 - p
        lookahead = self._lookahead(n)
        batch = self._batch(n)
        stats.extra["lookahead"] = lookahead
        stats.extra["playouts_run"] = 0

        def run(assign: np.ndarray, sides: np.ndarray) -> np.ndarray:
            """Playouts of ``m <= batch`` assignments (padded with copies of the first on JAX)."""
            m = assign.shape[0]
            if fn is None:
                from hybridmarl.search.native import pgs_call

                out = pgs_call(
                    dev.native,
                    root,
                    assign,
                    sides.astype(np.int32),
                    self.scripts,
                    int(o["playout_turns"]),
                    int(self.key()[0]),
                )
                stats.calls += 1
                stats.extra["playouts_run"] += m
                return out
            if m < batch:
                assign = np.concatenate([assign, np.repeat(assign[:1], batch - m, 0)])
                sides = np.concatenate([sides, np.repeat(sides[:1], batch - m)])
            out = np.asarray(fn(self.key(), root, assign, sides.astype(np.int32), *dev.args))
            stats.calls += 1
            stats.extra["playouts_run"] += m
            return out[:m]

        def first_best(values: np.ndarray) -> int:
            best = 0
            for i in range(1, len(values)):
                if values[i] > values[best]:
                    best = i
            return best

        def out_of_budget() -> bool:
            return time.perf_counter() > deadline or bool(budget and stats.playouts >= budget)

        # 1. Seeds: all of a side's units on one portfolio script, the other side on the seed
        #    script; evaluated from that side's view.
        seed_assign = np.full((2 * k, 2, n), eidx, np.int32)
        seed_assign[:k, p, :] = pidx[:, None]
        seed_assign[k:, e, :] = pidx[:, None]
        sides = np.array([p] * k + [e] * k)
        if lookahead == 2:
            vals = run(seed_assign, sides)
        else:
            vals = np.concatenate(
                [run(seed_assign[:k], sides[:k]), run(seed_assign[k:], sides[k:])]
            )
        stats.playouts += 2 * k
        current = np.empty((2, n), np.int32)
        current[p, :] = pidx[first_best(vals[:k])]
        current[e, :] = pidx[first_best(vals[k:])]

        # Living units in SparCraft's unit order (alive, free time, id) of the root state.
        hp = root[6 * 2 * n : 7 * 2 * n].reshape(2, n)
        order = info["order"]

        def improve(side: int) -> None:
            units = [int(u) for u in np.argsort(order[side], kind="stable") if hp[side, u] > 0]
            side_arr = np.full(batch, side)
            for _ in range(int(o["iterations"])):
                i = 0
                while i < len(units):
                    if out_of_budget():
                        stats.extra["stopped_early"] = True
                        break
                    u1 = units[i]
                    if lookahead == 2 and i + 1 < len(units):
                        # Speculative pair: u1's |P| candidates, and u2's |P| candidates for every
                        # choice u1 could make, in one call; the greedy choices are then read
                        # off exactly as the serial search would make them.
                        u2 = units[i + 1]
                        assign = np.repeat(current[None], batch, 0)
                        assign[:k, side, u1] = pidx
                        assign[k:, side, u1] = np.repeat(pidx, k)
                        assign[k:, side, u2] = np.tile(pidx, k)
                        vals = run(assign, side_arr)
                        b1 = first_best(vals[:k])
                        current[side, u1] = pidx[b1]
                        stats.playouts += k
                        if out_of_budget():
                            stats.extra["stopped_early"] = True
                            break
                        current[side, u2] = pidx[first_best(vals[k + b1 * k : k + (b1 + 1) * k])]
                        stats.playouts += k
                        i += 2
                    else:
                        assign = np.repeat(current[None], k, 0)
                        assign[:, side, u1] = pidx
                        current[side, u1] = pidx[first_best(run(assign, side_arr[:k]))]
                        stats.playouts += k
                        i += 1

        improve(p)
        for _ in range(int(o["responses"])):
            improve(e)
            improve(p)

        stats.extra["scripts"] = [self.scripts[int(s)] for s in current[p][hp[p] > 0]]
        move = s_moves[current[p], p, np.arange(n)]
        return np.where(acting, move, 0).astype(np.int32)
