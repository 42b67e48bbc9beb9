"""Shared machinery of the learners: the config base and its option groups, run directories,
numerical checks, periodic evaluation, the run clock.

Every learner ('--algo', registered in 'hybridmarl.algos') is a module with

- a frozen config dataclass deriving from 'TrainConfig' (tyro turns it into the command line,
  one box of '--help' per option group, with flat flags; every field's docstring says where its
  default comes from),
- 'PRESETS': preset name -> function '(env) -> config' ('--preset'),
- 'train(cfg) -> TrainResult': the whole run, on the skeleton of 'hybridmarl.training.run'.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from tyro.conf import OmitArgPrefixes

from hybridmarl.errors import TrainingDiverged
from hybridmarl.options import DEFAULT_IN_DOCSTRING
from hybridmarl.settings import check_options, get_setting
from hybridmarl.training.task import (
    TaskError,
    TaskSpec,
    canonical_env,
    canonical_script,
    default_enemy,
)


class Options:
    """Base of the option groups of a config (each group is one box of ``--help``)."""

    #: Fields of this group that only steer the run (budgets, cadences, paths, logging), never
    #: what the compiled learner computes: ``compile_key`` resets them. Every other field is
    #: part of the key.
    RUN_ONLY: ClassVar[frozenset[str]] = frozenset()


@dataclass(frozen=True)
class TaskOptions(Options):
    """The task: the environment, the demonstrator and the enemy."""

    # The compiled learners receive the task itself (and the demonstrator script) next to the
    # config, so the task's fields are not part of the compile key.
    RUN_ONLY = frozenset(
        {
            "env",
            "scenario",
            "demonstrator",
            "enemy",
            "p_arrive",
            "time_penalty",
            "max_turns",
            "setting",
        }
    )

    env: str = "combat"
    """Environment: 'combat' (SparCraft combat, paper Section 5.1) or 'traffic_junction'
    (Section 5.3)."""
    scenario: str = "m5v5"
    """Combat scenario m<A>v<B> (A Marines of ours vs B; Section 5.1 uses m5v5, m30v30,
    m18v20, m24v30). Ignored for traffic_junction."""
    demonstrator: str = "attack-closest"
    """The demonstrator A^D (Section 3): a script name (combat: 'attack-closest' = c,
    'attack-weakest' = w, Section 5.1; traffic_junction: 'always-gas' or
    'yield-before-junction'), optionally NAME:EPS for ε-random legal actions, or the path of a
    demonstration dataset ('hybridmarl demos collect'), which is then cloned (BC)."""
    enemy: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Combat enemy script during training. Default: the other heuristic (c <-> w), the paper's
    cross-validation setting (Section 5.1)."""
    setting: str = "sparcraft"
    """Named setting (docs/engine.md#settings): 'sparcraft' (SparCraft's current rules, disks
    r=100 px centred 150 px apart; traffic_junction p_arrive 0.2) or 'paper' (classic overkill,
    stalemate limit 200, the geometry calibrated to the paper's demonstrators, Table 1; for
    traffic_junction the p_arrive at which always-gas fails as often as the paper's D, Table 2)."""
    p_arrive: Annotated[float | None, DEFAULT_IN_DOCSTRING] = None
    """Traffic junction arrival probability. Default: the setting's (0.2 under 'sparcraft', the
    evaluation value of CommNet's medium task, Section 5.3)."""
    time_penalty: bool = False
    """Traffic junction: add CommNet's -0.01·τ per car per step (τ = steps since the car
    entered; docs/environments.md). Off: the paper's reward, collisions and arrivals only
    (Section 5.3)."""
    max_turns: int = 1000
    """Combat: cap on engine decision turns per episode (the env's default)."""


@dataclass(frozen=True)
class RunOptions(Options):
    """The run: seed, directory, checkpoints and logging."""

    RUN_ONLY = frozenset(
        {
            "seed",
            "run_dir",
            "name",
            "resume",
            "checkpoint_every",
            "keep_checkpoints",
            "tensorboard",
            "progress",
        }
    )

    seed: int = 0
    """Seed of everything random (start states, network initialisation, minibatches)."""
    run_dir: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Where logs and checkpoints go. Default runs/<name>."""
    name: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Run name (default <algo>-<env or scenario>-<demonstrator>-s<seed>)."""
    resume: bool = False
    """Continue from the newest checkpoint in the run directory (exactly as if uninterrupted)."""
    checkpoint_every: int = 1000
    """Save a checkpoint every this many training episodes (and at the end)."""
    keep_checkpoints: int = 3
    """How many of the newest checkpoints to keep."""
    tensorboard: bool = True
    """Write TensorBoard event files under <run_dir>/tb."""
    progress: bool = True
    """Show a progress display (a bar on a terminal, status lines otherwise)."""


@dataclass(frozen=True)
class EvalOptions(Options):
    """Evaluation: the final one (paper Section 5.1) and the periodic ones."""

    RUN_ONLY = frozenset({"eval_episodes", "eval_enemy", "eval_every", "keep_best"})

    eval_episodes: int = 100
    """Battles / episodes of the final evaluation (paper Section 5.1: 100 battles)."""
    eval_enemy: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Combat enemy of the final evaluation. Default: the paper's cross-validation (a model
    learned from c fights w and vice versa, Section 5.1)."""
    eval_every: int = 0
    """Also evaluate the frozen policy every this many training episodes (0: only at the end),
    on held-out selection start states (seed + 2) that the final evaluation (seed + 1) never
    uses; results go to evals.csv and TensorBoard (eval/). The training log's win rate is not a
    substitute: it is played by a policy that is still being updated."""
    keep_best: bool = True
    """With eval_every > 0: keep the policy of the best periodic evaluation (combat: W, then R;
    traffic junction: failure rate, then return) as checkpoint 'best'; the final evaluation
    then also reports it (eval.json's 'best'), and 'hybridmarl eval --checkpoint best'
    evaluates it. Selection uses its own states, so the final figures stay unbiased."""


def _groups(cls: type) -> dict[str, type]:
    """Group field name -> group class, of a config class."""
    out = {}
    for f in dataclasses.fields(cls):
        t = f.default_factory if f.default_factory is not dataclasses.MISSING else None
        if isinstance(t, type) and issubclass(t, Options):
            out[f.name] = t
    return out


@functools.lru_cache(maxsize=64)
def _locations(cls: type) -> dict[str, str | None]:
    """Flat field name -> the group holding it (None: a field of the config itself)."""
    groups = _groups(cls)
    out: dict[str, str | None] = {}
    for f in dataclasses.fields(cls):
        if f.name in groups:
            for g in dataclasses.fields(groups[f.name]):
                out[g.name] = f.name
        else:
            out[f.name] = None
    return out


@dataclass(frozen=True)
class TrainConfig:
    """Settings shared by every learner (the task, the run, logging and checkpoints).

    Fields live in option groups (one box each in '--help'), but their names are flat and
    unique: the command line ('--num-envs'), 'replace(num_envs=...)', reading 'cfg.num_envs'
    and config.json all use the flat name."""

    task: OmitArgPrefixes[TaskOptions] = dataclasses.field(default_factory=TaskOptions)
    run: OmitArgPrefixes[RunOptions] = dataclasses.field(default_factory=RunOptions)
    evaluation: OmitArgPrefixes[EvalOptions] = dataclasses.field(default_factory=EvalOptions)

    def __getattr__(self, name: str) -> Any:
        # Only called when normal lookup fails: read a grouped field by its flat name.
        if not name.startswith("_"):
            group = _locations(type(self)).get(name)
            if group is not None:
                return getattr(object.__getattribute__(self, group), name)
        raise AttributeError(f"{type(self).__name__!r} has no field {name!r}")

    def replace(self, **changes: Any) -> Any:
        """A copy with the given fields changed, by their flat names (as on the command line,
        with underscores); a group can also be replaced whole by its name."""
        where = _locations(type(self))
        top: dict[str, Any] = {}
        grouped: dict[str, dict[str, Any]] = {}
        for k, v in changes.items():
            if k not in where:
                if k in _groups(type(self)):
                    top[k] = v
                    continue
                raise TypeError(f"{type(self).__name__} has no field {k!r}")
            g = where[k]
            if g is None:
                top[k] = v
            else:
                grouped.setdefault(g, {})[k] = v
        for g, kw in grouped.items():
            top[g] = dataclasses.replace(top.get(g, getattr(self, g)), **kw)
        return dataclasses.replace(self, **top)

    @classmethod
    def field_names(cls) -> list[str]:
        """Every flat field name, in order."""
        return list(_locations(cls))

    def task_spec(self) -> TaskSpec:
        env = canonical_env(self.env)
        if env == "combat":
            setting = get_setting(self.setting)
            enemy = (
                canonical_script("combat", self.enemy)
                if self.enemy
                else default_enemy(self.base_demonstrator())
            )
            return TaskSpec(
                env=env,
                scenario=self.scenario,
                enemy=enemy,
                max_turns=self.max_turns,
                setting=setting.name,
            )
        setting = check_options(self.setting, p_arrive=self.p_arrive)
        p_arrive = setting.p_arrive if self.p_arrive is None else float(self.p_arrive)
        return TaskSpec(
            env=env, p_arrive=p_arrive, time_penalty=self.time_penalty, setting=setting.name
        )

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
        from hybridmarl.training.demos import load_dataset, peek_meta

        name = peek_meta(path).get("demonstrator")
        if not isinstance(name, str) or not name:
            load_dataset(path)  # names the file's problem
            raise TaskError(f"{path}: the dataset does not name its demonstrator")
        return name

    def demonstrator_name(self) -> str:
        """The script name (canonical), or 'dataset:<file name>'."""
        if self.demonstrator_is_dataset():
            return f"dataset:{Path(self.demonstrator).name}"
        return canonical_script(canonical_env(self.env), self.demonstrator)

    def eval_enemy_name(self) -> str:
        if self.eval_enemy:
            return canonical_script("combat", self.eval_enemy)
        return default_enemy(self.base_demonstrator())


#: Run-only fields of a config that are not in a group (the learners' own budgets).
RUN_ONLY_TOP = frozenset({"total_episodes", "time_limit_min"})


def compile_key(cfg: Any) -> Any:
    """The config with every run-only field (see 'Options.RUN_ONLY') reset to its default: the
    key under which a learner's compiled functions are cached. A field not declared run-only
    is part of the key, so a new field that shapes compilation can never reuse a stale
    program; two runs that differ only in run-only fields share their programs."""
    cls = type(cfg)
    default = cls()
    groups = _groups(cls)
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name in groups:
            g = getattr(cfg, f.name)
            reset = {n: getattr(getattr(default, f.name), n) for n in type(g).RUN_ONLY}
            changes[f.name] = dataclasses.replace(g, **reset)
        elif f.name in RUN_ONLY_TOP:
            changes[f.name] = getattr(default, f.name)
    return dataclasses.replace(cfg, **changes)


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
    """The config as one flat JSON-ready dict (flat field names; tuples as lists)."""
    out = {}
    for name in cfg.field_names():
        v = getattr(cfg, name)
        out[name] = list(v) if isinstance(v, tuple) else v
    return out


def config_from_dict(cls: type, d: dict[str, Any]) -> Any:
    """The inverse of 'config_to_dict' (unknown keys, such as options a later version removed,
    are ignored; missing ones keep their defaults)."""
    names = set(cls.field_names())  # type: ignore[attr-defined]
    kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in names}
    return cls().replace(**kw)


# -- numerical checks ------------------------------------------------------------------------------


@jax.jit
def _all_finite(tree: Any) -> jax.Array:
    leaves = [
        jnp.all(jnp.isfinite(x))
        for x in jax.tree.leaves(tree)
        if jnp.issubdtype(x.dtype, jnp.floating)
    ]
    return jnp.all(jnp.stack(leaves)) if leaves else jnp.asarray(True)


def check_finite(what: str, value: Any, where: str) -> None:
    """Raise :class:`TrainingDiverged` if ``value`` (a number or a pytree of arrays) has NaN/inf
    (``training.run.Run`` adds to the message what checkpoint is left to resume from)."""
    if isinstance(value, int | float | np.floating | np.integer):
        ok = math.isfinite(float(value))
    else:
        ok = bool(_all_finite(value))
    if not ok:
        raise TrainingDiverged(
            f"{what} became NaN/inf at {where}; lower the learning rate or check the inputs"
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
        self.every, self.keep_best, self.run_dir, self.log = (
            cfg.eval_every,
            cfg.keep_best,
            Path(run_dir),
            log,
        )
        self.best_key: tuple[float, float] | None = (
            None  # the best checkpoint's own meta has the rest
        )
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

    def maybe_run(
        self, episodes: int, evaluate: Any, actor_arrays: Any, meta: dict[str, Any]
    ) -> dict[str, Any] | None:
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
            save_checkpoint(
                self.run_dir,
                episodes,
                actor_arrays(),
                {**meta, "episodes": episodes, "selection": selection},
                name=BEST,
            )
        scalars = {k: v for k, v in res.items() if isinstance(v, float)}
        self.log.evals.write(
            [{"episodes": episodes, **scalars, "best": int(improved and self.keep_best)}]
        )
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
