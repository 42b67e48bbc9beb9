"""Turn-by-turn traces in the text format of SparCraft's reference traces (``tests/data/sparcraft_traces``; docs/engine.md#reference-traces).

``record_trace`` plays a game turn by turn (one jitted turn function, a host loop) and returns the
same records the reference C++ tracer printed; ``parse_trace`` reads a reference file. Tests compare
the two record by record, and ``format_trace`` writes ours in the reference format for diffing.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field

import jax
import numpy as np

from hybridmarl.engine import rules as R
from hybridmarl.engine.game import play_turn
from hybridmarl.engine.scripts import canonical_name, get_script
from hybridmarl.engine.state import GameState, Rules, UnitSpec
from hybridmarl.engine.units import PASS_DURATION

SPARCRAFT_SCRIPT_NAMES = {
    "AttackClosest": "attack-closest",
    "AttackWeakest": "attack-weakest",
    "AttackDPS": "attack-dps",
    "NOKDPS": "nokdps",
    "Kiter": "kiter",
    "KiterDPS": "kiter-dps",
    "Kiter_NOKDPS": "kiter-nokdps",
    "Cluster": "cluster",
}


@dataclass
class TurnRecord:
    turn: int
    time: int
    mover: str  # "P0" | "P1" | "BOTH"
    actions: list[str]  # e.g. "1 P1 MOVE dest=(751,366)" in application order
    hp: dict[int, int]  # unit id -> HP after the turn
    units: dict[int, tuple[int, int, int, int]]  # alive id -> (x, y, tMove, tAtk) after the turn
    next_time: int


@dataclass
class Trace:
    units: list[UnitSpec]
    turns: list[TurnRecord] = field(default_factory=list)
    end: str = ""


_ACT_RE = re.compile(r"^\s*ACT (\d+) P(\d) (.*)$")


def parse_trace(text: str) -> Trace:
    """Parse a reference trace file."""
    trace = Trace(units=[])
    cur: TurnRecord | None = None
    for line in text.splitlines():
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        if s.startswith("UNIT "):
            _, _uid, player, typ, x, y, _hp = s.split()
            trace.units.append(UnitSpec(typ, int(player), int(x), int(y)))
        elif s.startswith("TURN "):
            m = re.match(r"TURN (\d+) time=(\d+) mover=(\S+)", s)
            assert m, s
            cur = TurnRecord(int(m[1]), int(m[2]), m[3], [], {}, {}, -1)
            trace.turns.append(cur)
        elif s.startswith("ACT "):
            assert cur is not None
            m = _ACT_RE.match(s)
            assert m, s
            body = m[3].replace(" (target already dead -> PASS)", " [overkill->PASS]")
            cur.actions.append(f"{m[1]} P{m[2]} {body}")
        elif s.startswith("HP"):
            assert cur is not None
            cur.hp = {int(a): int(b) for a, b in (tok.split(":") for tok in s.split()[1:])}
        elif s.startswith("STATE"):
            assert cur is not None
            for tok in s.split()[1:]:
                m = re.match(r"(\d+):\((-?\d+),(-?\d+)\)/(-?\d+)/(-?\d+)", tok)
                assert m, tok
                cur.units[int(m[1])] = (int(m[2]), int(m[3]), int(m[4]), int(m[5]))
        elif s.startswith("NEXT"):
            assert cur is not None
            cur.next_time = int(s.split("=")[1])
        elif s.startswith("END"):
            trace.end = s
    return trace


@functools.lru_cache(maxsize=32)
def _turn_fn(p0: str, p1: str, stalemate_limit: int, overkill: str, max_turns: int):
    s0, s1 = get_script(p0), get_script(p1)

    def f(key, state, walkable):
        rules = Rules(
            walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=max_turns
        )
        new, actions, ctx = play_turn(key, state, rules, s0, s1)
        done = R.game_over(new, rules)
        return new, actions, ctx, done

    return jax.jit(f)


def _describe(state: GameState, new: GameState, ctx, actions: np.ndarray, p: int, s: int) -> str:
    uid = int(state.uid[p, s])
    code = int(actions[p, s])
    q = 1 - p
    if code >= R.ATTACK_BASE:
        j = code - R.ATTACK_BASE
        text = f"ATTACK target={int(state.uid[q, j])}"
        t = int(state.time)
        if (
            int(new.t_move[p, s]) == t + PASS_DURATION
            and int(new.t_attack[p, s]) == t + PASS_DURATION
        ):
            # executed as a PASS: the target died earlier in the turn
            text += " [overkill->PASS]"
    elif code in R.MOVE_ACTIONS:
        text = f"MOVE dest=({int(new.x[p, s])},{int(new.y[p, s])})"
    elif code == R.RELOAD_ACTION:
        text = "RELOAD"
    else:
        text = "PASS"
    return f"{uid} P{p} {text}"


def record_trace(
    units: list[UnitSpec],
    state: GameState,
    rules: Rules,
    p0: str,
    p1: str,
    seed: int = 0,
) -> Trace:
    """Play ``state`` turn by turn with scripts ``p0``/``p1`` and record every turn."""
    fn = _turn_fn(
        canonical_name(p0),
        canonical_name(p1),
        rules.stalemate_limit,
        rules.overkill,
        rules.max_turns,
    )
    key = jax.random.PRNGKey(seed)
    trace = Trace(units=list(units))
    n_units = len(units)
    done = bool(R.game_over(state, rules))
    while not done:
        key, sub = jax.random.split(key)
        new, actions, ctx, done_arr = fn(sub, state, rules.walkable)
        done = bool(done_arr)
        st = jax.tree.map(np.asarray, state)
        nw = jax.tree.map(np.asarray, new)
        acts = np.asarray(actions)
        acting = np.asarray(ctx.acting)
        movers = np.asarray(ctx.movers)
        mover = "BOTH" if movers.all() else ("P0" if movers[0] else "P1")
        lines = []
        for p in (1, 0):
            slots = [s for s in range(acting.shape[1]) if acting[p, s]]
            slots.sort(key=lambda s, p=p: int(st.uid[p, s]))
            lines += [_describe(st, nw, ctx, acts, p, s) for s in slots]
        hp: dict[int, int] = {}
        alive: dict[int, tuple[int, int, int, int]] = {}
        for p in range(2):
            for s in range(nw.hp.shape[1]):
                u = int(nw.uid[p, s])
                if u >= n_units:
                    continue
                hp[u] = max(int(nw.hp[p, s]), 0)
                if nw.hp[p, s] > 0:
                    alive[u] = (
                        int(nw.x[p, s]),
                        int(nw.y[p, s]),
                        int(nw.t_move[p, s]),
                        int(nw.t_attack[p, s]),
                    )
        trace.turns.append(
            TurnRecord(int(st.turn), int(st.time), mover, lines, hp, alive, int(nw.time))
        )
        state = new
    return trace


def format_trace(trace: Trace) -> str:
    out = []
    for i, u in enumerate(trace.units):
        out.append(f"UNIT {i} {u.player} {u.type} {u.x} {u.y}")
    for t in trace.turns:
        out.append(f"TURN {t.turn} time={t.time} mover={t.mover}")
        out += [f"  ACT {a}" for a in t.actions]
        out.append("  HP " + " ".join(f"{k}:{v}" for k, v in sorted(t.hp.items())))
        out.append(
            "  STATE "
            + " ".join(f"{k}:({x},{y})/{tm}/{ta}" for k, (x, y, tm, ta) in sorted(t.units.items()))
        )
        out.append(f"  NEXT time={t.next_time}")
    return "\n".join(out) + "\n"
