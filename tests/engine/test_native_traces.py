"""Every reference trace (SparCraft DC-HEAD, C++) reproduced turn by turn by the native engine,
record by record as ``tests/engine/test_traces.py`` checks the JAX engine; and the whole-game
path (``native.run_battles``) ends every reference game as the reference does."""

from __future__ import annotations

import pytest

from hybridmarl.engine import native
from hybridmarl.engine.trace import parse_trace
from tests.conftest import TRACE_DIR
from tests.engine.reference_traces import TRACES, assert_same_trace, end_fields, trace_scripts


def test_all_reference_traces_present():
    assert len(TRACES) == 17


@pytest.mark.parametrize("name", TRACES)
def test_reference_trace_native(name, rules):
    p0, p1 = trace_scripts(name)
    ref = parse_trace((TRACE_DIR / name).read_text())
    assert ref.turns, "reference trace parsed empty"
    assert_same_trace(name, ref, native.record_trace(ref.units, rules, p0, p1))


def test_native_run_battles_match_trace_outcomes(rules):
    """All reference games through ``native.run_battles`` (states of different sizes padded to
    one shape, played in parallel), grouped by script pair."""
    pairs: dict[tuple[str, str], list[str]] = {}
    for n in TRACES:
        pairs.setdefault(trace_scripts(n), []).append(n)
    for (p0, p1), names in pairs.items():
        refs = [parse_trace((TRACE_DIR / n).read_text()) for n in names]
        res = native.run_battles([r.units for r in refs], p0, p1, rules=rules, progress=False)
        for i, r in enumerate(refs):
            end = end_fields(r.end)
            want_winner = -1 if end["winner"] == "draw" else int(end["winner"])
            assert int(res.winner[i]) == want_winner, names[i]
            assert int(res.final_time[i]) == int(end["final_time"]), names[i]
            assert int(res.turns[i]) == int(end["turns"]), names[i]
            assert res.unit_hp[i] == [r.turns[-1].hp[u] for u in range(len(r.units))], names[i]
