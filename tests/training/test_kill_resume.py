"""A training process stopped from outside: Ctrl-C (SIGINT) stops at the end of the chunk with a
checkpoint and a line that says how to resume; SIGKILL anywhere (mid-chunk, during a checkpoint
write, during the final evaluation) leaves a run that --resume finishes exactly as the
uninterrupted run did. The process pauses at the chosen point through the
``HYBRIDMARL_PAUSE_AT`` hook (``training.checkpoint.pause_point``), so the signal lands there.

Each case spawns a training process (its start-up and compilation cost tens of seconds on a
2-core CPU), so they are marked ``slow`` and left out of the default run (``pytest -m slow``
runs them). The default run covers the same ground in-process, at a fraction of the cost,
in tests/training/test_data.py::test_exact_resume (a kill after a periodic checkpoint with its
leftovers, and Ctrl-C inside a chunk).
"""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hybridmarl.cli.main import main
from hybridmarl.training.checkpoint import PAUSE_ENV, list_checkpoints, load_checkpoint
from hybridmarl.training.rundir import LOCK_NAME

SRC = str(Path(__file__).resolve().parents[2] / "src")
TOY = ["--preset", "toy", "--scenario", "m3v3", "--no-progress", "--no-tensorboard"]
TIMING = ("chunk_s", "wall_s", "cpu_s", "env_steps_per_s")


def _spawn(run_dir: Path, pause: str) -> subprocess.Popen:
    """``hybridmarl train`` in its own process, paused at ``pause`` (returns once it is there)."""
    env = {**os.environ, "PYTHONPATH": SRC, PAUSE_ENV: pause}
    # One XLA host device, as in this process, so both compute the same numbers.
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=1").strip()
    cmd = [sys.executable, "-m", "hybridmarl.cli", "train", *TOY, "--run-dir", str(run_dir)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    assert proc.stderr is not None
    for line in proc.stderr:
        if line.startswith("hybridmarl: paused at"):
            return proc
    proc.wait()
    raise AssertionError(f"the training process ended (rc {proc.returncode}) before pausing at {pause}")


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


@pytest.mark.slow
def test_ctrl_c_saves_a_checkpoint_and_says_how_to_resume(tmp_path, capsys):
    run = tmp_path / "run"
    proc = _spawn(run, "chunk:3")
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, (out, err)
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("hybridmarl: interrupted at") and f"hybridmarl train --run-dir {run} --resume" in last, err
    # The checkpoint is the state after the chunk it stopped in, with the logs written up to it.
    newest = list_checkpoints(run)[-1]
    _, meta = load_checkpoint(newest)
    assert meta["iterations"] == 3 and meta["log_rows"]["train"] == len(_rows(run / "train.csv")) == 3
    assert not (run / LOCK_NAME).exists() and not any(p.name.startswith(".") for p in (run / "checkpoints").iterdir())
    assert main(["train", "--run-dir", str(run), "--resume", "--no-progress"]) == 0
    assert "resumed" in capsys.readouterr().out
    iterations = [int(r["iteration"]) for r in _rows(run / "train.csv")]
    assert iterations == list(range(1, len(iterations) + 1))  # every chunk logged once
    assert [int(r["episode"]) for r in _rows(run / "episodes.csv")] == list(range(1, 9))


@pytest.fixture(scope="module")
def straight(tmp_path_factory) -> Path:
    """The uninterrupted run every killed one must end equal to."""
    run = tmp_path_factory.mktemp("straight") / "run"
    assert main(["train", *TOY, "--run-dir", str(run)]) == 0
    return run


@pytest.mark.slow
@pytest.mark.parametrize("pause", ["chunk:3", "checkpoint:2", "evaluation"])
def test_a_run_killed_anywhere_resumes_exactly(straight, tmp_path, pause):
    run = tmp_path / "run"
    proc = _spawn(run, pause)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert (run / LOCK_NAME).exists()  # a killed process leaves its lock file behind
    assert main(["train", "--run-dir", str(run), "--resume", "--no-progress"]) == 0
    a, _ = load_checkpoint(list_checkpoints(straight)[-1])
    b, _ = load_checkpoint(list_checkpoints(run)[-1])
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for log in ("train.csv", "episodes.csv"):
        assert _rows(run / log) == _rows(straight / log), log
    assert not (run / LOCK_NAME).exists() and not any(p.name.startswith(".") for p in (run / "checkpoints").iterdir())
