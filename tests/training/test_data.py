"""Demonstration datasets (record, save/load round trip, restart from a recorded state,
validation errors), the replay buffer and episode assembly, checkpoints (round trip, pruning,
atomicity) and exact resume of a training run."""

from __future__ import annotations

import csv
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from safetensors.numpy import save_file

from hybridmarl.cli.main import main
from hybridmarl.training import checkpoint as C
from hybridmarl.training import demos as D
from hybridmarl.training.losses import discounted_returns
from hybridmarl.training.rollout import EpisodeAssembler, ReplayBuffer
from hybridmarl.training.task import TaskSpec, flatten_named, make_task, unflatten_named

TJ = TaskSpec(env="traffic_junction")


@pytest.fixture(scope="module")
def tj_dataset():
    return D.collect(TJ, "always-gas", 90, seed=3, num_envs=4)


def test_collect_and_round_trip(tj_dataset, tmp_path):
    ds = tj_dataset
    assert ds.size == 90
    a = ds.arrays
    assert a["obs"].shape == (90, 10, 259) and a["legal"].shape == (90, 10, 2)
    assert a["actions"].dtype == np.int32 and a["active"].dtype == np.bool_
    # TJ episodes are 40 steps: records 0..39 are episode 0, t = 0..39.
    np.testing.assert_array_equal(a["t"][:40], np.arange(40))
    assert a["episode"][0] == 0 and a["episode"][40] == 1
    # always-gas: gas exactly for active cars; returns match Eq. 1 on the recorded rewards.
    np.testing.assert_array_equal(a["actions"], a["active"].astype(np.int32))
    np.testing.assert_allclose(
        a["return"][:40], discounted_returns(a["reward"][:40], 0.995), rtol=1e-5
    )
    path = D.save_dataset(ds, tmp_path / "d.safetensors")
    back = D.load_dataset(path, expect=make_task(TJ))
    assert back.meta == json.loads(json.dumps(ds.meta))
    for k, v in ds.arrays.items():
        np.testing.assert_array_equal(back.arrays[k], v)


def test_restart_from_a_recorded_state(tj_dataset):
    """The recorded state reproduces the recorded next observation when stepped."""
    task = make_task(TJ)
    ds = tj_dataset
    s5 = D.state_at(ds, 5, task)
    np.testing.assert_allclose(np.asarray(task.observe(s5)), ds.arrays["obs"][5])
    s6 = D.state_at(ds, 6, task)
    assert int(s6.t) == 6 and int(s5.t) == 5
    batch = D.state_at(ds, np.arange(3), task)
    assert batch.pos.shape == (3, 10)


def _write(tmp_path, ds, name="bad.safetensors"):
    p = tmp_path / name
    save_file(
        {k: np.ascontiguousarray(v) for k, v in ds.arrays.items()},
        str(p),
        metadata={"hybridmarl": json.dumps(ds.meta)},
    )
    return p


def _variant(ds, arrays=None, meta=None):
    return D.Dataset(arrays={**ds.arrays, **(arrays or {})}, meta={**ds.meta, **(meta or {})})


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda ds: _variant(ds, meta={"version": 99}), "dataset version 99 is not supported"),
        (lambda ds: _variant(ds, meta={"format": "other"}), "expected 'hybridmarl-demos'"),
        (
            lambda ds: _variant(ds, arrays={"actions": ds.arrays["actions"].astype(np.int64)}),
            "array 'actions' has dtype int64, expected int32",
        ),
        (
            lambda ds: _variant(ds, arrays={"obs": ds.arrays["obs"][:, :, :5]}),
            "array 'obs' has shape (90, 10, 5), expected (90, 10, 259)",
        ),
        (
            lambda ds: _variant(
                ds,
                arrays={
                    "actions": np.where(
                        np.arange(90)[:, None] == 7, 5, ds.arrays["actions"]
                    ).astype(np.int32)
                },
            ),
            "action 5 out of range 0..1 at record 7, agent 0",
        ),
        (
            lambda ds: _variant(ds, arrays={"actions": np.ones_like(ds.arrays["actions"])}),
            "is illegal under the record's mask",
        ),
        (
            lambda ds: _variant(ds, arrays={"episode": ds.arrays["episode"][::-1].copy()}),
            "non-decreasing",
        ),
    ],
)
def test_validation_errors(tj_dataset, tmp_path, change, message):
    p = _write(tmp_path, change(tj_dataset))
    with pytest.raises(D.DatasetError) as e:
        D.load_dataset(p)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_validation_missing_and_unreadable(tj_dataset, tmp_path, capsys):
    arrays = {k: v for k, v in tj_dataset.arrays.items() if k != "legal"}
    p = _write(tmp_path, D.Dataset(arrays=arrays, meta=tj_dataset.meta))
    with pytest.raises(D.DatasetError, match="missing array 'legal'"):
        D.load_dataset(p)
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"not a file at all")
    with pytest.raises(D.DatasetError, match="not a safetensors file"):
        D.load_dataset(junk)
    with pytest.raises(D.DatasetError, match="no such dataset file"):
        D.load_dataset(tmp_path / "nope.safetensors")
    # The CLI: one line, exit code 2.
    assert main(["demos", "info", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing array 'legal'" in err[0]
    # Shape mismatch against the task it is used for.
    good = D.save_dataset(tj_dataset, tmp_path / "good.safetensors")
    with pytest.raises(D.DatasetError, match="recorded for 10 agents"):
        D.load_dataset(good, expect=make_task(TaskSpec(env="traffic_junction", num_cars=4)))


def test_demos_cli_collect_and_info(tmp_path, capsys):
    out = tmp_path / "tj.safetensors"
    assert (
        main(
            [
                "demos",
                "collect",
                "--env",
                "traffic_junction",
                "--demonstrator",
                "always-gas",
                "--n",
                "90",
                "--seed",
                "3",
                "--num-envs",
                "4",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert main(["demos", "info", str(out)]) == 0
    info = json.loads(capsys.readouterr().out.split("\n", 1)[1])
    assert info["observations"] == 90 and info["episodes"] == 3
    assert (
        main(
            [
                "demos",
                "collect",
                "--env",
                "traffic_junction",
                "--demonstrator",
                "nope",
                "--out",
                str(tmp_path / "x.safetensors"),
            ]
        )
        == 2
    )


def test_bc_fits_the_demonstrator(tj_dataset):
    from hybridmarl.training import networks as nets

    task = make_task(TJ)
    rows = D.bc_rows(tj_dataset)
    assert rows[0].shape[0] == int((tj_dataset.arrays["legal"].sum(-1) >= 2).sum())
    mod = nets.actor_module(task.num_actions, (16, 16, 16))
    actor = nets.init_net(mod, jax.random.key(0), task.obs_dim, nets.make_optimizer("adam", 1e-2))
    actor, losses = D.fit_bc(actor, mod, ("adam", 1e-2), rows, jax.random.key(1), 40, 64)
    assert losses[-5:].mean() < losses[:5].mean()
    assert D.bc_accuracy(actor, mod, rows) == 1.0  # always-gas is trivial to imitate


def test_episode_assembler_and_buffer():
    asm = EpisodeAssembler(num_envs=2, gamma=0.5)
    # Slot 0 finishes after 2 steps, slot 1 after 3 (split over two blocks).
    f1 = {"state.x": np.asarray([[1, 10], [2, 20]])}
    r1 = np.asarray([[1.0, 0.0], [2.0, 0.0]])
    d1 = np.asarray([[False, False], [True, False]])
    rows, ret, stats = asm.add_fields(f1, r1, d1, {"won": np.asarray([[0, 0], [1, 0]])})
    np.testing.assert_array_equal(rows["state.x"], [1, 2])
    np.testing.assert_allclose(ret, [2.0, 2.0])  # 1 + 0.5 * 2, 2
    assert stats["won"].tolist() == [1.0] and stats["return"].tolist() == [3.0]
    saved = asm.to_arrays()
    asm2 = EpisodeAssembler(num_envs=2, gamma=0.5)
    asm2.load_arrays(saved)
    f2 = {"state.x": np.asarray([[3, 30]])}
    rows, ret, _ = asm2.add_fields(
        f2, np.asarray([[0.0, 4.0]]), np.asarray([[False, True]]), {"won": np.zeros((1, 2))}
    )
    np.testing.assert_array_equal(rows["state.x"], [10, 20, 30])
    np.testing.assert_allclose(ret, [1.0, 2.0, 4.0])
    np.testing.assert_array_equal(rows["t"], [0, 1, 2])

    buf = ReplayBuffer(4, {"x": jnp.zeros((), jnp.int32)})
    buf.add({"state.x": np.arange(3)}, np.arange(3, dtype=np.float32))
    buf.add({"x": np.arange(3, 6)}, np.arange(3, 6, dtype=np.float32))
    assert buf.size == 4 and buf.ptr == 2
    np.testing.assert_array_equal(buf.states["x"], [4, 5, 2, 3])  # FIFO: 0 and 1 dropped
    buf2 = ReplayBuffer(4, {"x": jnp.zeros((), jnp.int32)})
    buf2.load_arrays(buf.to_arrays())
    tree, returns, size = buf2.device_arrays()
    np.testing.assert_array_equal(np.asarray(tree["x"]), [4, 5, 2, 3]) and int(size) == 4


def _assemble_row_by_row(blocks, num_envs, gamma):
    """The assembler's contract written out one step at a time: slot ``s``'s steps pile up
    until ``done``; finished episodes come out in order of (step, slot)."""
    pending: list[list[tuple[dict, float]]] = [[] for _ in range(num_envs)]
    rows, returns, wins, finished = [], [], [], 0
    for fields, reward, done, won in blocks:
        for t in range(reward.shape[0]):
            for s in range(num_envs):
                pending[s].append(({k: v[t, s] for k, v in fields.items()}, float(reward[t, s])))
                if done[t, s]:
                    acc, rets = 0.0, []
                    for _, r in reversed(pending[s]):
                        acc = r + gamma * acc
                        rets.append(acc)
                    returns.extend(reversed(rets))
                    rows.extend(
                        {**f, "t": i, "episode_key": finished}
                        for i, (f, _) in enumerate(pending[s])
                    )
                    wins.append(won[t, s])
                    finished += 1
                    pending[s] = []
    return rows, np.asarray(returns, np.float32), wins


def test_episode_assembler_matches_row_by_row_reference_across_checkpoints():
    rng = np.random.default_rng(0)
    for _ in range(60):
        b, k, p = int(rng.integers(1, 6)), int(rng.integers(1, 6)), float(rng.uniform(0.05, 0.6))
        blocks = [
            (
                {
                    "state.x": rng.integers(0, 100, (k, b, 3)).astype(np.int16),
                    "obs": rng.normal(size=(k, b)).astype(np.float32),
                },
                rng.normal(size=(k, b)).astype(np.float32),
                rng.uniform(size=(k, b)) < p,
                rng.integers(0, 2, (k, b)),
            )
            for _ in range(int(rng.integers(1, 8)))
        ]
        asm = EpisodeAssembler(b, 0.9)
        got_rows: dict[str, list] = {"state.x": [], "obs": [], "t": [], "episode_key": []}
        got_returns, got_wins = [], []
        for fields, reward, done, won in blocks:
            out, ret, stats = asm.add_fields(fields, reward, done, {"won": won})
            for name in got_rows:
                got_rows[name].extend(out[name])
            got_returns.extend(ret)
            got_wins.extend(stats["won"])
            if rng.uniform() < 0.4:  # a checkpoint between blocks changes nothing
                resumed = EpisodeAssembler(b, 0.9)
                resumed.load_arrays(asm.to_arrays())
                asm = resumed
        rows, returns, wins = _assemble_row_by_row(blocks, b, 0.9)
        for name in got_rows:
            np.testing.assert_array_equal(
                np.asarray(got_rows[name]), np.asarray([r[name] for r in rows])
            )
        np.testing.assert_allclose(got_returns, returns, rtol=1e-6)
        assert got_wins == wins


def test_checkpoint_arrays_get_the_array_file_bound_not_the_small_file_one(tmp_path, monkeypatch):
    """A DQfD checkpoint carries its replay buffer (about 290 MiB at m30v30), more than the
    bound on small user files (configs, states); it must still load, and a file beyond the
    array bound is refused in one line."""
    import hybridmarl.io as io

    path = C.save_checkpoint(tmp_path, 1, {"buffer": np.zeros(4096, np.float32)}, {"note": 1})
    monkeypatch.setattr(io, "MAX_USER_FILE_BYTES", 1024)  # the file is 16 KiB: over this bound
    arrays, _ = C.load_checkpoint(path)
    assert arrays["buffer"].shape == (4096,)
    # A policy reads only its own arrays, not the buffer beside them.
    C.save_checkpoint(
        tmp_path,
        2,
        {"buffer.rows": np.zeros(8, np.float32), "actor.params.w": np.ones(2, np.float32)},
        {"note": 2},
    )
    only, _ = C.load_checkpoint(C.latest_checkpoint(tmp_path), prefixes=("actor", "actor_average"))
    assert list(only) == ["actor.params.w"]
    monkeypatch.setattr(io, "MAX_ARRAY_FILE_BYTES", 1024)
    with pytest.raises(C.CheckpointError, match=r"checkpoint arrays .* MiB \(at most 0 MiB\)"):
        C.load_checkpoint(path)


def test_checkpoint_round_trip_and_pruning(tmp_path):
    tree = {
        "w": jnp.arange(6.0).reshape(2, 3),
        "flag": jnp.asarray([True, False]),
        "key": jax.random.key(7),
        "n": jnp.asarray(3, jnp.int32),
    }
    for step in (1, 2, 3, 4):
        C.save_checkpoint(
            tmp_path, step, C.prefixed(flatten_named(tree), "t"), {"note": step}, keep=2
        )
    ck = C.list_checkpoints(tmp_path)
    assert [p.name for p in ck] == ["ckpt_000000003", "ckpt_000000004"]
    assert not [p for p in (tmp_path / "checkpoints").iterdir() if p.name.startswith(".tmp")]
    arrays, meta = C.load_checkpoint(ck[-1])
    assert meta["note"] == 4 and meta["step"] == 4
    back = unflatten_named(tree, C.subtree(arrays, "t"))
    np.testing.assert_array_equal(back["w"], tree["w"])
    assert back["flag"].dtype == jnp.bool_
    assert jnp.array_equal(jax.random.key_data(back["key"]), jax.random.key_data(tree["key"]))
    # A directory without meta.json (a crash mid-write under a final name) is ignored.
    (tmp_path / "checkpoints" / "ckpt_000000009").mkdir()
    assert C.latest_checkpoint(tmp_path).name == "ckpt_000000004"
    with pytest.raises(C.CheckpointError, match="meta.json' not found"):
        C.load_checkpoint(tmp_path / "checkpoints" / "ckpt_000000009")
    with pytest.raises(ValueError, match="shape"):
        unflatten_named({"w": jnp.zeros((3, 3))}, {"w": np.zeros((2, 3), np.float32)})
    # A named checkpoint ("best") is replaced whole, never pruned, listed or resumed from.
    with pytest.raises(C.CheckpointError, match="no best checkpoint"):
        C.find_checkpoint(tmp_path, "best")
    for step in (5, 6):
        C.save_checkpoint(
            tmp_path, step, {"v": np.full(2, step, np.float32)}, {"note": step}, keep=2, name=C.BEST
        )
    C.save_checkpoint(tmp_path, 7, C.prefixed(flatten_named(tree), "t"), {"note": 7}, keep=2)
    best = C.find_checkpoint(tmp_path, "best")
    arrays, meta = C.load_checkpoint(best)
    assert best.name == "best" and meta["step"] == 6 and arrays["v"].tolist() == [6.0, 6.0]
    assert [p.name for p in C.list_checkpoints(tmp_path)] == ["ckpt_000000004", "ckpt_000000007"]
    assert C.latest_checkpoint(tmp_path).name == "ckpt_000000007"
    assert not [p for p in (tmp_path / "checkpoints").iterdir() if p.name.startswith(".")]


def test_weight_average_is_the_running_mean():
    from hybridmarl.algos.hybrid.train import _running_mean

    snaps = [
        {"params": {"w": jnp.asarray([x, 2 * x])}, "batch_stats": {"m": jnp.asarray(-x)}}
        for x in (1.0, 2.0, 3.0, 6.0)
    ]
    avg = snaps[0]
    for n, s in enumerate(snaps[1:], start=2):
        avg = _running_mean(avg, s, jnp.asarray(n, jnp.float32))
    np.testing.assert_allclose(avg["params"]["w"], [3.0, 6.0])
    np.testing.assert_allclose(avg["batch_stats"]["m"], -3.0)


def test_periodic_eval_keeps_the_best_on_selection_states(tmp_path):
    """--eval-every/--keep-best: due every k episodes, evaluated on the selection seed (never the
    final evaluation's), a row per evaluation, ``best`` replaced only on improvement (W, then R),
    and the comparison survives a resume through checkpoint metadata."""
    from hybridmarl.algos.hybrid import HybridConfig
    from hybridmarl.training.config import (
        FINAL_EVAL_SEED,
        SELECT_EVAL_SEED,
        PeriodicEval,
        selection_key,
    )
    from hybridmarl.training.logger import RunLogger

    assert SELECT_EVAL_SEED != FINAL_EVAL_SEED
    assert (
        selection_key({"W": 0.5, "R": 0.1})
        > selection_key({"W": 0.5, "R": 0.0})
        > selection_key({"W": 0.4, "R": 0.9})
    )
    assert selection_key({"failure_rate": 0.2, "R": -5.0}) > selection_key(
        {"failure_rate": 0.3, "R": 0.0}
    )
    cfg = HybridConfig().replace(eval_every=10)
    log = RunLogger(tmp_path, tensorboard=False)
    scores = iter([(0.2, 0.0), (0.5, -0.1), (0.5, -0.2), (0.5, 0.3)])
    seeds: list[int] = []

    def evaluate(offset):
        seeds.append(offset)
        w, r = next(scores)
        return {"n": 4, "W": w, "R": r, "W_ci95": [0.0, 1.0]}

    def actor_arrays(e):
        return lambda: {"actor.w": np.full(3, e, np.float32)}

    pe = PeriodicEval(cfg, tmp_path, log, 0)
    assert pe.maybe_run(9, evaluate, actor_arrays(9), {}) is None  # not due yet
    for e in (10, 24, 31):
        assert pe.maybe_run(e, evaluate, actor_arrays(e), {"episodes": e}) is not None
    assert seeds == [SELECT_EVAL_SEED] * 3
    arrays, meta = C.load_checkpoint(C.find_checkpoint(tmp_path, "best"))
    assert (
        meta["episodes"] == 24
        and arrays["actor.w"].tolist() == [24.0] * 3
        and meta["selection"]["W"] == 0.5
    )
    # Resume from a checkpoint written at episode 31: the same best, next evaluation at 40.
    pe2 = PeriodicEval(cfg, tmp_path, log, 0)
    pe2.resume(pe.meta(), 31)
    assert pe2.maybe_run(39, evaluate, actor_arrays(39), {}) is None
    assert (
        pe2.maybe_run(40, evaluate, actor_arrays(40), {})["R"] == 0.3
    )  # (0.5, 0.3) beats (0.5, -0.1)
    assert C.load_checkpoint(C.find_checkpoint(tmp_path, "best"))[1]["episodes"] == 40
    with open(tmp_path / "evals.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(int(r["episodes"]), int(r["best"])) for r in rows] == [
        (10, 1),
        (24, 1),
        (31, 0),
        (40, 1),
    ]
    # --no-keep-best: evaluations are logged, nothing is saved.
    off = PeriodicEval(
        HybridConfig().replace(eval_every=10, keep_best=False),
        tmp_path / "off",
        RunLogger(tmp_path / "off", tensorboard=False),
        0,
    )
    scores = iter([(0.9, 0.0)])
    off.maybe_run(10, evaluate, actor_arrays(10), {})
    assert off.meta() == {} and not (tmp_path / "off" / "checkpoints").exists()


@pytest.mark.parametrize("average", [False, True])
def test_exact_resume(tj_dataset, tmp_path, average):
    """N episodes straight == N/2 episodes, stop, --resume, N/2 more (CPU): identical state.
    (The demonstrator is a dataset, i.e. its behavioural clone, as in test_algos_cli.) Without
    the weight average the periodic evaluation and its best policy resume too; with it (and the
    cross-entropy actor target) the average is checkpointed, resumed and exported."""
    from hybridmarl.algos.hybrid import PRESETS, train
    from hybridmarl.training.checkpoint import latest_checkpoint, load_checkpoint
    from hybridmarl.training.evaluate import load_policy
    from hybridmarl.training.run import TrainResult

    data = D.save_dataset(tj_dataset, tmp_path / "tj.safetensors")
    base = PRESETS["toy"]("traffic_junction").replace(
        demonstrator=str(data),
        progress=False,
        checkpoint_every=4,
        actor_target="best" if average else "advantage",
        eval_every=0 if average else 3,  # periodic evaluation and the best policy resume too
        actor_average_from=2 if average else None,  # and so does the actor's weight average
        actor_lr_decay_from=3 if average else None,  # and the actor's learning-rate schedule
    )
    res = train(base.replace(total_episodes=8, run_dir=str(tmp_path / "straight")))
    assert isinstance(res, TrainResult) and res.run_dir == tmp_path / "straight"
    assert res.evaluation == json.loads((tmp_path / "straight" / "eval.json").read_text())
    train(base.replace(total_episodes=4, run_dir=str(tmp_path / "split")))
    _, m4 = load_checkpoint(latest_checkpoint(tmp_path / "split"))
    train(base.replace(total_episodes=8, run_dir=str(tmp_path / "split"), resume=True))
    a, ma = load_checkpoint(latest_checkpoint(tmp_path / "straight"))
    b, mb = load_checkpoint(latest_checkpoint(tmp_path / "split"))
    assert (
        ma["episodes"] == mb["episodes"] == 8 and ma["critic_updates"] == mb["critic_updates"] == 2
    )
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    if average:
        # The weight average is checkpointed, resumed exactly, and is what the run exports.
        assert mb["average_count"] >= 2 and "actor_average.params.Dense_0.kernel" in b
        assert not np.array_equal(
            b["actor_average.params.Dense_0.kernel"], b["actor.params.Dense_0.kernel"]
        )
        pol = load_policy(tmp_path / "split")
        np.testing.assert_array_equal(
            pol.variables["params"]["Dense_0"]["kernel"], b["actor_average.params.Dense_0.kernel"]
        )
        last = load_policy(tmp_path / "split", weights="last")  # 'hybridmarl eval --policy last'
        assert (pol.weights, last.weights) == ("average", "last")
        np.testing.assert_array_equal(
            last.variables["params"]["Dense_0"]["kernel"], b["actor.params.Dense_0.kernel"]
        )
        final = json.loads((tmp_path / "straight" / "eval.json").read_text())
        assert final["average_of"] == mb["average_count"] and "failure_rate" in final["last_actor"]
    else:
        with pytest.raises(C.CheckpointError, match="no weight average"):
            load_policy(tmp_path / "split", weights="average")
        straight, split = (C.find_checkpoint(tmp_path / r, "best") for r in ("straight", "split"))
        (ba, bma), (bb, bmb) = C.load_checkpoint(straight), C.load_checkpoint(split)
        assert (
            bma["episodes"] == bmb["episodes"]
            and set(ba) == set(bb)
            and all(k.startswith("actor.") for k in ba)
        )
        for k in ba:
            np.testing.assert_array_equal(ba[k], bb[k], err_msg=k)
        evals = [(tmp_path / r / "evals.csv").read_text() for r in ("straight", "split")]
        assert (
            evals[0] == evals[1] and len(evals[0].strip().splitlines()) == 1 + 2
        )  # episodes 3(+), 6(+)
        final = json.loads((tmp_path / "straight" / "eval.json").read_text())
        assert final["best"]["episodes"] == bma["episodes"] and "failure_rate" in final["best"]
    # Logs read as one uninterrupted run; wall and CPU time count across the resume.
    rows = (tmp_path / "split" / "episodes.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 8
    assert mb["wall_s"] > m4["wall_s"] > 0 and mb["cpu_s"] > m4["cpu_s"] > 0
    with open(tmp_path / "split" / "train.csv") as f:
        timed = [(float(r["wall_s"]), float(r["cpu_s"])) for r in csv.DictReader(f)]
    walls, cpus = zip(*timed, strict=True)
    assert (
        list(walls) == sorted(walls) and list(cpus) == sorted(cpus) and walls[-1] > m4["wall_s"]
    ), timed
    # Logs read as one uninterrupted run, row for row (timings aside).
    for log in ("train.csv", "episodes.csv"):
        assert _log_rows(tmp_path / "split" / log) == _log_rows(tmp_path / "straight" / log), log
    # Without --resume an existing run is refused.
    from hybridmarl.training.task import TaskError

    with pytest.raises(TaskError, match="--resume"):
        train(base.replace(run_dir=str(tmp_path / "split")))
    if not average:
        _resume_after_a_kill(tmp_path / "straight", tmp_path / "killed", base)
        _resume_after_ctrl_c(tmp_path / "straight", tmp_path / "interrupted", base)


def _resume_after_ctrl_c(straight, run_dir, base) -> None:
    """Ctrl-C (SIGINT) inside the second chunk: the loop ends with that chunk, saves a
    checkpoint and raises 'Interrupted' naming the resume command; --resume then ends equal to
    the uninterrupted run. (The spawned-process version is tests/training/test_kill_resume.py.)"""
    import os
    import signal
    import threading
    import time

    from hybridmarl.algos.hybrid import train
    from hybridmarl.errors import Interrupted
    from hybridmarl.training import checkpoint as ck

    def interrupt_when_paused() -> None:
        while ck._reached.get("chunk", 0) < 2:
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGINT)

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(ck.PAUSE_ENV, "chunk:2")
        mp.setattr(ck, "_reached", {})
        threading.Thread(target=interrupt_when_paused, daemon=True).start()
        with pytest.raises(
            Interrupted,
            match=rf"checkpoint saved; continue with: hybridmarl train --run-dir {run_dir} --resume",
        ):
            train(base.replace(total_episodes=8, run_dir=str(run_dir)))
    _, meta = ck.load_checkpoint(ck.list_checkpoints(run_dir)[-1])
    assert (
        meta["iterations"] == 2
        and meta["log_rows"]["train"] == len(_log_rows(run_dir / "train.csv")) == 2
    )
    train(base.replace(total_episodes=8, run_dir=str(run_dir), resume=True))
    a, _ = ck.load_checkpoint(ck.list_checkpoints(straight)[-1])
    b, _ = ck.load_checkpoint(ck.list_checkpoints(run_dir)[-1])
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for log in ("train.csv", "episodes.csv", "evals.csv"):
        assert _log_rows(run_dir / log) == _log_rows(straight / log), log


#: train.csv columns that time the run (they differ between any two runs).
TIMING = ("chunk_s", "wall_s", "cpu_s", "env_steps_per_s")


def _log_rows(path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


def _resume_after_a_kill(straight, killed, base) -> None:
    """What a kill after a periodic checkpoint leaves (rows logged after it, no later checkpoint,
    a checkpoint write cut short, the dead process's lock file): --resume removes the leftovers,
    takes over the lock, and ends with the uninterrupted run's parameters and log rows."""
    import contextlib
    import io
    import shutil

    from hybridmarl.algos.hybrid import train
    from hybridmarl.training.checkpoint import list_checkpoints, load_checkpoint
    from hybridmarl.training.rundir import LOCK_NAME

    shutil.copytree(straight, killed)
    *_, middle, _ = list_checkpoints(killed)
    for later in list_checkpoints(killed):
        if int(later.name[5:]) > int(middle.name[5:]):
            shutil.rmtree(later)
    (killed / "eval.json").unlink()
    assert (
        len(_log_rows(killed / "train.csv"))
        > json.loads((middle / "meta.json").read_text())["log_rows"]["train"]
    )
    partial = killed / "checkpoints" / ".tmp_ckpt_000000008_x1"
    partial.mkdir()
    (partial / "arrays.safetensors").write_bytes(bytes(4096))
    (killed / LOCK_NAME).write_text(
        json.dumps({"pid": 2**22 + 7, "host": "gone"})
    )  # above Linux's pid_max
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        train(base.replace(total_episodes=8, run_dir=str(killed), resume=True))
    text = out.getvalue()
    assert "taking over the lock of process 4194311" in text and "partial writes" in text, text
    assert not partial.exists() and not (killed / LOCK_NAME).exists()
    a, _ = load_checkpoint(list_checkpoints(straight)[-1])
    b, _ = load_checkpoint(list_checkpoints(killed)[-1])
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for log in ("train.csv", "episodes.csv", "evals.csv"):
        assert _log_rows(killed / log) == _log_rows(straight / log), log


def test_tj_time_penalty_reaches_the_task_and_costs_tau_per_car():
    from hybridmarl.algos.hybrid import HybridConfig

    spec = HybridConfig().replace(env="traffic_junction", time_penalty=True).task_spec()
    assert spec.time_penalty and "time penalty" in spec.label()
    assert (
        TaskSpec.from_dict({"env": "traffic_junction"}).time_penalty is False
    )  # older run metadata
    on, off = make_task(spec), make_task(TJ)
    assert bool(on.params.time_penalty) and not bool(off.params.time_penalty)
    demo = off.demonstrator("always-gas")
    _, s = off.reset(jax.random.key(0))
    for t in range(12):  # the same transitions under both rewards
        k = jax.random.fold_in(jax.random.key(1), t)
        a = demo(k, s)
        _, s_off, r_off, _, _ = off.step(k, s, a)
        _, _, r_on, _, _ = on.step(k, s, a)
        tau_after = np.where(np.asarray(s.active), np.asarray(s.tau) + 1, 0).sum()
        assert float(r_on) == pytest.approx(float(r_off) - 0.01 * tau_after, abs=1e-5)
        s = s_off
    assert int(np.asarray(s.active).sum()) > 0  # cars were on the road, so the penalty was tested


def test_tj_replay_reports_the_time_penalty():
    from hybridmarl.cli.replay import record_tj_episode

    _, off = record_tj_episode("always-gas", 0.3, seed=2, max_steps=15, cell_px=4)
    _, on = record_tj_episode("always-gas", 0.3, seed=2, max_steps=15, cell_px=4, time_penalty=True)
    assert on["time_penalty"] and not off["time_penalty"]
    assert (
        on["arrivals"] == off["arrivals"] and on["collisions"] == off["collisions"]
    )  # same episode
    assert on["return"] < off["return"]  # cars were on the road, each paying -0.01·τ per step


def test_time_limit_stops_alg2_and_still_evaluates(tmp_path, capsys):
    """``time_limit_min``: Alg. 2 stops at the first chunk boundary past the limit; the run is
    then checkpointed and evaluated as usual, and ``eval.json`` says the clock stopped it."""
    from hybridmarl.algos.hybrid import PRESETS, train
    from hybridmarl.training.checkpoint import latest_checkpoint, load_checkpoint

    cfg = PRESETS["toy"]("traffic_junction").replace(
        progress=False, total_episodes=10_000, time_limit_min=1e-6, run_dir=str(tmp_path / "run")
    )
    train(cfg)
    assert "time limit of 1e-06 min reached" in capsys.readouterr().out
    _, meta = load_checkpoint(latest_checkpoint(tmp_path / "run"))
    assert meta["episodes"] < 10_000 and meta["iterations"] == 1  # one chunk of Alg. 2
    res = json.loads((tmp_path / "run" / "eval.json").read_text())
    assert (
        res["time_limited"] is True
        and res["episodes"] == meta["episodes"]
        and "failure_rate" in res
    )


def test_progress_status_before_and_after_the_first_episode():
    from hybridmarl.training.logger import recent_status

    assert (
        recent_status({"won": float("nan")}, "won", "terminal_hp_reward")
        == "won@100 -  terminal_hp_reward@100 -"
    )
    assert recent_status(
        {"won": 0.25, "terminal_hp_reward": -0.1}, "won", "terminal_hp_reward"
    ) == ("won@100 0.25  terminal_hp_reward@100 -0.100")
