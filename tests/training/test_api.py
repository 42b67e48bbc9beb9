"""The Python API and the config machinery: grouped options with flat names (command line,
'replace', config.json), the learner's compile key, presets, 'hybridmarl.train' and
'hybridmarl.load_policy(...).predict'."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
import tyro

import hybridmarl
from hybridmarl.algos import ALGOS, DEFAULT_PRESET, algo_module
from hybridmarl.algos.hybrid import PRESETS, HybridConfig, build_learner
from hybridmarl.algos.hybrid.learner import Learner
from hybridmarl.training.config import compile_key, config_from_dict, config_to_dict


def test_grouped_config_keeps_flat_names():
    cfg = HybridConfig().replace(num_envs=7, brd_iterations=3, scenario="m3v3", seed=5, run_dir="x")
    assert (cfg.budget.num_envs, cfg.brd.brd_iterations, cfg.task.scenario, cfg.run.seed) == (
        7,
        3,
        "m3v3",
        5,
    )
    assert (cfg.num_envs, cfg.brd_iterations, cfg.scenario, cfg.seed, cfg.run_dir) == (
        7,
        3,
        "m3v3",
        5,
        "x",
    )
    with pytest.raises(TypeError, match="no field 'nope'"):
        cfg.replace(nope=1)
    with pytest.raises(AttributeError):
        _ = cfg.nope
    flat = config_to_dict(cfg)
    assert (
        flat["num_envs"] == 7 and flat["actor_hidden"] == [512, 256, 256] and "budget" not in flat
    )
    assert config_from_dict(HybridConfig, json.loads(json.dumps(flat))) == cfg
    assert (
        config_from_dict(HybridConfig, {**flat, "momentum": 0.9}) == cfg
    )  # a removed option is ignored


def test_command_line_flags_stay_flat():
    default = PRESETS["toy"]("combat")
    args = [
        "--num-envs",
        "6",
        "--brd-iterations",
        "3",
        "--total-episodes",
        "5",
        "--scenario",
        "m3v3",
        "--run-dir",
        "r",
        "--no-progress",
        "--actor-hidden",
        "8",
        "8",
    ]
    cfg = tyro.cli(HybridConfig, args=args, default=default)
    assert cfg == default.replace(
        num_envs=6,
        brd_iterations=3,
        total_episodes=5,
        scenario="m3v3",
        run_dir="r",
        progress=False,
        actor_hidden=(8, 8),
    )


def test_compile_key_follows_the_config():
    base = PRESETS["toy"]("combat")
    # Run-only fields do not change the key ...
    for change in (
        {"seed": 3},
        {"run_dir": "elsewhere"},
        {"total_episodes": 99},
        {"eval_every": 5},
        {"checkpoint_every": 1},
        {"progress": False},
        {"scenario": "m3v3"},
        {"e_update": 7},
    ):
        assert compile_key(base.replace(**change)) == compile_key(base), change
    # ... every other field does.
    for change in (
        {"num_envs": 5},
        {"actor_lr": 0.5},
        {"brd_iterations": 3},
        {"gamma": 0.9},
        {"lookahead_steps": 2},
        {"actor_hidden": (8, 8)},
        {"brd_work_batch": 0},
    ):
        assert compile_key(base.replace(**change)) != compile_key(base), change
    from hybridmarl.training.task import TaskSpec, make_task

    task = make_task(TaskSpec(env="combat", scenario="m3v3", enemy="attack-weakest"))
    assert build_learner(task, base, "attack-closest") is build_learner(
        task, base.replace(seed=9, total_episodes=3), "attack-closest"
    )
    assert build_learner(task, base, "attack-closest") is not build_learner(
        task, base.replace(actor_lr=0.5), "attack-closest"
    )


def test_learner_reads_no_run_only_field():
    """A run-only field read by the compiled learner would silently take its default from the
    compile key: the learner must not read one."""
    from hybridmarl.training.task import TaskSpec, make_task

    cfg = PRESETS["toy"]("combat")
    run_only = {
        n
        for g in ("task", "run", "evaluation", "budget", "clone", "critic", "actor")
        for n in type(getattr(cfg, g)).RUN_ONLY
    }
    read: set[str] = set()

    class Recorder:
        def __getattr__(self, name):
            read.add(name)
            return getattr(cfg, name)

    Learner(
        make_task(TaskSpec(env="combat", scenario="m3v3", enemy="attack-weakest")),
        Recorder(),
        "attack-closest",
    )  # type: ignore[arg-type]
    assert read and not (read & run_only), read & run_only


def test_every_preset_works_for_both_envs():
    for algo in ALGOS:
        mod = algo_module(algo)
        assert DEFAULT_PRESET in mod.PRESETS
        for name, make in mod.PRESETS.items():
            assert make.__doc__, (algo, name)
            for env in ("combat", "traffic_junction"):
                cfg = make(env)
                assert type(cfg) is mod.CONFIG and cfg.env == env
                cfg.task_spec()  # a valid task


def test_train_and_load_policy_predict(tmp_path, capsys):
    """'hybridmarl.train' runs the learner of the config and returns its result; the policy of
    'hybridmarl.load_policy' plays the evaluation's legal argmax, batched over leading axes."""
    from hybridmarl.algos.bc import PRESETS as BC
    from hybridmarl.training import evaluate as E
    from hybridmarl.training.task import make_task

    cfg = BC["toy"]("traffic_junction").replace(progress=False, run_dir=str(tmp_path / "bc"))
    result = hybridmarl.train(cfg)
    assert result.run_dir == tmp_path / "bc" and result.evaluation["n"] == 8
    assert "cloned 64 observations" in capsys.readouterr().out
    policy = hybridmarl.load_policy(result.run_dir)
    assert (
        policy.spec == result.policy.spec
        and policy.weights == "last"
        and policy.demonstrator == "always-gas"
    )
    task = make_task(policy.spec)
    obs, states = jax.vmap(task.reset)(jax.random.split(jax.random.key(0), 6))
    legal = jax.vmap(task.avail)(states)
    expected = np.asarray(E.actor_policy(policy.module)(policy.variables, None, states, obs, legal))
    got = policy.predict(np.asarray(obs), np.asarray(legal))
    assert got.dtype == np.int32 and got.shape == expected.shape == legal.shape[:2]
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(
        policy.predict(np.asarray(obs[2]), np.asarray(legal[2])), expected[2]
    )
    assert np.take_along_axis(np.asarray(legal), got[..., None], -1).all()


def test_divergence_raises_and_the_command_line_exits_3(tmp_path, capsys):
    """A NaN loss raises 'TrainingDiverged' from 'train'; 'hybridmarl train' prints one line
    and exits with code 3."""
    from hybridmarl.algos.bc import PRESETS as BC
    from hybridmarl.cli.main import main
    from hybridmarl.errors import EXIT_DIVERGED, TrainingDiverged

    # A learning rate this large is valid input (finite, > 0) that drives the loss to NaN.
    cfg = BC["toy"]("traffic_junction").replace(
        progress=False, actor_lr=1e30, run_dir=str(tmp_path / "api")
    )
    with pytest.raises(TrainingDiverged, match="behavioural-cloning loss"):
        hybridmarl.train(cfg)
    argv = [
        "train",
        "--algo",
        "bc",
        "--preset",
        "toy",
        "--env",
        "traffic_junction",
        "--actor-lr",
        "1e30",
        "--no-progress",
        "--run-dir",
        str(tmp_path / "cli"),
    ]
    assert main(argv) == EXIT_DIVERGED
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "training stopped" in err[0] and "NaN" in err[0], err
    assert "no checkpoint was saved" in err[0] and "still valid" not in err[0], (
        err
    )  # BC saves only at its end
    # A NaN learning rate is bad input, refused before any work (exit 2, no run directory).
    assert main([*argv[:-1], str(tmp_path / "nan"), "--actor-lr", "nan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--actor-lr must be a finite number > 0, got nan" in err[0], err
    assert not (tmp_path / "nan").exists()
