"""``hybridmarl reproduce`` end to end on a smoke slice: the tasks run as processes, the table
shows their numbers beside the paper's, a rerun does nothing, a failing task is reported as
failed (never a number) and retried by the next run, and Ray runs the same tasks."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

from hybridmarl.cli.main import main

SLICE = ["table1", "--budget", "smoke", "--scenarios", "m5v5", "--demonstrators", "c"]


@pytest.fixture(scope="module")
def smoke_slice(tmp_path_factory) -> Path:
    """The D and BC cells of m5v5 from c, run by the local executor (one process per task)."""
    out = tmp_path_factory.mktemp("reproduce") / "out"
    assert (
        main(["reproduce", *SLICE, "--rows", "D,BC", "--executor", "local", "--out", str(out)]) == 0
    )
    return out


def _task_dir(out: Path, label: str) -> Path:
    (d,) = [p for p in (out / "tasks").iterdir() if p.name.startswith(label + "-")]
    return d


def test_smoke_slice_fills_its_cells(smoke_slice):
    out = smoke_slice
    doc = json.loads((out / "table1.json").read_text())
    for row in ("D_c", "BC_c"):
        cell = doc["rows"][row]["m5v5/c"]
        assert cell["status"] == "done" and cell["n"] == 8 and 0.0 <= cell["W"] <= 1.0
        assert cell["W_ci95"][0] <= cell["W"] <= cell["W_ci95"][1]
    assert doc["rows"]["D_c"]["m5v5/c"]["paper"] == {"W": 0.43, "R": -0.02}
    assert doc["rows"]["BC_c"]["m5v5/c"]["seeds"] == [0]
    assert doc["protocol"]["eval_seed"] == 20_200_713
    md = (out / "table1.md").read_text()
    assert "| D_c |" in md and "paper 0.43" in md
    assert (_task_dir(out, "BC-m5v5-c-s0") / "run" / "eval.json").is_file()
    manifest = json.loads((out / "reproduce.json").read_text())
    assert manifest["setting"] == "paper" and manifest["budget"] == "smoke"


def test_rerun_runs_nothing(smoke_slice, capsys):
    out = smoke_slice
    before = {p: p.stat().st_mtime_ns for p in (out / "tasks").glob("*/result.json")}
    assert (
        main(["reproduce", *SLICE, "--rows", "D,BC", "--executor", "local", "--out", str(out)]) == 0
    )
    err = capsys.readouterr().err
    assert "2 done earlier, 0 to run" in err and "started" not in err
    assert {p: p.stat().st_mtime_ns for p in (out / "tasks").glob("*/result.json")} == before


def test_failed_task_is_reported_and_retried(smoke_slice, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(smoke_slice, out)
    d = _task_dir(out, "D-m5v5-c")
    result = d / "result.json"
    result.unlink()
    result.mkdir()  # the task cannot write its result: it fails
    assert (
        main(["reproduce", *SLICE, "--rows", "D,BC", "--executor", "local", "--out", str(out)]) == 1
    )
    err = capsys.readouterr().err
    assert "FAILED   D-m5v5-c" in err and str(d / "log.txt") in err
    failure = json.loads((d / "failed.json").read_text())
    assert failure["exit_code"] == 1 and failure["log"] == str(d / "log.txt")
    cell = json.loads((out / "table1.json").read_text())["rows"]["D_c"]["m5v5/c"]
    assert cell["status"] == "failed" and "W" not in cell
    line = next(ln for ln in (out / "table1.md").read_text().splitlines() if ln.startswith("| D_c"))
    assert "failed" in line and "[" not in line
    # Fixed, the next run retries the failed task only.
    result.rmdir()
    assert (
        main(["reproduce", *SLICE, "--rows", "D,BC", "--executor", "local", "--out", str(out)]) == 0
    )
    err = capsys.readouterr().err
    assert (
        "1 done earlier, 1 to run" in err
        and "started  D-m5v5-c" in err
        and "BC-m5v5-c-s0" not in err
    )
    assert not (d / "failed.json").exists()
    assert (
        json.loads((out / "table1.json").read_text())["rows"]["D_c"]["m5v5/c"]["status"] == "done"
    )


@pytest.mark.skipif(
    importlib.util.find_spec("ray") is None, reason="the 'scale' extra (ray) is not installed"
)
def test_ray_local_cluster_runs_the_same_task(smoke_slice, tmp_path):
    out = tmp_path / "out"
    assert (
        main(
            [
                "reproduce",
                *SLICE,
                "--rows",
                "D",
                "--executor",
                "ray",
                "--workers",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    ray_cell = json.loads((out / "table1.json").read_text())["rows"]["D_c"]["m5v5/c"]
    local_cell = json.loads((smoke_slice / "table1.json").read_text())["rows"]["D_c"]["m5v5/c"]
    assert (
        ray_cell["W"] == local_cell["W"] and ray_cell["R"] == local_cell["R"]
    )  # the same start states


def test_a_task_trained_earlier_counts_its_training_time(smoke_slice, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(smoke_slice, out)
    d = _task_dir(out, "BC-m5v5-c-s0")
    first = json.loads((d / "result.json").read_text())
    # As if the task had been killed after training, before writing its result.
    (d / "result.json").unlink()
    training = json.loads((d / "run" / "eval.json").read_text())
    training["wall_s"] = 1000.0  # a long training, so the evaluation alone cannot reach it
    (d / "run" / "eval.json").write_text(json.dumps(training))
    assert (
        main(["reproduce", *SLICE, "--rows", "D,BC", "--executor", "local", "--out", str(out)]) == 0
    )
    assert "training finished earlier" in (d / "log.txt").read_text()
    again = json.loads((d / "result.json").read_text())
    assert again["summary"] == first["summary"]
    assert 1000.0 < again["wall_s"] < 1000.0 + first["wall_s"] + 60.0
    assert again["training"]["wall_s"] == 1000.0 and again["training"]["eval_wall_s"] > 0.0
