"""The grid of a reproduction as data: tasks, and the table cells they fill.

A :class:`GridTask` is ``(kind, config)``; its key is a hash of both, so the same computation
asked for by two tables (Fig. 3 reuses Table 1's training runs at m18v20 and m24v30) is one task,
and a task's run directory never changes between invocations. Kinds:

- ``script``: evaluate a scripted player (the D rows);
- ``search``: evaluate a search player (UCT, A-B, Profile);
- ``train``: train a learner with one seed, then evaluate its policy (BC, DQfD, OGTL, Ours,
  Ours w/o D, Random).

A :class:`Cell` names the tasks of one table entry (one per seed for learners).
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from typing import Any

from hybridmarl.errors import UserError
from hybridmarl.reproduce import protocol as P

KINDS = ("script", "search", "train")


class GridError(UserError):
    """An unknown table, row, scenario, demonstrator, budget or seed list."""


@dataclass(frozen=True)
class GridTask:
    """One independent unit of work: ``kind`` and its full ``config`` (JSON-ready)."""

    kind: str
    config: dict[str, Any]

    @property
    def key(self) -> str:
        """A stable hash of the kind and the whole config (12 hex digits)."""
        doc = json.dumps(
            {"kind": self.kind, "config": self.config}, sort_keys=True, separators=(",", ":")
        )
        return hashlib.sha256(doc.encode()).hexdigest()[:12]

    @property
    def label(self) -> str:
        """A readable name: what is played or trained, where, from which demonstrator."""
        c = self.config
        where = c.get("scenario") or "tj"
        demo = _short(c.get("demonstrator") or c.get("script") or "")
        if self.kind == "train":
            return f"{c['row']}-{where}-{demo}-s{c['seed']}"
        return f"{c['row']}-{where}-{demo}"

    @property
    def dirname(self) -> str:
        """The task's directory under ``<out>/tasks``: readable label and key."""
        return f"{re.sub(r'[^A-Za-z0-9_.-]+', '_', self.label)}-{self.key}"

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "config": self.config, "key": self.key}


def _short(name: str) -> str:
    rev = {v: k for k, v in P.DEMONSTRATORS.items()}
    return rev.get(name, name.split(":")[0])


@dataclass(frozen=True)
class Cell:
    """One entry of a table: ``table``, ``column`` (e.g. ``m5v5/c``; Table 2: ``tj``), ``row``,
    and the keys of its tasks (learners: one per seed, in seed order)."""

    table: str
    column: str
    row: str
    keys: tuple[str, ...]


@dataclass
class Grid:
    """Tasks (by key, in the order they are first asked for) and the cells of each table."""

    budget: str
    setting: str
    tasks: dict[str, GridTask] = field(default_factory=dict)
    cells: list[Cell] = field(default_factory=list)
    selection: dict[str, Any] = field(default_factory=dict)

    def add(self, table: str, column: str, row: str, tasks: list[GridTask]) -> None:
        for t in tasks:
            self.tasks.setdefault(t.key, t)
        self.cells.append(Cell(table, column, row, tuple(t.key for t in tasks)))

    def cells_of(self, table: str) -> list[Cell]:
        return [c for c in self.cells if c.table == table]

    def tables(self) -> list[str]:
        return [t for t in P.TABLES if self.cells_of(t)]


@dataclass(frozen=True)
class Selection:
    """Which part of the grid to run (None: everything the table has)."""

    scenarios: tuple[str, ...] | None = None
    demonstrators: tuple[str, ...] | None = None
    rows: tuple[str, ...] | None = None
    seeds: tuple[int, ...] | None = None
    search_budget: str = "fixed"
    search_model: str = "enemy-playouts"


def _choose(what: str, given: tuple[str, ...] | None, known: tuple[str, ...]) -> tuple[str, ...]:
    if given is None:
        return known
    for g in given:
        if g not in known:
            raise GridError(f"unknown {what} {g!r} (known: {', '.join(known)})")
    return tuple(k for k in known if k in given)


def _train(
    row: str,
    learner: P.Learner,
    *,
    env: str,
    scenario: str | None,
    demonstrator: str,
    seed: int,
    setting: str,
    n: int,
) -> GridTask:
    overrides = dict(learner.overrides)
    if scenario not in (None, "m5v5"):
        overrides.update(learner.large_overrides)
    cfg: dict[str, Any] = {
        "row": row,
        "env": env,
        "algo": learner.algo,
        "preset": learner.preset,
        "overrides": overrides,
        "demonstrator": demonstrator,
        "seed": seed,
        "setting": setting,
        "n": n,
        "eval_seed": P.EVAL_SEED,
    }
    if env == "combat":
        cfg.update(scenario=scenario, enemy=P.CROSS_ENEMY[demonstrator])
    return GridTask("train", cfg)


def _combat_eval(
    row: str, kind: str, player: str, *, scenario: str, demonstrator: str, setting: str, n: int
) -> GridTask:
    return GridTask(
        kind,
        {
            "row": row,
            "env": "combat",
            "scenario": scenario,
            "demonstrator": demonstrator,
            "player": player,
            "enemy": P.CROSS_ENEMY[demonstrator],
            "setting": setting,
            "n": n,
            "eval_seed": P.EVAL_SEED,
        },
    )


_TREE_SEARCH = {"UCT": "uct", "A-B": "abcd"}


def _search_player(row: str, demonstrator: str, options: str, model: str) -> str:
    if row in _TREE_SEARCH:
        # The searching side orders and plays out with its demonstrator. What the search assumes
        # of the enemy (protocol, "Search rows"): its own script in its playouts
        # ("enemy-playouts"), also in the tree ("enemy-script", SparCraft's opponent model), or
        # the demonstrator, as on our side ("demonstrator").
        enemy = P.CROSS_ENEMY[demonstrator]
        knows = {
            "enemy-playouts": f"playout1={enemy},",
            "enemy-script": f"playout1={enemy},opponent_model={enemy},",
        }
        return f"{_TREE_SEARCH[row]}:script={demonstrator},{knows.get(model, '')}{options}"
    return f"pgs:portfolio={P.PROFILE_PORTFOLIO},{options}"  # Profile: PGS choosing between c and w


def expand(
    tables: tuple[str, ...],
    budget_name: str,
    setting: str,
    sel: Selection = Selection(),
    *,
    drop_empty: bool = False,
) -> Grid:
    """The grid of ``tables`` (``table1``, ``table2``, ``fig3``) at ``budget_name`` under
    ``setting``, restricted to ``sel``. Raises :class:`GridError` for an unknown name, or when
    the selection leaves a requested table empty (with ``drop_empty``: only when it leaves every
    table empty; ``reproduce all --rows D`` is Table 1's and Table 2's D rows)."""
    if budget_name not in P.BUDGETS:
        raise GridError(f"unknown budget {budget_name!r} (known: {', '.join(P.BUDGETS)})")
    for t in tables:
        if t not in P.TABLES:
            raise GridError(f"unknown table {t!r} (known: {', '.join(P.TABLES)}, all)")
    if sel.search_budget not in P.SEARCH_BUDGETS:
        raise GridError(
            f"unknown --search-budget {sel.search_budget!r} (known: {', '.join(P.SEARCH_BUDGETS)})"
        )
    if sel.search_model not in P.SEARCH_MODELS:
        raise GridError(
            f"unknown --search-model {sel.search_model!r} (known: {', '.join(P.SEARCH_MODELS)})"
        )
    budget = P.BUDGETS[budget_name]
    known_rows = tuple(dict.fromkeys(P.TABLE1_ROWS + P.TABLE2_ROWS + P.FIG3_CURVES))
    rows = _choose("row", sel.rows, known_rows)
    scenarios = _choose("scenario", sel.scenarios, P.SCENARIOS)
    letters = _choose("demonstrator", sel.demonstrators, tuple(P.DEMONSTRATORS))
    seeds = budget.seeds if sel.seeds is None else tuple(sel.seeds)
    if not seeds or any(s < 0 for s in seeds):
        raise GridError(f"--seeds must be non-negative integers, not {list(seeds)}")
    search = budget.search if sel.search_budget == "fixed" else budget.wallclock_search
    grid = Grid(
        budget_name,
        setting,
        selection={
            "tables": list(tables),
            "rows": list(rows),
            "scenarios": list(scenarios),
            "demonstrators": list(letters),
            "seeds": list(seeds),
            "search_budget": sel.search_budget,
            "search_model": sel.search_model,
        },
    )
    n = budget.eval_battles
    if "table1" in tables:
        for letter in letters:
            demo = P.DEMONSTRATORS[letter]
            for scenario in scenarios:
                column = f"{scenario}/{letter}"
                for row in P.TABLE1_ROWS:
                    if row not in rows:
                        continue
                    if row == "D":
                        tasks = [
                            _combat_eval(
                                row,
                                "script",
                                demo,
                                scenario=scenario,
                                demonstrator=demo,
                                setting=setting,
                                n=n,
                            )
                        ]
                    elif row in budget.search:
                        player = _search_player(
                            row,
                            demo,
                            search[row].format(**P.sparcraft_40ms_budget(scenario)),
                            sel.search_model,
                        )
                        tasks = [
                            _combat_eval(
                                row,
                                "search",
                                player,
                                scenario=scenario,
                                demonstrator=demo,
                                setting=setting,
                                n=n,
                            )
                        ]
                    else:
                        tasks = [
                            _train(
                                row,
                                budget.learners[row],
                                env="combat",
                                scenario=scenario,
                                demonstrator=demo,
                                seed=s,
                                setting=setting,
                                n=n,
                            )
                            for s in seeds
                        ]
                    grid.add("table1", column, row, tasks)
    if "table2" in tables:
        n_tj = budget.eval_episodes_tj
        for row in P.TABLE2_ROWS:
            if row not in rows:
                continue
            if row == "D":
                tasks = [
                    GridTask(
                        "script",
                        {
                            "row": row,
                            "env": "traffic_junction",
                            "demonstrator": P.TJ_DEMONSTRATOR,
                            "player": P.TJ_DEMONSTRATOR,
                            "setting": setting,
                            "n": n_tj,
                            "eval_seed": P.EVAL_SEED,
                        },
                    )
                ]
            else:
                tasks = [
                    _train(
                        row,
                        budget.learners[row],
                        env="traffic_junction",
                        scenario=None,
                        demonstrator=P.TJ_DEMONSTRATOR,
                        seed=s,
                        setting=setting,
                        n=n_tj,
                    )
                    for s in seeds
                ]
            grid.add("table2", "tj", row, tasks)
    if "fig3" in tables:
        demo = P.DEMONSTRATORS["c"]
        for scenario in P.FIG3_SCENARIOS:
            if scenario not in scenarios or "c" not in letters:
                continue
            for row in P.FIG3_CURVES:
                if row not in rows:
                    continue
                tasks = [
                    _train(
                        row,
                        budget.learners[row],
                        env="combat",
                        scenario=scenario,
                        demonstrator=demo,
                        seed=s,
                        setting=setting,
                        n=n,
                    )
                    for s in seeds
                ]
                grid.add("fig3", f"{scenario}/c", row, tasks)
    for t in tables:
        if not grid.cells_of(t) and not (drop_empty and grid.cells):
            raise GridError(
                f"the selection leaves {t} empty (rows {', '.join(rows)}; scenarios {', '.join(scenarios)}; demonstrators {', '.join(letters)})"
            )
    return grid


__all__ = ["KINDS", "Cell", "Grid", "GridError", "GridTask", "Selection", "expand"]
