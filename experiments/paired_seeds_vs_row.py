"""Are several seeds of a training recipe better than a row of a reproduction grid's column?

The grid compares Ours with the best other row of each column by averaging every row's
per-battle outcomes over its seeds and pairing the averages over the shared start states
(docs/reproducing.md, the protocol). This script does the same for a variant of a recipe:
the policies of ``--runs`` (one finished ``hybridmarl train`` run per seed) are played on the
column's start states (``eval_seed`` and ``n`` of the grid's tasks, against the column's
cross-validation enemy), averaged over the runs, and paired with a row of that column in the
grid's output folder ``--grid``: ``--row NAME``, or by default the best row other than Ours
(the highest mean W among the finished ones, as the grid picks it).

Prints one JSON object: W and R of the runs (their mean and each run's) and of the row, and the
paired differences ΔW and ΔR with a two-sided paired t-test on the per-state averages. Each
run's evaluation is cached in ``RUN/paired_vs_task.json``, shared with
``experiments/paired_vs_task.py``.

    python experiments/paired_seeds_vs_row.py \\
        --runs results/actor-lr-decay/m30v30-w-decay-s{0,1,2} --grid results/reproduce-cpu-paper
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np


def main() -> int:
    from paired_vs_task import evaluate_cached

    from hybridmarl.reproduce import protocol as P
    from hybridmarl.reproduce.driver import GridState
    from hybridmarl.reproduce.grid import expand
    from hybridmarl.reproduce.outputs import cell_summary, paired_test

    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument(
        "--runs",
        required=True,
        nargs="+",
        type=Path,
        help="finished runs of `hybridmarl train`, one per seed",
    )
    ap.add_argument(
        "--grid", required=True, type=Path, help="the output folder of `hybridmarl reproduce`"
    )
    ap.add_argument(
        "--row",
        default=None,
        help="the row of the runs' column to pair with (default: the best other than Ours)",
    )
    args = ap.parse_args()

    columns = set()
    for run in args.runs:
        if not (run / "config.json").is_file():
            print(f"{run}: not a run directory (no config.json)", file=sys.stderr)
            return 2
        c = json.loads((run / "config.json").read_text())["config"]
        columns.add((c["scenario"], c["demonstrator"], c["setting"]))
    if len(columns) != 1:
        print(f"--runs: the runs come from different columns {sorted(columns)}", file=sys.stderr)
        return 2
    scenario, demonstrator, setting = columns.pop()
    if not (args.grid / "reproduce.json").is_file():
        print(
            f"{args.grid}: not an output folder of `hybridmarl reproduce` (no reproduce.json)",
            file=sys.stderr,
        )
        return 2
    made = json.loads((args.grid / "reproduce.json").read_text())
    if made["setting"] != setting:
        print(
            f"the runs are in the {setting!r} setting and the grid in {made['setting']!r}",
            file=sys.stderr,
        )
        return 2
    letters = [k for k, v in P.DEMONSTRATORS.items() if v == demonstrator]
    if not letters:
        print(f"--runs: demonstrator {demonstrator!r} is not one of Table 1's", file=sys.stderr)
        return 2
    column = f"{scenario}/{letters[0]}"

    # -- the column's rows, as the grid summarises them ----------------------------------------------
    state = GridState(args.grid, expand(("table1",), made["budget"], made["setting"]))
    state.scan()
    cells = {cell.row: cell for cell in state.grid.cells_of("table1") if cell.column == column}
    summaries = {row: cell_summary(state, cell) for row, cell in cells.items()}
    done = {row: s for row, s in summaries.items() if s["status"] == "done" and row != "Ours"}
    if args.row is not None:
        if args.row not in done:
            print(
                f"--row {args.row}: not a finished row of {column} in {args.grid}", file=sys.stderr
            )
            return 2
        rival = args.row
    elif done:
        rival = max(done, key=lambda row: done[row]["W"])
    else:
        print(f"{args.grid}: no finished row of {column} besides Ours", file=sys.stderr)
        return 2
    row_state = done[rival]["per_state"]
    c0: dict[str, Any] = state.grid.tasks[cells[rival].keys[0]].config

    # -- the runs, on the same start states ------------------------------------------------------
    runs = [evaluate_cached(run, c0, None) for run in args.runs]
    won = np.mean([np.asarray(r["per_episode"]["won"], np.float64) for r in runs], axis=0)
    hp = np.mean(
        [np.asarray(r["per_episode"]["terminal_hp_reward"], np.float64) for r in runs], axis=0
    )
    w = paired_test(won.tolist(), row_state["won"])
    r = paired_test(hp.tolist(), row_state["terminal_hp_reward"])
    print(
        json.dumps(
            {
                "runs": [str(p) for p in args.runs],
                "column": column,
                "setting": setting,
                "against": rival,
                "rows_considered": {row: round(s["W"], 4) for row, s in sorted(done.items())},
                "W_runs": float(won.mean()),
                "W_each_run": [x["summary"]["W"] for x in runs],
                "W_row": float(np.mean(row_state["won"])),
                "dW": w["diff"],
                "p_W": w["p"],
                "R_runs": float(hp.mean()),
                "R_each_run": [x["summary"]["R"] for x in runs],
                "R_row": float(np.mean(row_state["terminal_hp_reward"])),
                "dR": r["diff"],
                "p_R": r["p"],
                "n_states": int(won.size),
            },
            indent=1,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
