"""Size guards of the commands whose size the user gives: before any work they estimate what the
job will hold in memory (and, where there is a measured rate, how long it will take) and, above
a threshold, stop with one line that gives the estimate and says to pass ``--yes``
(:class:`SizeError`, a ``UserError``: exit code 2). docs/engine.md#size-guards lists them.

- ``battle``: battles x units (``cli.engine.check_series_size``; ``trace``: its ``--index``);
- ``train``: the arrays its sizes set (:func:`train_memory`);
- ``demos collect --n``: the recorded dataset (:func:`demos_memory`);
- ``eval --n``: the games played at once (:func:`eval_memory`).

The estimates count the arrays whose size the options set, from the task's own shapes (one env
state, one joint observation), so they are exact in their units and approximate in total: a
guard, not a budget.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hybridmarl.errors import UserError

#: ``train``, ``demos collect`` and ``eval`` ask for --yes above this estimated memory (8 GiB).
CONFIRM_BYTES = 8 * 2**30
#: Observations per CPU-second of ``demos collect`` once compiled, for its time estimate: m5v5,
#: 19,000 observations in 4.6 CPU-s (2026-12-02, 2-core x86-64 CPU VM, shared;
#: docs/engine.md#size-guards).
DEMO_OBSERVATIONS_PER_S = 4_000
#: Copies of the arrays its sizes set that ``train`` holds at its peak: the host arrays, their
#: copy on the device (the critic's fit) and a checkpoint being serialized (measured 2.8: hybrid
#: 'toy' at m3v3, 935 MB more peak RSS with --buffer-size 1,000,000 than 512, 336 MB of states).
TRAIN_COPIES = 3
#: Copies of each recorded observation (with its state) that ``demos collect`` holds at its
#: peak: the chunks and their concatenation (measured 2.6: m5v5, 325 MB more peak RSS for 19,000
#: more observations of 6,598 bytes).
DEMO_COPIES = 3
#: Copies of each game's state and joint observation that ``eval`` holds at its peak: the
#: scan's carry, the policy's activations, the results (measured 2.2: a toy actor at m3v3,
#: 171 MB more peak RSS for 19,900 more games of 3,972 bytes).
EVAL_COPIES = 3


class SizeError(UserError):
    """A job above a size threshold, refused before any work (``--yes`` runs it)."""


def duration(seconds: float) -> str:
    """``seconds`` in the unit a person reads best (s, min, h)."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def gib(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:.1f} GiB"


def task_sizes(task: Any) -> tuple[int, int]:
    """Bytes of one env state of ``task`` and of one joint observation (every agent's
    observation, float32, and legal-action mask, bool). Traces the env's reset; runs nothing."""
    from hybridmarl.training.task import flatten_named

    state = sum(
        int(np.prod(v.shape)) * np.dtype(v.dtype).itemsize
        for v in flatten_named(task.state_template()).values()
    )
    observation = task.num_agents * (4 * task.obs_dim + task.num_actions)
    return state, observation


def train_memory(
    cfg: Any, state_bytes: int, observation_bytes: int, num_agents: int, num_actions: int
) -> dict[str, int]:
    """Estimated peak bytes of the arrays a training run's sizes set, by the option that sets
    them, each held :data:`TRAIN_COPIES` times (fields a learner does not have count 0):

    - ``--buffer-size``: the replay buffer, one state per entry (DQfD and OGTL: a state and
      the next, and the demonstrations kept in it);
    - ``--pretrain-trajectories`` (where > 0) or else ``--pretrain-samples``: the critic's
      pre-training states;
    - ``--demo-observations``: the recorded demonstrations (observations, with their states);
    - ``--num-envs``: the games' chunk of observations (x ``--chunk-steps``) and Alg. 1's
      look-ahead states (one per game, agent and action).
    """

    def field(name: str) -> int:
        value = getattr(cfg, name, 0)
        return (
            int(value) if isinstance(value, int | np.integer) and not isinstance(value, bool) else 0
        )

    transitions = hasattr(cfg, "target_update_every")  # DQfD, OGTL: (state, next state) rows
    demos = field("demo_observations")
    buffer_rows = field("buffer_size") + (demos if transitions else 0)
    pretrain = "pretrain_trajectories" if field("pretrain_trajectories") > 0 else "pretrain_samples"
    once = {
        "buffer_size": buffer_rows * state_bytes * (2 if transitions else 1),
        pretrain: field(pretrain) * state_bytes,
        "demo_observations": demos * (observation_bytes + state_bytes),
        "num_envs": field("num_envs")
        * (
            max(field("chunk_steps"), 1) * observation_bytes
            + num_agents * num_actions * state_bytes
        ),
    }
    return {option: TRAIN_COPIES * n_bytes for option, n_bytes in once.items()}


def check_train_size(cfg: Any, task: Any, *, yes: bool) -> None:
    """Refuse a training run whose :func:`train_memory` is above :data:`CONFIRM_BYTES` unless
    ``yes``; the message names the option that weighs most."""
    state_bytes, observation_bytes = task_sizes(task)
    parts = train_memory(cfg, state_bytes, observation_bytes, task.num_agents, task.num_actions)
    total = sum(parts.values())
    if total <= CONFIRM_BYTES or yes:
        return
    heaviest = max(parts, key=lambda k: parts[k])
    option = "--" + heaviest.replace("_", "-")
    raise SizeError(
        f"{option} {getattr(cfg, heaviest)}: this run's arrays would hold about {gib(total)} of memory "
        f"({gib(parts[heaviest])} of it for {option}) on {task.spec.label()}: pass --yes to train it, "
        f"or a smaller {option}"
    )


def demos_memory(n: int, state_bytes: int, observation_bytes: int) -> int:
    """Estimated peak bytes of ``demos collect --n``: the dataset (each observation with its
    state) is held whole before it is written, :data:`DEMO_COPIES` times at the peak."""
    return n * DEMO_COPIES * (observation_bytes + state_bytes)


def check_demos_size(n: int, task: Any, *, yes: bool) -> None:
    """Refuse ``demos collect --n`` above :data:`CONFIRM_BYTES` unless ``yes``."""
    state_bytes, observation_bytes = task_sizes(task)
    need = demos_memory(n, state_bytes, observation_bytes)
    if need <= CONFIRM_BYTES or yes:
        return
    raise SizeError(
        f"--n {n} observations of {task.spec.label()} would hold about {gib(need)} of memory (and write "
        f"a file about {gib(need / DEMO_COPIES)}) and take about {duration(n / DEMO_OBSERVATIONS_PER_S)} of CPU time: "
        "pass --yes to record them, or a smaller --n"
    )


def eval_memory(n: int, state_bytes: int, observation_bytes: int) -> int:
    """Estimated bytes of ``eval --n``: the ``n`` games are played at once, each holding
    :data:`EVAL_COPIES` of its state and joint observation."""
    return n * EVAL_COPIES * (observation_bytes + state_bytes)


def check_eval_size(n: int, task: Any, *, yes: bool) -> None:
    """Refuse ``eval --n`` above :data:`CONFIRM_BYTES` unless ``yes``."""
    state_bytes, observation_bytes = task_sizes(task)
    need = eval_memory(n, state_bytes, observation_bytes)
    if need <= CONFIRM_BYTES or yes:
        return
    raise SizeError(
        f"--n {n} episodes of {task.spec.label()} are played at once and would hold about {gib(need)} of "
        "memory: pass --yes to play them, or a smaller --n"
    )
