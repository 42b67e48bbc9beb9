"""Annotations for the config dataclasses that tyro turns into command-line options.

The library's configs (:mod:`hybridmarl.training.config`, the learners' configs) and the
commands' own option dataclasses (:mod:`hybridmarl.cli`) share them; they live here so that the
library never imports the command line.
"""

from __future__ import annotations

import tyro

#: For ``Annotated[T | None, DEFAULT_IN_DOCSTRING] = None``: an option whose docstring says what
#: leaving it unset means ("default: the run's"). tyro would add "(default: None)" after it.
DEFAULT_IN_DOCSTRING = tyro.conf.arg(help_behavior_hint="")
