"""Run directories: reading one back (``config.json``, checkpoint contents), the lock that keeps
two processes out of one run, the clean-up of writes a killed process left behind, and what a
``--resume`` may change.

- :func:`read_run_config`: ``config.json``, validated (an object with ``algo``, ``config`` and
  ``task``; every field of the right type and within its rule, ``hybridmarl.validate``); any
  problem is one :class:`~hybridmarl.training.checkpoint.CheckpointError` line naming the file.
- :class:`RunLock`: ``<run_dir>/.lock``, held (``flock``) while a process trains in the
  directory. A second process is refused with a line naming the holder; the lock of a process
  that died is taken over with a message (the kernel drops a dead process's ``flock``).
- :func:`remove_partial_writes`: checkpoint directories and files a killed write left under
  temporary names (``checkpoints/.tmp_ckpt_*``, ``.old_*``, ``.<name>.*.tmp``).
- :func:`check_resume_config`: a resumed run must train exactly as before; only the fields in
  :data:`RESUME_MAY_CHANGE` (budgets, cadences, logging) may differ from the checkpoint's.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import json
import os
import shutil
import socket
from pathlib import Path
from typing import Any

import numpy as np

from hybridmarl.io import read_user_json
from hybridmarl.training.checkpoint import CKPT_DIR, CheckpointError
from hybridmarl.validate import check_values, rule_for

#: Config fields a ``--resume`` may change: they steer how long the run goes on, how often it
#: saves or evaluates, and where it logs, never what it learns.
RESUME_MAY_CHANGE = frozenset(
    {
        "total_episodes",
        "time_limit_min",  # budgets
        "eval_episodes",
        "eval_every",
        "keep_best",  # evaluation cadence
        "run_dir",
        "name",
        "resume",
        "checkpoint_every",
        "keep_checkpoints",
        "tensorboard",
        "progress",  # the run itself
        "demonstrator_name",
        "eval_enemy_name",  # derived labels that config.json stores beside the fields
    }
)

LOCK_NAME = ".lock"


# -- config.json -------------------------------------------------------------------------------------


def _type_problem(value: Any, default: Any) -> str | None:
    """Why ``value`` (from JSON) cannot stand for a field whose default is ``default``, or None."""
    if default is None:
        return None  # an optional field: its rule (hybridmarl.validate) checks what it holds
    if isinstance(default, bool):
        return None if isinstance(value, bool) else "true or false"
    if isinstance(default, int):
        return None if isinstance(value, int) and not isinstance(value, bool) else "an integer"
    if isinstance(default, float):
        return (
            None if isinstance(value, int | float) and not isinstance(value, bool) else "a number"
        )
    if isinstance(default, str):
        return None if isinstance(value, str) else "a string"
    if isinstance(default, tuple):
        return None if isinstance(value, list) else "a list"
    return None


def check_config_fields(path: Path, section: str, values: Any, defaults: Any) -> None:
    """Every known key of ``values`` (a JSON object) has the type of its field in ``defaults``
    (a config or a TaskSpec instance) and keeps its rule; unknown keys are ignored (options a
    later or earlier version has)."""
    if not isinstance(values, dict):
        raise CheckpointError(f"{path}: {section!r} must be an object, not {type(values).__name__}")
    names = getattr(defaults, "field_names", None)
    flat = names() if names is not None else [f.name for f in dataclasses.fields(defaults)]
    known = {n: getattr(defaults, n) for n in flat}
    for name, value in values.items():
        if name not in known:
            continue
        problem = _type_problem(value, known[name])
        if problem is not None:
            raise CheckpointError(f"{path}: {section}.{name} must be {problem}, got {value!r}")
    checked = {n: (tuple(v) if isinstance(v, list) else v) for n, v in values.items() if n in known}
    checked = {
        n: v for n, v in checked.items() if rule_for(n, known[n] if v is None else v) is not None
    }
    check_values(checked, label=lambda n: f"{path}: {section}.{n}", error=CheckpointError)


def read_run_config(run_dir: str | Path) -> dict[str, Any]:
    """The validated ``config.json`` of a run directory (see the module docstring)."""
    from hybridmarl.algos import ALGOS, algo_module
    from hybridmarl.training.task import TaskError, TaskSpec, make_task

    run_dir = Path(run_dir)
    path = run_dir / "config.json"
    if not run_dir.is_dir():
        raise CheckpointError(f"{run_dir}: no such run directory (no config.json)")
    if not path.exists():
        raise CheckpointError(f"{run_dir}: no config.json (not a hybridmarl run directory)")
    doc = read_user_json(path, "run config", CheckpointError)
    for key in ("algo", "config", "task"):
        if key not in doc:
            raise CheckpointError(
                f"{path}: missing key {key!r} (not a complete hybridmarl run config)"
            )
    if not isinstance(doc["algo"], str) or doc["algo"] not in ALGOS:
        raise CheckpointError(
            f"{path}: algo must be one of {', '.join(ALGOS)}, got {doc['algo']!r}"
        )
    mod = algo_module(doc["algo"])
    check_config_fields(path, "config", doc["config"], type(mod.PRESETS["toy"]("combat"))())
    check_config_fields(path, "task", doc["task"], TaskSpec())
    try:
        make_task(TaskSpec.from_dict(doc["task"]))
    except TaskError as e:
        raise CheckpointError(f"{path}: task: {e}") from None
    return doc


# -- the lock ----------------------------------------------------------------------------------------


class RunLock:
    """``<run_dir>/.lock`` held with ``flock`` while this process trains in ``run_dir`` (module
    docstring). ``acquire()`` raises :class:`RunInUse` when a live process holds it."""

    def __init__(self, run_dir: Path) -> None:
        self.path = Path(run_dir) / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                os.close(fd)
                if e.errno not in (errno.EAGAIN, errno.EACCES):
                    raise
                holder = _describe(_read_holder(self.path))
                raise RunInUse(
                    f"{self.path.parent} is in use by {holder} (lock file {self.path}): wait for it to finish or stop it"
                ) from None
            # The file may have been removed by its previous holder between our open and our lock.
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        previous = _read_holder(self.path)
        if previous and previous.get("pid") != os.getpid():
            print(
                f"{self.path.parent}: taking over the lock of {_describe(previous)}, which is no longer running"
            )
        os.ftruncate(fd, 0)
        os.write(
            fd, (json.dumps({"pid": os.getpid(), "host": socket.gethostname()}) + "\n").encode()
        )
        os.fsync(fd)
        self._fd = fd

    def release(self) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)  # while still locked: nobody can take it in between
        os.close(self._fd)
        self._fd = None


class RunInUse(CheckpointError):
    """Another live process holds the run directory's lock."""


def _read_holder(path: Path) -> dict[str, Any] | None:
    try:
        doc = json.loads(path.read_text() or "null")
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    return doc if isinstance(doc, dict) else None


def _describe(holder: dict[str, Any] | None) -> str:
    if not holder:
        return "another process"
    return f"process {holder.get('pid')} on {holder.get('host', '?')}"


# -- leftovers of killed writes --------------------------------------------------------------------


def remove_partial_writes(run_dir: Path) -> int:
    """Remove what a killed checkpoint or file write left under a temporary name; returns the
    bytes freed. Only call it while holding the run's lock (another live writer's temporary
    files would go too)."""
    freed = 0
    candidates: list[Path] = []
    root = Path(run_dir) / CKPT_DIR
    if root.is_dir():
        candidates += [p for p in root.iterdir() if p.name.startswith((".tmp_", ".old_"))]
    if Path(run_dir).is_dir():
        candidates += [
            p for p in Path(run_dir).iterdir() if p.name.startswith(".") and p.name.endswith(".tmp")
        ]
    for p in candidates:
        if p.is_dir() and not p.is_symlink():
            freed += sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
            shutil.rmtree(p, ignore_errors=True)
        elif p.is_file():
            freed += p.stat().st_size
            p.unlink(missing_ok=True)
    return freed


# -- resume ------------------------------------------------------------------------------------------


def check_resume_config(checkpoint: Path, saved: Any, current: dict[str, Any]) -> None:
    """Refuse (:class:`CheckpointError`, naming the first field) a resume whose config differs
    from the checkpoint's in a field outside :data:`RESUME_MAY_CHANGE`. ``saved``: the
    checkpoint meta's ``config`` (flat field names); ``current``: ``config_to_dict`` of the
    config asked for. Fields in only one of them (a version added or removed them) pass."""
    if saved is None:
        return  # a checkpoint that does not record its config (written by hand or by a tool)
    if not isinstance(saved, dict):
        raise CheckpointError(
            f"checkpoint {checkpoint}: meta.json's config must be an object, not {type(saved).__name__}"
        )
    for name, value in current.items():
        if name in RESUME_MAY_CHANGE or name not in saved:
            continue
        old = saved[name]
        if _normal(old) != _normal(value):
            run_dir = checkpoint.parent.parent
            raise CheckpointError(
                f"{run_dir} was trained with {name} = {old!r}; cannot resume it with {name} = {value!r} "
                f"(only {', '.join(sorted(RESUME_MAY_CHANGE - {'run_dir', 'name', 'resume', 'demonstrator_name', 'eval_enemy_name'}))} "
                "may change on --resume; start a new --run-dir to change the rest)"
            )


def _normal(v: Any) -> Any:
    if isinstance(v, tuple | list):
        return [_normal(x) for x in v]
    if isinstance(v, int | float) and not isinstance(v, bool):
        return float(v)
    return v


def non_finite_array(arrays: dict[str, np.ndarray], prefixes: tuple[str, ...]) -> str | None:
    """The name of the first floating array under one of ``prefixes`` holding NaN/inf, or None."""
    for name, a in arrays.items():
        if (
            name.split(".")[0] in prefixes
            and np.issubdtype(a.dtype, np.floating)
            and not np.all(np.isfinite(a))
        ):
            return name
    return None


__all__ = [
    "LOCK_NAME",
    "RESUME_MAY_CHANGE",
    "RunInUse",
    "RunLock",
    "check_config_fields",
    "check_resume_config",
    "non_finite_array",
    "read_run_config",
    "remove_partial_writes",
]
