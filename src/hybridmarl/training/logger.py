"""Run logging: CSV files, TensorBoard (tensorboardX), the hyper-parameters, a progress display.

Under the run directory:

- ``config.json``: the full config (every hyper-parameter), the task and versions;
- ``train.csv``: one row per training iteration (losses, BRD statistics, timings);
- ``episodes.csv``: one row per finished training episode (its metrics);
- ``evals.csv``: one row per periodic evaluation of the frozen policy (``--eval-every``);
- ``tb/``: TensorBoard event files (the same scalars, plus the config as text);
- ``curve.png``: the training curve (``training.plots``).

On ``--resume`` the CSV rows written after the checkpoint are dropped (each checkpoint records
how many rows every log had), so the files read as if the run had never stopped; a run that
starts from scratch in a directory with old logs starts them afresh. TensorBoard event files
are append-only, so the resumed run's new event file starts with a purge marker instead
(tensorboardX's ``purge_step``): TensorBoard then hides the older events at a step after the
checkpoint's (its episode count), which the resumed run logs again. Events at the checkpoint's
own step are kept, as some were logged before it was saved: the rows of chunks that finished
no episode after it can show twice there (with equal values, timings aside). A fresh start
purges from step 0, hiding every event of the earlier attempt. The progress display is a rich progress bar on a terminal and a
plain status line every few seconds otherwise (log files, CI).
"""

from __future__ import annotations

import csv
import io
import math
import sys
import time
from pathlib import Path
from typing import Any

from hybridmarl.errors import UserError
from hybridmarl.io import write_json_atomic, write_text_atomic


class LogFileError(UserError):
    """A run's CSV log that cannot be read back (on --resume): one line naming the file."""


class CsvLog:
    """Append-only CSV with a header fixed by the first row written. ``rows`` counts its data
    rows, so a checkpoint can record where each log stood (``RunLogger.row_counts``)."""

    def __init__(self, path: Path, step_key: str) -> None:
        self.path = path
        self.step_key = step_key
        self.fields: list[str] | None = None
        self.rows = 0
        if path.exists():
            header, rows = self._read()
            self.fields = header or None
            self.rows = len(rows)

    def _read(self) -> tuple[list[str], list[list[str]]]:
        from hybridmarl.io import read_user_bytes

        data = read_user_bytes(self.path, "run log", LogFileError)
        if b"\0" in data:
            raise LogFileError(
                f"run log {str(self.path)!r} is a binary file, not CSV (remove it to start a new log)"
            )
        try:
            table = list(csv.reader(io.StringIO(data.decode("utf-8"), newline="")))
        except (UnicodeDecodeError, csv.Error) as e:
            raise LogFileError(
                f"run log {str(self.path)!r} is not a CSV file ({e}; remove it to start a new log)"
            ) from None
        return (table[0], table[1:]) if table else ([], [])

    def truncate_to(self, rows: int | None, step: float) -> None:
        """Keep the first ``rows`` data rows (what a checkpoint recorded), or, for a checkpoint
        that recorded none, the rows whose ``step_key`` is at most ``step``; rewritten atomically."""
        if not self.path.exists():
            return
        header, table = self._read()
        if rows is not None:
            if len(table) < rows:
                raise LogFileError(
                    f"run log {str(self.path)!r} has {len(table)} rows but the checkpoint was saved after {rows}: "
                    "the log was cut short (restore it, or remove it to start a new log)"
                )
            keep = table[:rows]
        else:
            col = header.index(self.step_key) if self.step_key in header else None
            keep = [r for r in table if col is None or col >= len(r) or _number(r[col]) <= step]
        self.fields = header or None
        self.rows = len(keep)
        text = io.StringIO(newline="")
        if header:
            w = csv.writer(text)
            w.writerow(header)
            w.writerows(keep)
        write_text_atomic(self.path, text.getvalue())

    def reset(self) -> None:
        """Start the log afresh (a run that starts from scratch in a directory that has one)."""
        self.path.unlink(missing_ok=True)
        self.fields, self.rows = None, 0

    def write(self, rows: list[dict[str, Any]]) -> None:
        if not rows:
            return
        new = not self.path.exists() or self.fields is None
        if self.fields is None:
            self.fields = list(rows[0])
        with open(self.path, "a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=self.fields, extrasaction="ignore")
            if new:
                w.writeheader()
            for r in rows:
                w.writerow({k: _fmt(v) for k, v in r.items()})
        self.rows += len(rows)


def _number(text: str) -> float:
    try:
        return float(text or 0)
    except ValueError:
        return 0.0


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return f"{v:.6g}"
    return v


class RunLogger:
    def __init__(self, run_dir: Path, *, tensorboard: bool = True) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.train = CsvLog(self.run_dir / "train.csv", "episodes")
        self.episodes = CsvLog(self.run_dir / "episodes.csv", "episode")
        self.evals = CsvLog(self.run_dir / "evals.csv", "episodes")
        self._tensorboard = False
        self._tb: Any = None
        # The first step of the run the new event file holds (None: the run starts with it).
        self._purge_step: int | None = None
        if tensorboard:
            try:
                import tensorboardX  # noqa: F401
            except ImportError:
                # An optional extra: the run goes on with its CSV logs.
                print(
                    "TensorBoard logging is off: tensorboardX is not installed (pip install 'hybridmarl[tensorboard]')"
                )
            else:
                self._tensorboard = True

    @property
    def tb(self) -> Any:
        """The TensorBoard writer (None when TensorBoard is off). Opened at its first use, so
        that 'reset' or 'resume_at' can first say from which step on its events replace older
        ones."""
        if self._tb is None and self._tensorboard:
            from tensorboardX import SummaryWriter

            self._tb = SummaryWriter(
                str(self.run_dir / "tb"), flush_secs=30, purge_step=self._purge_step
            )
        return self._tb

    def write_config(self, doc: dict[str, Any]) -> None:
        write_json_atomic(self.run_dir / "config.json", doc)
        if self.tb is not None:
            import json

            self.tb.add_text(
                "config", "```\n" + json.dumps(doc, indent=2, sort_keys=True) + "\n```", 0
            )
            for k, v in _flat(doc.get("config", {})).items():
                self.tb.add_text(f"hparams/{k}", str(v), 0)

    def logs(self) -> dict[str, CsvLog]:
        return {"train": self.train, "episodes": self.episodes, "evals": self.evals}

    def row_counts(self) -> dict[str, int]:
        """Data rows of each CSV log (a checkpoint records them; ``resume_at`` cuts back to them)."""
        return {name: log.rows for name, log in self.logs().items()}

    def resume_at(self, episodes: int, rows: dict[str, int] | None = None) -> None:
        """Cut every CSV log back to where the checkpoint left it: its recorded ``rows``, or for
        a checkpoint without them, the rows up to ``episodes``."""
        for name, log in self.logs().items():
            log.truncate_to(None if rows is None else int(rows.get(name, 0)), episodes)
        # TensorBoard steps are episode counts, shared by the chunks that finish no episode:
        # the events at the checkpoint's own step stay (some were logged before it).
        self._purge_step = int(episodes) + 1

    def reset(self) -> None:
        for log in self.logs().values():
            log.reset()
        self._purge_step = 0  # TensorBoard hides every event of an earlier attempt

    def scalars(self, step: int, values: dict[str, Any], prefix: str = "train") -> None:
        if self.tb is None:
            return
        for k, v in values.items():
            if isinstance(v, int | float) and math.isfinite(float(v)):
                self.tb.add_scalar(f"{prefix}/{k}", float(v), step)

    def close(self) -> None:
        if self._tb is not None:
            self._tb.flush()
            self._tb.close()
        self._tb, self._tensorboard = None, False


def _flat(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        elif isinstance(v, list | tuple):
            out[prefix + k] = str(v)
        else:
            out[prefix + k] = v
    return out


def recent_status(recent: dict[str, float], primary: str, secondary: str) -> str:
    """The live part of the progress line: the two headline metrics over the last 100 episodes,
    ``-`` until the first episode has finished (rather than ``nan``, which reads as a failure)."""

    def fmt(name: str, spec: str) -> str:
        v = recent.get(name, float("nan"))
        return f"{name}@100 {'-' if not math.isfinite(v) else format(v, spec)}"

    return f"{fmt(primary, '.2f')}  {fmt(secondary, '+.3f')}"


class Progress:
    """A rich progress bar on a terminal; a plain line every ``every_s`` seconds otherwise."""

    def __init__(
        self,
        total: int,
        description: str,
        *,
        enabled: bool = True,
        every_s: float = 30.0,
        start: int = 0,
    ) -> None:
        self.total = total
        self.enabled = enabled
        self.every_s = every_s
        self.description = description
        self._last = 0.0
        self._bar = None
        self._task = None
        self._t0 = time.time()
        self._start = start
        if not enabled:
            return
        from rich.console import Console

        console = Console(stderr=True)
        if console.is_terminal:
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )
            from rich.progress import Progress as RichProgress

            self._bar = RichProgress(
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("episodes"),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                TextColumn("{task.fields[status]}"),
                console=console,
            )
            self._bar.start()
            self._task = self._bar.add_task(description, total=total, completed=start, status="")

    def update(self, completed: int, status: str) -> None:
        if not self.enabled:
            return
        if self._bar is not None and self._task is not None:
            self._bar.update(self._task, completed=min(completed, self.total), status=status)
            return
        now = time.time()
        if now - self._last >= self.every_s or completed >= self.total:
            self._last = now
            el = now - self._t0
            print(
                f"[{self.description}] {completed}/{self.total} episodes  {el:7.0f}s  {status}",
                file=sys.stderr,
                flush=True,
            )

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()
