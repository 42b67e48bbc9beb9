"""The optional extras of the package, and turning a missing one into a one-line error.

The core install (engine, environments, learners) needs none of them; each extra adds the
packages of one feature (``pip install 'hybridmarl[video]'``, or ``hybridmarl[all]``).
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

from hybridmarl.errors import UserError

#: Top-level module name -> the extra that installs it.
EXTRA_OF_MODULE: dict[str, str] = {
    "pettingzoo": "pettingzoo",
    "gymnasium": "pettingzoo",
    "tensorboardX": "tensorboard",
    "matplotlib": "plots",
    "PIL": "video",
    "imageio": "video",
}


def missing_extra_error(err: ImportError) -> UserError | None:
    """The :class:`UserError` for an import of an optional package that is not installed, or
    None if ``err`` is about another module."""
    root = (err.name or "").split(".")[0]
    extra = EXTRA_OF_MODULE.get(root)
    if extra is None:
        return None
    return UserError(
        f"{root} is not installed; install the {extra!r} extra: pip install 'hybridmarl[{extra}]'"
    )


@contextmanager
def optional_extras() -> Iterator[None]:
    """Turn an ImportError of an optional package inside the block into a :class:`UserError`
    naming the extra to install; other import errors pass through."""
    try:
        yield
    except ImportError as e:
        user_error = missing_extra_error(e)
        if user_error is None:
            raise
        raise user_error from e


def import_optional(module: str) -> ModuleType:
    """Import ``module`` of an optional extra, or raise a :class:`UserError` naming the extra."""
    with optional_extras():
        return importlib.import_module(module)


__all__ = ["EXTRA_OF_MODULE", "import_optional", "missing_extra_error", "optional_extras"]
