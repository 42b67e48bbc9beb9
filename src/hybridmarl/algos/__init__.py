"""The learners: the hybrid method of Peng, Xing & Cao (IJCAI 2020) and the baselines BC, DQfD
and OGTL. Each is a module with a frozen config dataclass ('CONFIG'), 'PRESETS' (name ->
'(env) -> config') and 'train(config) -> TrainResult'; the machinery they share lives in
'hybridmarl.training' (the run skeleton in 'hybridmarl.training.run').

'ALGOS' maps '--algo' names to those modules (imported lazily): adding a learner is one module
and one entry here.
"""

from __future__ import annotations

import importlib
from typing import Any

from hybridmarl.errors import UserError

#: '--algo' name -> module implementing it.
ALGOS: dict[str, str] = {
    "hybrid": "hybridmarl.algos.hybrid",
    "bc": "hybridmarl.algos.bc",
    "dqfd": "hybridmarl.algos.dqfd",
    "ogtl": "hybridmarl.algos.ogtl",
}

#: The preset a run starts from when none is named: minutes on a CPU (every learner has it).
DEFAULT_PRESET = "quick"


def algo_module(name: str) -> Any:
    key = name.strip().lower()
    if key not in ALGOS:
        raise UserError(f"unknown algo {name!r} (known: {', '.join(ALGOS)})")
    return importlib.import_module(ALGOS[key])


def module_for_config(config: Any) -> Any:
    """The learner module whose config class 'config' is an instance of (exactly)."""
    for name in ALGOS:
        mod = algo_module(name)
        if type(config) is mod.CONFIG:
            return mod
    raise UserError(
        f"{type(config).__name__} is not the config of a learner (known: {', '.join(ALGOS)})"
    )


__all__ = ["ALGOS", "DEFAULT_PRESET", "algo_module", "module_for_config"]
