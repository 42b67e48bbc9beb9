"""The tables, the figure and the report of a reproduction, from the results of its tasks.

A cell shows a number only when every task it needs (every seed) is done; a cell with a failed
task shows "failed" and the log to read, one still to run shows "pending". Every number stands
beside the paper's. Written (atomically) to the output folder:

- ``table1.md`` / ``table1.json``: W and R of every row and column, the best of each column in
  bold (ours and the paper's separately), the per-seed values, the paired tests;
- ``table2.md`` / ``table2.json``: failure rate and arrivals per episode (Traffic Junction);
- ``fig3.png``: terminal HP reward of the training episodes at m18v20 and m24v30 (the mean of
  the following 100 episodes; mean over seeds, each seed faint);
- ``report.html``: one self-contained page with all of them (the figure inlined).
"""

from __future__ import annotations

import base64
import csv
import html
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hybridmarl.envs.stats import t_interval, wilson_interval
from hybridmarl.io import write_json_atomic, write_text_atomic
from hybridmarl.reproduce import protocol as P
from hybridmarl.reproduce.driver import GridState
from hybridmarl.reproduce.grid import Cell

# -- one cell -------------------------------------------------------------------------------------


def _mean_over_seeds(per_seed: list[list[float]]) -> np.ndarray:
    """Per start state, the outcome averaged over the seeds (all seeds share the start states)."""
    return np.mean(np.asarray(per_seed, np.float64), axis=0)


#: Per-seed metrics that are rates (their intervals are clipped to [0, 1]).
_RATES = frozenset({"W", "failure_rate"})


def cell_summary(state: GridState, cell: Cell) -> dict[str, Any]:
    """What a cell shows: ``status`` (done, failed, pending), and when done its numbers with 95 %
    intervals pooled over seeds, each seed's numbers, and the per-start-state outcomes."""
    tasks = [state.grid.tasks[k] for k in cell.keys]
    failed = [state.failures[k] for k in cell.keys if k in state.failures]
    if failed:
        return {
            "status": "failed",
            "logs": [f["log"] for f in failed],
            "errors": [f["error"] for f in failed],
        }
    results = [state.results.get(k) for k in cell.keys]
    if any(r is None for r in results):
        done = sum(r is not None for r in results)
        return {"status": "pending", "done_tasks": done, "tasks": len(results)}
    rs: list[dict[str, Any]] = [r for r in results if r is not None]
    seeds = [t.config.get("seed") for t in tasks]
    per = [r["per_episode"] for r in rs]
    out: dict[str, Any] = {
        "status": "done",
        "n": len(per[0][next(iter(per[0]))]),
        "seeds": seeds if tasks[0].kind == "train" else None,
    }
    if "won" in per[0]:
        won = np.concatenate([np.asarray(p["won"]) for p in per])
        hp = np.concatenate([np.asarray(p["terminal_hp_reward"]) for p in per])
        r_mean, r_lo, r_hi = t_interval(hp)
        out.update(
            W=float(won.mean()),
            W_ci95=list(wilson_interval(int(won.sum()), won.size)),
            R=r_mean,
            R_ci95=[r_lo, r_hi],
            per_seed=[
                {"seed": s, "W": r["summary"]["W"], "R": r["summary"]["R"]}
                for s, r in zip(seeds, rs, strict=True)
            ],
            per_state={
                "won": _mean_over_seeds([p["won"] for p in per]).tolist(),
                "terminal_hp_reward": _mean_over_seeds(
                    [p["terminal_hp_reward"] for p in per]
                ).tolist(),
            },
        )
    else:
        failed_ep = np.concatenate([np.asarray(p["failed"]) for p in per])
        arrivals = np.concatenate([np.asarray(p["arrivals"]) for p in per])
        a_mean, a_lo, a_hi = t_interval(arrivals)
        out.update(
            failure_rate=float(failed_ep.mean()),
            failure_rate_ci95=list(wilson_interval(int(failed_ep.sum()), failed_ep.size)),
            arrivals=a_mean,
            arrivals_ci95=[a_lo, a_hi],
            per_seed=[
                {
                    "seed": s,
                    "failure_rate": r["summary"]["failure_rate"],
                    "arrivals": r["summary"]["mean_arrivals"],
                }
                for s, r in zip(seeds, rs, strict=True)
            ],
            per_state={
                "failed": _mean_over_seeds([p["failed"] for p in per]).tolist(),
                "arrivals": _mean_over_seeds([p["arrivals"] for p in per]).tolist(),
            },
        )
    if tasks[0].kind == "train" and len(rs) > 1:
        # The pooled interval above counts battles; this one counts seeds, so it also carries
        # the spread between training runs (Student-t over the per-seed means).
        out["over_seeds_ci95"] = {}
        for m in (m for m in out["per_seed"][0] if m != "seed"):
            _, lo, hi = t_interval(np.asarray([p[m] for p in out["per_seed"]], np.float64))
            # A rate's interval stays within [0, 1], where the t interval of 3 seeds can overshoot.
            out["over_seeds_ci95"][m] = [max(lo, 0.0), min(hi, 1.0)] if m in _RATES else [lo, hi]
    out["search_cost"] = {
        k: rs[0]["summary"].get(k)
        for k in (
            "ms_per_decision",
            "traversals_per_decision",
            "nodes_per_decision",
            "playouts_per_decision",
        )
        if rs[0]["summary"].get(k) is not None
    } or None
    out["wall_s"] = float(sum(r.get("wall_s", 0.0) for r in rs))
    out["cpu_s"] = float(sum(r.get("cpu_s", 0.0) for r in rs))
    out["cpu_s_per_task"] = [float(r.get("cpu_s", 0.0)) for r in rs]
    return out


def paired_test(a: list[float], b: list[float]) -> dict[str, Any]:
    """Two-sided paired t-test of ``a - b`` over shared start states: mean difference and p."""
    from scipy.stats import ttest_rel

    x, y = np.asarray(a, np.float64), np.asarray(b, np.float64)
    diff = x - y
    if diff.size < 2 or np.allclose(diff, diff[0]):
        p = 1.0 if np.allclose(diff, 0.0) else 0.0
    else:
        p = float(ttest_rel(x, y).pvalue)
    return {"diff": float(diff.mean()), "p": p}


# -- formatting -----------------------------------------------------------------------------------


def _num(x: float | None, digits: int = 2, *, signed: bool | None = None) -> str:
    """A number for a table: rates plain (0.43), rewards signed (+0.180, −0.02)."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    signed = digits >= 3 if signed is None else signed
    s = f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"
    return s.replace("-", "−")


def _ci(ci: list[float], digits: int = 2, *, signed: bool | None = None) -> str:
    return f"[{_num(ci[0], digits, signed=signed)}, {_num(ci[1], digits, signed=signed)}]"


def _status_text(s: dict[str, Any]) -> str:
    if s["status"] == "failed":
        return "failed"
    return f"pending ({s['done_tasks']}/{s['tasks']})"


@dataclass
class Rendered:
    """A table as header + rows of (text, bold) cells, rendered to Markdown or HTML."""

    header: list[str]
    rows: list[list[tuple[str, bool]]]

    def markdown(self) -> str:
        lines = ["| " + " | ".join(self.header) + " |", "|" + "---|" * len(self.header)]
        for row in self.rows:
            lines.append("| " + " | ".join(f"**{t}**" if b else t for t, b in row) + " |")
        return "\n".join(lines)

    def html(self) -> str:
        head = "".join(f"<th>{html.escape(h)}</th>" for h in self.header)
        body = "".join(
            "<tr>"
            + "".join(
                f"<td>{'<b>' if b else ''}{html.escape(t)}{'</b>' if b else ''}</td>"
                for t, b in row
            )
            + "</tr>"
            for row in self.rows
        )
        return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _best(values: dict[str, float | None], *, lower: bool = False) -> set[str]:
    """Rows holding the best value (ties all bold); None values do not compete."""
    known = {k: v for k, v in values.items() if v is not None}
    if not known:
        return set()
    target = min(known.values()) if lower else max(known.values())
    return {k for k, v in known.items() if abs(v - target) < 1e-12}


# -- Table 1 --------------------------------------------------------------------------------------


def table1(state: GridState) -> tuple[dict[str, Any], str, str]:
    """Table 1 as JSON, Markdown and HTML."""
    cells = state.grid.cells_of("table1")
    columns = list(dict.fromkeys(c.column for c in cells))
    scenarios = [s for s in P.SCENARIOS if any(col.startswith(s + "/") for col in columns)]
    letters = [x for x in P.DEMONSTRATORS if any(col.endswith("/" + x) for col in columns)]
    summaries = {(c.column, c.row): cell_summary(state, c) for c in cells}
    doc: dict[str, Any] = {"columns": columns, "rows": {}, "paired_tests": {}}
    header = ["row"] + [f"{s} {m}" for s in scenarios for m in ("W", "R")]
    rendered_rows: list[list[tuple[str, bool]]] = []
    for letter in letters:
        rows = [
            r for r in P.TABLE1_ROWS if any((f"{s}/{letter}", r) in summaries for s in scenarios)
        ]
        best: dict[tuple[str, str], set[str]] = {}
        paper_best: dict[tuple[str, str], set[str]] = {}
        for s in scenarios:
            col = f"{s}/{letter}"
            for m in ("W", "R"):
                best[(col, m)] = _best(
                    {r: summaries[(col, r)].get(m) for r in rows if (col, r) in summaries}
                )
                idx = 0 if m == "W" else 1
                # The paper's best of its whole column, whether or not that row was run here.
                paper_best[(col, m)] = _best(
                    {r: P.PAPER_TABLE1[(r, letter)][s][idx] for r in P.TABLE1_ROWS}
                )
        for r in rows:
            name = f"{r}_{letter}"
            line: list[tuple[str, bool]] = [(name, False)]
            for s in scenarios:
                col = f"{s}/{letter}"
                paper = P.PAPER_TABLE1[(r, letter)][s]
                sm = summaries.get((col, r))
                entry: dict[str, Any] = {"paper": {"W": paper[0], "R": paper[1]}}
                if sm is None:
                    line += [("", False), ("", False)]
                    continue
                entry.update({k: v for k, v in sm.items() if k != "per_state"})
                doc["rows"].setdefault(name, {})[col] = entry
                for m, digits, idx in (("W", 2, 0), ("R", 3, 1)):
                    paper_text = f"paper {_num(paper[idx], 2, signed=m == 'R')}{'*' if r in paper_best[(col, m)] else ''}"
                    if sm["status"] != "done":
                        line.append((f"{_status_text(sm)} · {paper_text}", False))
                        continue
                    text = f"{_num(sm[m], digits)} {_ci(sm[m + '_ci95'], digits)} · {paper_text}"
                    line.append((text, r in best[(col, m)]))
            rendered_rows.append(line)
        for s in scenarios:
            col = f"{s}/{letter}"
            test = _paired(summaries, col, rows, "won", "terminal_hp_reward", lower=False)
            if test:
                doc["paired_tests"][col] = test
    rendered = Rendered(header, rendered_rows)
    cost = cost_table(
        {
            (col.split("/")[0], f"{row}_{col.split('/')[1]}"): sm
            for (col, row), sm in summaries.items()
        },
        scenarios,
        [(name, name) for name in (line[0][0] for line in rendered_rows)],
    )
    md = [
        f"# Table 1 (budget {state.grid.budget}, setting {state.grid.setting})",
        "",
        "Each cell: ours, W or R with its 95 % interval (Wilson for W, Student-t for R), then the paper's "
        "(IJCAI 2020, Table 1). Our best of each column is in bold; * marks the paper's best. "
        f"Every row of a column is evaluated on the same start states (seed {P.EVAL_SEED}). "
        f"{_search_sentence(state.grid.selection)}",
        "",
        rendered.markdown(),
        "",
        *_seed_lines(
            [(f"{name} {col}", e) for name, cols in doc["rows"].items() for col, e in cols.items()],
            ("W", "R"),
        ),
        *_test_lines(doc["paired_tests"], "W", "R"),
        *_cost_lines(cost),
        *_failure_lines(summaries),
    ]
    return doc, "\n".join(md) + "\n", rendered.html() + _cost_html(cost)


def _search_sentence(selection: dict[str, Any]) -> str:
    budget = selection.get("search_budget", "fixed")
    model = selection.get("search_model", "enemy-playouts")
    how = "fixed traversals and nodes per decision" if budget == "fixed" else "40 ms per decision"
    return f"UCT and A-B search with {how}, {P.SEARCH_MODELS[model]} (--search-budget {budget}, --search-model {model})."


def _paired(
    summaries: dict[tuple[str, str], dict[str, Any]],
    col: str,
    rows: list[str],
    primary: str,
    secondary: str,
    *,
    lower: bool,
) -> dict[str, Any] | None:
    """Ours against the best other done row of a column (by the primary metric's mean)."""
    ours = summaries.get((col, "Ours"))
    if ours is None or ours["status"] != "done":
        return None
    others = {
        r: summaries[(col, r)]
        for r in rows
        if r != "Ours" and (col, r) in summaries and summaries[(col, r)]["status"] == "done"
    }
    if not others:
        return None
    score = {r: float(np.mean(s["per_state"][primary])) for r, s in others.items()}
    rival = (min if lower else max)(score, key=lambda r: score[r])
    return {
        "against": rival,
        primary: paired_test(ours["per_state"][primary], others[rival]["per_state"][primary]),
        secondary: paired_test(ours["per_state"][secondary], others[rival]["per_state"][secondary]),
        "n_states": len(ours["per_state"][primary]),
    }


#: Per-seed metrics shown with a sign (rewards); rates and counts are shown plain.
_SIGNED = frozenset({"R"})


def _seed_lines(entries: list[tuple[str, dict[str, Any]]], metrics: tuple[str, str]) -> list[str]:
    """One line per done learner cell: each seed's numbers and, with two or more seeds, a
    Student-t interval over the seeds' means (the spread between training runs)."""
    lines = []
    for name, e in entries:
        if e.get("status") == "done" and e.get("seeds"):
            each = ", ".join(
                f"seed {p['seed']}: "
                + ", ".join(
                    f"{m.replace('_', ' ')} {_num(p[m], 3, signed=m in _SIGNED)}" for m in metrics
                )
                for p in e["per_seed"]
            )
            spread = e.get("over_seeds_ci95")
            if spread:
                each += "; over seeds, 95 % CI " + ", ".join(
                    f"{m.replace('_', ' ')} {_ci(spread[m], 3, signed=m in _SIGNED)}"
                    for m in metrics
                )
            lines.append(f"- {name}: {each}")
    return (["## Each seed", "", *lines, ""]) if lines else []


def _test_lines(tests: dict[str, Any], m1: str, m2: str) -> list[str]:
    if not tests:
        return []
    keys = {"W": "won", "R": "terminal_hp_reward", "failure rate": "failed", "arrivals": "arrivals"}
    lines = [
        "## Paired tests",
        "",
        "Ours against the best other row of each column, on the shared start states "
        "(per state, each row's outcome averaged over its seeds; two-sided paired t-test).",
        "",
    ]
    for col, t in tests.items():
        a, b = t[keys[m1]], t[keys[m2]]
        lines.append(
            f"- {col}: Ours − {t['against']}: {m1} {_num(a['diff'], 3)} (p = {a['p']:.3g}), {m2} {_num(b['diff'], 3)} (p = {b['p']:.3g}); {t['n_states']} start states"
        )
    return [*lines, ""]


_COST_NOTE = (
    "CPU minutes per task (process time of training, when the row learns, and of the evaluation "
    "battles), as each task's result.json records it; min–max over a learner's seeds. Wall time "
    "depends on the machine's load; the JSON output has both."
)


def cost_table(
    summaries: dict[tuple[str, str], dict[str, Any]],
    columns: list[str],
    rows: list[tuple[str, str]],
) -> Rendered | None:
    """CPU minutes per task for ``rows`` (name, row key) x ``columns``: one number for a single
    task, min–max over a learner's seeds; None when no cell is done."""
    table: list[list[tuple[str, bool]]] = []
    for name, row in rows:
        line: list[tuple[str, bool]] = [(name, False)]
        for col in columns:
            s = summaries.get((col, row))
            per = (
                [x / 60.0 for x in s.get("cpu_s_per_task", [])]
                if s and s["status"] == "done"
                else []
            )
            if not per:
                line.append(("", False))
            elif round(min(per), 1) == round(max(per), 1):
                line.append((f"{min(per):.1f}", False))
            else:
                line.append((f"{min(per):.1f}–{max(per):.1f}", False))
        table.append(line)
    if not any(t for line in table for t, _ in line[1:]):
        return None
    return Rendered(["row", *columns], table)


def _cost_lines(cost: Rendered | None) -> list[str]:
    return ["## Cost", "", _COST_NOTE, "", cost.markdown(), ""] if cost else []


def _cost_html(cost: Rendered | None) -> str:
    return f"<h3>Cost</h3><p>{html.escape(_COST_NOTE)}</p>{cost.html()}" if cost else ""


def _failure_lines(summaries: dict[Any, dict[str, Any]]) -> list[str]:
    lines = []
    for (col, row), s in summaries.items():
        if s["status"] == "failed":
            for err, log in zip(s["errors"], s["logs"], strict=True):
                lines.append(f"- {row} {col}: {err} (log: {log})")
    return (["## Failed cells", "", *lines, ""]) if lines else []


# -- Table 2 --------------------------------------------------------------------------------------


def table2(state: GridState) -> tuple[dict[str, Any], str, str]:
    """Table 2 (Traffic Junction) as JSON, Markdown and HTML: failure rate and arrivals."""
    cells = state.grid.cells_of("table2")
    summaries = {("tj", c.row): cell_summary(state, c) for c in cells}
    rows = [r for r in P.TABLE2_ROWS if ("tj", r) in summaries]
    best_fr = _best({r: summaries[("tj", r)].get("failure_rate") for r in rows}, lower=True)
    best_arr = _best({r: summaries[("tj", r)].get("arrivals") for r in rows})
    paper_best = _best({r: P.PAPER_TABLE2[r] for r in P.TABLE2_ROWS}, lower=True)
    doc: dict[str, Any] = {"rows": {}, "paired_tests": {}}
    out_rows: list[list[tuple[str, bool]]] = []
    for r in rows:
        s = summaries[("tj", r)]
        paper = P.PAPER_TABLE2[r]
        doc["rows"][r] = {
            "paper": {"failure_rate": paper},
            **{k: v for k, v in s.items() if k != "per_state"},
        }
        paper_text = f"{_num(paper)}{'*' if r in paper_best else ''}"
        if s["status"] != "done":
            out_rows.append(
                [
                    (r, False),
                    (_status_text(s), False),
                    (paper_text, False),
                    (_status_text(s), False),
                ]
            )
            continue
        out_rows.append(
            [
                (r, False),
                (
                    f"{_num(s['failure_rate'], 3, signed=False)} {_ci(s['failure_rate_ci95'], 3, signed=False)}",
                    r in best_fr,
                ),
                (paper_text, False),
                (f"{_num(s['arrivals'], 2)} {_ci(s['arrivals_ci95'], 2)}", r in best_arr),
            ]
        )
    test = _paired(summaries, "tj", rows, "failed", "arrivals", lower=True)
    if test:
        doc["paired_tests"]["tj"] = test
    rendered = Rendered(
        ["row", "failure rate [95 % CI]", "paper failure rate", "arrivals / episode [95 % CI]"],
        out_rows,
    )
    cost = cost_table(summaries, ["tj"], [(r, r) for r in rows])
    md = [
        f"# Table 2, Traffic Junction (budget {state.grid.budget}, setting {state.grid.setting})",
        "",
        "Failure rate (an episode fails when any collision happens; Wilson interval) and arrivals per "
        "episode (Student-t interval), demonstrator always-gas; our best in bold, * marks the paper's best. "
        "The paper reports failure rates only; a "
        "low failure rate with few arrivals means cars that wait, not a solved junction. "
        f"Every row is evaluated on the same start states (seed {P.EVAL_SEED}).",
        "",
        rendered.markdown(),
        "",
        *_seed_lines(list(doc["rows"].items()), ("failure_rate", "arrivals")),
        *_test_lines(doc["paired_tests"], "failure rate", "arrivals"),
        *_cost_lines(cost),
        *_failure_lines(summaries),
    ]
    return doc, "\n".join(md) + "\n", rendered.html() + _cost_html(cost)


# -- Fig. 3 ---------------------------------------------------------------------------------------


def _episode_curve(run_dir: Path, window: int) -> np.ndarray | None:
    """The forward mean of the terminal HP reward of a run's training episodes (episodes.csv)."""
    from hybridmarl.training.plots import forward_mean

    path = run_dir / "episodes.csv"
    if not path.is_file():
        return None
    with open(path, newline="") as f:
        values = [
            float(row["terminal_hp_reward"])
            for row in csv.DictReader(f)
            if row.get("terminal_hp_reward")
        ]
    return forward_mean(np.asarray(values), window) if values else None


def fig3(state: GridState, path: Path) -> dict[str, Any] | None:
    """Fig. 3 (paper layout: one panel per scenario, terminal HP reward against training
    episodes) as a PNG; returns what each curve shows, or None without a done curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = state.grid.cells_of("fig3")
    panels = list(dict.fromkeys(c.column for c in cells))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4), squeeze=False)
    info: dict[str, Any] = {}
    drawn = False
    for ax, col in zip(axes[0], panels, strict=True):
        ax.set_title(f"{col.split('/')[0]}, demonstrator c")
        ax.set_xlabel("training episodes")
        ax.set_ylabel("terminal HP reward (mean of the next 100)")
        for i, cell in enumerate(c for c in cells if c.column == col):
            color = f"C{i}"
            s = cell_summary(state, cell)
            if s["status"] != "done":
                info.setdefault(col, {})[cell.row] = s["status"]
                continue
            curves = [
                _episode_curve(state.task_dir(state.grid.tasks[k]) / "run", P.FIG3_WINDOW)
                for k in cell.keys
            ]
            curves = [c for c in curves if c is not None and c.size]
            if not curves:
                # A learner without interaction episodes (BC): its evaluated R as a level.
                ax.axhline(s["R"], color=color, linestyle="--", label=f"{cell.row} (evaluation R)")
                info.setdefault(col, {})[cell.row] = {"evaluation_R": s["R"]}
                drawn = True
                continue
            length = min(c.size for c in curves)
            stack = np.stack([c[:length] for c in curves])
            x = np.arange(1, length + 1)
            if len(curves) > 1:
                for c in curves:
                    ax.plot(np.arange(1, c.size + 1), c, color=color, alpha=0.2, linewidth=0.8)
            # A short run (the smoke budget) has only a few points: mark them.
            marker = "o" if length < 20 else None
            ax.plot(
                x,
                stack.mean(0),
                color=color,
                marker=marker,
                label=f"{cell.row} ({len(curves)} seed{'s' if len(curves) > 1 else ''})",
            )
            info.setdefault(col, {})[cell.row] = {
                "episodes": int(length + P.FIG3_WINDOW - 1),
                "final": float(stack.mean(0)[-1]),
            }
            drawn = True
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    if not drawn:
        plt.close(fig)
        return None
    fig.suptitle(f"Fig. 3 (budget {state.grid.budget}, setting {state.grid.setting})")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    from hybridmarl.io import atomic_write

    with atomic_write(path, "wb") as f:
        f.write(buf.getvalue())
    return info


# -- everything -----------------------------------------------------------------------------------

#: Where replay viewers of chosen battles will go in report.html.
REPLAY_PLACEHOLDER = "<!-- REPLAY-VIEWERS: embed replay viewers here -->"


def write_outputs(state: GridState, manifest: dict[str, Any]) -> list[Path]:
    """Write the tables, the figure and the report of every table of the grid; returns the
    paths written."""
    out = state.out
    written: list[Path] = []
    sections: list[str] = []
    tables = state.grid.tables()
    if "table1" in tables:
        doc, md, table_html = table1(state)
        write_json_atomic(out / "table1.json", {"protocol": _protocol(state), **doc})
        write_text_atomic(out / "table1.md", md)
        written += [out / "table1.md", out / "table1.json"]
        sections.append(_section("Table 1, combat", table_html, md))
    if "table2" in tables:
        doc, md, table_html = table2(state)
        write_json_atomic(out / "table2.json", {"protocol": _protocol(state), **doc})
        write_text_atomic(out / "table2.md", md)
        written += [out / "table2.md", out / "table2.json"]
        sections.append(_section("Table 2, Traffic Junction", table_html, md))
    if "fig3" in tables:
        png = out / "fig3.png"
        try:
            info = fig3(state, png)
        except ImportError:  # matplotlib is the optional 'plots' extra
            info = None
            sections.append(
                "<h2>Fig. 3</h2><p>Not drawn: matplotlib is not installed (pip install 'hybridmarl[plots]').</p>"
            )
        else:
            if info is None:
                sections.append("<h2>Fig. 3</h2><p>No curve is done yet.</p>")
        if info is not None:
            written.append(png)
            b64 = base64.b64encode(png.read_bytes()).decode()
            sections.append(
                f'<h2>Fig. 3</h2><img alt="Fig. 3" src="data:image/png;base64,{b64}" style="max-width:100%">'
            )
    write_text_atomic(out / "report.html", _report(state, manifest, sections))
    written.append(out / "report.html")
    return written


def _protocol(state: GridState) -> dict[str, Any]:
    budget = P.BUDGETS[state.grid.budget]
    return {
        "budget": budget.name,
        "budget_doc": budget.doc,
        "setting": state.grid.setting,
        "eval_seed": P.EVAL_SEED,
        "selection": state.grid.selection,
        "intervals": "95 %: Wilson for W and failure rates (battles pooled over seeds), Student-t for R and arrivals; for learners also a Student-t interval over the seeds' means (over_seeds_ci95)",
        "paired_test": "Ours vs the best other row of each column: two-sided paired t-test over the shared start states, per-state outcomes averaged over seeds",
    }


def _section(title: str, table_html: str, md: str) -> str:
    notes = [ln[2:] for ln in md.splitlines() if ln.startswith("- ")]
    items = "".join(f"<li>{html.escape(n.replace('**', ''))}</li>" for n in notes)
    return f"<h2>{html.escape(title)}</h2>{table_html}" + (f"<ul>{items}</ul>" if items else "")


def _report(state: GridState, manifest: dict[str, Any], sections: list[str]) -> str:
    budget = P.BUDGETS[state.grid.budget]
    counts = {
        s: sum(1 for k in state.grid.tasks if state.status(k) == s)
        for s in ("done", "failed", "queued")
    }
    style = (
        "body{font-family:sans-serif;max-width:1400px;margin:2em auto;padding:0 1em}"
        "table{border-collapse:collapse;font-size:13px;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 6px}"
        "th{background:#f3f3f3}"
    )
    head = (
        f"<h1>hybridmarl reproduction of Peng, Xing &amp; Cao (IJCAI 2020)</h1>"
        f"<p>hybridmarl {html.escape(str(manifest.get('version')))}, setting <b>{html.escape(state.grid.setting)}</b>, "
        f"budget <b>{html.escape(budget.name)}</b>: {html.escape(budget.doc)}</p>"
        f"<p>Tasks: {counts['done']} done, {counts['failed']} failed, {counts['queued']} not run. Evaluation start states: seed "
        f"{P.EVAL_SEED} (used by no training run). Updated {html.escape(str(manifest.get('updated')))}.</p>"
    )
    replays = f"<h2>Replays</h2>{REPLAY_PLACEHOLDER}<p>(Replay viewers of selected battles are not embedded yet.)</p>"
    return f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>hybridmarl reproduction</title><style>{style}</style></head><body>{head}{''.join(sections)}{replays}</body></html>\n"


__all__ = [
    "REPLAY_PLACEHOLDER",
    "cell_summary",
    "cost_table",
    "fig3",
    "paired_test",
    "table1",
    "table2",
    "write_outputs",
]
