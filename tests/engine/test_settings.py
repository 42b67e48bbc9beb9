"""Named settings (``hybridmarl.settings``, docs/engine.md#settings): their rules and geometry,
the default equal to the behaviour before settings existed, contradictions and unknown names
(one line, exit code 2), a resumed run under another setting, Traffic Junction's paper value."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hybridmarl.cli.main import main
from hybridmarl.engine.scenarios import Scenario, named_scenario
from hybridmarl.errors import UserError
from hybridmarl.settings import (
    PAPER_GEOMETRY,
    SETTINGS,
    SettingError,
    check_options,
    get_setting,
)
from hybridmarl.training.task import TaskSpec


def test_settings_are_data():
    sp, pa = SETTINGS["sparcraft"], SETTINGS["paper"]
    assert (sp.overkill, sp.stalemate_limit, sp.p_arrive) == ("pass", 50, 0.2)
    assert (pa.overkill, pa.stalemate_limit) == ("classic", 200)
    r = pa.rules()
    assert (r.overkill, r.stalemate_limit, r.max_turns) == ("classic", 200, 20000)
    assert get_setting(None) is sp and get_setting(" Paper ") is pa
    with pytest.raises(AttributeError):
        pa.overkill = "pass"  # type: ignore[misc]  # frozen


def test_sparcraft_geometry_is_the_former_default():
    """m<A>v<B> under the default setting: disks r=100 px at (565, 352) and (715, 352), the same
    start states as before settings existed (same generator stream)."""
    for name in ("m5v5", "m18v20", "m30v30", "m24v30"):
        a, b = (int(v) for v in name[1:].split("v"))
        old = Scenario(
            name=name,
            side0=(("Terran_Marine", a),),
            side1=(("Terran_Marine", b),),
            center0=(565, 352),
            center1=(715, 352),
            radius0=100,
            radius1=100,
        )
        for sc in (named_scenario(name), named_scenario(name, "sparcraft")):
            assert (sc.center0, sc.center1, sc.radius0, sc.radius1) == (
                old.center0,
                old.center1,
                100,
                100,
            )
            assert sc.generate(3, 7) == old.generate(3, 7)
    apart = named_scenario("m4v6-apart", "paper")  # -apart keeps its geometry under every setting
    assert (apart.center0, apart.center1, apart.radius0) == ((440, 352), (840, 352), 100)


def test_paper_geometry_rule():
    """Disks of radius 110 px, centres 112 + A + B px apart around the map centre."""
    assert PAPER_GEOMETRY.radius == 110
    expected = {"m5v5": 122, "m18v20": 150, "m24v30": 166, "m30v30": 172}
    for name, sep in expected.items():
        sc = named_scenario(name, "paper")
        assert sc.center1[0] - sc.center0[0] == sep and sc.center0[1] == sc.center1[1] == 352
        assert abs((sc.center0[0] + sc.center1[0]) / 2 - 640) <= 0.5
        assert sc.radius0 == sc.radius1 == 110
        pts = np.array([[u.x, u.y] for s in sc.generate(20, 0) for u in s if u.player == 0])
        assert (((pts - np.array(sc.center0)) ** 2).sum(1) <= 110**2).all()
    with pytest.raises(UserError, match="leave the"):
        named_scenario("m500v500", "paper")


def test_unknown_setting_and_contradictions():
    with pytest.raises(SettingError, match="unknown setting 'classic'.*sparcraft, paper"):
        get_setting("classic")
    with pytest.raises(SettingError, match="--overkill pass contradicts --setting paper"):
        check_options("paper", overkill="pass")
    with pytest.raises(SettingError, match="--stalemate-limit 50 contradicts"):
        check_options("paper", stalemate_limit=50)
    with pytest.raises(SettingError, match="--p-arrive 0.2 contradicts"):
        check_options("paper", p_arrive=0.2)
    assert check_options("paper", overkill="classic", stalemate_limit=200).name == "paper"
    # The default setting is the base of custom runs: options change it.
    assert (
        check_options("sparcraft", overkill="classic", stalemate_limit=200, p_arrive=0.5).name
        == "sparcraft"
    )


@pytest.mark.parametrize(
    "argv, msg",
    [
        (
            ["battle", "--setting", "paper", "--overkill", "pass"],
            "--overkill pass contradicts --setting paper",
        ),
        (
            ["battle", "--setting", "paper", "--stalemate-limit", "50"],
            "contradicts --setting paper",
        ),
        (["battle", "--setting", "nope"], "unknown setting 'nope'"),
        (
            [
                "eval",
                "--script",
                "always-gas",
                "--env",
                "traffic_junction",
                "--setting",
                "paper",
                "--p-arrive",
                "0.3",
            ],
            "--p-arrive 0.3 contradicts",
        ),
        (["eval", "--script", "attack-closest", "--setting", "nope"], "unknown setting"),
        (["demos", "collect", "--out", "x.safetensors", "--setting", "nope"], "unknown setting"),
        (["replay", "--setting", "nope"], "unknown setting"),
        (["trace", "--setting", "nope"], "unknown setting"),
        (["quickstart", "--setting", "nope"], "unknown setting"),
    ],
)
def test_cli_bad_setting_one_line_exit_2(argv, msg, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x.safetensors").exists()


def test_battle_setting_sparcraft_equals_default(tmp_path):
    docs = []
    for extra in ([], ["--setting", "sparcraft"]):
        out = tmp_path / f"r{len(docs)}.json"
        assert (
            main(
                [
                    "battle",
                    "--scenario",
                    "m5v5",
                    "--n",
                    "20",
                    "--seed",
                    "2",
                    "--out",
                    str(out),
                    "--no-progress",
                    *extra,
                ]
            )
            == 0
        )
        docs.append(json.loads(out.read_text()))
    assert docs[0]["results"] == docs[1]["results"] and docs[0]["setting"] == "sparcraft"


def test_battle_paper_setting_plays_its_rules_and_geometry(tmp_path):
    from hybridmarl.engine.battle import run_battles

    out = tmp_path / "p.json"
    assert (
        main(
            [
                "battle",
                "--scenario",
                "m5v5",
                "--n",
                "20",
                "--seed",
                "2",
                "--setting",
                "paper",
                "--overkill",
                "classic",
                "--out",
                str(out),
                "--no-progress",
                "--engine",
                "native",
            ]
        )
        == 0
    )
    doc = json.loads(out.read_text())
    states = named_scenario("m5v5", "paper").generate(20, 2)
    res = run_battles(
        states,
        "attack-closest",
        "attack-weakest",
        rules=get_setting("paper").rules(),
        progress=False,
        engine="native",
    )
    assert doc["setting"] == "paper" and doc["results"] == res.to_document()["results"]


def test_quickstart_run_dir_names_a_non_default_setting():
    from hybridmarl.cli.quickstart import default_run_dir

    assert (
        str(default_run_dir("m5v5", "attack-closest", 0))
        == "runs/quickstart-m5v5-attack-closest-s0"
    )
    assert (
        str(default_run_dir("m5v5", "attack-closest", 0, setting="paper"))
        == "runs/quickstart-m5v5-attack-closest-paper-s0"
    )


def test_combat_env_and_task_take_the_setting():
    from hybridmarl.envs.combat import Combat
    from hybridmarl.envs.combat.opponents import mirror_env
    from hybridmarl.training.task import Task

    env = Combat("m5v5", setting="paper")
    assert (env.rules.overkill, env.rules.stalemate_limit) == ("classic", 200)
    assert env.scenario == named_scenario("m5v5", "paper")
    assert mirror_env(env).setting.name == "paper" and mirror_env(env).rules.overkill == "classic"
    default = Combat("m5v5", stalemate_limit=80)  # the default setting takes overrides
    assert (default.rules.overkill, default.rules.stalemate_limit) == ("pass", 80)
    with pytest.raises(SettingError):
        Combat("m5v5", setting="paper", overkill="pass")
    task = Task(TaskSpec(scenario="m5v5", setting="paper"))
    assert task.env.rules.overkill == "classic" and "paper setting" in task.spec.label()
    assert (
        TaskSpec.from_dict({"env": "combat", "scenario": "m5v5"}).setting == "sparcraft"
    )  # old runs


def test_training_config_records_the_setting():
    from hybridmarl.algos.hybrid import PRESETS

    cfg = PRESETS["toy"]("combat").replace(setting="paper")
    assert cfg.task_spec().setting == "paper"
    tj = PRESETS["toy"]("traffic_junction")
    assert tj.task_spec().p_arrive == 0.2 and tj.task_spec().setting == "sparcraft"
    assert tj.replace(p_arrive=0.5).task_spec().p_arrive == 0.5
    paper = tj.replace(setting="paper").task_spec()
    assert paper.p_arrive == SETTINGS["paper"].p_arrive and paper.setting == "paper"
    with pytest.raises(SettingError, match="contradicts"):
        tj.replace(setting="paper", p_arrive=0.5).task_spec()


def test_traffic_junction_paper_setting():
    """p_arrive 0.105: the always-gas demonstrator fails in about 0.72 of the episodes there (the
    paper's D, Table 2; experiments/paper_setting.py --mode tj, 4 x 2000 episodes: 0.719)."""
    from hybridmarl.training.task import Task

    assert SETTINGS["paper"].p_arrive == 0.105
    task = Task(TaskSpec(env="traffic_junction", p_arrive=0.105, setting="paper"))
    assert (
        float(task.params.p_arrive) == pytest.approx(0.105) and "paper setting" in task.spec.label()
    )
    with pytest.raises(UserError, match="contradicts"):
        Task(TaskSpec(env="traffic_junction", setting="paper"))  # p_arrive 0.2 is not the paper's
    line = task.result_line(
        {
            "n": 10,
            "failure_rate": 0.7,
            "failure_rate_ci95": [0.4, 0.9],
            "R": -1.0,
            "mean_arrivals": 11.54,
        }
    )
    assert "arrivals/episode 11.5" in line


def test_resume_under_another_setting_is_refused(tmp_path):
    from hybridmarl.algos.hybrid import PRESETS
    from hybridmarl.training.checkpoint import save_checkpoint
    from hybridmarl.training.run import Run

    run_dir = tmp_path / "run"
    base = PRESETS["toy"]("traffic_junction").replace(
        run_dir=str(run_dir), progress=False, tensorboard=False, resume=True
    )
    # A checkpoint written before settings existed (no "setting" in its task) reads as sparcraft.
    save_checkpoint(
        run_dir, 4, {"x": np.zeros(1, np.float32)}, {"task": {"env": "traffic_junction"}}
    )
    with pytest.raises(
        UserError,
        match=r"trained under setting 'sparcraft'; cannot resume it under setting 'paper'",
    ):
        Run("hybrid", base.replace(setting="paper"))
    with Run("hybrid", base):  # the same setting resumes
        pass
    save_checkpoint(
        run_dir,
        8,
        {"x": np.zeros(1, np.float32)},
        {"task": {"env": "traffic_junction", "setting": "paper"}},
    )
    with pytest.raises(UserError, match=r"'paper'; cannot resume it under setting 'sparcraft'"):
        Run("hybrid", base)
