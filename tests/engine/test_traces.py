"""Every reference trace (SparCraft DC-HEAD, C++) reproduced turn by turn: decision times, movers,
every unit action in application order, HP after the turn, stored positions and both timers of every
living unit, and the next decision time."""

from __future__ import annotations

import pytest

from hybridmarl.engine.state import build_state
from hybridmarl.engine.trace import SPARCRAFT_SCRIPT_NAMES, parse_trace, record_trace
from tests.conftest import TRACE_DIR

TRACES = sorted(p.name for p in TRACE_DIR.glob("trace_*.txt"))


def test_all_reference_traces_present():
    assert len(TRACES) == 17


@pytest.mark.parametrize("name", TRACES)
def test_reference_trace(name, rules):
    parts = name[:-4].split("_")
    p0, p1 = SPARCRAFT_SCRIPT_NAMES[parts[3]], SPARCRAFT_SCRIPT_NAMES[parts[5]]
    ref = parse_trace((TRACE_DIR / name).read_text())
    assert ref.turns, "reference trace parsed empty"
    ours = record_trace(ref.units, build_state(ref.units), rules, p0, p1)
    for a, b in zip(ref.turns, ours.turns, strict=False):
        where = f"{name} turn {a.turn}"
        assert (b.turn, b.time, b.mover) == (a.turn, a.time, a.mover), where
        assert b.actions == a.actions, where
        assert b.hp == a.hp, where
        assert b.units == a.units, where
        assert b.next_time == a.next_time, where
    assert len(ours.turns) == len(ref.turns)
    # The END line: winner and final time.
    end = dict(kv.split("=", 1) for kv in ref.end.split()[1:] if "=" in kv)
    assert int(end["final_time"]) == ours.turns[-1].next_time
    assert int(end["turns"]) == len(ours.turns)


def _end_fields(text: str) -> dict:
    return dict(kv.split("=", 1) for kv in text.split()[1:] if "=" in kv)


PAIRS = sorted({tuple(n[:-4].split("_")[3:6:2]) for n in TRACES})


@pytest.mark.parametrize("pair", PAIRS)
def test_batched_games_match_trace_outcomes(pair):
    """The whole-game path (while_loop + vmap, states of different sizes padded to one shape)
    ends every reference game with the reference's winner, final time, turns and HP."""
    from hybridmarl.engine.battle import run_battles

    names = [n for n in TRACES if tuple(n[:-4].split("_")[3:6:2]) == pair]
    refs = [parse_trace((TRACE_DIR / n).read_text()) for n in names]
    res = run_battles([r.units for r in refs], SPARCRAFT_SCRIPT_NAMES[pair[0]], SPARCRAFT_SCRIPT_NAMES[pair[1]], progress=False)
    for i, r in enumerate(refs):
        end = _end_fields(r.end)
        want_winner = -1 if end["winner"] == "draw" else int(end["winner"])
        assert int(res.winner[i]) == want_winner, names[i]
        assert int(res.final_time[i]) == int(end["final_time"]), names[i]
        assert int(res.turns[i]) == int(end["turns"]), names[i]
        assert res.unit_hp[i] == [r.turns[-1].hp[u] for u in range(len(r.units))], names[i]
