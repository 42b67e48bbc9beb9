"""The errors a user can cause, and what the command line makes of them.

:class:`UserError` is the one base of every problem with what a user gave (a file, a name, a
number): the message is one line that names the input and the problem, and the command line
prints it and exits with :data:`EXIT_BAD_INPUT`. :class:`TrainingDiverged` is a training run whose
losses or parameters became NaN/inf; the command line exits with :data:`EXIT_DIVERGED`. Ctrl-C
exits with :data:`EXIT_INTERRUPTED` (a training run first saves a checkpoint, :class:`Interrupted`).
"""

from __future__ import annotations

#: Exit code of a command given bad input (one line on stderr, no traceback, no partial output).
EXIT_BAD_INPUT = 2
#: Exit code of a training run stopped because a loss or parameter became NaN/inf.
EXIT_DIVERGED = 3
#: Exit code of a command stopped by Ctrl-C (SIGINT), as shells report it (128 + 2).
EXIT_INTERRUPTED = 130


class UserError(ValueError):
    """Bad input from the user: a one-line message naming the input and the problem."""


class TrainingDiverged(RuntimeError):
    """A loss or parameter became NaN/inf (the message names which, and when)."""


class Interrupted(RuntimeError):
    """Training stopped by Ctrl-C at a chunk boundary, after saving a checkpoint (the message
    says how to resume)."""


__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_DIVERGED",
    "EXIT_INTERRUPTED",
    "Interrupted",
    "TrainingDiverged",
    "UserError",
]
