"""The output folder of a reproduction, the state of each task, and the loop that runs what is
left.

Folder layout::

    <out>/reproduce.json          version, setting and budget the folder belongs to
    <out>/grid.json               the tasks and the cells they fill
    <out>/tasks/<label>-<key>/    one per task: task.json, log.txt, result.json | failed.json,
                                  run/ (training runs: checkpoints, episodes.csv, eval.json)
    <out>/table1.md|json, table2.md|json, fig3.png, report.html

A task is done when its ``result.json`` exists and validates (its key, and one outcome per
evaluation battle); it is never run again. A failed task has ``failed.json`` (exit code, error,
log path) and is retried by the next invocation. Everything is written atomically, and this
module does not import JAX (the workers do).
"""

from __future__ import annotations

import contextlib
import datetime
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hybridmarl.errors import EXIT_BAD_INPUT, EXIT_DIVERGED, UserError
from hybridmarl.io import write_json_atomic
from hybridmarl.reproduce.executors import LOG_FILE, LocalExecutor, RayExecutor
from hybridmarl.reproduce.grid import Grid, GridTask
from hybridmarl.reproduce.protocol import army_sizes
from hybridmarl.reproduce.worker import RESULT_FILE, TASK_FILE

MANIFEST = "reproduce.json"
FAILED_FILE = "failed.json"


class OutputFolderError(UserError):
    """An output folder that belongs to another version, setting or budget."""


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def check_output_folder(out: Path, grid: Grid, *, force: bool) -> None:
    """Refuse a folder made by another version, setting or budget (unless ``force``); record
    ours in its manifest."""
    from hybridmarl import __version__

    mine = {"version": __version__, "setting": grid.setting, "budget": grid.budget}
    path = out / MANIFEST
    doc: dict[str, Any] = {}
    if path.is_file():
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError):
            doc = {}
        for k, v in mine.items():
            if doc.get(k) != v and not force:
                raise OutputFolderError(
                    f"{out} holds a reproduction of {k} {doc.get(k)!r}, not {v!r}; choose another --out or pass --force"
                )
    elif out.exists() and any(out.iterdir()) and not force:
        raise OutputFolderError(
            f"{out} is not empty and holds no {MANIFEST}; choose another --out or pass --force"
        )
    write_json_atomic(
        path, {**doc, **mine, "created": doc.get("created", _now()), "updated": _now()}
    )


def load_result(task_dir: Path, task: GridTask) -> dict[str, Any] | None:
    """The task's result if it is complete and belongs to this task, else None."""
    try:
        r = json.loads((task_dir / RESULT_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(r, dict) or r.get("key") != task.key or "summary" not in r:
        return None
    per = r.get("per_episode") or {}
    n = task.config["n"]
    if not per or any(len(v) != n for v in per.values()):
        return None
    return r


@dataclass
class GridState:
    """Each task's status (done, failed, running, queued) and what is known about it."""

    out: Path
    grid: Grid
    results: dict[str, dict[str, Any]] = field(default_factory=dict)
    failures: dict[str, dict[str, Any]] = field(default_factory=dict)
    running: dict[str, float] = field(default_factory=dict)  # key -> start time

    def task_dir(self, task: GridTask) -> Path:
        return self.out / "tasks" / task.dirname

    def scan(self) -> None:
        """Read every task's result or failure from disk."""
        self.results.clear()
        self.failures.clear()
        for key, t in self.grid.tasks.items():
            d = self.task_dir(t)
            r = load_result(d, t)
            if r is not None:
                self.results[key] = r
                continue
            with contextlib.suppress(OSError, ValueError):
                self.failures[key] = json.loads((d / FAILED_FILE).read_text())

    def status(self, key: str) -> str:
        if key in self.results:
            return "done"
        if key in self.running:
            return "running"
        if key in self.failures:
            return "failed"
        return "queued"


def prepare(state: GridState, *, retry_failed: bool = True) -> list[GridTask]:
    """Write grid.json and every task.json; return the tasks to run: those not done. Failed ones
    are among them, and their failure record is cleared, unless ``retry_failed`` is False (a
    status report, which runs nothing)."""
    grid = state.grid
    write_json_atomic(
        state.out / "grid.json",
        {
            "budget": grid.budget,
            "setting": grid.setting,
            "selection": grid.selection,
            "tasks": {
                k: {**t.to_dict(), "dir": f"tasks/{t.dirname}"} for k, t in grid.tasks.items()
            },
            "cells": [
                {"table": c.table, "column": c.column, "row": c.row, "keys": list(c.keys)}
                for c in grid.cells
            ],
        },
    )
    state.scan()
    todo = []
    for key, t in grid.tasks.items():
        d = state.task_dir(t)
        d.mkdir(parents=True, exist_ok=True)
        if not (d / TASK_FILE).is_file():
            write_json_atomic(d / TASK_FILE, t.to_dict())
        if key in state.results:
            continue
        if key in state.failures:
            if not retry_failed:
                continue
            (d / FAILED_FILE).unlink(missing_ok=True)
            del state.failures[key]
        todo.append(t)
    return todo


def _why(exit_code: int, error: str | None) -> str:
    if error:
        return error
    if exit_code == EXIT_DIVERGED:
        return "training diverged (NaN/inf, exit 3)"
    if exit_code == EXIT_BAD_INPUT:
        return "bad input (exit 2)"
    if exit_code == -9:
        return "killed (SIGKILL; out of memory?)"
    if exit_code < 0:
        return f"killed by signal {-exit_code}"
    if exit_code == 0:
        return "exited without a valid result.json"
    return f"exit code {exit_code}"


def _last_line(log: Path) -> str:
    """The last non-empty line of a log (the error of a traceback), for the failure record."""
    try:
        lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


def _duration_keys(config: dict[str, Any], kind: str) -> tuple[tuple[str, ...], ...]:
    """The groups a task's duration is pooled in, most specific first: the same row, kind and
    scenario (or environment); the same row and kind. Rows of one kind differ too much in cost
    (a BC run takes a tenth of a hybrid one) to stand in for each other."""
    where = str(config.get("scenario") or config.get("env", ""))
    row = str(config.get("row", ""))
    return (kind, row, where), (kind, row)


#: How a task's wall time grows with the units on the field, as ``units ** exponent``, used when a
#: task's estimate comes from finished tasks of another scenario. Fitted to the ``cpu`` grid's
#: measured costs (docs/results.md#table-1): a learner's per-seed time goes from m5v5 (10 units)
#: to m24v30 (54) and m30v30 (60) about 9-11 times up (exponent 1.2-1.4); a search task, whose
#: budget per decision is fixed, about twice (0.4-0.5); a scripted series is short either way.
SIZE_EXPONENT: dict[str, float] = {"train": 1.3, "search": 0.5, "script": 1.0}


def _units(config: dict[str, Any]) -> int:
    """Units on the field of a combat task (``mAvB``: A + B); 1 for any other task."""
    scenario = config.get("scenario")
    return sum(army_sizes(scenario)) if scenario else 1


def finished_durations(
    out: Path, *, skip: frozenset[str] = frozenset()
) -> list[tuple[dict[str, Any], str, float]]:
    """(config, kind, wall seconds) of every finished task in the output folder, whichever
    command ran it, except the task folders named in ``skip``: what the time left is estimated
    from. Unreadable records are passed over."""
    found = []
    for result in sorted((out / "tasks").glob(f"*/{RESULT_FILE}")):
        if result.parent.name in skip:
            continue
        with contextlib.suppress(OSError, ValueError, TypeError, KeyError, AttributeError):
            r = json.loads(result.read_text())
            found.append(
                (
                    dict(r["config"]),
                    str(json.loads((result.parent / TASK_FILE).read_text())["kind"]),
                    float(r["wall_s"]),
                )
            )
    return found


class Progress:
    """The progress display over the grid: done, running, queued and failed tasks and the
    estimated time left, divided among the workers. A task's expected duration is the mean wall
    time of the finished tasks in the output folder most like it (same row, kind and scenario;
    else same row and kind, scaled to its scenario's size); rows with no finished task yet are
    named instead. A live table on a terminal, a status line per event otherwise."""

    def __init__(self, state: GridState, workers: int, *, live: bool | None = None) -> None:
        self.state, self.workers = state, max(1, workers)
        # Finished tasks outside this command's selection; the selection's own come from state.results.
        self._earlier = finished_durations(
            state.out, skip=frozenset(t.dirname for t in state.grid.tasks.values())
        )
        self.t0 = time.time()
        self.live = sys.stderr.isatty() if live is None else live
        self._rich: Any = None
        self._last_line = 0.0
        if self.live:
            from rich.console import Console
            from rich.live import Live

            self._rich = Live(
                self._render(), console=Console(stderr=True), refresh_per_second=2, transient=False
            )
            self._rich.start()

    def counts(self) -> dict[str, int]:
        c = {"done": 0, "running": 0, "queued": 0, "failed": 0}
        for key in self.state.grid.tasks:
            c[self.state.status(key)] += 1
        return c

    def time_left(self) -> tuple[float, tuple[str, ...]]:
        """Seconds left for the tasks that have an estimate, divided among the workers, and the
        rows of those that have none yet (no task of the same row finished). A duration
        borrowed from another scenario is scaled by the units on the field
        (:data:`SIZE_EXPONENT`)."""
        durations: dict[tuple[str, ...], list[tuple[float, int]]] = {}
        finished = list(self._earlier)
        finished += [
            (
                self.state.grid.tasks[k].config,
                self.state.grid.tasks[k].kind,
                float(r.get("wall_s", 0.0)),
            )
            for k, r in self.state.results.items()
        ]
        for cfg, kind, wall in finished:
            for group in _duration_keys(cfg, kind):
                durations.setdefault(group, []).append((wall, _units(cfg)))
        left, unknown = 0.0, []
        now = time.time()
        for key, t in self.state.grid.tasks.items():
            status = self.state.status(key)
            if status in ("done", "failed"):
                continue
            known = next(
                (durations[g] for g in _duration_keys(t.config, t.kind) if g in durations), None
            )
            if not known:
                row = str(t.config.get("row", t.kind))
                if row not in unknown:
                    unknown.append(row)
                continue
            units, exponent = _units(t.config), SIZE_EXPONENT.get(t.kind, 1.0)
            mean = sum(wall * (units / n) ** exponent for wall, n in known) / len(known)
            left += (
                max(mean - (now - self.state.running[key]), 0.0) if status == "running" else mean
            )
        return left / self.workers, tuple(unknown)

    def eta_s(self) -> float | None:
        """Seconds left, or None while some task still to run has no estimate."""
        left, unknown = self.time_left()
        return None if unknown else left

    def line(self) -> str:
        c = self.counts()
        seconds, unknown = self.time_left()
        left = f"~{_duration(seconds)} left"
        if unknown:
            # Rows with no finished task yet are named, not guessed from other rows' durations.
            left = (
                f"{left}, plus {', '.join(unknown)} (none finished yet)"
                if seconds > 0
                else "~? left"
            )
        return (
            f"reproduce: {c['done']}/{sum(c.values())} done, {c['running']} running, {c['queued']} queued, "
            f"{c['failed']} failed; {_duration(time.time() - self.t0)} elapsed, {left}"
        )

    def _render(self) -> Any:
        from rich.table import Table

        table = Table(title=self.line(), title_justify="left", show_edge=False)
        table.add_column("running task")
        table.add_column("for", justify="right")
        now = time.time()
        for key, since in self.state.running.items():
            table.add_row(self.state.grid.tasks[key].label, _duration(now - since))
        return table

    def event(self, message: str) -> None:
        if self._rich is not None:
            self._rich.console.print(message)
            self._rich.update(self._render())
        else:
            print(f"{message}\n{self.line()}", file=sys.stderr, flush=True)
            self._last_line = time.time()

    def tick(self) -> None:
        if self._rich is not None:
            self._rich.update(self._render())
        elif time.time() - self._last_line > 60.0:
            print(self.line(), file=sys.stderr, flush=True)
            self._last_line = time.time()

    def close(self) -> None:
        if self._rich is not None:
            self._rich.update(self._render())
            self._rich.stop()


def _duration(s: float) -> str:
    s = int(round(s))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{(s % 3600) // 60:02d}m"


def run_grid(
    state: GridState, executor: LocalExecutor | RayExecutor, *, live: bool | None = None
) -> None:
    """Run every task that is not done (failed ones again), recording each result or failure
    as it comes; the grid goes on when a task fails."""
    todo = prepare(state)
    workers = getattr(executor, "workers", None) or 1
    progress = Progress(state, workers, live=live)
    done_before = len(state.results)
    progress.event(
        f"{len(state.grid.tasks)} tasks: {done_before} done earlier, {len(todo)} to run ({executor.name} executor)"
    )

    def started(key: str) -> None:
        state.running[key] = time.time()
        progress.event(f"started  {state.grid.tasks[key].label}")

    def finished(key: str, exit_code: int, error: str | None) -> None:
        t = state.grid.tasks[key]
        d = state.task_dir(t)
        since = state.running.pop(key, time.time())
        r = load_result(d, t) if exit_code == 0 else None
        if r is not None:
            state.results[key] = r
            progress.event(f"done     {t.label} ({_duration(time.time() - since)})")
            return
        log = d / LOG_FILE
        failure = {
            "exit_code": exit_code,
            "error": _why(exit_code, error),
            "last_log_line": _last_line(log),
            "log": str(log),
            "at": _now(),
        }
        write_json_atomic(d / FAILED_FILE, failure)
        state.failures[key] = failure
        progress.event(f"FAILED   {t.label}: {failure['error']}; log {log}")

    try:
        executor.run(todo, state.task_dir, started, finished, progress.tick)
    finally:
        state.running.clear()
        progress.close()


__all__ = [
    "FAILED_FILE",
    "MANIFEST",
    "GridState",
    "OutputFolderError",
    "Progress",
    "check_output_folder",
    "load_result",
    "prepare",
    "run_grid",
]
