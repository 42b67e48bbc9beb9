"""``hybridmarl quickstart``: the m5v5 row of the paper's Table 1 in one command.

One command, resumable at any point:

1. train the hybrid method (``--preset quick`` by default) on a combat scenario from a scripted
   demonstrator, in this process (the learner's ``train(config)``; an interrupted run is
   resumed, a finished one reused if it was made with the same settings);
2. evaluate the demonstrator D and the trained policy with the paper's protocol (Section 5.1:
   ``n`` battles, legal argmax, W and R with 95% intervals) against the paper's cross-validation
   enemy (a model learned from c fights w and vice versa), on the same start states;
3. print the comparison table (with the paper's Table 1 numbers where the paper has the row),
   write it as ``comparison.json`` and ``comparison.md``, and write a replay GIF of one battle of
   the trained policy; ``curve.png`` (Fig. 3 style) comes from the training run.

Everything lands in ``--run-dir`` (default :func:`default_run_dir`:
``runs/quickstart-<scenario>-<demonstrator>-s<seed>``).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from hybridmarl.errors import UserError
from hybridmarl.options import DEFAULT_IN_DOCSTRING
from hybridmarl.settings import get_setting

#: The paper's Table 1 (W, R) of the demonstrator D and of "Ours", by (scenario, demonstrator).
PAPER_TABLE1: dict[tuple[str, str], dict[str, tuple[float, float]]] = {
    ("m5v5", "attack-closest"): {"D": (0.43, -0.02), "Ours": (0.98, 0.18)},
    ("m30v30", "attack-closest"): {"D": (0.75, 0.18), "Ours": (1.00, 0.51)},
    ("m18v20", "attack-closest"): {"D": (0.32, -0.11), "Ours": (0.87, 0.24)},
    ("m24v30", "attack-closest"): {"D": (0.12, -0.26), "Ours": (0.76, 0.19)},
    ("m5v5", "attack-weakest"): {"D": (0.61, 0.02), "Ours": (0.99, 0.19)},
    ("m30v30", "attack-weakest"): {"D": (0.13, -0.23), "Ours": (0.91, 0.22)},
    ("m18v20", "attack-weakest"): {"D": (0.03, -0.36), "Ours": (0.71, 0.16)},
    ("m24v30", "attack-weakest"): {"D": (0.00, -0.49), "Ours": (0.58, 0.03)},
}

#: The learner the quickstart trains (``hybridmarl.algos``).
ALGO = "hybrid"
#: Its preset unless --preset says otherwise.
DEFAULT_PRESET = "quick"
#: Config fields that do not change what a run learns: a finished run that differs from the
#: asked-for settings only in these is reused.
_NOT_COMPARED = frozenset(
    {"run_dir", "name", "resume", "progress", "tensorboard", "keep_checkpoints"}
)


@dataclass(frozen=True)
class QuickstartConfig:
    """Train the hybrid method on a combat scenario, compare it with its demonstrator (W, R with
    95% intervals), and write the training curve and a replay."""

    scenario: str = "m5v5"
    """Combat scenario (paper Section 5.1: m5v5, m30v30, m18v20, m24v30)."""
    setting: str = "sparcraft"
    """Named setting (docs/engine.md#settings): 'sparcraft' (SparCraft's current rules) or
    'paper' (the paper's rules and a start geometry calibrated to its demonstrator rows, Table 1)."""
    demonstrator: str = "attack-closest"
    """Demonstrator script A^D (the paper's c = attack-closest or w = attack-weakest)."""
    enemy: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Enemy script, for training and evaluation. Default: the paper's cross-validation (a model
    learned from c fights w, and vice versa)."""
    preset: str = DEFAULT_PRESET
    """Training preset of 'hybridmarl train --algo hybrid': 'quick' (the recipe of the best CPU
    runs, the paper's method with extensions: W 0.88-0.93 of 100 battles over seven seeds
    against D's 0.44 on the same states, 10-13 CPU-minutes; README, "Results") or 'quick-paper'
    (the paper's own method at a small budget, about 6 minutes; it does not beat D at this
    budget)."""
    seed: int = 0
    """Seed of training and of the evaluation's start states."""
    n: int = 100
    """Evaluation battles per policy (Section 5.1: 100)."""
    total_episodes: Annotated[int | None, DEFAULT_IN_DOCSTRING] = None
    """Training episodes (default: the preset's)."""
    run_dir: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Where everything is written (default runs/quickstart-<scenario>-<demonstrator>-s<seed>,
    with -<preset> before -s<seed> for a preset other than quick, and -<setting> for a setting
    other than sparcraft). A finished run there is
    reused if it was made with the same settings, and refused otherwise."""
    replay_seed: int = 0
    """Which battle the replay GIF shows (its start-state seed)."""
    progress: bool = True
    """Show the training progress bar."""


def default_run_dir(
    scenario: str,
    demonstrator: str,
    seed: int,
    preset: str = DEFAULT_PRESET,
    setting: str = "sparcraft",
) -> Path:
    """The quickstart's run directory for these settings: every seed, preset and setting has its
    own, so a run of one is never taken for a run of another."""
    suffix = ("" if preset == DEFAULT_PRESET else f"-{preset}") + (
        "" if setting == "sparcraft" else f"-{setting}"
    )
    return Path("runs") / f"quickstart-{scenario}-{demonstrator}{suffix}-s{seed}"


def _flatten(doc: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts as one level of ``a.b`` keys; lists and tuples compare alike."""
    if isinstance(doc, dict):
        out: dict[str, Any] = {}
        for k, v in doc.items():
            out.update(_flatten(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: list(doc) if isinstance(doc, tuple) else doc}


def settings_mismatch(saved: dict[str, Any], wanted: dict[str, Any]) -> tuple[str, Any, Any] | None:
    """The first field whose value differs between a run's saved config and the wanted config,
    as ``(field, saved value, wanted value)``; fields in only one of them, and fields that do not
    change what a run learns, are not compared."""
    old, new = _flatten(saved), _flatten(wanted)
    for key, value in new.items():
        if key.split(".")[-1] in _NOT_COMPARED or key not in old:
            continue
        if old[key] != value:
            return key, old[key], value
    return None


def check_run_dir(run_dir: Path, config: Any) -> None:
    """Refuse (:class:`UserError`) a run directory whose run was made by another learner or with
    other settings than ``config``."""
    from hybridmarl.training.config import config_to_dict
    from hybridmarl.training.rundir import read_run_config

    if not (run_dir / "config.json").exists():
        return
    doc = read_run_config(run_dir)
    if doc.get("algo") != ALGO:
        raise UserError(
            f"{run_dir} holds a {doc.get('algo')!r} run, not a {ALGO!r} run: choose another --run-dir"
        )
    diff = settings_mismatch(doc.get("config", {}), config_to_dict(config))
    if diff is not None:
        field, old, new = diff
        raise UserError(
            f"{run_dir} holds a run made with other settings ({field} = {old!r}, asked for {new!r}): "
            "delete it or choose another --run-dir"
        )


def training_config(
    cfg: QuickstartConfig, demonstrator: str, enemy: str, run_dir: Path, resume: bool
) -> Any:
    """The hybrid learner's config for ``cfg``: its preset, then the quickstart's settings."""
    from hybridmarl.algos import algo_module

    mod = algo_module(ALGO)
    if cfg.preset not in mod.PRESETS:
        raise UserError(f"unknown preset {cfg.preset!r} (known: {', '.join(mod.PRESETS)})")
    base = mod.PRESETS[cfg.preset]("combat")
    changes: dict[str, Any] = {
        "scenario": cfg.scenario,
        "demonstrator": demonstrator,
        "enemy": enemy,
        "seed": cfg.seed,
        "setting": cfg.setting,
        "run_dir": str(run_dir),
        "resume": resume,
        "progress": cfg.progress,
    }
    if importlib.util.find_spec("tensorboardX") is None:
        changes["tensorboard"] = False  # event files need the "tensorboard" extra
    if cfg.total_episodes is not None:
        if cfg.total_episodes < 1:
            raise UserError("--total-episodes must be at least 1")
        changes["total_episodes"] = cfg.total_episodes
    return base.replace(**changes)


def run_quickstart(cfg: QuickstartConfig) -> int:
    """Train (or resume, or reuse), evaluate, compare and replay as the module describes; return
    0. Raises :class:`UserError` on bad input and :class:`TrainingDiverged` if training diverges."""
    from hybridmarl.algos import algo_module
    from hybridmarl.io import write_json_atomic, write_text_atomic
    from hybridmarl.training import evaluate as E
    from hybridmarl.training.checkpoint import latest_checkpoint, load_checkpoint
    from hybridmarl.training.task import TaskSpec, canonical_script, default_enemy, make_task
    from hybridmarl.validate import COUNT, SEED, check_values, optional

    check_values(
        {
            "n": cfg.n,
            "seed": cfg.seed,
            "replay_seed": cfg.replay_seed,
            "total_episodes": cfg.total_episodes,
        },
        {"n": COUNT, "seed": SEED, "replay_seed": SEED, "total_episodes": optional(COUNT)},
    )
    demo = canonical_script("combat", cfg.demonstrator)
    enemy = canonical_script("combat", cfg.enemy) if cfg.enemy else default_enemy(demo)
    setting = get_setting(cfg.setting).name
    make_task(
        TaskSpec(env="combat", scenario=cfg.scenario, enemy=enemy, setting=setting)
    )  # validates the scenario
    run_dir = (
        Path(cfg.run_dir)
        if cfg.run_dir
        else default_run_dir(cfg.scenario, demo, cfg.seed, cfg.preset, setting)
    )
    train_cfg = training_config(
        cfg, demo, enemy, run_dir, resume=latest_checkpoint(run_dir) is not None
    )
    check_run_dir(run_dir, train_cfg)
    t0 = time.time()

    # ---- 1. train (or resume, or reuse a finished run) -------------------------------------------------
    if (run_dir / "eval.json").is_file():
        print(f"{run_dir} holds a finished run: reusing it (delete the directory to retrain)")
    else:
        algo_module(ALGO).train(train_cfg)
    train_s = time.time() - t0
    bundle = E.load_policy(run_dir)
    _, meta = load_checkpoint(latest_checkpoint(run_dir))  # type: ignore[arg-type]

    # ---- 2. evaluate D and the trained policy on the same start states -------------------------------
    task = make_task(dataclasses.replace(bundle.spec, enemy=enemy))
    res_d = E.evaluate_task(task, None, None, n=cfg.n, seed=cfg.seed, script=demo)
    res_ours = E.evaluate_task(task, bundle.module, bundle.variables, n=cfg.n, seed=cfg.seed)

    # ---- 3. the table, the files, the replay ------------------------------------------------------------
    paper = PAPER_TABLE1.get((bundle.spec.scenario, demo), {})
    train_doc: dict[str, Any] = {}
    if (run_dir / "eval.json").is_file():
        train_doc = json.loads((run_dir / "eval.json").read_text())
    doc = {
        "scenario": bundle.spec.scenario,
        "demonstrator": demo,
        "enemy": enemy,
        "n": cfg.n,
        "seed": cfg.seed,
        "preset": cfg.preset,
        "setting": bundle.spec.setting,
        "episodes_trained": meta.get("episodes"),
        "train_wall_s": train_doc.get("wall_s"),
        "train_cpu_s": train_doc.get("cpu_s"),
        "rows": {
            "D": {k: res_d[k] for k in ("W", "W_ci95", "R", "R_ci95")},
            "Ours": {k: res_ours[k] for k in ("W", "W_ci95", "R", "R_ci95")},
        },
        "paper": {k: {"W": v[0], "R": v[1]} for k, v in paper.items()},
    }
    write_json_atomic(run_dir / "comparison.json", doc)
    lines = [
        f"{bundle.spec.scenario}, demonstrator {demo}, enemy {enemy}, {cfg.n} battles (seed {cfg.seed})"
        + ("" if bundle.spec.setting == "sparcraft" else f", {bundle.spec.setting} setting"),
        "",
        "| policy | W [95% CI] | R [95% CI] | paper W | paper R |",
        "|---|---|---|---|---|",
    ]
    for name, r in (("D", res_d), ("Ours", res_ours)):
        pw, pr = paper.get(name, (None, None))
        lines.append(
            f"| {name} | {r['W']:.2f} [{r['W_ci95'][0]:.2f}, {r['W_ci95'][1]:.2f}] | {r['R']:+.3f} "
            f"[{r['R_ci95'][0]:+.3f}, {r['R_ci95'][1]:+.3f}] | {'' if pw is None else f'{pw:.2f}'} | {'' if pr is None else f'{pr:+.2f}'} |"
        )
    table = "\n".join(lines)
    write_text_atomic(run_dir / "comparison.md", table + "\n")
    print()
    print(table)
    print()

    from hybridmarl.cli.replay import ReplayConfig, run_replay

    written = [run_dir / "comparison.json", run_dir / "comparison.md"]
    if (run_dir / "curve.png").is_file():
        written.append(run_dir / "curve.png")
    if (
        importlib.util.find_spec("PIL") is not None
        and importlib.util.find_spec("imageio") is not None
    ):
        run_replay(
            ReplayConfig(
                run_dir=str(run_dir),
                enemy=enemy,
                seed=cfg.replay_seed,
                out=str(run_dir / "replay.gif"),
            )
        )
        written.append(run_dir / "replay.gif")
    else:
        print("no replay.gif: it needs the 'video' extra (pip install 'hybridmarl[video]')")
    print(f"written: {', '.join(str(p) for p in written)}")
    timing = f"{time.time() - t0:.0f}s in all, training {train_s:.0f}s"
    if importlib.util.find_spec("tensorboard") is not None and (run_dir / "tb").is_dir():
        print(f"TensorBoard: tensorboard --logdir {run_dir / 'tb'}   ({timing})")
    else:
        print(f"({timing})")
    return 0


def quickstart_command(args: list[str]) -> int:
    """``hybridmarl quickstart [options]``."""
    import tyro

    return run_quickstart(tyro.cli(QuickstartConfig, args=args, prog="hybridmarl quickstart"))
