"""The reproduction grid as data (tasks per table, stable keys, shared tasks), the bookkeeping
of finished and failed tasks, the tables built from results, and bad input. No task runs here."""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from hybridmarl.cli.main import main
from hybridmarl.errors import EXIT_BAD_INPUT
from hybridmarl.io import write_json_atomic
from hybridmarl.reproduce import driver, grid, outputs, protocol
from hybridmarl.reproduce.grid import Selection, expand


def test_task_counts_per_table_and_budget():
    kinds = lambda g: Counter(t.kind for t in g.tasks.values())  # noqa: E731
    for budget, seeds in (("smoke", 1), ("cpu", 3), ("full", 3)):
        t1 = expand(("table1",), budget, "paper")
        # 4 scenarios x 2 demonstrators = 8 columns; D is a script, UCT/A-B/Profile search,
        # BC/DQfD/OGTL/Ours one training task per seed.
        assert len(t1.cells) == 8 * 8
        assert kinds(t1) == {"script": 8, "search": 24, "train": 8 * 4 * seeds}
        t2 = expand(("table2",), budget, "paper")
        assert [c.row for c in t2.cells] == list(protocol.TABLE2_ROWS)
        assert kinds(t2) == {"script": 1, "train": 3 * seeds}
        f3 = expand(("fig3",), budget, "paper")
        assert len(f3.cells) == 2 * 5 and kinds(f3) == {"train": 10 * seeds}
        everything = expand(protocol.TABLES, budget, "paper")
        # Fig. 3 reuses Table 1's BC/DQfD/OGTL/Ours runs at m18v20 and m24v30 (demonstrator c):
        # only its Random curves are new tasks.
        assert len(everything.tasks) == len(t1.tasks) + len(t2.tasks) + 2 * seeds
        assert set(f3.tasks) - set(t1.tasks) == {
            k for k, t in f3.tasks.items() if t.config["row"] == "Random"
        }
    # At 'cpu' Random is 'quick-wo-d' with the one-step Q (native engine), w/o D 'quick-wo-d' as it is.
    cpu = expand(("fig3", "table2"), "cpu", "paper", Selection(seeds=(0,)))
    by_row = {t.config["row"]: t.config for t in cpu.tasks.values() if t.kind == "train"}
    assert by_row["Random"]["preset"] == "quick-wo-d" and by_row["Random"]["overrides"] == {
        "lookahead_steps": 1
    }
    assert (
        by_row["Ours w/o D"]["preset"] == "quick-wo-d" and by_row["Ours w/o D"]["overrides"] == {}
    )


def test_keys_are_stable_hashes_of_the_config():
    sel = Selection(scenarios=("m5v5",), demonstrators=("c",), rows=("D", "BC"))
    g = expand(("table1",), "smoke", "paper", sel)
    # A key names a task's run directory: changing it would orphan every finished result.
    assert {t.label: k for k, t in g.tasks.items()} == {
        "D-m5v5-c": "ddeb2d3ec57c",
        "BC-m5v5-c-s0": "910168af1f2c",
    }
    # The same task asked for by a larger selection keeps its key; another setting does not.
    full = expand(("table1",), "smoke", "paper")
    assert set(g.tasks) <= set(full.tasks)
    other = expand(("table1",), "smoke", "sparcraft", sel)
    assert not set(g.tasks) & set(other.tasks)
    d = g.tasks["ddeb2d3ec57c"]
    assert d.config["eval_seed"] == protocol.EVAL_SEED and d.config["enemy"] == "attack-weakest"
    assert d.dirname == "D-m5v5-c-ddeb2d3ec57c"


def test_cross_validation_and_search_budgets():
    g = expand(("table1",), "cpu", "paper", Selection(scenarios=("m18v20",), demonstrators=("w",)))
    by_row = {c.row: [g.tasks[k] for k in c.keys] for c in g.cells}
    assert (
        by_row["D"][0].config["player"] == "attack-weakest"
        and by_row["D"][0].config["enemy"] == "attack-closest"
    )
    # SparCraft's 40 ms on one core, interpolated between its 16- and 32-Marine figures for 20 units.
    assert (
        by_row["UCT"][0].config["player"]
        == "uct:script=attack-weakest,playout1=attack-closest,traversals=90,time_ms=0"
    )
    assert (
        by_row["A-B"][0].config["player"]
        == "abcd:script=attack-weakest,playout1=attack-closest,nodes=175,time_ms=0"
    )
    assert (
        by_row["Profile"][0].config["player"]
        == "pgs:portfolio=attack-closest+attack-weakest,time_ms=0"
    )
    ours = by_row["Ours"]
    assert [t.config["seed"] for t in ours] == [0, 1, 2]
    assert (
        ours[0].config["overrides"] == {"brd_start": "demonstrator"}
        and ours[0].config["enemy"] == "attack-closest"
    )
    wall = expand(
        ("table1",),
        "cpu",
        "paper",
        Selection(scenarios=("m5v5",), rows=("A-B",), search_budget="wallclock"),
    )
    assert all(t.config["player"].endswith("time_ms=40") for t in wall.tasks.values())
    both_sides = expand(
        ("table1",),
        "cpu",
        "paper",
        Selection(
            scenarios=("m18v20",),
            demonstrators=("w",),
            rows=("UCT", "A-B", "Profile"),
            search_model="demonstrator",
        ),
    )
    players = sorted(t.config["player"] for t in both_sides.tasks.values())
    assert (
        players
        == [
            "abcd:script=attack-weakest,nodes=175,time_ms=0",
            "pgs:portfolio=attack-closest+attack-weakest,time_ms=0",  # PGS has no playout script per side
            "uct:script=attack-weakest,traversals=90,time_ms=0",
        ]
    )
    known = expand(
        ("table1",),
        "cpu",
        "paper",
        Selection(
            scenarios=("m5v5",), demonstrators=("c",), rows=("A-B",), search_model="enemy-script"
        ),
    )
    assert [t.config["player"] for t in known.tasks.values()] == [
        "abcd:script=attack-closest,playout1=attack-weakest,opponent_model=attack-weakest,nodes=350,time_ms=0"
    ]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["reproduce", "table9"], "unknown table 'table9'"),
        (["reproduce", "table1", "--budget", "huge"], "unknown budget 'huge'"),
        (["reproduce", "table1", "--rows", "D,Magic"], "unknown row 'Magic'"),
        (["reproduce", "table1", "--scenarios", "m9v9"], "unknown scenario 'm9v9'"),
        (["reproduce", "table1", "--demonstrators", "x"], "unknown demonstrator 'x'"),
        (["reproduce", "table1", "--seeds", "a,b"], "--seeds must be comma-separated integers"),
        (["reproduce", "table1", "--search-model", "both"], "unknown --search-model 'both'"),
        (["reproduce", "table2", "--rows", "UCT"], "leaves table2 empty"),
        (["reproduce", "table1", "--setting", "moon"], "unknown setting 'moon'"),
        (["reproduce", "table1", "--executor", "slurm"], "unknown --executor 'slurm'"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv, message, tmp_path, capsys):
    out = tmp_path / "out"
    assert main([*argv, "--out", str(out)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not out.exists()


def test_the_driver_does_not_import_jax():
    import subprocess

    code = (
        "import sys, hybridmarl.cli.main, hybridmarl.cli.reproduce, hybridmarl.reproduce.driver, "
        "hybridmarl.reproduce.executors, hybridmarl.reproduce.outputs, hybridmarl.reproduce.worker; "
        "assert 'jax' not in sys.modules, 'jax imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_unreachable_ray_address_is_named(tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["reproduce", "table1", "--rows", "D", "--address", "127.0.0.1:9", "--out", str(out)])
    assert rc == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    if "ray" in sys.modules or _ray_installed():
        assert "cannot reach the Ray cluster at --address 127.0.0.1:9" in err[0]
    else:
        assert "ray is not installed" in err[0]
    assert not out.exists()


def _ray_installed() -> bool:
    import importlib.util

    return importlib.util.find_spec("ray") is not None


def test_output_folder_of_another_setting_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    g = expand(("table1",), "smoke", "paper", Selection(rows=("D",)))
    driver.check_output_folder(out, g, force=False)
    other = expand(("table1",), "smoke", "sparcraft", Selection(rows=("D",)))
    with pytest.raises(driver.OutputFolderError, match="setting 'paper', not 'sparcraft'"):
        driver.check_output_folder(out, other, force=False)
    driver.check_output_folder(out, other, force=True)
    assert json.loads((out / driver.MANIFEST).read_text())["setting"] == "sparcraft"
    stranger = tmp_path / "stranger"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("mine")
    assert (
        main(
            [
                "reproduce",
                "table1",
                "--budget",
                "smoke",
                "--rows",
                "D",
                "--status",
                "--out",
                str(stranger),
            ]
        )
        == EXIT_BAD_INPUT
    )
    assert "holds no reproduce.json" in capsys.readouterr().err


def _fake_result(
    state: driver.GridState,
    task: grid.GridTask,
    rng: np.random.Generator,
    win_p: float,
    cpu_s: float = 60.0,
) -> None:
    n = task.config["n"]
    won = (rng.random(n) < win_p).astype(float).tolist()
    hp = rng.normal(0.2 if win_p > 0.5 else -0.2, 0.1, n).tolist()
    d = state.task_dir(task)
    d.mkdir(parents=True, exist_ok=True)
    write_json_atomic(
        d / "result.json",
        {
            "key": task.key,
            "kind": task.kind,
            "config": task.config,
            "wall_s": 1.0,
            "cpu_s": cpu_s,
            "summary": {"W": float(np.mean(won)), "R": float(np.mean(hp))},
            "per_episode": {"won": won, "terminal_hp_reward": hp},
        },
    )


def test_finished_tasks_are_skipped_and_failed_ones_retried(tmp_path):
    sel = Selection(
        scenarios=("m5v5",), demonstrators=("c",), rows=("D", "Profile", "Ours"), seeds=(0, 1)
    )
    g = expand(("table1",), "smoke", "paper", sel)
    state = driver.GridState(tmp_path, g)
    assert len(driver.prepare(state)) == 4  # D, Profile, Ours seeds 0 and 1
    rng = np.random.default_rng(0)
    by_row = {c.row: [g.tasks[k] for k in c.keys] for c in g.cells}
    _fake_result(state, by_row["D"][0], rng, 0.3, cpu_s=30.0)
    _fake_result(state, by_row["Ours"][0], rng, 0.9, cpu_s=240.0)
    _fake_result(state, by_row["Ours"][1], rng, 0.9, cpu_s=120.0)
    # A result of another task, or a truncated one, does not count as done.
    bad = state.task_dir(by_row["Profile"][0]) / "result.json"
    write_json_atomic(bad, {"key": "someoneelse", "summary": {}, "per_episode": {"won": [1.0]}})
    write_json_atomic(
        state.task_dir(by_row["Profile"][0]) / driver.FAILED_FILE,
        {"exit_code": 1, "error": "exit code 1", "log": "x/log.txt"},
    )
    state.scan()
    assert state.status(by_row["Profile"][0].key) == "failed"
    doc, md, _ = outputs.table1(state)
    assert doc["rows"]["Profile_c"]["m5v5/c"]["status"] == "failed"
    profile_line = next(ln for ln in md.splitlines() if ln.startswith("| Profile_c"))
    assert "failed" in profile_line and "[" not in profile_line  # no number in a failed cell
    assert "x/log.txt" in md
    # Ours (two seeds) against the best other done row, D, on the shared start states.
    test = doc["paired_tests"]["m5v5/c"]
    assert test["against"] == "D" and test["won"]["diff"] > 0.3 and test["won"]["p"] < 0.05
    ours = doc["rows"]["Ours_c"]["m5v5/c"]
    assert [p["seed"] for p in ours["per_seed"]] == [0, 1]
    # Over two seeds the interval is mean ± t(0.975, 1)·|x0 − x1|/2, t(0.975, 1) = 12.706; a
    # rate's interval is clipped to [0, 1], a reward's is not.
    for metric, clip in (("W", (0.0, 1.0)), ("R", (-np.inf, np.inf))):
        x0, x1 = (p[metric] for p in ours["per_seed"])
        half = 12.7062 * abs(x0 - x1) / 2
        expected = [max((x0 + x1) / 2 - half, clip[0]), min((x0 + x1) / 2 + half, clip[1])]
        assert ours["over_seeds_ci95"][metric] == pytest.approx(expected, rel=1e-4), metric
    assert "over seeds, 95 % CI W [" in md
    # The cost table: CPU minutes per task, min–max over a learner's seeds; none for a failed cell.
    cost = md[md.index("## Cost") :].splitlines()
    assert "| D_c | 0.5 |" in cost and "| Ours_c | 2.0–4.0 |" in cost and "| Profile_c |  |" in cost
    assert ours["cpu_s"] == 360.0 and ours["cpu_s_per_task"] == [240.0, 120.0]
    # A status report keeps the failure; the next run does only the failed task, and clears
    # its failure record first.
    assert [t.key for t in driver.prepare(state, retry_failed=False)] == []
    assert state.status(by_row["Profile"][0].key) == "failed"
    todo = driver.prepare(state)
    assert [t.key for t in todo] == [by_row["Profile"][0].key]
    assert not (state.task_dir(by_row["Profile"][0]) / driver.FAILED_FILE).exists()


def test_outputs_of_a_partial_grid(tmp_path):
    pytest.importorskip("matplotlib")
    g = expand(
        protocol.TABLES,
        "smoke",
        "paper",
        Selection(scenarios=("m18v20",), demonstrators=("c",), rows=("D", "Ours")),
        drop_empty=True,
    )
    state = driver.GridState(tmp_path, g)
    driver.check_output_folder(tmp_path, g, force=False)
    driver.prepare(state)
    by = {(c.table, c.row): [g.tasks[k] for k in c.keys] for c in g.cells}
    _fake_result(state, by[("table1", "D")][0], np.random.default_rng(1), 0.3)
    ours = by[("fig3", "Ours")][0]
    _fake_result(state, ours, np.random.default_rng(2), 0.8)
    run = state.task_dir(ours) / "run"
    run.mkdir()
    (run / "episodes.csv").write_text(
        "episode,terminal_hp_reward\n" + "".join(f"{i},{i / 300:.4f}\n" for i in range(1, 301))
    )
    state.scan()
    written = outputs.write_outputs(state, json.loads((tmp_path / driver.MANIFEST).read_text()))
    assert {p.name for p in written} == {
        "table1.md",
        "table1.json",
        "table2.md",
        "table2.json",
        "fig3.png",
        "report.html",
    }
    report = (tmp_path / "report.html").read_text()
    assert "data:image/png;base64," in report and outputs.REPLAY_PLACEHOLDER in report
    t2 = json.loads((tmp_path / "table2.json").read_text())
    assert (
        t2["rows"]["D"]["status"] == "pending" and t2["rows"]["D"]["paper"]["failure_rate"] == 0.72
    )
    assert Path(tmp_path / "fig3.png").stat().st_size > 1000


def test_the_paper_star_marks_the_best_of_the_papers_whole_column(tmp_path):
    g = expand(
        ("table1",),
        "smoke",
        "paper",
        Selection(scenarios=("m18v20",), demonstrators=("c",), rows=("D",)),
        drop_empty=True,
    )
    state = driver.GridState(tmp_path, g)
    driver.check_output_folder(tmp_path, g, force=False)
    driver.prepare(state)
    (cell,) = g.cells
    _fake_result(state, g.tasks[cell.keys[0]], np.random.default_rng(1), 0.3)
    state.scan()
    outputs.write_outputs(state, json.loads((tmp_path / driver.MANIFEST).read_text()))
    d_line = next(
        line
        for line in (tmp_path / "table1.md").read_text().splitlines()
        if line.startswith("| D_c |")
    )
    d_line = d_line.replace("**", "")  # our best of the column, in bold
    # The paper's best at m18v20 is Ours (0.87, +0.24), not D, even when D is the only row run.
    assert "paper 0.32" in d_line and "paper 0.32*" not in d_line and "paper −0.11*" not in d_line


def test_search_budgets_are_sparcraft_40ms_by_army_size():
    assert protocol.sparcraft_40ms_budget("m5v5") == {
        "traversals": 240,
        "nodes": 350,
    }  # held at 8 Marines
    assert protocol.sparcraft_40ms_budget("m16v16") == {
        "traversals": 105,
        "nodes": 200,
    }  # a measured size
    assert protocol.sparcraft_40ms_budget("m24v30") == {
        "traversals": 52,
        "nodes": 112,
    }  # 30 units: 105 - 14/16 * 60
    assert protocol.sparcraft_40ms_budget("m60v60") == {"traversals": 25, "nodes": 50}  # held at 50
    g = expand(
        ("table1",),
        "full",
        "paper",
        Selection(scenarios=("m5v5",), demonstrators=("c",), rows=("UCT", "A-B")),
    )
    assert sorted(t.config["player"] for t in g.tasks.values()) == [
        "abcd:script=attack-closest,playout1=attack-weakest,nodes=350,time_ms=0",
        "uct:script=attack-closest,playout1=attack-weakest,traversals=240,time_ms=0",
    ]
