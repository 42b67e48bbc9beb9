"""Portfolio Greedy Search (PGS; Churchill & Buro, CIG 2013; SparCraft ``PortfolioGreedySearch``).

What it does (sparcraft.md §4.3): searches over assignments of *scripts to units* by greedy
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
  run as one batched engine call.
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
    SearchPlayer,
    SearchStats,
    deadline_from,
    info_for,
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

    def _fn(self, dev: DeviceArgs):
        return K.pgs_fn(dev.num_slots, len(self.portfolio), self.scripts, int(self.options["playout_turns"]), dev.rules_key)

    def _warmup(self, root: np.ndarray, dev: DeviceArgs) -> None:
        k = len(self.portfolio)
        info_for(dev, self.scripts)(self.key(), root[None], *dev.args)
        out = self._fn(dev)(self.key(), root, np.zeros((k, 2, dev.num_slots), np.int32), np.zeros(k, np.int32), *dev.args)
        jax.block_until_ready(out)

    def _search(self, root: np.ndarray, dev: DeviceArgs, p: int, stats: SearchStats, t0: float) -> np.ndarray:
        o = self.options
        info = jax.device_get(info_for(dev, self.scripts)(self.key(), root[None], *dev.args))
        info = {k: v[0] for k, v in info.items()}
        stats.calls += 1
        acting = info["acting"][p]
        s_moves = info["scripts"]  # [S, 2, U]
        pidx = np.array([self.scripts.index(s) for s in self.portfolio], np.int32)
        eidx = self.scripts.index(self.enemy_seed)
        if not info["movers"][p]:
            return np.zeros(dev.num_slots, np.int32)

        fn = self._fn(dev)
        deadline = deadline_from(t0, o["time_ms"])
        budget = int(o["playouts"])
        k = len(self.portfolio)
        n = dev.num_slots
        e = 1 - p

        def run(assign: np.ndarray, side: int) -> np.ndarray:
            out = fn(self.key(), root, assign, np.full(k, side, np.int32), *dev.args)
            stats.calls += 1
            stats.playouts += k
            return np.asarray(out)

        def first_best(values: np.ndarray) -> int:
            best = 0
            for i in range(1, len(values)):
                if values[i] > values[best]:
                    best = i
            return best

        # 1. Seeds: all of a side's units on one portfolio script, the other side on the seed script.
        seeds = []
        for side in (p, e):
            assign = np.full((k, 2, n), eidx, np.int32)
            assign[:, side, :] = pidx[:, None]
            seeds.append(int(pidx[first_best(run(assign, side))]))
        current = np.empty((2, n), np.int32)
        current[p, :] = seeds[0]
        current[e, :] = seeds[1]

        # Living units in SparCraft's unit order (alive, free time, id) of the root state.
        hp = root[6 * 2 * n : 7 * 2 * n].reshape(2, n)
        order = info["order"]

        def improve(side: int) -> None:
            units = [int(u) for u in np.argsort(order[side], kind="stable") if hp[side, u] > 0]
            for _ in range(int(o["iterations"])):
                for u in units:
                    if time.perf_counter() > deadline or (budget and stats.playouts >= budget):
                        stats.extra["stopped_early"] = True
                        break
                    assign = np.repeat(current[None], k, 0)
                    assign[:, side, u] = pidx
                    current[side, u] = pidx[first_best(run(assign, side))]

        improve(p)
        for _ in range(int(o["responses"])):
            improve(e)
            improve(p)

        stats.extra["scripts"] = [self.scripts[int(s)] for s in current[p][hp[p] > 0]]
        move = s_moves[current[p], p, np.arange(n)]
        return np.where(acting, move, 0).astype(np.int32)
