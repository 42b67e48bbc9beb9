"""``hybridmarl reproduce``: the paper's Table 1, Table 2 and Fig. 3 as a resumable grid of runs.

::

    hybridmarl reproduce table1 --budget smoke --scenarios m5v5 --demonstrators c --rows D,BC
    hybridmarl reproduce all --budget cpu                       # every cell, on Ray if installed
    hybridmarl reproduce all --budget full --address HOST:6379  # an existing Ray cluster
    hybridmarl reproduce all --budget cpu --status              # where it stands; tables so far

Every cell is one or more independent tasks (:mod:`hybridmarl.reproduce.grid`); finished ones are
never run again, interrupted training runs resume from their checkpoints, failed ones are
retried. The protocol is :mod:`hybridmarl.reproduce.protocol` (docs/reproducing.md).

This module, and everything the driver imports, leaves JAX to the task processes.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from hybridmarl.errors import UserError
from hybridmarl.options import DEFAULT_IN_DOCSTRING


@dataclass(frozen=True)
class ReproduceConfig:
    """Reproduce the paper's Table 1, Table 2 and Fig. 3 (or one of them) as a grid of independent
    tasks, in parallel on Ray when it is installed, else one after another on this machine.
    Rerunning the same command continues where it stopped."""

    what: tyro.conf.Positional[Annotated[str, tyro.conf.arg(metavar="{table1,table2,fig3,all}")]]
    """What to reproduce: table1, table2, fig3 or all."""
    budget: str = "cpu"
    """smoke (minutes: toy presets, few battles; meaningless numbers), cpu (quick presets, 3
    seeds, 1,000 battles per row: meant for one 2-core machine) or full (the paper's presets)."""
    setting: str = "paper"
    """paper (the paper's rules and calibrated geometry; Traffic Junction p_arrive 0.105) or
    sparcraft (SparCraft's current rules); docs/engine.md#settings."""
    scenarios: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Comma-separated combat scenarios (default: m5v5,m30v30,m18v20,m24v30)."""
    demonstrators: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Comma-separated demonstrators, c and/or w (or attack-closest, attack-weakest); default
    both."""
    rows: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Comma-separated rows (Table 1: D,UCT,A-B,Profile,BC,DQfD,OGTL,Ours; Table 2: D,BC,'Ours
    w/o D',Ours; Fig. 3: Random,BC,DQfD,OGTL,Ours). Default: all of them."""
    seeds: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Comma-separated training seeds of the learner rows (default: the budget's)."""
    search_budget: str = "fixed"
    """Search rows: fixed (deterministic traversals/nodes/playouts per decision) or wallclock
    (the paper's 40 ms per decision; results then depend on the machine)."""
    search_model: str = "enemy-playouts"
    """What the UCT and A-B rows assume of the enemy: enemy-playouts (its own script, known in
    the cross-validation, plays its playouts), enemy-script (also inside the tree: SparCraft's
    opponent model) or demonstrator (the row's demonstrator plays both sides' playouts)."""
    out: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Output folder (default runs/reproduce-<budget>-<setting>)."""
    executor: str = "auto"
    """auto (ray when installed), ray, or local (tasks as child processes on this machine)."""
    address: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Ray cluster to join (HOST:PORT, ray://HOST:PORT or auto); default: start a local one.
    The output folder must be visible to every node."""
    workers: Annotated[int | None, DEFAULT_IN_DOCSTRING] = None
    """Tasks run at the same time (local default 1; Ray default: the cluster's CPUs)."""
    gpus_per_train_task: float = 0.0
    """Ray: GPUs each training task asks for (0: training on the CPU)."""
    status: bool = False
    """Run nothing: show how many tasks are done and write the tables of what is done."""
    force: bool = False
    """Use an output folder made by another version, setting or budget."""


def _split(value: str | None) -> tuple[str, ...] | None:
    if value is None:
        return None
    items = tuple(v.strip() for v in value.split(",") if v.strip())
    if not items:
        raise UserError(f"empty list {value!r}")
    return items


def _seeds(value: str | None) -> tuple[int, ...] | None:
    items = _split(value)
    if items is None:
        return None
    try:
        return tuple(int(s) for s in items)
    except ValueError:
        raise UserError(f"--seeds must be comma-separated integers, not {value!r}") from None


def _demonstrators(value: str | None) -> tuple[str, ...] | None:
    from hybridmarl.reproduce.protocol import DEMONSTRATORS

    items = _split(value)
    if items is None:
        return None
    by_script = {v: k for k, v in DEMONSTRATORS.items()}
    return tuple(by_script.get(d, d) for d in items)


def run_reproduce(cfg: ReproduceConfig, *, live: bool | None = None) -> int:
    """Expand the grid ``cfg`` asks for, run what is not done, write the tables and the report.
    Returns 0 when every task is done, 1 when some failed (each named with its log)."""
    from hybridmarl.reproduce import driver, grid, outputs, protocol
    from hybridmarl.reproduce.executors import make_executor
    from hybridmarl.settings import get_setting

    what = cfg.what.strip().lower()
    tables = protocol.TABLES if what == "all" else (what,)
    setting = get_setting(cfg.setting).name
    if cfg.workers is not None and cfg.workers < 1:
        raise UserError("--workers must be at least 1")
    if cfg.gpus_per_train_task < 0:
        raise UserError("--gpus-per-train-task must be non-negative")
    sel = grid.Selection(
        scenarios=_split(cfg.scenarios),
        demonstrators=_demonstrators(cfg.demonstrators),
        rows=_split(cfg.rows),
        seeds=_seeds(cfg.seeds),
        search_budget=cfg.search_budget,
        search_model=cfg.search_model,
    )
    the_grid = grid.expand(tables, cfg.budget, setting, sel, drop_empty=what == "all")
    executor = (
        None
        if cfg.status
        else make_executor(
            cfg.executor,
            address=cfg.address,
            workers=cfg.workers,
            gpus_per_train_task=cfg.gpus_per_train_task,
        )
    )
    out = Path(cfg.out) if cfg.out else Path("runs") / f"reproduce-{cfg.budget}-{setting}"
    driver.check_output_folder(out, the_grid, force=cfg.force)
    state = driver.GridState(out, the_grid)
    interrupted = False
    try:
        if executor is None:
            driver.prepare(state, retry_failed=False)
        else:
            driver.run_grid(state, executor, live=live)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        # Also after an interruption: the tables show what is done so far.
        import json

        manifest = json.loads((out / driver.MANIFEST).read_text())
        written = outputs.write_outputs(state, manifest)
        print("\n".join(f"wrote {p}" for p in written))
    done = sum(1 for k in the_grid.tasks if state.status(k) == "done")
    print(f"{done}/{len(the_grid.tasks)} tasks done, {len(state.failures)} failed ({out})")
    if interrupted:
        print(
            "interrupted: rerun the same command to continue (finished tasks are kept, training resumes)",
            file=sys.stderr,
        )
        return 130
    for key, f in state.failures.items():
        print(
            f"failed: {the_grid.tasks[key].label}: {f['error']} (log: {f['log']})", file=sys.stderr
        )
    if state.failures:
        print("rerun the same command to retry the failed tasks", file=sys.stderr)
        return 1
    return 0


def reproduce_command(args: list[str]) -> int:
    """``hybridmarl reproduce {table1,table2,fig3,all} [options]``."""
    return run_reproduce(tyro.cli(ReproduceConfig, args=args, prog="hybridmarl reproduce"))


__all__ = ["ReproduceConfig", "reproduce_command", "run_reproduce"]
