"""Every reference trace (SparCraft DC-HEAD, C++) reproduced turn by turn: decision times, movers,
every unit action in application order, HP after the turn, stored positions and both timers of every
living unit, and the next decision time."""

from __future__ import annotations

import pytest

from hybridmarl.engine.state import build_state
from hybridmarl.engine.trace import parse_trace, record_trace
from tests.conftest import TRACE_DIR
from tests.engine.reference_traces import TRACES, assert_same_trace, end_fields, trace_scripts


def test_all_reference_traces_present():
    assert len(TRACES) == 17


@pytest.mark.parametrize("name", TRACES)
def test_reference_trace(name, rules):
    p0, p1 = trace_scripts(name)
    ref = parse_trace((TRACE_DIR / name).read_text())
    assert ref.turns, "reference trace parsed empty"
    assert_same_trace(name, ref, record_trace(ref.units, build_state(ref.units), rules, p0, p1))


PAIRS = sorted({trace_scripts(n) for n in TRACES})


@pytest.mark.parametrize("pair", PAIRS)
def test_batched_games_match_trace_outcomes(pair):
    """The whole-game path (while_loop + vmap, states of different sizes padded to one shape)
    ends every reference game with the reference's winner, final time, turns and HP."""
    from hybridmarl.engine.battle import run_battles

    names = [n for n in TRACES if trace_scripts(n) == pair]
    refs = [parse_trace((TRACE_DIR / n).read_text()) for n in names]
    res = run_battles([r.units for r in refs], pair[0], pair[1], progress=False)
    for i, r in enumerate(refs):
        end = end_fields(r.end)
        want_winner = -1 if end["winner"] == "draw" else int(end["winner"])
        assert int(res.winner[i]) == want_winner, names[i]
        assert int(res.final_time[i]) == int(end["final_time"]), names[i]
        assert int(res.turns[i]) == int(end["turns"]), names[i]
        assert res.unit_hp[i] == [r.turns[-1].hp[u] for u in range(len(r.units))], names[i]
