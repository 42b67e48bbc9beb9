"""The reference SparCraft traces and the turn-by-turn comparison both engine backends must pass
(``test_traces`` for the JAX engine, ``test_native_traces`` for the native one)."""

from __future__ import annotations

from hybridmarl.engine.trace import SPARCRAFT_SCRIPT_NAMES
from tests.conftest import TRACE_DIR

TRACES = sorted(p.name for p in TRACE_DIR.glob("trace_*.txt"))


def trace_scripts(name: str) -> tuple[str, str]:
    """The two scripts of a trace file, ``trace_<size>_<state>_<P0>_vs_<P1>[...].txt``."""
    parts = name[:-4].split("_")
    return SPARCRAFT_SCRIPT_NAMES[parts[3]], SPARCRAFT_SCRIPT_NAMES[parts[5]]


def end_fields(text: str) -> dict[str, str]:
    """The ``key=value`` fields of a trace's END line."""
    return dict(kv.split("=", 1) for kv in text.split()[1:] if "=" in kv)


def assert_same_trace(name: str, ref, ours) -> None:
    """Every turn equal (decision time, mover, unit actions in order, HP, positions and timers,
    next decision time), the same number of turns, and the END line's final time and turns."""
    for a, b in zip(ref.turns, ours.turns, strict=False):
        where = f"{name} turn {a.turn}"
        assert (b.turn, b.time, b.mover) == (a.turn, a.time, a.mover), where
        assert b.actions == a.actions, where
        assert b.hp == a.hp, where
        assert b.units == a.units, where
        assert b.next_time == a.next_time, where
    assert len(ours.turns) == len(ref.turns)
    end = end_fields(ref.end)
    assert int(end["final_time"]) == ours.turns[-1].next_time
    assert int(end["turns"]) == len(ours.turns)
