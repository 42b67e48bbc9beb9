"""hybridmarl: hybrid learning for multi-agent cooperation from sub-optimal demonstrations.

Layout:
- 'hybridmarl.engine': SparCraft's combat rules, frame-exact, as pure JAX functions.
- 'hybridmarl.envs': the paper's environments (combat Dec-POMDP, Traffic Junction).
- 'hybridmarl.algos': the learners (the hybrid method, BC, DQfD, OGTL); 'hybridmarl.training':
  the machinery they share.
- 'hybridmarl.cli': the 'hybridmarl' command.

Python API (imports are lazy, so 'import hybridmarl' stays light)::

    from hybridmarl.algos.hybrid import PRESETS
    result = hybridmarl.train(PRESETS["quick"]("combat").replace(scenario="m5v5", seed=0))
    policy = hybridmarl.load_policy(result.run_dir)      # or result.policy
    actions = policy.predict(obs, legal)
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pathlib import Path

    from hybridmarl.training.evaluate import Policy
    from hybridmarl.training.run import TrainResult

__version__ = "0.1.0"


def train(config: Any) -> TrainResult:
    """Train the learner 'config' belongs to (a 'HybridConfig', 'DQfDConfig', 'OGTLConfig' or
    'BCConfig'). Returns a 'TrainResult' (run_dir, evaluation, policy); raises a
    'hybridmarl.errors.UserError' for bad input and 'hybridmarl.errors.TrainingDiverged' when
    a loss or parameter becomes NaN/inf."""
    from hybridmarl.algos import module_for_config

    return module_for_config(config).train(config)


def load_policy(
    run_dir: str | Path, checkpoint: str | int | None = None, weights: str = "auto"
) -> Policy:
    """The trained policy of a run directory: its newest checkpoint, or 'checkpoint' (an
    episode count, a checkpoint name, or 'best'); 'weights' = 'auto' (the run's policy),
    'average' or 'last'. 'Policy.predict(obs, legal)' plays it."""
    from hybridmarl.training.evaluate import load_policy as _load

    return _load(run_dir, checkpoint, weights)


__all__ = ["__version__", "load_policy", "train"]
