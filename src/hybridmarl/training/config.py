"""Shared machinery of the learners: the config base, run directories, checks, the registry.

Every learner (``--algo``) is a module with

- a frozen config dataclass deriving from :class:`TrainConfig` (tyro turns it into the command
  line; every field's docstring says where its default comes from),
- ``PRESETS``: preset name -> function ``(env) -> config`` (``--preset``),
- ``train(cfg) -> int``: the whole run (exit code), using ``algos.checkpoint``,
  ``algos.logger`` and ``algos.evaluate`` like every other learner.

:data:`ALGOS` maps ``--algo`` names to those modules (imported lazily). Adding a learner (DQfD,
OGTL, ...) = one module with those three names + one entry here.
"""

from __future__ import annotations

import dataclasses
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.errors import TrainingDiverged
from hybridmarl.training.task import (
    TaskError,
    TaskSpec,
    canonical_env,
    canonical_script,
    default_enemy,
)


@dataclass(frozen=True)
class TrainConfig:
    """Settings shared by every learner (the task, the run, logging and checkpoints)."""

    env: str = "combat"
    """Environment: ``combat`` (SparCraft combat, paper Section 5.1) or ``traffic_junction``
    (Section 5.3)."""
    scenario: str = "m5v5"
    """Combat scenario ``m<A>v<B>`` (A Marines of ours vs B; Section 5.1 uses m5v5, m30v30,
    m18v20, m24v30). Ignored for traffic_junction."""
    demonstrator: str = "attack-closest"
    """The demonstrator A^D (Section 3): a script name (combat: ``attack-closest`` = c,
    ``attack-weakest`` = w, Section 5.1; traffic_junction: ``always-gas`` or
    ``yield-before-junction``), optionally ``NAME:EPS`` for ε-random legal actions, or the path
    of a demonstration dataset (``hybridmarl demos collect``), which is then cloned (BC)."""
    enemy: str | None = None
    """Combat enemy script during training. Default: the other heuristic (c <-> w), the paper's
    cross-validation setting (Section 5.1)."""
    p_arrive: float = 0.2
    """Traffic junction arrival probability (0.2: the evaluation value of CommNet's medium
    task, which the paper follows, Section 5.3)."""
    time_penalty: bool = False
    """Traffic junction: add CommNet's ``-0.01·τ`` per car per step (τ = steps since the car
    entered; reference §1.0). Off: the paper's reward, collisions and arrivals only (Section 5.3)."""
    max_turns: int = 1000
    """Combat: cap on engine decision turns per episode (the env's default)."""
    seed: int = 0
    """Seed of everything random (start states, network initialisation, minibatches)."""
    run_dir: str | None = None
    """Where logs and checkpoints go. Default ``runs/<name>``."""
    name: str | None = None
    """Run name (default ``<algo>-<env or scenario>-<demonstrator>-s<seed>``)."""
    resume: bool = False
    """Continue from the newest checkpoint in the run directory (exactly as if uninterrupted)."""
    checkpoint_every: int = 1000
    """Save a checkpoint every this many training episodes (and at the end)."""
    keep_checkpoints: int = 3
    """How many of the newest checkpoints to keep."""
    eval_episodes: int = 100
    """Battles / episodes of the final evaluation (paper Section 5.1: 100 battles)."""
    eval_enemy: str | None = None
    """Combat enemy of the final evaluation. Default: the paper's cross-validation (a model
    learned from c fights w and vice versa, Section 5.1)."""
    eval_every: int = 0
    """Also evaluate the frozen policy every this many training episodes (0: only at the end),
    on held-out *selection* start states (seed + 2) that the final evaluation (seed + 1) never
    uses; results go to ``evals.csv`` and TensorBoard (``eval/``). The training log's win rate
    is not a substitute: it is played by a policy that is still being updated."""
    keep_best: bool = True
    """With ``eval_every`` > 0: keep the policy of the best periodic evaluation (combat: W, then
    R; traffic junction: failure rate, then return) as checkpoint ``best``; the final evaluation
    then also reports it (``eval.json``'s ``best``), and ``hybridmarl eval --checkpoint best``
    evaluates it. Selection uses its own states, so the final figures stay unbiased."""
    tensorboard: bool = True
    """Write TensorBoard event files under ``<run_dir>/tb``."""
    progress: bool = True
    """Show a progress display (a bar on a terminal, status lines otherwise)."""

    def replace(self, **changes: Any) -> Any:
        """A copy with the given fields changed (field names as on the command line, with
        underscores)."""
        return dataclasses.replace(self, **changes)

    def task_spec(self) -> TaskSpec:
        env = canonical_env(self.env)
        if env == "combat":
            enemy = canonical_script("combat", self.enemy) if self.enemy else default_enemy(self.base_demonstrator())
            return TaskSpec(env=env, scenario=self.scenario, enemy=enemy, max_turns=self.max_turns)
        return TaskSpec(env=env, p_arrive=self.p_arrive, time_penalty=self.time_penalty)

    def demonstrator_is_dataset(self) -> bool:
        d = self.demonstrator
        return d.endswith((".safetensors", ".npz")) or "/" in d or Path(d).is_file()

    def base_demonstrator(self) -> str:
        """The demonstrator's script name; for a dataset, the script it was recorded from."""
        if not self.demonstrator_is_dataset():
            return canonical_script(canonical_env(self.env), self.demonstrator)
        path = Path(self.demonstrator)
        if not path.is_file():
            raise TaskError(f"{path}: no such dataset file")
        from hybridmarl.training.demos import peek_meta

        return str(peek_meta(path).get("demonstrator", ""))

    def demonstrator_name(self) -> str:
        """The script name (canonical), or ``dataset:<file name>``."""
        if self.demonstrator_is_dataset():
            return f"dataset:{Path(self.demonstrator).name}"
        return canonical_script(canonical_env(self.env), self.demonstrator)

    def eval_enemy_name(self) -> str:
        if self.eval_enemy:
            return canonical_script("combat", self.eval_enemy)
        return default_enemy(self.base_demonstrator())


def default_run_name(algo: str, cfg: TrainConfig) -> str:
    env = canonical_env(cfg.env)
    where = cfg.scenario if env == "combat" else "tj"
    demo = re.sub(r"[^A-Za-z0-9_.-]+", "_", cfg.demonstrator_name().replace("dataset:", "ds-"))
    return f"{algo}-{where}-{demo}-s{cfg.seed}"


def resolve_run_dir(algo: str, cfg: TrainConfig) -> Path:
    if cfg.run_dir:
        return Path(cfg.run_dir)
    return Path("runs") / (cfg.name or default_run_name(algo, cfg))


def config_to_dict(cfg: Any) -> dict[str, Any]:
    out = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


def config_from_dict(cls: type, d: dict[str, Any]) -> Any:
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kw = {}
    for k, v in d.items():
        if k in fields:
            kw[k] = tuple(v) if isinstance(v, list) else v
    return cls(**kw)


# -- numerical checks ------------------------------------------------------------------------------


@jax.jit
def _all_finite(tree: Any) -> jax.Array:
    leaves = [jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree) if jnp.issubdtype(x.dtype, jnp.floating)]
    return jnp.all(jnp.stack(leaves)) if leaves else jnp.asarray(True)


def check_finite(what: str, value: Any, where: str) -> None:
    """Raise :class:`TrainingDiverged` if ``value`` (a number or a pytree of arrays) has NaN/inf."""
    if isinstance(value, int | float | np.floating | np.integer):
        ok = math.isfinite(float(value))
    else:
        ok = bool(_all_finite(value))
    if not ok:
        raise TrainingDiverged(
            f"{what} became NaN/inf at {where}; lower the learning rate or check the inputs "
            "(the last checkpoint is still valid: fix the cause and --resume)"
        )


#: Seed offsets (added to ``--seed``) of the evaluation start states: the final evaluation's and
#: the periodic selection evaluations'. Distinct, so that picking the best checkpoint on one set
#: and reporting it on the other does not flatter it.
FINAL_EVAL_SEED = 1
SELECT_EVAL_SEED = 2


def selection_key(result: dict[str, Any]) -> tuple[float, float]:
    """Larger is better: combat (W, R); traffic junction (-failure rate, return)."""
    if "W" in result:
        return (float(result["W"]), float(result["R"]))
    return (-float(result["failure_rate"]), float(result["R"]))


class PeriodicEval:
    """``--eval-every``/``--keep-best``: when due, evaluate the frozen policy on the selection
    states, log a row to ``evals.csv`` and TensorBoard, and save the policy as checkpoint
    ``best`` when it beats every earlier evaluation. Its state travels in checkpoint metadata
    (``meta()``/``resume()``), so a resumed run keeps comparing against the same best."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, log: Any, episodes: int) -> None:
        self.every, self.keep_best, self.run_dir, self.log = cfg.eval_every, cfg.keep_best, Path(run_dir), log
        self.best_key: tuple[float, float] | None = None  # the best checkpoint's own meta has the rest
        self._next = self._after(episodes)

    def _after(self, episodes: int) -> int | None:
        return (episodes // self.every + 1) * self.every if self.every > 0 else None

    def resume(self, meta: dict[str, Any], episodes: int) -> None:
        b = meta.get("best_eval")
        if b:
            self.best_key = (float(b["key"][0]), float(b["key"][1]))
        self._next = self._after(episodes)

    def meta(self) -> dict[str, Any]:
        if self.best_key is None:
            return {}
        return {"best_eval": {"key": list(self.best_key)}}

    def maybe_run(self, episodes: int, evaluate: Any, actor_arrays: Any, meta: dict[str, Any]) -> dict[str, Any] | None:
        """Evaluate if due: ``evaluate(seed_offset) -> result``; ``actor_arrays() -> dict`` (the
        arrays named ``actor.*`` that ``evaluate.load_policy`` reads). Returns the result or None."""
        if self._next is None or episodes < self._next:
            return None
        self._next = self._after(episodes)
        res = evaluate(SELECT_EVAL_SEED)
        key = selection_key(res)
        improved = self.best_key is None or key > self.best_key
        if improved and self.keep_best:
            from hybridmarl.training.checkpoint import BEST, save_checkpoint

            self.best_key = key
            selection = {k: v for k, v in res.items() if isinstance(v, int | float | list)}
            save_checkpoint(self.run_dir, episodes, actor_arrays(), {**meta, "episodes": episodes, "selection": selection}, name=BEST)
        scalars = {k: v for k, v in res.items() if isinstance(v, float)}
        self.log.evals.write([{"episodes": episodes, **scalars, "best": int(improved and self.keep_best)}])
        self.log.scalars(episodes, scalars, prefix="eval")
        return res


class RunClock:
    """Wall and CPU seconds of a whole run across ``--resume``: this process's time plus what the
    checkpoint it resumed from recorded (``elapsed()`` goes into every checkpoint's meta). Work
    redone after a kill is counted once, by the process that redid it."""

    def __init__(self) -> None:
        self._wall0, self._cpu0 = time.time(), time.process_time()
        self._wall_before = self._cpu_before = 0.0

    def resume(self, meta: dict[str, Any]) -> None:
        self._wall_before = float(meta.get("wall_s", 0.0))  # absent in older checkpoints
        self._cpu_before = float(meta.get("cpu_s", 0.0))

    def elapsed(self) -> dict[str, float]:
        return {
            "wall_s": self._wall_before + time.time() - self._wall0,
            "cpu_s": self._cpu_before + time.process_time() - self._cpu0,
        }


def key_of(data: Any) -> jax.Array:
    """A typed PRNG key from raw uint32 key data (state pytrees keep raw data)."""
    return jax.random.wrap_key_data(jnp.asarray(data, jnp.uint32))


def key_data(key: jax.Array) -> jax.Array:
    return jax.random.key_data(key)
