"""Run directories that behave: the lock (a second process is refused, a dead one's lock is
taken over), --resume on a directory that is not a run, a resume that would change training,
every invalid number refused before any work starts, and the size guard of long battle series.
(A killed run's resume -- leftovers removed, logs as if it never stopped -- is tested with the
exact resume in test_data.py, reusing its training runs.)"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hybridmarl.cli.main import main
from hybridmarl.training.checkpoint import (
    CheckpointError,
    save_checkpoint,
)
from hybridmarl.training.rundir import LOCK_NAME, RunInUse, RunLock

SRC = str(Path(__file__).resolve().parents[2] / "src")


def _toy(run_dir: Path, **changes):
    from hybridmarl.algos.hybrid import PRESETS

    return PRESETS["toy"]("combat").replace(
        scenario="m3v3", run_dir=str(run_dir), progress=False, **changes
    )


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def _holder(lock_dir: Path) -> subprocess.Popen:
    """Another process that takes the run's lock and keeps it until killed."""
    code = (
        "import sys, time; from pathlib import Path; from hybridmarl.training.rundir import RunLock; "
        "RunLock(Path(sys.argv[1])).acquire(); print('locked', flush=True); time.sleep(600)"
    )
    env = {**os.environ, "PYTHONPATH": SRC}
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(lock_dir)], stdout=subprocess.PIPE, text=True, env=env
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
    return proc


def test_a_second_process_is_refused_and_a_dead_ones_lock_taken_over(tmp_path, capsys):
    run = tmp_path / "run"
    holder = _holder(run)
    try:
        argv = [
            "train",
            "--preset",
            "toy",
            "--scenario",
            "m3v3",
            "--no-progress",
            "--run-dir",
            str(run),
        ]
        assert main(argv) == 2
        line = _one_line(capsys)
        assert f"is in use by process {holder.pid}" in line and LOCK_NAME in line, line
        assert sorted(p.name for p in run.iterdir()) == [LOCK_NAME]  # refused before any work
        with pytest.raises(RunInUse):
            RunLock(run).acquire()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    # The holder died without cleaning up: its lock file (and PID) remain, the kernel's lock not.
    assert json.loads((run / LOCK_NAME).read_text())["pid"] == holder.pid
    lock = RunLock(run)
    lock.acquire()
    assert f"taking over the lock of process {holder.pid}" in capsys.readouterr().out
    assert json.loads((run / LOCK_NAME).read_text())["pid"] == os.getpid()
    lock.release()
    assert not (run / LOCK_NAME).exists()


def test_resume_on_a_directory_that_is_not_a_run(tmp_path, capsys):
    typo = tmp_path / "rnus"
    assert (
        main(["train", "--preset", "toy", "--no-progress", "--run-dir", str(typo), "--resume"]) == 2
    )
    line = _one_line(capsys)
    assert str(typo) in line and "no such run directory" in line, line
    assert not typo.exists()
    (tmp_path / "empty").mkdir()
    assert (
        main(
            [
                "train",
                "--preset",
                "toy",
                "--no-progress",
                "--run-dir",
                str(tmp_path / "empty"),
                "--resume",
            ]
        )
        == 2
    )
    assert "not a run directory" in _one_line(capsys)
    assert main(["eval", "--run-dir", str(typo)]) == 2
    assert "no such run directory" in _one_line(capsys)


def test_a_resume_that_changes_training_is_refused(tmp_path, capsys):
    from hybridmarl.training.config import config_to_dict
    from hybridmarl.training.run import Run

    run = tmp_path / "run"
    cfg = _toy(run)
    save_checkpoint(
        run,
        4,
        {"x": np.zeros(1, np.float32)},
        {"config": config_to_dict(cfg), "task": cfg.task_spec().to_dict()},
    )
    for field, value in (
        ("critic_lr", 0.5),
        ("seed", 3),
        ("actor_hidden", (8, 8)),
        ("num_envs", 8),
        ("enemy", "attack-closest"),
    ):
        with pytest.raises(
            CheckpointError, match=rf"trained with {field} = .*cannot resume it with {field} = "
        ):
            Run("hybrid", cfg.replace(resume=True, **{field: value}))
    # Budgets, cadences and logging may change.
    with Run(
        "hybrid",
        cfg.replace(
            resume=True, total_episodes=50, eval_every=5, time_limit_min=1.0, keep_checkpoints=1
        ),
    ):
        pass
    assert not (run / LOCK_NAME).exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "--num-envs", "0"], "--num-envs must be at least 1, got 0"),
        (["train", "--max-turns", "0"], "--max-turns must be at least 1, got 0"),
        (["train", "--gamma", "2"], "--gamma must be a number in [0, 1), got 2.0"),
        (["train", "--gamma", "1"], "--gamma must be a number in [0, 1), got 1.0"),
        (["train", "--seed", "-1"], "--seed must be an integer in [0, 4294967295], got -1"),
        (["train", "--checkpoint-every", "0"], "--checkpoint-every must be at least 1, got 0"),
        (["train", "--e-update", "0"], "--e-update must be at least 1, got 0"),
        (["train", "--actor-lr", "nan"], "--actor-lr must be a finite number > 0, got nan"),
        (["train", "--critic-lr", "inf"], "--critic-lr must be a finite number > 0, got inf"),
        (
            ["train", "--actor-hidden", "16", "0"],
            "--actor-hidden must be a non-empty list of layer sizes",
        ),
        (["train", "--total-episodes", "-5"], "--total-episodes must be at least 1, got -5"),
        (
            ["train", "--algo", "dqfd", "--eps-start", "1.5"],
            "--eps-start must be a number in [0, 1], got 1.5",
        ),
        (["train", "--algo", "bc", "--bc-steps", "0"], "--bc-steps must be at least 1, got 0"),
        (
            ["train", "--env", "traffic_junction", "--p-arrive", "5"],
            "--p-arrive must be a number in [0, 1], got 5.0",
        ),
        (
            ["demos", "collect", "--num-envs", "0", "--n", "100"],
            "--num-envs must be at least 1, got 0",
        ),
        (["demos", "collect", "--gamma", "-0.5"], "--gamma must be a number in [0, 1), got -0.5"),
        (
            ["eval", "--script", "attack-closest", "--env", "traffic_junction", "--p-arrive", "5"],
            "--p-arrive must be a number in [0, 1], got 5.0",
        ),
        (
            ["eval", "--script", "attack-closest", "--seed", "-1"],
            "--seed must be an integer in [0, 4294967295], got -1",
        ),
        (["battle", "--stalemate-limit", "-1"], "--stalemate-limit must be at least 0, got -1"),
        (["battle", "--max-turns", "0"], "--max-turns must be at least 1, got 0"),
        (["battle", "--batch-size", "0"], "--batch-size must be at least 1, got 0"),
        (["trace", "--index", "-1"], "--index must be at least 0, got -1"),
        (["quickstart", "--total-episodes", "0"], "--total-episodes must be at least 1, got 0"),
        (["quickstart", "--seed", "-1"], "--seed must be an integer in [0, 4294967295], got -1"),
    ],
)
def test_invalid_numbers_are_refused_before_any_work(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    extra = {
        "train": ["--preset", "toy", "--no-progress", "--run-dir", str(out)],
        "demos": ["--out", str(out)],
        "quickstart": ["--run-dir", str(out)],
    }
    t0 = time.perf_counter()
    rc = main([*argv, *extra.get(argv[0], [])])
    assert rc == 2
    assert (
        time.perf_counter() - t0 < 30
    )  # refused at once, not after a training run or a battle series
    if message is not None:
        assert message in _one_line(capsys)
    assert not out.exists()


def test_out_pointing_at_a_directory_is_refused_before_the_games(tmp_path, capsys):
    for argv in (
        ["battle", "--n", "4", "--no-progress"],
        ["eval", "--script", "attack-closest", "--n", "4"],
        ["demos", "collect", "--n", "10"],
    ):
        assert main([*argv, "--out", str(tmp_path)]) == 2
        line = _one_line(capsys)
        assert "--out" in line and "is a directory" in line, line


def test_size_guard_answers_at_once(tmp_path, capsys):
    t0 = time.perf_counter()
    assert (
        main(["battle", "--scenario", "m5v5", "--n", "10000000", "--out", str(tmp_path / "r.json")])
        == 2
    )
    assert time.perf_counter() - t0 < 2.0
    line = _one_line(capsys)
    assert (
        "--n 10000000 battles of 10 units" in line
        and "would take about" in line
        and "--yes" in line
        and "GB" in line
    ), line
    assert not (tmp_path / "r.json").exists()
    t0 = time.perf_counter()
    assert main(["trace", "--index", "100000000"]) == 2
    assert time.perf_counter() - t0 < 2.0
    assert "--index 100000000" in _one_line(capsys)


def test_long_series_are_played_in_chunks(tmp_path, capsys, monkeypatch):
    """A series longer than a chunk: the same document as one chunk of that size would give
    for its first chunk, and a summary over every battle."""
    import hybridmarl.cli.engine as cli_engine

    one = tmp_path / "one.json"
    assert (
        main(
            [
                "battle",
                "--scenario",
                "m2v2",
                "--n",
                "3",
                "--no-progress",
                "--engine",
                "native",
                "--out",
                str(one),
            ]
        )
        == 0
    )
    monkeypatch.setattr(cli_engine, "CHUNK_UNITS", 12)  # 3 battles of m2v2 a chunk
    two = tmp_path / "two.json"
    assert (
        main(
            [
                "battle",
                "--scenario",
                "m2v2",
                "--n",
                "7",
                "--no-progress",
                "--engine",
                "native",
                "--swap",
                "--out",
                str(two),
            ]
        )
        == 0
    )
    a, b = json.loads(one.read_text()), json.loads(two.read_text())
    assert (
        b["results"][:3] == a["results"]
        and len(b["results"]) == 7
        and len(b["swapped"]["results"]) == 7
    )
    assert (
        b["summary"]["battles"] == 7
        and b["swapped"]["summary"]["battles"] == 7
        and b["setting"] == "sparcraft"
    )
    wins = sum(r["winner"] == 0 for r in b["results"])
    assert b["summary"]["p0_wins"] == wins
    monkeypatch.setattr(cli_engine, "CONFIRM_UNIT_BATTLES", 10)  # --yes passes the guard
    assert (
        main(["battle", "--scenario", "m2v2", "--n", "4", "--no-progress", "--engine", "native"])
        == 2
    )
    assert (
        main(
            [
                "battle",
                "--scenario",
                "m2v2",
                "--n",
                "4",
                "--no-progress",
                "--engine",
                "native",
                "--yes",
            ]
        )
        == 0
    )


def test_every_preset_keeps_the_rules():
    """The number rules refuse nothing a preset (or a config's defaults) sets."""
    from hybridmarl.algos import ALGOS, algo_module
    from hybridmarl.validate import check_config

    for algo in ALGOS:
        mod = algo_module(algo)
        for make in mod.PRESETS.values():
            for env in ("combat", "traffic_junction"):
                check_config(make(env))
        check_config(type(mod.PRESETS["toy"]("combat"))())


def test_nan_counters_survive_a_checkpoint_as_json(tmp_path):
    """A counter that is NaN when a checkpoint is saved (the critic's loss before its first fit,
    in the "w/o D" presets) is written as JSON null, read back by the strict reader, and
    restored as NaN, so the run resumes."""
    from hybridmarl.algos.hybrid.train import HybridState
    from hybridmarl.training.checkpoint import find_checkpoint, load_checkpoint

    def state() -> HybridState:
        return HybridState(
            pool=None, key=None, assembler=None, actor=None, critic=None, clone=None, buffer=None
        )  # type: ignore[arg-type]

    saved = state()
    saved.episodes, saved.critic_loss, saved.demo_stats = (
        40,
        float("nan"),
        {"won": 0.5, "R": float("nan")},
    )
    save_checkpoint(tmp_path, 40, {"x": np.zeros(1, np.float32)}, saved.meta())
    text = (tmp_path / "checkpoints" / "ckpt_000000040" / "meta.json").read_text()
    assert "NaN" not in text and '"critic_loss": null' in text
    _, meta = load_checkpoint(find_checkpoint(tmp_path, None))
    restored = state()
    restored.restore_counters(meta)
    assert restored.episodes == 40 and np.isnan(restored.critic_loss)
    assert restored.demo_stats["won"] == 0.5 and np.isnan(restored.demo_stats["R"])
