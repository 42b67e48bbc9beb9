"""Would a learner row gain from playing its checkpoint chosen on the selection states?

A hybrid run evaluates its frozen policy every ``--eval-every`` episodes on its own selection
start states (``--seed`` S + 2, 100 battles) and keeps the best of those as its ``best``
checkpoint. The reproduction grid plays each run's *final* policy. This script plays the
``best`` checkpoint of every finished learner task of a grid on the same protocol start states
as the grid (the task's ``eval_seed`` and ``n``, against the task's cross-validation enemy),
and compares it with the final policy state by state:

- W of each, the paired difference ΔW = W(best) − W(final) with a 95 % interval and McNemar's
  exact p on the battles only one of them wins;
- per cell (scenario, demonstrator, row), the mean over seeds of each.

The selection states are disjoint from the protocol's, so the choice never sees the states it
is scored on. Each evaluation is written atomically to ``TASK/best_checkpoint.json`` and
reused on the next call, so the script resumes. Prints one JSON object.

    python experiments/best_checkpoint.py --grid runs/reproduce --rows Ours --scenarios m24v30
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

OUT_FILE = "best_checkpoint.json"


def evaluate_best(task_dir: Path) -> dict[str, Any] | None:
    """The protocol evaluation of ``task_dir``'s best checkpoint (cached), or None if the run
    keeps none."""
    from hybridmarl.io import write_json_atomic
    from hybridmarl.reproduce.worker import evaluate_run
    from hybridmarl.training.checkpoint import BEST

    out = task_dir / OUT_FILE
    if out.is_file():
        return json.loads(out.read_text())
    run_dir = task_dir / "run"
    if not (run_dir / "checkpoints" / BEST).exists():
        return None
    c = json.loads((task_dir / "task.json").read_text())["config"]
    ev = evaluate_run(run_dir, c, BEST)
    result = {
        "summary": ev["summary"],
        "per_episode": ev["per_episode"],
        "episodes": ev["meta"].get("episodes"),
        "selection": ev["meta"].get("selection"),
        "wall_s": ev["wall_s"],
        "cpu_s": ev["cpu_s"],
    }
    write_json_atomic(out, result)
    return result


def main() -> None:
    from hybridmarl.envs.stats import paired_wins
    from hybridmarl.reproduce.driver import GridState
    from hybridmarl.reproduce.grid import expand
    from hybridmarl.reproduce.outputs import cell_summary, paired_test

    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--grid", required=True, help="the output folder of `hybridmarl reproduce`")
    ap.add_argument(
        "--rows", default="Ours", help="comma-separated learner rows of Table 1 (default: Ours)"
    )
    ap.add_argument("--scenarios", default=None, help="comma-separated scenarios (default: all)")
    args = ap.parse_args()
    out = Path(args.grid)
    made = json.loads((out / "reproduce.json").read_text())
    state = GridState(out, expand(("table1",), made["budget"], made["setting"]))
    state.scan()
    rows = set(args.rows.split(","))
    scenarios = set(args.scenarios.split(",")) if args.scenarios else None

    cells, tasks = {}, []
    columns = {}
    for cell in state.grid.cells_of("table1"):
        columns.setdefault(cell.column, []).append(cell)
    for column, col_cells in columns.items():
        if scenarios and column.split("/")[0] not in scenarios:
            continue
        summaries = {c.row: cell_summary(state, c) for c in col_cells}
        for cell in col_cells:
            if cell.row not in rows or summaries[cell.row]["status"] != "done":
                continue
            bests, entries = [], []
            for key in cell.keys:
                task = state.grid.tasks[key]
                best = evaluate_best(state.task_dir(task))
                if best is None:
                    break
                final = state.results[key]
                won_best = np.asarray(best["per_episode"]["won"]) > 0
                stats = paired_wins(won_best, np.asarray(final["per_episode"]["won"]) > 0)
                entries.append(
                    {
                        "task": task.dirname,
                        "seed": task.config["seed"],
                        "best_episodes": best["episodes"],
                        "selection_W": (best["selection"] or {}).get("W"),
                        "W_final": stats["W_b"],
                        "W_best": stats["W_a"],
                        "R_final": final["summary"]["R"],
                        "R_best": best["summary"]["R"],
                        "dW": stats["dW"],
                        "dW_ci95": [stats["dW_low"], stats["dW_high"]],
                        "only_best": stats["only_a"],
                        "only_final": stats["only_b"],
                        "p_mcnemar": stats["p_mcnemar"],
                        "eval_cpu_s": best["cpu_s"],
                    }
                )
                bests.append(best["per_episode"])
            else:
                tasks.extend(entries)
                per_state = np.mean([np.asarray(b["won"], np.float64) for b in bests], axis=0)
                others = {
                    r: s for r, s in summaries.items() if r not in rows and s["status"] == "done"
                }
                rival = max(others, key=lambda r: others[r]["W"]) if others else None
                cells[f"{cell.row} {column}"] = {
                    "seeds": len(entries),
                    "W_final": float(np.mean([e["W_final"] for e in entries])),
                    "W_best": float(np.mean([e["W_best"] for e in entries])),
                    "R_final": float(np.mean([e["R_final"] for e in entries])),
                    "R_best": float(np.mean([e["R_best"] for e in entries])),
                    "best_other_row": rival,
                    "W_best_other_row": others[rival]["W"] if rival else None,
                    # Per state, the best checkpoints' wins averaged over seeds, as the grid's own test.
                    "paired_best_vs_other": paired_test(
                        per_state.tolist(), others[rival]["per_state"]["won"]
                    )
                    if rival
                    else None,
                }
    print(json.dumps({"grid": args.grid, "cells": cells, "tasks": tasks}, indent=1))


if __name__ == "__main__":
    main()
