"""Files: atomic writes, checked reads of user files, and pytrees as named arrays (the form
datasets and checkpoints store).

Every file the package writes goes through a temporary file in the target's folder and a rename,
so a killed process leaves either the old file or the new one, never half of one. Files get the
user's umask, like those of any other tool.

Every file a user hands in (a run's ``config.json``, a states, scenario or map file, a checkpoint's
metadata) is read through :func:`read_user_bytes`, :func:`read_user_text` or
:func:`read_user_json`: a missing file, a directory, an unreadable file, an empty file, binary
garbage, malformed JSON, JSON's non-standard ``NaN``/``Infinity`` and a top level of the wrong
type each raise one :class:`~hybridmarl.errors.UserError` line that names the file and the problem.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from hybridmarl.errors import UserError

#: Largest user file read whole (a states, scenario, map or config file); a bigger one is a
#: mistake (a dataset or a video passed as a config), refused before it is read.
MAX_USER_FILE_BYTES = 256 * 1024 * 1024
#: Largest array file (a checkpoint's or a dataset's safetensors). A DQfD or OGTL checkpoint
#: carries its replay buffer for exact resume: at m30v30 the ``quick`` preset's is about 290 MiB
#: and the ``paper`` preset's about 0.7 GiB, so these files get a larger bound than the others.
MAX_ARRAY_FILE_BYTES = 8 * 1024**3


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def grant_umask(path: str | Path, *, directory: bool = False) -> None:
    """Give a temporary file or directory (mkstemp/mkdtemp: 0600/0700) the permissions a plain
    ``open``/``mkdir`` would have given it under the user's umask, before it is renamed into
    place."""
    os.chmod(path, (0o777 if directory else 0o666) & ~_umask())


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w") -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path``; on a clean exit it is synced and renamed onto
    ``path``, on an exception it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~_umask())
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_json_atomic(path: str | Path, doc: Any, *, indent: int | None = 2) -> None:
    """Write ``doc`` as JSON (sorted keys, a final newline) to ``path`` atomically."""
    with atomic_write(path) as f:
        json.dump(doc, f, indent=indent, sort_keys=True)
        f.write("\n")


def write_text_atomic(path: str | Path, text: str) -> None:
    with atomic_write(path) as f:
        f.write(text)


# -- checked reads of user files ------------------------------------------------------------------


def check_user_file(
    path: str | Path, what: str, error: type[UserError] = UserError, *, max_bytes: int | None = None
) -> Path:
    """``path`` as a Path if it names a readable regular file of at most ``max_bytes`` (default
    :data:`MAX_USER_FILE_BYTES`); else ``error`` naming ``what`` (e.g. "states file") and the
    problem."""
    limit = MAX_USER_FILE_BYTES if max_bytes is None else max_bytes
    p = Path(path)
    if not p.exists():
        raise error(f"{what} {str(p)!r} not found")
    if p.is_dir():
        raise error(f"{what} {str(p)!r} is a directory, not a file")
    if not p.is_file():
        raise error(f"{what} {str(p)!r} is not a regular file")
    if not os.access(p, os.R_OK):
        raise error(f"{what} {str(p)!r}: permission denied")
    size = p.stat().st_size
    if size > limit:
        raise error(
            f"{what} {str(p)!r} is {size / 2**20:.0f} MiB (at most {limit // 2**20} MiB): not a {what}"
        )
    return p


def check_output_path(
    path: str | Path, option: str = "--out", error: type[UserError] = UserError
) -> Path:
    """``path`` as a Path if a file can be written there (checked before any work, so a bad
    ``--out`` fails at once, not after the work it would have saved)."""
    p = Path(path)
    if p.is_dir():
        raise error(f"{option} {str(p)!r} is a directory; give a file name")
    parent = next((q for q in p.parents if q.exists()), Path("."))
    if not parent.is_dir():
        raise error(f"{option} {str(p)!r}: {str(parent)!r} is a file, not a directory")
    if not os.access(parent, os.W_OK):
        raise error(f"{option} {str(p)!r}: cannot write in {str(parent)!r} (permission denied)")
    return p


def read_user_bytes(path: str | Path, what: str, error: type[UserError] = UserError) -> bytes:
    """The bytes of a user file, checked by :func:`check_user_file`."""
    p = check_user_file(path, what, error)
    try:
        return p.read_bytes()
    except OSError as e:
        raise error(f"{what} {str(p)!r}: cannot read ({e.strerror or e})") from None


def read_user_text(path: str | Path, what: str, error: type[UserError] = UserError) -> str:
    """The text of a user file: UTF-8, not empty, without NUL bytes (binary garbage)."""
    data = read_user_bytes(path, what, error)
    if not data.strip():
        raise error(f"{what} {str(path)!r} is empty")
    if b"\0" in data:
        raise error(f"{what} {str(path)!r} is a binary file, not text")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(f"{what} {str(path)!r} is not UTF-8 text (byte {e.start})") from None


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def read_user_json(
    path: str | Path, what: str, error: type[UserError] = UserError, *, top: type = dict
) -> Any:
    """A user JSON file whose top level is a ``top`` (``dict`` or ``list``); ``NaN`` and
    ``Infinity``, which Python's json accepts but JSON does not, are refused."""
    text = read_user_text(path, what, error)
    try:
        doc = json.loads(text, parse_constant=_no_constant)
    except json.JSONDecodeError as e:
        raise error(
            f"{what} {str(path)!r}: malformed JSON at line {e.lineno} column {e.colno}: {e.msg}"
        ) from None
    except (ValueError, RecursionError) as e:
        raise error(f"{what} {str(path)!r}: {str(e) or 'nested too deeply'}") from None
    if not isinstance(doc, top):
        kind = {dict: "an object", list: "a list"}.get(top, top.__name__)
        raise error(f"{what} {str(path)!r}: the top level must be {kind}, not {_json_type(doc)}")
    return doc


def _json_type(v: Any) -> str:
    return {
        dict: "an object",
        list: "a list",
        str: "a string",
        bool: "a boolean",
        type(None): "null",
    }.get(type(v), "a number")


# -- pytrees <-> named arrays ---------------------------------------------------------------------


def flatten_named(tree: Any, prefix: str = "") -> dict[str, np.ndarray]:
    """A pytree as ``{path: numpy array}`` (typed PRNG keys become their uint32 key data;
    ``jax.ShapeDtypeStruct`` leaves become zeros of that shape)."""
    import jax
    import jax.numpy as jnp

    out: dict[str, np.ndarray] = {}
    leaves, _ = jax.tree_util.tree_flatten_with_path(tree)
    for path, leaf in leaves:
        name = prefix + jax.tree_util.keystr(path, simple=True, separator=".")
        if isinstance(leaf, jax.ShapeDtypeStruct):
            if jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key):
                leaf = jax.eval_shape(jax.random.key_data, leaf)
            out[name] = np.zeros(leaf.shape, leaf.dtype)
            continue
        if isinstance(leaf, jax.Array) and jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            leaf = jax.random.key_data(leaf)
        out[name] = np.asarray(leaf)
    return out


def unflatten_named(
    template: Any, arrays: dict[str, np.ndarray], prefix: str = "", *, batch_dims: int = 0
) -> Any:
    """Rebuild a pytree shaped like ``template`` from :func:`flatten_named` output.

    ``batch_dims`` leading axes are allowed in the arrays on top of the template's leaf shapes.
    Raises ``KeyError``/``ValueError`` naming the first missing or mis-shaped entry.
    """
    import jax
    import jax.numpy as jnp

    leaves, treedef = jax.tree_util.tree_flatten_with_path(template)
    new = []
    for path, leaf in leaves:
        name = prefix + jax.tree_util.keystr(path, simple=True, separator=".")
        if name not in arrays:
            raise KeyError(f"missing array {name!r}")
        arr = np.asarray(arrays[name])
        is_key = jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key)
        ref = jax.eval_shape(jax.random.key_data, leaf) if is_key else leaf
        ref_shape, ref_dtype = tuple(np.shape(ref)), np.dtype(ref.dtype)
        if arr.shape[batch_dims:] != ref_shape:
            raise ValueError(f"array {name!r} has shape {arr.shape}, expected (...,) + {ref_shape}")
        if arr.dtype != ref_dtype:
            raise ValueError(f"array {name!r} has dtype {arr.dtype}, expected {ref_dtype}")
        new.append(jax.random.wrap_key_data(jnp.asarray(arr)) if is_key else jnp.asarray(arr))
    return jax.tree_util.tree_unflatten(treedef, new)


__all__ = [
    "MAX_ARRAY_FILE_BYTES",
    "MAX_USER_FILE_BYTES",
    "atomic_write",
    "check_output_path",
    "check_user_file",
    "flatten_named",
    "read_user_bytes",
    "read_user_json",
    "read_user_text",
    "unflatten_named",
    "write_json_atomic",
    "write_text_atomic",
]
