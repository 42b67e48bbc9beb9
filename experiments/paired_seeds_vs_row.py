"""Are several seeds of a training recipe better than a row of a reproduction grid's column?

The grid compares Ours with the best other row of each column by averaging every row's
per-battle outcomes over its seeds and pairing the averages over the shared start states
(docs/reproducing.md, the protocol). This script does the same for a variant of a recipe:
the policies of ``--runs`` (one finished ``hybridmarl train`` run per seed) are played on the
column's start states (``eval_seed`` and ``n`` of the grid's tasks, against the column's
cross-validation enemy), averaged over the runs, and paired with

- ``--row TASK [TASK ...]``: the finished task folders of one row (its seeds, or the one task
  of a search or script row), or
- ``--best-of TASKS_DIR``: the best row of the column other than Ours among the finished tasks
  of a grid's ``tasks/`` folder (the row with the highest mean W, as the grid picks it).

Prints one JSON object: W and R of the runs (their mean and each run's) and of the row, and the
paired differences ΔW and ΔR with a two-sided paired t-test on the per-state averages. Each
run's evaluation is cached in ``RUN/paired_vs_task.json``, shared with
``experiments/paired_vs_task.py``.

    python experiments/paired_seeds_vs_row.py \\
        --runs results/actor-lr-decay/m30v30-w-decay-s{0,1,2} \\
        --best-of results/reproduce-cpu-paper/tasks
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

#: What a run's task and the row's tasks must share to be paired state by state.
_SAME = ("env", "scenario", "setting", "enemy", "eval_seed", "n")


def _load_task(path: Path) -> tuple[dict[str, Any], dict[str, Any]] | None:
    task_file, result_file = path / "task.json", path / "result.json"
    if not (task_file.is_file() and result_file.is_file()):
        return None
    return json.loads(task_file.read_text())["config"], json.loads(result_file.read_text())


def _column_of(run_config: dict[str, Any]) -> tuple[str, str, str]:
    c = run_config["config"]
    return c["scenario"], c["demonstrator"], c["setting"]


def main() -> int:
    from paired_vs_task import evaluate_cached

    from hybridmarl.reproduce.outputs import paired_test

    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--runs", required=True, nargs="+", type=Path, help="finished runs of `hybridmarl train`, one per seed")
    group = ap.add_mutually_exclusive_group(required=True)
    group.add_argument("--row", nargs="+", type=Path, help="the finished task folders of one row of the column")
    group.add_argument("--best-of", type=Path, help="a grid's tasks/ folder; pair with the best other row of the runs' column")
    args = ap.parse_args()

    columns = set()
    for run in args.runs:
        if not (run / "config.json").is_file():
            print(f"{run}: not a run directory (no config.json)", file=sys.stderr)
            return 2
        columns.add(_column_of(json.loads((run / "config.json").read_text())))
    if len(columns) != 1:
        print(f"--runs: the runs come from different columns {sorted(columns)}", file=sys.stderr)
        return 2
    scenario, demonstrator, setting = columns.pop()

    # -- the row's tasks ------------------------------------------------------------------------
    rows: dict[str, list[tuple[dict[str, Any], dict[str, Any]]]] = defaultdict(list)
    if args.row is not None:
        for path in args.row:
            loaded = _load_task(path)
            if loaded is None:
                print(f"{path}: not a finished task folder (need task.json and result.json)", file=sys.stderr)
                return 2
            rows[loaded[0]["row"]].append(loaded)
        if len(rows) != 1:
            print(f"--row: the tasks belong to different rows {sorted(rows)}", file=sys.stderr)
            return 2
    else:
        if not args.best_of.is_dir():
            print(f"{args.best_of}: not a folder", file=sys.stderr)
            return 2
        for path in sorted(args.best_of.iterdir()):
            loaded = _load_task(path)
            if loaded is None:
                continue
            c = loaded[0]
            if (c.get("env"), c.get("scenario"), c.get("demonstrator"), c.get("setting")) == ("combat", scenario, demonstrator, setting) and c["row"] != "Ours":
                rows[c["row"]].append(loaded)
        if not rows:
            print(f"{args.best_of}: no finished task of the column {scenario}, {demonstrator}, {setting}", file=sys.stderr)
            return 2
    tasks = [t for row in rows.values() for t in row]
    c0 = tasks[0][0]
    if c0["env"] != "combat":
        print(f"{args.row[0] if args.row else args.best_of}: a Traffic Junction task; this compares combat battles", file=sys.stderr)
        return 2
    for c, _ in tasks:
        if any(c.get(k) != c0.get(k) for k in _SAME):
            print(f"the row's tasks differ in their evaluation ({', '.join(_SAME)}); they cannot be paired", file=sys.stderr)
            return 2
    if (c0["scenario"], c0["setting"]) != (scenario, setting):
        print(f"the runs are {scenario}/{setting} and the row's tasks {c0['scenario']}/{c0['setting']}", file=sys.stderr)
        return 2

    def per_state(results: list[dict[str, Any]], metric: str) -> np.ndarray:
        return np.mean([np.asarray(r["per_episode"][metric], np.float64) for r in results], axis=0)

    means = {row: float(per_state([r for _, r in ts], "won").mean()) for row, ts in rows.items()}
    rival = max(means, key=lambda row: means[row])
    rival_results = [r for _, r in rows[rival]]

    # -- the runs, on the same start states ------------------------------------------------------
    runs = [evaluate_cached(run, c0, None) for run in args.runs]
    w = paired_test(per_state(runs, "won").tolist(), per_state(rival_results, "won").tolist())
    r = paired_test(per_state(runs, "terminal_hp_reward").tolist(), per_state(rival_results, "terminal_hp_reward").tolist())
    print(json.dumps({
        "runs": [str(p) for p in args.runs], "column": f"{scenario}/{demonstrator}/{setting}",
        "against": rival, "rows_considered": {row: round(m, 4) for row, m in sorted(means.items())},
        "W_runs": float(per_state(runs, "won").mean()), "W_each_run": [x["summary"]["W"] for x in runs],
        "W_row": means[rival], "dW": w["diff"], "p_W": w["p"],
        "R_runs": float(per_state(runs, "terminal_hp_reward").mean()), "R_each_run": [x["summary"]["R"] for x in runs],
        "R_row": float(per_state(rival_results, "terminal_hp_reward").mean()), "dR": r["diff"], "p_R": r["p"],
        "n_states": int(c0["n"]),
    }, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
