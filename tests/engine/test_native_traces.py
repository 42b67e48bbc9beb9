"""Every reference trace (SparCraft DC-HEAD, C++) reproduced turn by turn by the native engine,
record by record as ``tests/test_engine_traces.py`` checks the JAX engine; and the whole-game
path (``native.run_battles``) ends every reference game as the reference does."""

from __future__ import annotations

import pytest

from hybridmarl.engine import native
from hybridmarl.engine.trace import SPARCRAFT_SCRIPT_NAMES, parse_trace

from ..conftest import TRACE_DIR

TRACES = sorted(p.name for p in TRACE_DIR.glob("trace_*.txt"))


def _scripts(name: str) -> tuple[str, str]:
    parts = name[:-4].split("_")
    return SPARCRAFT_SCRIPT_NAMES[parts[3]], SPARCRAFT_SCRIPT_NAMES[parts[5]]


def _end_fields(text: str) -> dict:
    return dict(kv.split("=", 1) for kv in text.split()[1:] if "=" in kv)


def test_all_reference_traces_present():
    assert len(TRACES) == 17


@pytest.mark.parametrize("name", TRACES)
def test_reference_trace_native(name, rules):
    p0, p1 = _scripts(name)
    ref = parse_trace((TRACE_DIR / name).read_text())
    assert ref.turns, "reference trace parsed empty"
    ours = native.record_trace(ref.units, rules, p0, p1)
    for a, b in zip(ref.turns, ours.turns, strict=False):
        where = f"{name} turn {a.turn}"
        assert (b.turn, b.time, b.mover) == (a.turn, a.time, a.mover), where
        assert b.actions == a.actions, where
        assert b.hp == a.hp, where
        assert b.units == a.units, where
        assert b.next_time == a.next_time, where
    assert len(ours.turns) == len(ref.turns)
    end = _end_fields(ref.end)
    assert int(end["final_time"]) == ours.turns[-1].next_time
    assert int(end["turns"]) == len(ours.turns)


def test_native_run_battles_match_trace_outcomes(rules):
    """All reference games through ``native.run_battles`` (states of different sizes padded to
    one shape, played in parallel), grouped by script pair."""
    pairs: dict[tuple[str, str], list[str]] = {}
    for n in TRACES:
        pairs.setdefault(_scripts(n), []).append(n)
    for (p0, p1), names in pairs.items():
        refs = [parse_trace((TRACE_DIR / n).read_text()) for n in names]
        res = native.run_battles([r.units for r in refs], p0, p1, rules=rules, progress=False)
        for i, r in enumerate(refs):
            end = _end_fields(r.end)
            want_winner = -1 if end["winner"] == "draw" else int(end["winner"])
            assert int(res.winner[i]) == want_winner, names[i]
            assert int(res.final_time[i]) == int(end["final_time"]), names[i]
            assert int(res.turns[i]) == int(end["turns"]), names[i]
            assert res.unit_hp[i] == [r.turns[-1].hp[u] for u in range(len(r.units))], names[i]
