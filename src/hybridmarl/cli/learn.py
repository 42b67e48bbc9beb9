"""``hybridmarl train``, ``hybridmarl eval`` and ``hybridmarl demos`` (wired into ``hybridmarl.cli``).

Train (``--algo`` picks the learner, ``--preset`` its starting config; every config field can
then be overridden, ``hybridmarl train --algo hybrid --help`` lists them)::

    hybridmarl train --algo hybrid --preset quick --scenario m5v5 \\
        --demonstrator attack-closest --enemy attack-weakest --seed 0 --run-dir runs/m5v5-c
    hybridmarl train --algo hybrid --preset quick --env traffic_junction --demonstrator always-gas
    hybridmarl train --run-dir runs/m5v5-c --resume          # continue an interrupted run

Evaluate (Section 5.1 protocol; ``--json`` prints one JSON object)::

    hybridmarl eval --run-dir runs/m5v5-c --enemy attack-weakest --n 100 --seed 0 --json
    hybridmarl eval --script attack-closest --scenario m5v5 --enemy attack-weakest   # a script

Demonstrations::

    hybridmarl demos collect --scenario m5v5 --demonstrator attack-closest --enemy attack-weakest \\
        --n 10000 --out demos/m5v5-c.safetensors
    hybridmarl demos info demos/m5v5-c.safetensors

Bad input (unknown script or scenario, an invalid dataset, a missing run) raises
:class:`~hybridmarl.errors.UserError` (one line on stderr, exit code 2); a diverged training run
(NaN) raises :class:`~hybridmarl.errors.TrainingDiverged` (exit code 3); see
:mod:`hybridmarl.cli.main`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from hybridmarl.errors import UserError
from hybridmarl.options import DEFAULT_IN_DOCSTRING

# -- train -----------------------------------------------------------------------------------------------


def train_command(args: list[str]) -> int:
    """``hybridmarl train [--algo A] [--preset P] [--env E] [--run-dir D] [--resume] [options]``.

    ``--algo`` picks the learner and ``--preset`` its starting config (default
    ``hybridmarl.algos.DEFAULT_PRESET``); every field of the config can then be given on the
    command line. ``--resume`` with ``--run-dir`` and no ``--preset`` starts from the run's own
    ``config.json``."""
    from hybridmarl import algos
    from hybridmarl.training.config import config_from_dict
    from hybridmarl.training.task import canonical_env

    default_preset: str = getattr(algos, "DEFAULT_PRESET", "quick")
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--algo", default=None)
    pre.add_argument("--preset", default=None)
    pre.add_argument("--env", default="combat")
    pre.add_argument("--run-dir", "--run_dir", dest="run_dir", default=None)
    pre.add_argument("--resume", action="store_true")
    pre.add_argument("--yes", action="store_true")
    known, rest = pre.parse_known_args(args)
    # --resume with a run directory and no preset: start from the run's own (validated) config.
    doc = None
    if (
        known.resume
        and known.preset is None
        and known.run_dir
        and (Path(known.run_dir) / "config.json").exists()
    ):
        from hybridmarl.training.rundir import read_run_config

        doc = read_run_config(known.run_dir)
    mod = algos.algo_module(known.algo or (doc["algo"] if doc else "hybrid"))
    env = canonical_env(known.env)
    if doc is not None:
        if doc["algo"] != mod.ALGO:
            raise UserError(f"{known.run_dir} is a {doc['algo']!r} run, not {mod.ALGO!r}")
        default = config_from_dict(type(mod.PRESETS[default_preset](env)), doc["config"])
        env = default.env
    else:
        preset = known.preset or default_preset
        if preset not in mod.PRESETS:
            raise UserError(
                f"unknown preset {preset!r} for --algo {known.algo or mod.ALGO} (known: {', '.join(mod.PRESETS)})"
            )
        default = mod.PRESETS[preset](env)
    cls = type(default)
    extra = ["--env", env]
    if known.run_dir:
        extra += ["--run-dir", known.run_dir]
    if known.resume:
        extra += ["--resume"]
    desc = (
        f"{(cls.__doc__ or '').strip()}\n\n--algo {{{', '.join(algos.ALGOS)}}} (default hybrid); "
        f"--preset {{{', '.join(mod.PRESETS)}}} (default {default_preset}) sets the defaults below; "
        "--yes trains a run whose arrays are estimated above the size guard (docs/engine.md#size-guards)."
    )
    cfg = tyro.cli(
        cls,
        args=extra + rest,
        default=default,
        prog=f"hybridmarl train --algo {mod.ALGO}",
        description=desc,
    )
    from hybridmarl.cli.sizes import check_train_size
    from hybridmarl.training.task import make_task
    from hybridmarl.validate import check_config

    check_config(cfg)  # every number first: the task and the estimate need valid ones
    check_train_size(cfg, make_task(cfg.task_spec()), yes=known.yes)
    mod.train(cfg)
    return 0


# -- eval ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EvalConfig:
    """Evaluate a trained policy (or a script) with the paper's protocol (Section 5.1)."""

    run_dir: str | None = None
    """Run directory of the policy (its newest checkpoint)."""
    checkpoint: str | None = None
    """With --run-dir: evaluate this checkpoint instead of the newest, by its episode count
    (700) or its name (ckpt_000000700); the run keeps its last --keep-checkpoints.
    'best': the policy of the run's best periodic evaluation (trained with --eval-every)."""
    policy: Literal["auto", "average", "last"] = "auto"
    """With --run-dir: which weights of the checkpoint to play. 'auto': the run's policy (the
    actor's weight average where the run keeps one, --actor-average-from, else the actor);
    'average': the average (exit 2 without one); 'last': the last actor itself."""
    script: str | None = None
    """Evaluate this scripted player instead of a trained policy (e.g. the demonstrator D), or,
    in combat, a search player as in 'hybridmarl battle --p0'
    ('uct:script=attack-closest,playout1=attack-weakest' is UCT_c as 'hybridmarl reproduce'
    plays it, 'abcd:...' A-B_c; docs/reproducing.md#search-budgets): the same start states,
    played turn by turn on the host."""
    env: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """With --script: the environment (default combat)."""
    scenario: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Combat scenario (default: the run's)."""
    enemy: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Enemy script. Default: the paper's cross-validation (a model learned from c fights w and
    vice versa); for --script, attack-weakest."""
    enemy_run_dir: str | None = None
    """Use another run's trained actor as the enemy (combat; its agents/actions must match the
    enemy side)."""
    n: int = 100
    """Battles / episodes (Section 5.1: 100)."""
    seed: int = 0
    """Seed of the start states."""
    engine: Literal["auto", "native", "jax"] = "auto"
    """Engine of a combat --script against a scripted enemy: 'native' (the default on a CPU,
    'auto') plays the same start states to the same results faster; the 'random' script always
    plays on jax (docs/engine-backends.md)."""
    setting: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Named setting (docs/engine.md#settings): 'sparcraft' or 'paper'; combat rules and
    scenario geometry, traffic_junction p_arrive. Default: the run's; for --script, sparcraft."""
    p_arrive: Annotated[float | None, DEFAULT_IN_DOCSTRING] = None
    """Traffic junction arrival probability (default: the run's, or the setting's: 0.2 under
    sparcraft)."""
    time_penalty: Annotated[bool | None, DEFAULT_IN_DOCSTRING] = None
    """Traffic junction: CommNet's -0.01·τ time penalty in the reported return (default: the
    run's setting; off for --script). The failure rate does not depend on it."""
    json: bool = False
    """Print exactly one JSON object (W, R, their 95% intervals, ...) on stdout."""
    out: str | None = None
    """Also write the JSON here."""
    yes: bool = False
    """Play an --n whose games are estimated above the size guard (8 GiB of memory;
    docs/engine.md#size-guards)."""


def apply_setting(spec: Any, setting: str | None, *, p_arrive: float | None = None) -> Any:
    """``spec`` under ``setting`` (None: keep the spec's) with ``p_arrive`` where given;
    ``SettingError`` (a ``UserError``) if they contradict each other."""
    from hybridmarl.settings import check_options

    s = check_options(spec.setting if setting is None else setting, p_arrive=p_arrive)
    if p_arrive is not None:
        p = float(p_arrive)
    elif setting is not None and spec.env != "combat":
        p = s.p_arrive
    else:
        p = spec.p_arrive
    return dataclasses.replace(spec, setting=s.name, p_arrive=p)


def run_eval(cfg: EvalConfig) -> int:
    """Evaluate what ``cfg`` names and print the result (or one JSON object); raises
    ``UserError`` on bad input."""
    from hybridmarl.io import check_output_path
    from hybridmarl.training import evaluate as E
    from hybridmarl.training.task import (
        TaskSpec,
        canonical_env,
        canonical_script,
        default_enemy,
        make_task,
    )
    from hybridmarl.validate import COUNT, PROBABILITY, SEED, check_values, optional

    check_values(
        {"n": cfg.n, "seed": cfg.seed, "p_arrive": cfg.p_arrive},
        {"n": COUNT, "seed": SEED, "p_arrive": optional(PROBABILITY)},
    )
    if cfg.out:
        check_output_path(cfg.out)
    if (cfg.run_dir is None) == (cfg.script is None):
        raise UserError("give exactly one of --run-dir (a trained policy) or --script")
    if cfg.script is not None and cfg.enemy_run_dir and E.is_search_spec(cfg.script):
        raise UserError(
            "a search player (--script uct/abcd/pgs) needs a script enemy (--enemy), not --enemy-run-dir"
        )
    bundle = None
    if cfg.run_dir is not None:
        bundle = E.load_policy(cfg.run_dir, cfg.checkpoint, cfg.policy)
        spec = bundle.spec
        trained_from = bundle.config.get("config", {}).get("demonstrator_name", "")
    else:
        env = canonical_env(cfg.env or "combat")
        spec = TaskSpec(env=env)
        trained_from = ""
    if cfg.scenario:
        spec = dataclasses.replace(spec, scenario=cfg.scenario)
    spec = apply_setting(spec, cfg.setting, p_arrive=cfg.p_arrive)
    if cfg.time_penalty is not None:
        spec = dataclasses.replace(spec, time_penalty=cfg.time_penalty)
    enemy_label = None
    if spec.env == "combat":
        if cfg.enemy_run_dir:
            enemy_bundle = E.load_policy(cfg.enemy_run_dir)
            script_fn = E.mirrored_enemy(enemy_bundle, spec)
            from hybridmarl.training.task import Task

            task = Task(spec, enemy_script=script_fn)
            enemy_label = f"policy:{cfg.enemy_run_dir}"
        else:
            if cfg.enemy:
                enemy = canonical_script("combat", cfg.enemy)
            elif trained_from and not trained_from.startswith("dataset:"):
                enemy = default_enemy(trained_from)
            elif bundle is not None:
                enemy = bundle.config.get("config", {}).get("eval_enemy_name") or spec.enemy
            else:
                enemy = "attack-weakest"
            spec = dataclasses.replace(spec, enemy=enemy)
            task = make_task(spec)
            enemy_label = enemy
    else:
        task = make_task(spec)
    if bundle is not None and (task.num_agents, task.num_actions, task.obs_dim) != (
        make_task(bundle.spec).num_agents,
        make_task(bundle.spec).num_actions,
        make_task(bundle.spec).obs_dim,
    ):
        raise UserError(
            f"the policy of {cfg.run_dir} was trained on {bundle.spec.label()}; {spec.label()} has other observation/action shapes"
        )
    from hybridmarl.cli.sizes import check_eval_size

    check_eval_size(cfg.n, task, yes=cfg.yes)
    if bundle is not None:
        res = E.evaluate_task(task, bundle.module, bundle.variables, n=cfg.n, seed=cfg.seed)
    elif cfg.script is not None and E.is_search_spec(cfg.script):
        # A search player (Table 1's UCT_c, A-B_c, Profile) on the same start states as a script.
        from hybridmarl.search import make_player

        if task.kind != "combat":
            raise UserError("search players (uct, abcd, pgs) play combat only")
        try:
            make_player(cfg.script)
        except ValueError as e:
            raise UserError(str(e).splitlines()[0]) from None
        res = E.evaluate_player(task, cfg.script, n=cfg.n, seed=cfg.seed, progress=True)
    else:
        assert cfg.script is not None
        res = E.evaluate_task(
            task,
            None,
            None,
            n=cfg.n,
            seed=cfg.seed,
            script=canonical_script(task.kind, cfg.script),
            engine=cfg.engine,
        )
    res.update(
        policy=cfg.run_dir or f"script:{cfg.script}",
        env=spec.env,
        scenario=spec.scenario if spec.env == "combat" else None,
        enemy=enemy_label,
        seed=cfg.seed,
        setting=spec.setting,
    )
    if bundle is not None:
        res["episodes"] = bundle.meta.get("episodes")  # of the checkpoint evaluated
        res["weights"] = bundle.weights
    text = json.dumps(res, sort_keys=True)
    if cfg.out:
        from hybridmarl.io import write_json_atomic

        write_json_atomic(cfg.out, res)
    if cfg.json:
        print(text)
        return 0

    print(f"{res['policy']} on {task.spec.label()}")
    print(task.result_line(res))
    return 0


def eval_command(args: list[str]) -> int:
    """``hybridmarl eval [options]``."""
    return run_eval(tyro.cli(EvalConfig, args=args, prog="hybridmarl eval"))


# -- demos -----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DemosCollectConfig:
    """Record a scripted demonstrator against a scripted enemy into a dataset file."""

    out: str
    """Output file (.safetensors), written atomically."""
    env: str = "combat"
    """Environment: combat or traffic_junction."""
    scenario: str = "m5v5"
    """Combat scenario."""
    demonstrator: str = "attack-closest"
    """Demonstrator script (NAME or NAME:EPS)."""
    enemy: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Combat enemy script (default: the cross-validation enemy of the demonstrator)."""
    n: int = 10_000
    """Observations (joint states) to record (Section 5.1: 10,000)."""
    seed: int = 0
    """Seed of the start states."""
    num_envs: int = 64
    """Games recorded in parallel."""
    gamma: float = 0.995
    """Discount of the recorded returns (Section 5.1)."""
    setting: str = "sparcraft"
    """Named setting (docs/engine.md#settings): 'sparcraft' or 'paper' (combat rules and scenario
    geometry; traffic_junction p_arrive)."""
    p_arrive: Annotated[float | None, DEFAULT_IN_DOCSTRING] = None
    """Traffic junction arrival probability (default: the setting's; sparcraft: 0.2)."""
    time_penalty: bool = False
    """Traffic junction: record rewards and returns with CommNet's time penalty (-0.01·τ per car
    per step; as 'hybridmarl train --time-penalty'). The paper's reward has none."""
    max_turns: int = 1000
    """Combat turn cap per episode."""
    engine: Literal["auto", "native", "jax"] = "auto"
    """Engine of a combat script against a scripted enemy: 'native' (the default on a CPU,
    'auto') records the same dataset faster; the 'random' script always plays on jax
    (docs/engine-backends.md)."""
    yes: bool = False
    """Record an --n whose dataset is estimated above the size guard (8 GiB of memory;
    docs/engine.md#size-guards)."""


@dataclass(frozen=True)
class DemosInfoConfig:
    """Validate a dataset file and print a summary (exit code 2 with the problem if invalid)."""

    path: tyro.conf.Positional[str]
    """The dataset file."""


def run_demos_info(cfg: DemosInfoConfig) -> int:
    """Validate a dataset file and print its summary as JSON; raises
    :class:`~hybridmarl.training.demos.DatasetError` (a ``UserError``) if it is invalid."""
    from hybridmarl.training import demos as D

    ds = D.load_dataset(cfg.path)
    a = ds.arrays
    summary = {
        "path": cfg.path,
        **{
            k: ds.meta.get(k)
            for k in (
                "version",
                "demonstrator",
                "task",
                "num_agents",
                "num_actions",
                "obs_dim",
                "seed",
            )
        },
        "observations": ds.size,
        "episodes": int(a["episode"].max()) + 1,
        "agent_decisions": int((a["legal"].sum(-1) >= 2).sum()),
        "mean_return": float(a["return"][a["t"] == 0].mean()) if (a["t"] == 0).any() else None,
    }
    print(json.dumps(summary, indent=2))
    return 0


def run_demos_collect(cfg: DemosCollectConfig) -> int:
    """Record the demonstrations ``cfg`` describes; raises ``UserError`` on bad input."""
    from hybridmarl.io import check_output_path
    from hybridmarl.training import demos as D
    from hybridmarl.training.task import TaskSpec, canonical_env, canonical_script, default_enemy
    from hybridmarl.validate import COUNT, DISCOUNT, PROBABILITY, SEED, check_values, optional

    check_values(
        {
            "n": cfg.n,
            "seed": cfg.seed,
            "num_envs": cfg.num_envs,
            "gamma": cfg.gamma,
            "p_arrive": cfg.p_arrive,
            "max_turns": cfg.max_turns,
        },
        {
            "n": COUNT,
            "seed": SEED,
            "num_envs": COUNT,
            "gamma": DISCOUNT,
            "p_arrive": optional(PROBABILITY),
            "max_turns": COUNT,
        },
    )
    check_output_path(cfg.out)
    env = canonical_env(cfg.env)
    demo = canonical_script(env, cfg.demonstrator)
    if env == "combat":
        enemy = canonical_script("combat", cfg.enemy) if cfg.enemy else default_enemy(demo)
        spec = TaskSpec(env=env, scenario=cfg.scenario, enemy=enemy, max_turns=cfg.max_turns)
    else:
        spec = TaskSpec(env=env, time_penalty=cfg.time_penalty)
    spec = apply_setting(spec, cfg.setting, p_arrive=cfg.p_arrive)
    from hybridmarl.cli.sizes import check_demos_size
    from hybridmarl.training.task import make_task

    check_demos_size(cfg.n, make_task(spec), yes=cfg.yes)
    ds = D.collect(
        spec, demo, cfg.n, seed=cfg.seed, num_envs=cfg.num_envs, gamma=cfg.gamma, engine=cfg.engine
    )
    path = D.save_dataset(ds, cfg.out)
    print(
        f"recorded {ds.size} observations ({int(ds.arrays['episode'].max()) + 1} episodes) of {demo} on {spec.label()} -> {path}"
    )
    return 0


def demos_command(args: list[str]) -> int:
    """``hybridmarl demos {collect,info} [options]``."""
    if not args or args[0] not in ("collect", "info"):
        raise UserError("usage: hybridmarl demos {collect,info} [options]")
    if args[0] == "info":
        return run_demos_info(
            tyro.cli(DemosInfoConfig, args=args[1:], prog="hybridmarl demos info")
        )
    return run_demos_collect(
        tyro.cli(DemosCollectConfig, args=args[1:], prog="hybridmarl demos collect")
    )
