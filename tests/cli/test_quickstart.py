"""``hybridmarl quickstart`` without training: its run directory per seed and preset, and its
refusal of a run directory that holds a run made with other settings."""

from __future__ import annotations

import json

from hybridmarl.cli.main import main
from hybridmarl.cli.quickstart import (
    QuickstartConfig,
    default_run_dir,
    settings_mismatch,
    training_config,
)
from hybridmarl.training.config import config_to_dict


def test_run_dir_differs_by_seed_and_preset():
    s0 = default_run_dir("m5v5", "attack-closest", 0)
    s1 = default_run_dir("m5v5", "attack-closest", 1)
    assert s0 != s1
    assert s0.as_posix() == "runs/quickstart-m5v5-attack-closest-s0"
    assert s1.as_posix() == "runs/quickstart-m5v5-attack-closest-s1"
    assert default_run_dir("m5v5", "attack-closest", 0, "quick-paper") not in (s0, s1)


def test_settings_mismatch_names_the_field():
    assert settings_mismatch({"seed": 0, "run_dir": "a"}, {"seed": 0, "run_dir": "b"}) is None
    assert settings_mismatch({"seed": 0}, {"seed": 1}) == ("seed", 0, 1)
    assert settings_mismatch({"net": {"hidden": [16, 8]}}, {"net": {"hidden": (16, 8)}}) is None
    assert settings_mismatch({"net": {"hidden": [16, 8]}}, {"net": {"hidden": (16,)}}) == (
        "net.hidden",
        [16, 8],
        [16],
    )
    assert settings_mismatch({}, {"new_field": 1}) is None  # a field the run predates


def test_refuses_run_made_with_other_settings(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    cfg = QuickstartConfig(scenario="m3v3", preset="toy", seed=0)
    made = training_config(cfg, "attack-closest", "attack-weakest", run, resume=False).replace(
        seed=1
    )
    doc = {
        "algo": "hybrid",
        "config": {**config_to_dict(made), "demonstrator_name": "attack-closest"},
        "task": made.task_spec().to_dict(),
    }
    (run / "config.json").write_text(json.dumps(doc))
    (run / "eval.json").write_text("{}")
    argv = [
        "quickstart",
        "--run-dir",
        str(run),
        "--scenario",
        "m3v3",
        "--preset",
        "toy",
        "--seed",
        "0",
        "--no-progress",
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "seed = 1" in err[0] and "other settings" in err[0], err
    assert not (run / "comparison.json").exists()
    doc["algo"] = "bc"
    (run / "config.json").write_text(json.dumps(doc))
    assert main(argv) == 2
    assert "'bc' run" in capsys.readouterr().err
    # Another seed is another run directory: the quickstart of seed 1 never lands in seed 0's.
    assert training_config(
        QuickstartConfig(seed=1),
        "attack-closest",
        "attack-weakest",
        default_run_dir("m5v5", "attack-closest", 1),
        resume=False,
    ).run_dir.endswith("-s1")
    # A damaged config.json is named, not reused.
    (run / "config.json").write_text("{")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "config.json" in err[0] and "malformed JSON" in err[0], err
