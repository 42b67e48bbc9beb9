"""A training process stopped from outside: Ctrl-C (SIGINT) stops at the end of the chunk with a
checkpoint and a line that says how to resume; SIGKILL anywhere (mid-chunk, during a checkpoint
write, during the final evaluation) leaves a run that --resume finishes exactly as the
uninterrupted run did (the same final parameters, the same logs). The process pauses at the
chosen point through the ``HYBRIDMARL_PAUSE_AT`` hook (``training.checkpoint.pause_point``), so
the signal lands there.

Compiling the training programs, not running them, is most of what a toy run costs (28 CPU-s
for a whole toy run from a cold compilation cache, 10 from a warm one, on a 2-core CPU at the
tests' XLA level). So this module shares one persistent JAX compilation cache
between this process and the processes it spawns: the uninterrupted reference run (computed
once, in this process) compiles every program and fills the cache; each spawned process and
each resume then loads them from it instead of compiling them again. The cache lives in a
temporary directory of the test session, or in ``JAX_COMPILATION_CACHE_DIR`` where that is set
(kept between sessions, so a second session compiles nothing).
"""

from __future__ import annotations

import csv
import os
import shutil
import signal
import struct
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from hybridmarl.cli.main import main
from hybridmarl.training.checkpoint import PAUSE_ENV, list_checkpoints, load_checkpoint
from hybridmarl.training.rundir import LOCK_NAME

SRC = str(Path(__file__).resolve().parents[2] / "src")
TOY = ["--preset", "toy", "--scenario", "m3v3", "--no-progress"]  # TensorBoard off (the preset's)
TIMING = ("chunk_s", "wall_s", "cpu_s", "env_steps_per_s")
#: Every program is cached, however fast it compiled and however small it is.
CACHE_OPTIONS = {
    "jax_compilation_cache_dir": None,  # set per test session
    "jax_persistent_cache_min_compile_time_secs": 0.0,
    "jax_persistent_cache_min_entry_size_bytes": -1,
}


@pytest.fixture(scope="module")
def spawn_env(tmp_path_factory) -> Iterator[dict[str, str]]:
    """The environment of the spawned training processes, with a compilation cache shared with
    this process (which uses it too, while this module runs)."""
    import jax
    from jax._src import compilation_cache

    cache_dir = os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(
        tmp_path_factory.mktemp("jax_cache")
    )
    options = {**CACHE_OPTIONS, "jax_compilation_cache_dir": cache_dir}
    # One XLA host device, as in this process, so both compute the same numbers. XLA_FLAGS is
    # part of the cache key, so this process states the same (true) device count while the
    # module runs, or its cache entries would not be found by the spawned processes.
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        assert jax.local_device_count() == 1
        flags = (flags + " --xla_force_host_platform_device_count=1").strip()
    env = {**os.environ, "PYTHONPATH": SRC, "XLA_FLAGS": flags}
    env.update({name.upper(): str(value) for name, value in options.items()})

    saved_flags = os.environ.get("XLA_FLAGS")
    saved = {name: getattr(jax.config, name) for name in options}
    os.environ["XLA_FLAGS"] = flags
    for name, value in options.items():
        jax.config.update(name, value)
    compilation_cache.reset_cache()  # an earlier test may have found the cache switched off
    try:
        yield env
    finally:
        for name, value in saved.items():
            jax.config.update(name, value)
        compilation_cache.reset_cache()
        if saved_flags is None:
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = saved_flags


@pytest.fixture(scope="module")
def straight(spawn_env, tmp_path_factory) -> Path:
    """The uninterrupted run every stopped one must end equal to (it fills the cache)."""
    run = tmp_path_factory.mktemp("straight") / "run"
    assert main(["train", *TOY, "--tensorboard", "--run-dir", str(run)]) == 0
    return run


def _spawn(env: dict[str, str], run_dir: Path, pause: str) -> subprocess.Popen:
    """``hybridmarl train`` in its own process, paused at ``pause`` (returns once it is there)."""
    cmd = [sys.executable, "-m", "hybridmarl.cli", "train", *TOY, "--run-dir", str(run_dir)]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**env, PAUSE_ENV: pause},
    )
    assert proc.stderr is not None
    for line in proc.stderr:
        if line.startswith("hybridmarl: paused at"):
            return proc
    proc.wait()
    raise AssertionError(
        f"the training process ended (rc {proc.returncode}) before pausing at {pause}"
    )


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


def _assert_same_run(run: Path, straight: Path) -> None:
    """``run`` ended exactly as ``straight``: the same final arrays, the same logs, and nothing
    left behind (lock, partial writes)."""
    a, _ = load_checkpoint(list_checkpoints(straight)[-1])
    b, _ = load_checkpoint(list_checkpoints(run)[-1])
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for log in ("train.csv", "episodes.csv"):
        assert _rows(run / log) == _rows(straight / log), log
    assert not (run / LOCK_NAME).exists() and not any(
        p.name.startswith(".") for p in (run / "checkpoints").iterdir()
    )


def test_ctrl_c_saves_a_checkpoint_and_says_how_to_resume(spawn_env, straight, tmp_path, capsys):
    run = tmp_path / "run"
    proc = _spawn(spawn_env, run, "chunk:3")
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, (out, err)
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert (
        last.startswith("hybridmarl: interrupted at")
        and f"hybridmarl train --run-dir {run} --resume" in last
    ), err
    # The checkpoint is the state after the chunk it stopped in, with the logs written up to it.
    newest = list_checkpoints(run)[-1]
    _, meta = load_checkpoint(newest)
    assert (
        meta["iterations"] == 3 and meta["log_rows"]["train"] == len(_rows(run / "train.csv")) == 3
    )
    assert not (run / LOCK_NAME).exists() and not any(
        p.name.startswith(".") for p in (run / "checkpoints").iterdir()
    )
    assert main(["train", "--run-dir", str(run), "--resume", "--no-progress"]) == 0
    assert "resumed" in capsys.readouterr().out
    _assert_same_run(run, straight)


@pytest.mark.parametrize("pause", ["chunk:3", "checkpoint:2", "evaluation"])
def test_a_run_killed_anywhere_resumes_exactly(spawn_env, straight, tmp_path, pause):
    run = tmp_path / "run"
    proc = _spawn(spawn_env, run, pause)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert (run / LOCK_NAME).exists()  # a killed process leaves its lock file behind
    assert main(["train", "--run-dir", str(run), "--resume", "--no-progress"]) == 0
    _assert_same_run(run, straight)


def _shown_scalars(tb_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """The scalars TensorBoard shows of the event files in ``tb_dir``: (step, value) per tag,
    read in file-name (creation) order, where a purge marker (a START session log at step s)
    hides the events at step s or later read before it (TensorBoard's rule for a restarted run)."""
    from tensorboardX.proto import event_pb2

    Event, SessionLog = event_pb2.Event, event_pb2.SessionLog  # pyright: ignore[reportAttributeAccessIssue]  (generated)
    shown: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(tb_dir.glob("events.out.tfevents.*")):
        data, at = path.read_bytes(), 0
        while at < len(data):  # TFRecord: length (8 bytes), its CRC (4), the record, its CRC (4)
            (size,) = struct.unpack("<Q", data[at : at + 8])
            event = Event.FromString(data[at + 12 : at + 12 + size])
            at += 12 + size + 4
            if event.HasField("session_log") and event.session_log.status == SessionLog.START:
                shown = {
                    tag: [p for p in points if p[0] < event.step] for tag, points in shown.items()
                }
            for value in event.summary.value:
                if value.HasField("simple_value"):
                    shown.setdefault(value.tag, []).append((event.step, value.simple_value))
    return shown


def test_tensorboard_after_resume_shows_the_run_as_if_it_never_stopped(straight, tmp_path):
    # A run stopped after its checkpoint at 4 episodes, its event file holding all that followed.
    run = tmp_path / "run"
    shutil.copytree(straight, run)
    shutil.rmtree(list_checkpoints(run)[-1])
    (run / "eval.json").unlink()
    step = load_checkpoint(list_checkpoints(run)[-1])[1]["step"]
    assert 0 < step < 8
    assert main(["train", "--run-dir", str(run), "--resume", "--no-progress"]) == 0
    straight_shown, shown = _shown_scalars(straight / "tb"), _shown_scalars(run / "tb")
    assert set(shown) == set(straight_shown) and any(tag.startswith("eval/") for tag in shown)
    for tag, points in straight_shown.items():
        # Timings differ between runs: compare only their steps.
        timing = tag.rsplit("/", 1)[-1] in TIMING
        resumed_below, resumed_at, resumed_above = _around(shown[tag], step, timing)
        straight_below, straight_at, straight_above = _around(points, step, timing)
        # Before the checkpoint's step: the first attempt's events, untouched.
        assert resumed_below == straight_below, tag
        # At it: all of the uninterrupted run's (the rows after the checkpoint may show twice).
        assert set(straight_at) <= set(resumed_at), tag
        # After it: only the resumed run's, one per row, equal to the uninterrupted run's.
        assert resumed_above == straight_above, tag


def _around(
    points: list[tuple[int, float]], step: int, steps_only: bool
) -> tuple[list, list, list]:
    """``points`` below, at and above ``step`` (their steps only, with ``steps_only``)."""
    kept = [(s, s if steps_only else v) for s, v in points]
    return (
        [p for p in kept if p[0] < step],
        [p for p in kept if p[0] == step],
        [p for p in kept if p[0] > step],
    )
