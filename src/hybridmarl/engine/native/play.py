"""Playing games on the native backend: whole batches in parallel, K turns at a time, single
turns (with scripted or caller-given actions), reference-format traces, and ``run_battles``.

Every function takes the same ``Rules`` and script names as the JAX engine and gives the same
results; the ``random`` script is the exception (see ``docs/engine-backends.md``): it draws from
its own counter-based generator, reproducible per seed but not equal to JAX's draws.
"""

from __future__ import annotations

import sys
import time as _time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from hybridmarl.engine.battle import BattleResults
from hybridmarl.engine.native import kernels as K
from hybridmarl.engine.native.state import NativeStates, build_native_states
from hybridmarl.engine.scenarios import InputError
from hybridmarl.engine.scripts import canonical_name
from hybridmarl.engine.state import PAD_ID_BASE, Rules, UnitSpec, make_rules
from hybridmarl.engine.trace import Trace, TurnRecord

#: Seconds the first ``compile_kernels`` call took in this process (None before it ran).
compile_seconds: float | None = None
_ready = False


@dataclass
class NativeResults:
    """Per-game outcomes of ``play`` (the fields of ``engine.game.GameResult``, as NumPy)."""

    winner: np.ndarray  # int32 [B]: 0, 1, or -1 for a draw / unfinished
    final_time: np.ndarray  # int32 [B]
    turns: np.ndarray  # int32 [B]
    hp: np.ndarray  # int32 [B, 2, U]
    ltd2_eval: np.ndarray  # int32 [B]
    unit_actions: np.ndarray  # int32 [B]


def threading_layer() -> str:
    """The Numba threading layer in use (runs the kernels once if none ran yet)."""
    compile_kernels()
    return str(numba.threading_layer())


def _cached_on_disk() -> bool:
    """Whether Numba's on-disk cache already holds the batch kernel (best effort)."""
    try:
        cache = K.play_games._cache  # type: ignore[attr-defined]
        return Path(cache._cache_file._index_path).exists()
    except Exception:
        return False


def compile_kernels(quiet: bool = False) -> float:
    """Compile (or load from Numba's cache) every kernel, once per process, with a one-line note
    on stderr while it runs. Returns the seconds it took (0.0 if already done)."""
    global _ready, compile_seconds
    if _ready:
        return 0.0
    note = not quiet and not _cached_on_disk()
    if note:
        print(
            "hybridmarl: compiling the native engine (first run only, about a minute; cached afterwards) ...",
            end="",
            file=sys.stderr,
            flush=True,
        )
    start = _time.perf_counter()
    tiny = build_native_states(
        [[UnitSpec("Terran_Marine", 0, 100, 100), UnitSpec("Terran_Marine", 1, 140, 100)]]
    )
    walkable = np.ones((4, 4), np.bool_)
    codes = np.zeros(1, np.int64)
    _run_kernel(tiny, walkable, codes, codes, True, 50, 20000, -1, 0, np.zeros(1, np.int64), 1)
    acts = np.zeros((2, 1), np.int64)
    K.step_one(
        0,
        tiny.unit_fields(),
        tiny.time,
        tiny.turn,
        tiny.stale,
        tiny.prev_hp_sum,
        walkable,
        K.EXTERNAL,
        K.EXTERNAL,
        True,
        0,
        0,
        acts,
        np.zeros((2, 1), np.bool_),
        np.zeros(2, np.bool_),
    )
    compile_seconds = _time.perf_counter() - start
    if note:
        print(f" done in {compile_seconds:.1f} s", file=sys.stderr, flush=True)
    _ready = True
    return compile_seconds


def _run_kernel(
    states: NativeStates,
    walkable,
    s0,
    s1,
    overkill_pass,
    stalemate_limit,
    max_turns,
    turn_budget,
    seed,
    game_ids,
    threads,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    b = states.batch_size
    winner = np.zeros(b, np.int32)
    ltd2 = np.zeros(b, np.int32)
    n_actions = np.zeros(b, np.int32)
    if threads is not None:
        numba.set_num_threads(int(threads))
    chunks = max(1, min(b, numba.get_num_threads() * 16))
    s0 = np.array(np.broadcast_to(np.asarray(s0, np.int64), (b,)))
    s1 = np.array(np.broadcast_to(np.asarray(s1, np.int64), (b,)))
    K.play_games(
        states.unit_fields(),
        states.time,
        states.turn,
        states.stale,
        states.prev_hp_sum,
        states.ltd2_total,
        walkable,
        s0,
        s1,
        overkill_pass,
        stalemate_limit,
        max_turns,
        turn_budget,
        seed,
        game_ids,
        chunks,
        winner,
        ltd2,
        n_actions,
    )
    return winner, ltd2, n_actions


def _script_code(name: str | None) -> int:
    if name is None:
        return K.EXTERNAL
    return K.SCRIPT_CODES[canonical_name(name)]


def _script_codes(names: str | Sequence[str]) -> np.ndarray | int:
    """One script code, or one per game for a sequence of names (mixed match-ups in a batch)."""
    if isinstance(names, str):
        return _script_code(names)
    return np.array([_script_code(n) for n in names], np.int64)


def _walkable(rules: Rules) -> np.ndarray:
    # A writable copy: NumPy views of JAX arrays are read-only, a distinct Numba type that
    # would compile the kernels a second time.
    return np.array(rules.walkable, dtype=np.bool_, order="C", copy=True)


def play(
    states: NativeStates,
    rules: Rules,
    p0: str | Sequence[str],
    p1: str | Sequence[str],
    *,
    seed: int = 0,
    threads: int | None = None,
    game_ids: np.ndarray | None = None,
    in_place: bool = False,
) -> tuple[NativeStates, NativeResults]:
    """Play every game of the batch to its end (``game.play_game`` for each). Returns the final
    states and the results. ``p0``/``p1``: a script name, or one per game. ``game_ids`` (default 0..B-1) and ``seed`` feed the random script."""
    compile_kernels()
    final = states if in_place else states.copy()
    ids = (
        np.arange(final.batch_size, dtype=np.int64)
        if game_ids is None
        else np.asarray(game_ids, np.int64)
    )
    winner, ltd2, n_actions = _run_kernel(
        final,
        _walkable(rules),
        _script_codes(p0),
        _script_codes(p1),
        rules.overkill == "pass",
        rules.stalemate_limit,
        rules.max_turns,
        -1,
        int(seed),
        ids,
        threads,
    )
    res = NativeResults(
        winner, final.time.copy(), final.turn.copy(), final.hp.copy(), ltd2, n_actions
    )
    return final, res


def advance(
    states: NativeStates,
    rules: Rules,
    p0: str | Sequence[str],
    p1: str | Sequence[str],
    turns: int,
    *,
    seed: int = 0,
    threads: int | None = None,
) -> NativeStates:
    """The batch after ``turns`` more decision turns; a game that ends sooner stays at its end.
    ``p0``/``p1``: a script name, or one per game."""
    compile_kernels()
    out = states.copy()
    _run_kernel(
        out,
        _walkable(rules),
        _script_codes(p0),
        _script_codes(p1),
        rules.overkill == "pass",
        rules.stalemate_limit,
        rules.max_turns,
        int(turns),
        int(seed),
        np.arange(out.batch_size, dtype=np.int64),
        threads,
    )
    return out


def step(
    states: NativeStates,
    index: int,
    rules: Rules,
    p0: str | None,
    p1: str | None,
    *,
    actions: np.ndarray | None = None,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Play one decision turn of game ``index`` in place (whether or not it is over, like
    ``game.play_turn``). A side whose script is None plays its row of ``actions`` (int [2, U],
    action codes of ``engine.rules``). Returns (actions played [2, U], acting [2, U], movers [2])."""
    compile_kernels()
    n = states.num_slots
    acts = (
        np.zeros((2, n), np.int64)
        if actions is None
        else np.array(actions, dtype=np.int64).reshape(2, n)
    )
    acting = np.zeros((2, n), np.bool_)
    movers = np.zeros(2, np.bool_)
    K.step_one(
        int(index),
        states.unit_fields(),
        states.time,
        states.turn,
        states.stale,
        states.prev_hp_sum,
        _walkable(rules),
        _script_code(p0),
        _script_code(p1),
        rules.overkill == "pass",
        int(seed),
        int(index),
        acts,
        acting,
        movers,
    )
    return acts, acting, movers


def apply_actions(
    states: NativeStates, index: int, actions: np.ndarray, rules: Rules
) -> np.ndarray:
    """Play one turn of game ``index`` in place with the given actions for both sides (for search
    code: ``rules.apply_actions`` of the turn's context). Returns the acting mask [2, U]."""
    return step(states, index, rules, None, None, actions=actions)[1]


def game_over(states: NativeStates, index: int, rules: Rules) -> bool:
    return bool(
        K.game_over(
            states.utype[index],
            states.hp[index],
            int(states.stale[index]),
            int(states.turn[index]),
            rules.stalemate_limit,
            rules.max_turns,
        )
    )


def _describe(before: NativeStates, after: NativeStates, actions, p: int, s: int) -> str:
    uid = int(before.uid[0, p, s])
    code = int(actions[p, s])
    if code >= K.ATTACK_BASE:
        text = f"ATTACK target={int(before.uid[0, 1 - p, code - K.ATTACK_BASE])}"
        t = int(before.time[0])
        if (
            int(after.t_move[0, p, s]) == t + K.PASS_DURATION
            and int(after.t_attack[0, p, s]) == t + K.PASS_DURATION
        ):
            text += " [overkill->PASS]"
    elif K.MOVE_BASE <= code < K.ATTACK_BASE:
        text = f"MOVE dest=({int(after.x[0, p, s])},{int(after.y[0, p, s])})"
    elif code == K.RELOAD_ACTION:
        text = "RELOAD"
    else:
        text = "PASS"
    return f"{uid} P{p} {text}"


def record_trace(units: list[UnitSpec], rules: Rules, p0: str, p1: str, seed: int = 0) -> Trace:
    """``engine.trace.record_trace`` on the native engine: every turn in the reference format."""
    state = build_native_states([units])
    trace = Trace(units=list(units))
    n_units = len(units)
    while not game_over(state, 0, rules):
        before = state.copy()
        acts, acting, movers = step(state, 0, rules, p0, p1, seed=seed)
        mover = "BOTH" if movers.all() else ("P0" if movers[0] else "P1")
        lines = []
        for p in (1, 0):
            slots = sorted(
                (s for s in range(state.num_slots) if acting[p, s]),
                key=lambda s, p=p: int(before.uid[0, p, s]),
            )
            lines += [_describe(before, state, acts, p, s) for s in slots]
        hp: dict[int, int] = {}
        alive: dict[int, tuple[int, int, int, int]] = {}
        for p in range(2):
            for s in range(state.num_slots):
                u = int(state.uid[0, p, s])
                if u >= n_units:
                    continue
                hp[u] = max(int(state.hp[0, p, s]), 0)
                if state.hp[0, p, s] > 0:
                    alive[u] = (
                        int(state.x[0, p, s]),
                        int(state.y[0, p, s]),
                        int(state.t_move[0, p, s]),
                        int(state.t_attack[0, p, s]),
                    )
        trace.turns.append(
            TurnRecord(
                int(before.turn[0]),
                int(before.time[0]),
                mover,
                lines,
                hp,
                alive,
                int(state.time[0]),
            )
        )
    return trace


def unit_hp_lists(final_hp: np.ndarray, uid: np.ndarray, sizes: Sequence[int]) -> list[list[int]]:
    """Final HP per unit id (0 if dead) for each game, from [B, 2, U] HP and ids."""
    b = final_hp.shape[0]
    width = max(max(sizes, default=0), 1)
    table = np.zeros((b, width), np.int64)
    flat_uid = uid.reshape(b, -1)
    flat_hp = np.maximum(final_hp.reshape(b, -1), 0)
    keep = flat_uid < np.asarray(sizes)[:, None]
    rows = np.broadcast_to(np.arange(b)[:, None], flat_uid.shape)
    table[rows[keep], flat_uid[keep]] = flat_hp[keep]
    return [table[i, : sizes[i]].tolist() for i in range(b)]


def run_battles(
    states: Sequence[Sequence[UnitSpec]] | NativeStates,
    p0: str,
    p1: str,
    *,
    seed: int = 0,
    rules: Rules | None = None,
    batch_size: int = 16384,
    progress: bool = True,
    threads: int | None = None,
) -> BattleResults:
    """``engine.battle.run_battles`` on the native engine: same arguments, same result type and
    values (``batch_size`` only sets how many games run per kernel call, i.e. progress steps).
    ``states`` may also be a ready ``NativeStates`` batch (e.g. ``from_arrays`` of
    ``Scenario.generate_arrays``), which skips building per-unit objects."""
    try:
        p0c, p1c = canonical_name(p0), canonical_name(p1)
    except KeyError as e:
        raise InputError(str(e.args[0])) from None
    if (states.batch_size if isinstance(states, NativeStates) else len(states)) == 0:
        raise InputError("no start states to play")
    rules = make_rules() if rules is None else rules
    if isinstance(states, NativeStates):
        native = states.copy()
        sizes = (native.uid < PAD_ID_BASE).sum(axis=(1, 2)).tolist()
    else:
        native = build_native_states(states)
        sizes = [len(s) for s in states]
    compile_kernels(quiet=not progress)
    n = native.batch_size
    bar = None
    if progress:
        from hybridmarl.engine.battle import _progress

        bar = _progress(True, n, f"{p0c} vs {p1c} (native)")
    parts = []
    for start in range(0, n, batch_size):
        stop = min(start + batch_size, n)
        chunk = native.take(slice(start, stop))
        _, res = play(
            chunk,
            rules,
            p0c,
            p1c,
            seed=seed,
            threads=threads,
            game_ids=np.arange(start, stop, dtype=np.int64),
            in_place=True,
        )
        parts.append(res)
        if bar is not None:
            bar[0].update(bar[1], advance=stop - start)
    if bar is not None:
        bar[0].stop()

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(r, name) for r in parts])

    return BattleResults(
        p0=p0c,
        p1=p1c,
        winner=cat("winner"),
        final_time=cat("final_time"),
        turns=cat("turns"),
        unit_hp=unit_hp_lists(cat("hp"), native.uid, sizes),
        ltd2_eval=cat("ltd2_eval"),
        unit_actions=cat("unit_actions"),
    )
