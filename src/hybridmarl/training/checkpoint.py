"""Atomic checkpoints: safetensors for arrays, JSON for metadata; never pickle.

Layout under a run directory::

    checkpoints/
      ckpt_000000123/          # 123 = the training counter (episodes) at save time
        arrays.safetensors     # every array of the training state, by name
        meta.json              # counters, config, versions; written last
      ckpt_000000456/
      ...
      best/                    # the actor of the best periodic evaluation (--eval-every), if any

A checkpoint directory is written under a temporary name and renamed into place, so a crash
never leaves a half-written checkpoint under a final name; a directory without ``meta.json`` is
ignored. The last ``keep`` checkpoints are kept; ``best`` is never pruned and never resumed from.

Named arrays come from ``training.task.flatten_named`` (pytree paths such as ``actor.params.Dense_0.kernel``);
typed PRNG keys are stored as their uint32 key data.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from safetensors import safe_open
from safetensors.numpy import load_file, save_file

from hybridmarl.errors import UserError
from hybridmarl.io import grant_umask

CKPT_DIR = "checkpoints"
#: Name of the checkpoint holding the best periodically evaluated policy (``training.config.PeriodicEval``).
BEST = "best"
#: Array prefix of the actor's weight average (hybrid ``actor_average_from``); a policy loaded
#: from a checkpoint that has it is the average (``evaluate.load_policy``).
AVERAGE_PREFIX = "actor_average"
FORMAT_VERSION = 1
_NAME = re.compile(r"^ckpt_(\d{9,})$")


class CheckpointError(UserError):
    """A missing or unreadable checkpoint (one-line message)."""


#: Environment variable naming a point where a training process pauses (for tests that kill
#: or interrupt it there): ``chunk:N`` (inside the N-th chunk of the training loop, before it is
#: logged), ``checkpoint:N`` (inside the N-th checkpoint write, before the rename),
#: ``evaluation`` (before the final evaluation).
PAUSE_ENV = "HYBRIDMARL_PAUSE_AT"
_reached: dict[str, int] = {}


def pause_point(point: str, resume: Any = None) -> None:
    """Pause here if :data:`PAUSE_ENV` names this point (and this is its N-th time): say so on
    stderr, then wait until ``resume()`` is true (e.g. a Ctrl-C was received) or forever."""
    wanted = os.environ.get(PAUSE_ENV)
    if not wanted:
        return
    name, _, nth = wanted.partition(":")
    if name != point:
        return
    _reached[point] = _reached.get(point, 0) + 1
    if _reached[point] != int(nth or 1):
        return
    import sys
    import time

    print(f"hybridmarl: paused at {wanted}", file=sys.stderr, flush=True)
    while resume is None or not resume():
        time.sleep(0.05)


def _contiguous(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    out = {}
    for k, v in arrays.items():
        a = np.asarray(v)
        if not a.flags.c_contiguous:  # (np.ascontiguousarray would turn a 0-d array into 1-d)
            a = a.copy(order="C")
        if a.dtype == object:
            raise TypeError(f"array {k!r} has dtype object; only numeric arrays are checkpointed")
        out[k] = a
    return out


def _json_safe(value: Any) -> Any:
    """``value`` with every NaN or infinite float replaced by None: meta.json stays JSON (a
    counter such as the critic's loss is NaN until the first fit), and its readers refuse NaN."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def checkpoint_name(step: int) -> str:
    """Directory name of checkpoint ``step`` (the training counter at save time)."""
    return f"ckpt_{int(step):09d}"


def save_checkpoint(
    run_dir: str | Path,
    step: int,
    arrays: dict[str, np.ndarray],
    meta: dict[str, Any],
    keep: int = 3,
    name: str | None = None,
) -> Path:
    """Write checkpoint ``step`` atomically and prune to the newest ``keep``. Returns its path.

    ``name`` (e.g. :data:`BEST`) writes a named checkpoint instead, replaced as a whole on each
    save; named checkpoints are not counted, pruned or resumed from."""
    root = Path(run_dir) / CKPT_DIR
    root.mkdir(parents=True, exist_ok=True)
    final = root / (name or checkpoint_name(step))
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp_{final.name}_", dir=root))
    try:
        grant_umask(tmp, directory=True)
        save_file(_contiguous(arrays), str(tmp / "arrays.safetensors"))
        grant_umask(tmp / "arrays.safetensors")  # safetensors writes it private
        pause_point("checkpoint")
        doc = _json_safe(dict(meta))
        doc["format_version"] = FORMAT_VERSION
        doc["step"] = int(step)
        with open(tmp / "meta.json", "w") as f:
            json.dump(doc, f, indent=2, sort_keys=True, allow_nan=False)
            f.flush()
            os.fsync(f.fileno())
        if final.exists():
            # Move the old one aside first: a crash between the two renames leaves no
            # checkpoint under the final name (ignored), never a half-written one.
            stale = Path(tempfile.mkdtemp(prefix=f".old_{final.name}_", dir=root))
            os.replace(final, stale / final.name)
            os.replace(tmp, final)
            shutil.rmtree(stale, ignore_errors=True)
        else:
            os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if name is not None:
        return final
    for old in list_checkpoints(run_dir)[:-keep] if keep > 0 else []:
        shutil.rmtree(old, ignore_errors=True)
    return final


def list_checkpoints(run_dir: str | Path) -> list[Path]:
    """Complete checkpoints of a run, oldest first."""
    root = Path(run_dir) / CKPT_DIR
    if not root.is_dir():
        return []
    found = []
    for p in root.iterdir():
        m = _NAME.match(p.name)
        if (
            m
            and p.is_dir()
            and (p / "meta.json").is_file()
            and (p / "arrays.safetensors").is_file()
        ):
            found.append((int(m.group(1)), p))
    return [p for _, p in sorted(found)]


def latest_checkpoint(run_dir: str | Path) -> Path | None:
    ck = list_checkpoints(run_dir)
    return ck[-1] if ck else None


def find_checkpoint(run_dir: str | Path, which: str | int | None = None) -> Path:
    """The newest complete checkpoint (``which`` None), or the one named by its step (``700``),
    its directory name (``ckpt_000000700``) or ``best``. :class:`CheckpointError` names what is kept."""
    kept = list_checkpoints(run_dir)
    best = Path(run_dir) / CKPT_DIR / BEST
    if which is not None and str(which).strip() == BEST:
        if (best / "meta.json").is_file() and (best / "arrays.safetensors").is_file():
            return best
        raise CheckpointError(
            f"{run_dir}: no best checkpoint (it is kept by training with --eval-every > 0)"
        )
    if not kept:
        raise CheckpointError(f"{run_dir}: no checkpoint found under {Path(run_dir) / CKPT_DIR}")
    if which is None:
        return kept[-1]
    name = str(which).strip()
    name = checkpoint_name(int(name)) if name.isdigit() else name
    for p in kept:
        if p.name == name:
            return p
    raise CheckpointError(
        f"{run_dir}: no checkpoint {which!r} (have: {', '.join(p.name for p in kept)})"
    )


def load_checkpoint(
    path: str | Path, prefixes: tuple[str, ...] | None = None
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """``(arrays, meta)`` of one checkpoint directory; :class:`CheckpointError` (one line naming
    the file) for a missing, unreadable or malformed file. With ``prefixes`` only the arrays
    under them are read (a policy without the replay buffer a DQfD checkpoint carries)."""
    from hybridmarl.io import MAX_ARRAY_FILE_BYTES, check_user_file, read_user_json

    path = Path(path)
    meta = read_user_json(path / "meta.json", "checkpoint metadata", CheckpointError)
    arrays_path = check_user_file(
        path / "arrays.safetensors",
        "checkpoint arrays",
        CheckpointError,
        max_bytes=MAX_ARRAY_FILE_BYTES,
    )
    try:
        if prefixes is None:
            arrays = load_file(str(arrays_path))
        else:
            with safe_open(str(arrays_path), framework="numpy") as f:
                # safe_open is not iterable: its keys() is the only way to list them.
                names = f.keys()
                wanted = [
                    k for k in names if any(k == p or k.startswith(p + ".") for p in prefixes)
                ]
                arrays = {k: f.get_tensor(k) for k in wanted}
    except Exception as e:  # safetensors raises its own error type for a malformed file
        raise CheckpointError(
            f"checkpoint arrays {str(arrays_path)!r}: unreadable ({_one_line(e)})"
        ) from None
    if meta.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"checkpoint {path}: format version {meta.get('format_version')!r}, expected {FORMAT_VERSION}"
        )
    return arrays, meta


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())[:200] or type(e).__name__


def subtree(arrays: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    """The entries under ``prefix.`` with the prefix removed."""
    p = prefix + "."
    out = {k[len(p) :]: v for k, v in arrays.items() if k.startswith(p)}
    if prefix in arrays:
        out[""] = arrays[prefix]
    return out


def prefixed(arrays: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    return {(f"{prefix}.{k}" if k else prefix): v for k, v in arrays.items()}
