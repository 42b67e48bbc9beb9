"""Is a training run better than a finished task of a reproduction grid, battle by battle?

Plays the policy of ``--run-dir`` (a run of ``hybridmarl train``, for instance a variant of a
grid cell's recipe) on the start states of a grid task (the task's ``eval_seed`` and ``n``,
against the task's cross-validation enemy, exactly as the grid evaluated the task) and pairs
its outcomes with the task's kept per-battle outcomes:

- W of each and ΔW = W(run) − W(task) with a 95 % interval and McNemar's exact p on the
  battles only one of them wins;
- R of each and ΔR with a two-sided paired t-test.

With ``--versus-run OTHER`` the run is paired with a second run instead, both played on the
task's start states (for two runs made on the same machine, where the task was made on another
CPU whose rounding led training elsewhere).

The run's evaluation is written atomically to ``RUN/paired_vs_task.json`` (keyed by the
task's evaluation settings) and reused on the next call. Prints one JSON object.

    python experiments/paired_vs_task.py --run-dir RUN \\
        --task results/reproduce-cpu-paper/tasks/Ours-m24v30-c-s1-448be9039177
    python experiments/paired_vs_task.py --run-dir RUN --versus-run OTHER --task TASK
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

OUT_FILE = "paired_vs_task.json"


def evaluate_cached(run_dir: Path, c: dict[str, Any], checkpoint: str | None) -> dict[str, Any]:
    """The protocol evaluation of the run's policy on the task's start states (cached)."""
    from hybridmarl.io import write_json_atomic
    from hybridmarl.reproduce.worker import evaluate_run

    ident = {
        "eval_seed": c["eval_seed"],
        "n": c["n"],
        "enemy": c.get("enemy"),
        "checkpoint": checkpoint,
    }
    out = run_dir / OUT_FILE
    if out.is_file():
        cached = json.loads(out.read_text())
        if cached.get("ident") == ident:
            return cached
    ev = evaluate_run(run_dir, c, checkpoint)
    result = {
        "ident": ident,
        **{k: ev[k] for k in ("summary", "per_episode", "weights", "wall_s", "cpu_s")},
    }
    write_json_atomic(out, result)
    return result


def main() -> int:
    from hybridmarl.envs.stats import paired_wins
    from hybridmarl.reproduce.outputs import paired_test

    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument(
        "--run-dir", required=True, type=Path, help="a finished run of `hybridmarl train`"
    )
    ap.add_argument(
        "--task",
        required=True,
        type=Path,
        help="a finished combat task folder of a grid (task.json, result.json)",
    )
    ap.add_argument(
        "--checkpoint",
        default=None,
        help="the run's checkpoint to play (default: the run's policy)",
    )
    ap.add_argument(
        "--versus-run",
        default=None,
        type=Path,
        help="pair with this finished run (its final policy on the task's states) instead of the task",
    )
    args = ap.parse_args()
    task_file, result_file = args.task / "task.json", args.task / "result.json"
    for path in (task_file, result_file):
        if not path.is_file():
            print(f"{path}: not found (need a finished task folder)", file=sys.stderr)
            return 2
    c = json.loads(task_file.read_text())["config"]
    if c["env"] != "combat":
        print(
            f"{args.task}: a Traffic Junction task; this compares combat battles", file=sys.stderr
        )
        return 2
    for path in (args.run_dir, args.versus_run):
        if path is not None and not (path / "config.json").is_file():
            print(f"{path}: not a run directory (no config.json)", file=sys.stderr)
            return 2
    run = evaluate_cached(args.run_dir, c, args.checkpoint)
    # What the run is paired with: the task's kept battles, or the other run's on the same states.
    # The output's "*_task" fields hold whichever it is.
    other = (
        evaluate_cached(args.versus_run, c, None)
        if args.versus_run is not None
        else json.loads(result_file.read_text())
    )
    won = paired_wins(
        np.asarray(run["per_episode"]["won"]) > 0, np.asarray(other["per_episode"]["won"]) > 0
    )
    r = paired_test(
        run["per_episode"]["terminal_hp_reward"], other["per_episode"]["terminal_hp_reward"]
    )
    print(
        json.dumps(
            {
                "run": str(args.run_dir),
                "task": str(args.task),
                "weights": run["weights"],
                "versus": str(args.versus_run or args.task),
                "W_run": won["W_a"],
                "W_task": won["W_b"],
                "dW": won["dW"],
                "dW_ci95": [won["dW_low"], won["dW_high"]],
                "only_run": won["only_a"],
                "only_task": won["only_b"],
                "p_mcnemar": won["p_mcnemar"],
                "R_run": run["summary"]["R"],
                "R_task": other["summary"]["R"],
                "dR": r["diff"],
                "p_R": r["p"],
                "eval_cpu_s": run["cpu_s"],
            },
            indent=1,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
