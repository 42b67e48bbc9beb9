"""``hybridmarl quickstart``: the README's main job, the m5v5 row of the paper's Table 1.

One command, resumable at any point:

1. train the hybrid method (``--preset quick`` by default) on a combat scenario from a scripted
   demonstrator (``hybridmarl train``; an interrupted run is resumed, a finished one reused);
2. evaluate the demonstrator D and the trained policy with the paper's protocol (Section 5.1:
   ``n`` battles, legal argmax, W and R with 95% intervals) against the paper's cross-validation
   enemy (a model learned from c fights w and vice versa), on the same start states;
3. print the comparison table (with the paper's Table 1 numbers where the paper has the row),
   write it as ``comparison.json`` and ``comparison.md``, and write a replay GIF of one battle of
   the trained policy; ``curve.png`` (Fig. 3 style) comes from the training run.

Everything lands in ``--run-dir`` (default ``runs/quickstart-<scenario>-<demonstrator>``).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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


@dataclass(frozen=True)
class QuickstartConfig:
    """Train the hybrid method on a combat scenario, compare it with its demonstrator (W, R with
    95% intervals), and write the training curve and a replay."""

    scenario: str = "m5v5"
    """Combat scenario (paper Section 5.1: m5v5, m30v30, m18v20, m24v30)."""
    demonstrator: str = "attack-closest"
    """Demonstrator script A^D (the paper's c = attack-closest or w = attack-weakest)."""
    enemy: str | None = None
    """Enemy script, for training and evaluation. Default: the paper's cross-validation (a model
    learned from c fights w, and vice versa)."""
    preset: str = "quick"
    """Training preset of ``hybridmarl train --algo hybrid``: ``quick`` (the recipe of our best
    CPU runs, the paper's method with extensions: W 0.88-0.93 of 100 battles over seven seeds
    against D's 0.44 on the same states, 10-13 CPU-minutes since session 9; README, "Results")
    or ``quick-paper`` (the paper's own method at a small budget, about 6 minutes; it does not
    beat D at this budget)."""
    seed: int = 0
    """Seed of training and of the evaluation's start states."""
    n: int = 100
    """Evaluation battles per policy (Section 5.1: 100)."""
    run_dir: str | None = None
    """Where everything is written (default ``runs/quickstart-<scenario>-<demonstrator>``, plus
    ``-<preset>`` for a preset other than ``quick``)."""
    replay_seed: int = 0
    """Which battle the replay GIF shows (its start-state seed)."""
    train_args: tuple[str, ...] = ()
    """Extra ``hybridmarl train`` options passed through, e.g. ``--train-args --total-episodes 500``."""
    progress: bool = True
    """Show the training progress bar."""


def run_quickstart(cfg: QuickstartConfig) -> int:
    from hybridmarl.cli import learn as algos_cli
    from hybridmarl.io import write_json_atomic, write_text_atomic
    from hybridmarl.training import evaluate as E
    from hybridmarl.training.checkpoint import latest_checkpoint, load_checkpoint
    from hybridmarl.training.task import (
        TaskError,
        TaskSpec,
        canonical_script,
        default_enemy,
        make_task,
    )

    errors = algos_cli._user_errors()
    try:
        demo = canonical_script("combat", cfg.demonstrator)
        enemy = canonical_script("combat", cfg.enemy) if cfg.enemy else default_enemy(demo)
        if cfg.n < 1:
            raise TaskError("--n must be at least 1")
        make_task(TaskSpec(env="combat", scenario=cfg.scenario, enemy=enemy))  # validates the scenario
    except errors as e:
        return algos_cli._fail(str(e))
    # Each preset gets its own default directory: a finished run is reused, and a run of
    # another preset must not be mistaken for the one asked for.
    suffix = "" if cfg.preset == "quick" else f"-{cfg.preset}"
    run_dir = Path(cfg.run_dir or f"runs/quickstart-{cfg.scenario}-{demo}{suffix}")
    t0 = time.time()

    # ---- 1. train (or resume, or reuse a finished run) -------------------------------------------------
    finished = (run_dir / "eval.json").is_file()
    if finished:
        print(f"{run_dir} holds a finished run: reusing it (delete the directory to retrain)")
    else:
        argv = [
            "--algo", "hybrid", "--preset", cfg.preset, "--scenario", cfg.scenario, "--demonstrator", demo,
            "--enemy", enemy, "--seed", str(cfg.seed), "--run-dir", str(run_dir), *cfg.train_args,
        ]
        if not cfg.progress:
            argv.append("--no-progress")
        if latest_checkpoint(run_dir) is not None:
            argv.append("--resume")
        rc = algos_cli.run_train(argv)
        if rc != 0:
            return rc
    train_s = time.time() - t0
    try:
        bundle = E.load_policy(run_dir)
        _, meta = load_checkpoint(latest_checkpoint(run_dir))  # type: ignore[arg-type]
    except errors as e:
        return algos_cli._fail(str(e))

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
        "scenario": bundle.spec.scenario, "demonstrator": demo, "enemy": enemy, "n": cfg.n, "seed": cfg.seed,
        "preset": cfg.preset,
        "episodes_trained": meta.get("episodes"),
        "train_wall_s": train_doc.get("wall_s"), "train_cpu_s": train_doc.get("cpu_s"),
        "rows": {
            "D": {k: res_d[k] for k in ("W", "W_ci95", "R", "R_ci95")},
            "Ours": {k: res_ours[k] for k in ("W", "W_ci95", "R", "R_ci95")},
        },
        "paper": {k: {"W": v[0], "R": v[1]} for k, v in paper.items()},
    }
    write_json_atomic(run_dir / "comparison.json", doc)
    lines = [
        f"{bundle.spec.scenario}, demonstrator {demo}, enemy {enemy}, {cfg.n} battles (seed {cfg.seed})",
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

    rc = run_replay(ReplayConfig(run_dir=str(run_dir), enemy=enemy, seed=cfg.replay_seed, out=str(run_dir / "replay.gif")))
    if rc != 0:
        return rc
    print(f"written: {run_dir / 'comparison.json'}, {run_dir / 'comparison.md'}, {run_dir / 'curve.png'}, {run_dir / 'replay.gif'}")
    print(f"TensorBoard: tensorboard --logdir {run_dir / 'tb'}   ({time.time() - t0:.0f}s in all, training {train_s:.0f}s)")
    return 0


def main(args: list[str]) -> int:
    import tyro

    return run_quickstart(tyro.cli(QuickstartConfig, args=args, prog="hybridmarl quickstart"))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
