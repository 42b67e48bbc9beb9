"""CLI smoke runs of ``hybridmarl train`` + ``hybridmarl eval`` at a toy budget (Traffic Junction
from a recorded demonstration dataset, i.e. the behavioural-clone path, and ``--algo bc`` on it;
combat m3v3 from the attack-closest script), the
``--json`` contract, presets and bad input (one line, exit code 2)."""

from __future__ import annotations

import csv
import json

import numpy as np

from hybridmarl.cli.main import main
from hybridmarl.training.checkpoint import latest_checkpoint, load_checkpoint

TOY = ["--preset", "toy", "--no-progress"]


def _one_json(text: str) -> dict:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, text
    return json.loads(lines[0])


def test_demos_train_clone_and_eval_traffic_junction(tmp_path, capsys):
    """Record a dataset, train the method from its behavioural clone, evaluate; --algo bc too."""
    data = tmp_path / "tj.safetensors"
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
                str(data),
            ]
        )
        == 0
    )
    run = tmp_path / "tj"
    rc = main(
        [
            "train",
            "--algo",
            "hybrid",
            *TOY,
            "--env",
            "traffic_junction",
            "--demonstrator",
            str(data),
            "--seed",
            "1",
            "--run-dir",
            str(run),
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert (
        "behavioural clone of 90 observations" in out
        and "critic pre-trained" in out
        and "failure rate" in out
    )
    for f in ("config.json", "train.csv", "episodes.csv", "eval.json", "curve.png"):
        assert (run / f).is_file(), f
    cfg = json.loads((run / "config.json").read_text())
    assert (
        cfg["algo"] == "hybrid"
        and cfg["config"]["gamma"] == 0.995
        and cfg["config"]["brd_iterations"] == 2
    )
    assert (
        cfg["task"]["env"] == "traffic_junction"
        and cfg["config"]["demonstrator_name"] == "dataset:tj.safetensors"
    )
    with open(run / "train.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows and {
        "actor_loss",
        "brd_sweeps",
        "critic_loss",
        "agree",
        "failed_100",
        "return_100",
    } <= set(rows[0])
    assert (
        rows[0]["failed_100"] == "nan" and 0.0 <= float(rows[-1]["failed_100"]) <= 1.0
    )  # live once episodes end
    _, meta = load_checkpoint(latest_checkpoint(run))
    assert meta["episodes"] >= 8 and meta["phase"] == "joint"
    assert main(["eval", "--run-dir", str(run), "--n", "8", "--seed", "2", "--json"]) == 0
    res = _one_json(capsys.readouterr().out)
    assert (
        res["n"] == 8 and 0.0 <= res["failure_rate"] <= 1.0 and len(res["failure_rate_ci95"]) == 2
    )
    assert {"W", "R", "W_ci95", "R_ci95"} <= set(res)
    # --algo bc on the same dataset, through the same machinery.
    bc = tmp_path / "bc"
    assert (
        main(
            [
                "train",
                "--algo",
                "bc",
                *TOY,
                "--env",
                "traffic_junction",
                "--demonstrator",
                str(data),
                "--run-dir",
                str(bc),
            ]
        )
        == 0
    )
    assert "cloned 90 observations" in capsys.readouterr().out
    assert json.loads((bc / "eval.json").read_text())["n"] == 8
    # --time-penalty records the same play (same seed) under CommNet's penalised reward.
    from hybridmarl.training.demos import load_dataset

    pen = tmp_path / "tj-penalty.safetensors"
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
                "--time-penalty",
                "--out",
                str(pen),
            ]
        )
        == 0
    )
    plain, penal = load_dataset(data), load_dataset(pen)
    assert (
        penal.meta["task"]["time_penalty"] is True and plain.meta["task"]["time_penalty"] is False
    )
    np.testing.assert_array_equal(plain.arrays["actions"], penal.arrays["actions"])
    gap = plain.arrays["reward"] - penal.arrays["reward"]
    assert gap.min() >= 0 and gap.max() > 0  # the penalty only subtracts, and it bites


def test_train_and_eval_combat(tmp_path, capsys):
    """The stable contract: train --algo hybrid --preset ... --scenario --demonstrator --enemy
    --seed --run-dir, then eval --run-dir --enemy --n --seed --json (one JSON object)."""
    run = tmp_path / "m3v3"
    rc = main(
        [
            "train",
            "--algo",
            "hybrid",
            *TOY,
            "--scenario",
            "m3v3",
            "--demonstrator",
            "attack-closest",
            "--enemy",
            "attack-weakest",
            "--seed",
            "0",
            "--run-dir",
            str(run),
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "critic pre-trained" in out and "eval vs attack-weakest" in out
    assert (
        main(
            [
                "eval",
                "--run-dir",
                str(run),
                "--enemy",
                "attack-weakest",
                "--n",
                "8",
                "--seed",
                "0",
                "--json",
            ]
        )
        == 0
    )
    res = _one_json(capsys.readouterr().out)
    assert res["n"] == 8 and res["enemy"] == "attack-weakest" and res["scenario"] == "m3v3"
    assert 0.0 <= res["W"] <= 1.0 and res["W_ci95"][0] <= res["W"] <= res["W_ci95"][1]
    assert res["R_ci95"][0] <= res["R"] <= res["R_ci95"][1]
    # The newest checkpoint by default; an older one on request (by episodes); a missing one is named.
    from hybridmarl.training.checkpoint import list_checkpoints

    older, newest = list_checkpoints(run)[-2:]
    assert res["episodes"] == int(newest.name.split("_")[1]) >= 8
    assert (
        main(
            [
                "eval",
                "--run-dir",
                str(run),
                "--checkpoint",
                str(int(older.name.split("_")[1])),
                "--n",
                "8",
                "--seed",
                "0",
                "--json",
            ]
        )
        == 0
    )
    assert (
        _one_json(capsys.readouterr().out)["episodes"]
        == int(older.name.split("_")[1])
        < res["episodes"]
    )
    assert main(["eval", "--run-dir", str(run), "--checkpoint", "999", "--n", "8"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no checkpoint '999'" in err[0] and older.name in err[0], err
    # The main job on the finished run (reused, not retrained): D vs ours table, files, replay.
    assert (
        main(
            [
                "quickstart",
                "--run-dir",
                str(run),
                "--scenario",
                "m3v3",
                "--preset",
                "toy",
                "--n",
                "4",
                "--no-progress",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "reusing it" in out and "| D |" in out and "| Ours |" in out
    doc = json.loads((run / "comparison.json").read_text())
    assert doc["n"] == 4 and doc["enemy"] == "attack-weakest" and set(doc["rows"]) == {"D", "Ours"}
    assert (run / "replay.gif").stat().st_size > 1000 and (run / "comparison.md").is_file()
    assert (
        main(["replay", "--run-dir", str(tmp_path / "nothing"), "--out", str(tmp_path / "x.gif")])
        == 2
    )


def test_bad_input_one_line_exit_2(tmp_path, capsys):
    cases = [
        (["train", "--algo", "nope"], "unknown algo 'nope'"),
        (["train", "--preset", "nope"], "unknown preset 'nope'"),
        (["train", "--preset", "toy", "--env", "mars"], "unknown env 'mars'"),
        (
            ["train", *TOY, "--demonstrator", "attack-nobody", "--run-dir", str(tmp_path / "a")],
            "unknown script 'attack-nobody'",
        ),
        (
            [
                "train",
                *TOY,
                "--demonstrator",
                str(tmp_path / "missing.safetensors"),
                "--run-dir",
                str(tmp_path / "b"),
            ],
            "no such dataset file",
        ),
        (["eval", "--run-dir", str(tmp_path / "nothing")], "no config.json"),
        (["eval", "--script", "attack-closest", "--n", "0"], "--n must be at least 1"),
    ]
    for argv, msg in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0], (argv, err)


def test_every_preset_builds_and_round_trips_through_config_json():
    """Every ``--preset`` of every algo, for both envs, is a valid config that survives the
    config.json round trip that ``--resume`` relies on; the documented extension presets set
    what their docstrings say."""
    from hybridmarl.algos import ALGOS, algo_module
    from hybridmarl.training.config import config_from_dict, config_to_dict

    for algo in ALGOS:
        mod = algo_module(algo)
        for name, make in mod.PRESETS.items():
            for env in ("combat", "traffic_junction"):
                cfg = make(env)
                assert cfg.env == env, (algo, name, env)
                assert config_from_dict(type(cfg), config_to_dict(cfg)) == cfg, (algo, name, env)
    hybrid = algo_module("hybrid").PRESETS
    combat, tj = hybrid["quick"]("combat"), hybrid["quick"]("traffic_junction")
    assert (
        combat.lookahead_steps,
        combat.actor_target,
        combat.actor_steps,
        combat.total_episodes,
    ) == (8, "best", 4, 3000)
    assert (combat.lookahead_policy, combat.num_envs, combat.actor_average_from) == (
        "demonstrator",
        128,
        1500,
    )
    assert (tj.lookahead_steps, tj.actor_target, tj.total_episodes) == (4, "advantage", 1_500)
    paper_quick = hybrid["quick-paper"]("combat")  # the paper's method at a small budget
    assert (
        paper_quick.lookahead_steps,
        paper_quick.actor_target,
        paper_quick.actor_average_from,
    ) == (1, "advantage", None)
    assert (
        hybrid["paper"]("combat").lookahead_steps == 1
    )  # the paper's one-step Q stays the field default
    for env in (
        "combat",
        "traffic_junction",
    ):  # Table 2's "w/o D": the same recipe with no demonstrator in it
        wo = hybrid["quick-wo-d"](env)
        assert (wo.pretrain_critic, wo.brd_start, wo.lookahead_policy) == (False, "actor", "start")
        full = hybrid["quick"](env)
        assert wo.replace(pretrain_critic=True, lookahead_policy=full.lookahead_policy) == full
