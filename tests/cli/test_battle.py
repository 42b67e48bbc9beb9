"""`hybridmarl battle` / `trace`: smoke runs at toy sizes, the output format, and bad input
(one line naming the problem, exit code 2, no output file)."""

from __future__ import annotations

import json

import pytest

from hybridmarl.cli.main import main
from hybridmarl.engine.scenarios import InputError, load_scenario_file, load_states_file
from tests.conftest import TRACE_DIR


def _write(tmp_path, name, obj):
    p = tmp_path / name
    p.write_text(obj if isinstance(obj, str) else json.dumps(obj))
    return p


def test_battle_scenario_smoke(tmp_path, capsys):
    out = tmp_path / "res.json"
    rc = main(
        [
            "battle",
            "--scenario",
            "m3v3",
            "--p0",
            "attack-closest",
            "--p1",
            "attack-weakest",
            "--n",
            "6",
            "--seed",
            "1",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "P0 wins" in text and "attack-closest" in text
    doc = json.loads(out.read_text())
    assert len(doc["results"]) == 6
    r = doc["results"][0]
    assert set(r) == {"winner", "final_time", "turns", "unit_hp"}
    assert r["winner"] in (0, 1, None) and len(r["unit_hp"]) == 6
    assert doc["summary"]["battles"] == 6


@pytest.mark.parametrize("scenario", ["m5v5", "m4v6-apart"])
def test_battle_engines_agree(tmp_path, scenario):
    """--engine native and --engine jax write the same results document (every battle's
    winner, final frame, turns and unit HP), both directions with --swap."""
    docs = {}
    for engine in ("native", "jax"):
        out = tmp_path / f"{engine}.json"
        argv = [
            "battle",
            "--scenario",
            scenario,
            "--n",
            "40",
            "--seed",
            "3",
            "--swap",
            "--engine",
            engine,
            "--out",
            str(out),
            "--no-progress",
        ]
        assert main(argv) == 0
        docs[engine] = json.loads(out.read_text())
    assert docs["native"] == docs["jax"]


def test_battle_engine_auto_is_native_on_cpu():
    from hybridmarl.cli.engine import resolve_engine

    assert resolve_engine("auto") == "native"  # the test machines have no GPU
    assert resolve_engine("jax") == "jax"


def test_battle_states_file_matches_reference(tmp_path):
    """Start states from a JSON file (extra keys ignored), results in input order."""
    states = json.loads((TRACE_DIR / "trace_states.json").read_text())
    out = tmp_path / "res.json"
    f = _write(tmp_path, "states.json", states)
    rc = main(
        [
            "battle",
            "--states",
            str(f),
            "--p0",
            "attack-closest",
            "--p1",
            "attack-weakest",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    # trace_3v3_state0_AttackClosest_vs_AttackWeakest: P0 wins at frame 151 after 60 turns.
    r = doc["results"][1]
    assert (r["winner"], r["final_time"], r["turns"]) == (0, 151, 60)
    assert r["unit_hp"] == [0, 0, 0, 0, 28, 0]


BAD = [
    (
        {
            "states": [
                {
                    "units": [
                        {"type": "Terran_Batman", "player": 0, "x": 1, "y": 1},
                        {"type": "Terran_Marine", "player": 1, "x": 5, "y": 5},
                    ]
                }
            ]
        },
        "unknown unit type",
    ),
    (
        {
            "states": [
                {
                    "units": [
                        {"type": "Terran_Marine", "player": 0, "x": 5000, "y": 1},
                        {"type": "Terran_Marine", "player": 1, "x": 5, "y": 5},
                    ]
                }
            ]
        },
        "off the map",
    ),
    (
        {"states": [{"units": [{"type": "Terran_Marine", "player": 0, "x": 5, "y": 1}]}]},
        "player 1 has no units",
    ),
    (
        {"states": [{"units": [{"type": "Terran_Marine", "player": 2, "x": 5, "y": 1}]}]},
        "player must be 0 or 1",
    ),
    (
        {"states": [{"units": [{"type": "Terran_Marine", "player": 0, "x": 1.5, "y": 1}]}]},
        "integer pixel",
    ),
    ({"states": []}, "non-empty"),
    ({"foo": 1}, "'states' list"),
    ("{not json", "malformed JSON"),
]


@pytest.mark.parametrize(("doc", "msg"), BAD)
def test_battle_bad_states_file(tmp_path, capsys, doc, msg):
    f = _write(tmp_path, "bad.json", doc)
    out = tmp_path / "out.json"
    rc = main(["battle", "--states", str(f), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and msg in err[0], err
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "msg"),
    [
        (["--p0", "attack-nearest"], "unknown script"),
        (["--scenario", "z5v5"], "unknown scenario"),
        (["--states", "/nonexistent/states.json"], "not found"),
        (["--scenario", "m0v5"], "1..512"),
        (["--n", "0"], "--n must be at least 1"),
        (["--map-file", "/nonexistent.map"], "not found"),
    ],
)
def test_battle_bad_arguments(tmp_path, capsys, args, msg):
    out = tmp_path / "out.json"
    rc = main(["battle", *args, "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and msg in err[0], err
    assert not out.exists()


def test_unknown_command(capsys):
    assert main(["fly"]) == 2
    assert "unknown command" in capsys.readouterr().err


def test_trace_command(capsys):
    rc = main(
        [
            "trace",
            "--states",
            str(TRACE_DIR / "trace_states.json"),
            "--index",
            "0",
            "--p0",
            "AttackClosest",
            "--p1",
            "AttackClosest",
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    ref = (TRACE_DIR / "trace_1v1_state0_AttackClosest_vs_AttackClosest.txt").read_text()
    ref_turns = [
        ln for ln in ref.splitlines() if ln.startswith(("TURN", "  ACT", "  HP", "  NEXT"))
    ]
    ours = [ln for ln in text.splitlines() if ln.startswith(("TURN", "  ACT", "  HP", "  NEXT"))]
    assert ours == ref_turns


def test_scenario_file(tmp_path):
    f = _write(
        tmp_path,
        "sc.json",
        {
            "name": "zd",
            "player0": [{"type": "Protoss_Zealot", "count": 3}],
            "player1": [
                {"type": "Protoss_Dragoon", "count": 2},
                {"type": "Terran_Marine", "count": 1},
            ],
        },
    )
    sc = load_scenario_file(f)
    states = sc.generate(3, 0)
    assert len(states) == 3 and sum(u.player == 1 for u in states[0]) == 3
    bad = _write(
        tmp_path, "bad.json", {"player0": [{"type": "Protoss_Zealot", "count": 0}], "player1": []}
    )
    with pytest.raises(InputError, match="count must be a positive integer"):
        load_scenario_file(bad)
    bad2 = _write(
        tmp_path,
        "bad2.json",
        {
            "player0": [{"type": "Protoss_Zealot", "count": 1}],
            "player1": [{"type": "Protoss_Zealot", "count": 1}],
            "center0": [10, 10],
        },
    )
    with pytest.raises(InputError, match="leaves the"):
        load_scenario_file(bad2)


def test_battle_with_scenario_file_runs(tmp_path, capsys):
    f = _write(
        tmp_path,
        "sc.json",
        {
            "player0": [{"type": "Zerg_Zergling", "count": 3}],
            "player1": [{"type": "Zerg_Hydralisk", "count": 2}],
        },
    )
    rc = main(
        [
            "battle",
            "--scenario-file",
            str(f),
            "--n",
            "4",
            "--p0",
            "nokdps",
            "--p1",
            "kiter-dps",
            "--no-progress",
        ]
    )
    assert rc == 0
    assert "nokdps" in capsys.readouterr().out


def test_load_states_file_errors_are_one_line(tmp_path):
    with pytest.raises(InputError) as e:
        load_states_file(tmp_path / "missing.json")
    assert "\n" not in str(e.value)
