"""The learners: the hybrid method of Peng, Xing & Cao (IJCAI 2020) and the baselines BC, DQfD
and OGTL. Each is a module with a frozen config dataclass, ``PRESETS`` (name -> ``(env) -> config``)
and ``train(config)``; the machinery they share lives in :mod:`hybridmarl.training`.

:data:`ALGOS` maps ``--algo`` names to those modules (imported lazily): adding a learner is one
module and one entry here.
"""

from __future__ import annotations

import importlib
from typing import Any

from hybridmarl.errors import UserError

#: ``--algo`` name -> module implementing it.
ALGOS: dict[str, str] = {
    "hybrid": "hybridmarl.algos.hybrid",
    "bc": "hybridmarl.algos.bc",
    "dqfd": "hybridmarl.algos.dqfd",
    "ogtl": "hybridmarl.algos.ogtl",
}


def algo_module(name: str) -> Any:
    key = name.strip().lower()
    if key not in ALGOS:
        raise UserError(f"unknown algo {name!r} (known: {', '.join(ALGOS)})")
    return importlib.import_module(ALGOS[key])


__all__ = ["ALGOS", "algo_module"]
