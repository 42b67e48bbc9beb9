"""Files: atomic writes, and pytrees as named arrays (the form datasets and checkpoints store).

Every file the package writes goes through a temporary file in the target's folder and a rename,
so a killed process leaves either the old file or the new one, never half of one. Files get the
user's umask, like those of any other tool.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import jax
import jax.numpy as jnp
import numpy as np


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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


# -- pytrees <-> named arrays ---------------------------------------------------------------------


def flatten_named(tree: Any, prefix: str = "") -> dict[str, np.ndarray]:
    """A pytree as ``{path: numpy array}`` (typed PRNG keys become their uint32 key data;
    ``jax.ShapeDtypeStruct`` leaves become zeros of that shape)."""
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


def unflatten_named(template: Any, arrays: dict[str, np.ndarray], prefix: str = "", *, batch_dims: int = 0) -> Any:
    """Rebuild a pytree shaped like ``template`` from :func:`flatten_named` output.

    ``batch_dims`` leading axes are allowed in the arrays on top of the template's leaf shapes.
    Raises ``KeyError``/``ValueError`` naming the first missing or mis-shaped entry.
    """
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


__all__ = ["atomic_write", "flatten_named", "unflatten_named", "write_json_atomic", "write_text_atomic"]
