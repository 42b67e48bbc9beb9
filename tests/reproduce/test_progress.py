"""The grid's estimate of the time left: each queued task is expected to take the mean wall time
of the finished tasks most like it in the output folder, whichever command finished them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hybridmarl.reproduce import driver
from hybridmarl.reproduce.grid import Selection, expand


def _finish(out: Path, task, wall_s: float) -> None:
    d = out / "tasks" / task.dirname
    d.mkdir(parents=True)
    (d / driver.TASK_FILE).write_text(json.dumps(task.to_dict()))
    (d / driver.RESULT_FILE).write_text(
        json.dumps({"config": task.config, "wall_s": wall_s, "key": task.key})
    )


def test_time_left_pools_the_most_similar_finished_tasks(tmp_path):
    out = tmp_path / "out"
    earlier = expand(
        ("table1",),
        "cpu",
        "paper",
        Selection(
            scenarios=("m5v5", "m18v20"), demonstrators=("c",), rows=("BC", "Ours"), seeds=(0,)
        ),
    )
    by_name = {t.dirname.rsplit("-", 1)[0]: t for t in earlier.tasks.values()}
    _finish(out, by_name["BC-m5v5-c-s0"], 60.0)
    _finish(out, by_name["Ours-m5v5-c-s0"], 600.0)
    _finish(out, by_name["Ours-m18v20-c-s0"], 1200.0)
    (out / "tasks" / "broken").mkdir()
    (out / "tasks" / "broken" / driver.RESULT_FILE).write_text("{not json")  # passed over

    # Queued now: Ours at m18v20 seeds 1 and 2 (same row and scenario: 1,200 s each) and BC at
    # m18v20 seeds 1 and 2 (same row, another scenario: 60 s scaled from 10 to 38 units,
    # 60 * 3.8 ** 1.3 = 340.3 s each); two workers share them.
    now = expand(
        ("table1",),
        "cpu",
        "paper",
        Selection(scenarios=("m18v20",), demonstrators=("c",), rows=("BC", "Ours"), seeds=(1, 2)),
    )
    state = driver.GridState(out, now)
    state.scan()
    progress = driver.Progress(state, workers=2, live=False)
    assert progress.eta_s() == pytest.approx((2 * 1200.0 + 2 * 340.3) / 2, abs=0.1)

    # A row nothing has finished of yet: no estimate for it, and the line names it.
    search = expand(
        ("table1",),
        "cpu",
        "paper",
        Selection(scenarios=("m5v5",), demonstrators=("c",), rows=("UCT",)),
    )
    state = driver.GridState(out, search)
    state.scan()
    progress = driver.Progress(state, workers=2, live=False)
    assert progress.eta_s() is None and progress.time_left() == (0.0, ("UCT",))
    assert "~? left" in progress.line()

    # Some rows known, one not: the known part is summed and the other row named, never
    # estimated from another row's durations (a BC run is no guide to a DQfD one).
    mixed = expand(
        ("table1",),
        "cpu",
        "paper",
        Selection(scenarios=("m5v5",), demonstrators=("c",), rows=("BC", "DQfD"), seeds=(1,)),
    )
    state = driver.GridState(out, mixed)
    state.scan()
    progress = driver.Progress(state, workers=2, live=False)
    assert progress.eta_s() is None and progress.time_left() == (30.0, ("DQfD",))
    assert progress.line().endswith("~30s left, plus DQfD (none finished yet)")
