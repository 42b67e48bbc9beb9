"""The search players' engine calls on the native CPU engine (``engine.native.search``).

:class:`NativeArgs` holds one decision's fixed inputs as NumPy arrays; :func:`search_call` and
:func:`pgs_call` take the same arguments as the compiled JAX programs ``kernels.search_fn`` and
``kernels.pgs_fn`` and return the same arrays (no padding: one row per entry given). Both engines
give equal results for every deterministic script (tested in ``tests/search/test_native_search.py``);
the ``random`` script draws from the native engine's own generator (docs/engine-backends.md).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hybridmarl.engine.state import GameState, Rules
from hybridmarl.search import kernels as K

_compiled = False


def _writable(a: Any, dtype: Any) -> np.ndarray:
    # C-contiguous and writable: read-only views (of JAX arrays, broadcasts) are a distinct Numba
    # type that would compile the kernels again.
    return np.require(a, dtype=dtype, requirements=["C", "W"])


def pack_state_host(state: GameState) -> tuple[np.ndarray, K.Consts]:
    """``kernels.pack_state`` on the host: the packed vector and constants of one state."""
    parts = [np.asarray(getattr(state, f), np.int32).reshape(-1) for f in K.DYNAMIC_FIELDS]
    prev = np.asarray(state.prev_hp_sum, np.int32).reshape(-1)
    scalars = np.array(
        [int(state.time), int(state.turn), int(state.stale), int(prev[0]), int(prev[1])], np.int32
    )
    vec = np.concatenate(parts + [scalars]).astype(np.int32)
    consts = K.Consts(
        utype=_writable(np.asarray(state.utype), np.int32),
        uid=_writable(np.asarray(state.uid), np.int32),
        ltd_total=_writable(np.asarray(state.ltd_total), np.float32),
        ltd2_total=_writable(np.asarray(state.ltd2_total), np.float32),
    )
    return vec, consts


class NativeArgs:
    """One decision's fixed kernel inputs: unit constants, map, rules."""

    def __init__(self, consts: K.Consts, rules: Rules):
        self.utype = _writable(consts.utype, np.int32)
        self.uid = _writable(consts.uid, np.int32)
        self.ltd_total = _writable(consts.ltd_total, np.float32)
        self.ltd2_total = _writable(consts.ltd2_total, np.float32)
        self.walkable = _writable(np.asarray(rules.walkable), np.bool_)
        self.overkill_pass = bool(rules.overkill == "pass")
        self.stalemate_limit = int(rules.stalemate_limit)


def script_codes(names: tuple[str, ...]) -> np.ndarray:
    from hybridmarl.engine.native.kernels import SCRIPT_CODES

    return np.array([SCRIPT_CODES[n] for n in names], np.int64)


def _chunks(m: int) -> int:
    import numba

    return max(1, min(m, 4 * numba.get_num_threads()))


def compile_search_kernels() -> float:
    """Compile (or load from the on-disk cache) the native search kernels; seconds spent."""
    global _compiled
    import time

    from hybridmarl.engine.native import compile_kernels

    t0 = time.perf_counter()
    compile_kernels()
    if not _compiled:
        from hybridmarl.engine.state import UnitSpec, build_state, make_rules

        st = build_state(
            [UnitSpec("Terran_Marine", 0, 100, 100), UnitSpec("Terran_Marine", 1, 140, 100)]
        )
        vec, consts = pack_state_host(st)
        args = NativeArgs(consts, make_rules())
        search_call(
            args,
            vec[None],
            np.zeros((1, 2, 1), np.int32),
            np.ones((1, 2), bool),
            np.ones(1, bool),
            0,
            2,
            False,
            ("nokdps",),
            ("nokdps", "nokdps"),
            0,
        )
        pgs_call(args, vec, np.zeros((1, 2, 1), np.int32), np.zeros(1, np.int32), ("nokdps",), 2, 0)
        _compiled = True
    return time.perf_counter() - t0


def search_call(
    args: NativeArgs,
    base: np.ndarray,
    actions: np.ndarray,
    mask: np.ndarray,
    do_step: np.ndarray,
    player: int,
    cap: int,
    use_ltd: bool,
    info_scripts: tuple[str, ...],
    playout_scripts: tuple[str, str],
    seed: int,
) -> dict[str, Any]:
    """``kernels.search_fn``'s result for ``m`` entries (``base`` [m, L] or one [L] state for
    all, ``actions`` [m, 2, U], ``mask`` [m, 2], ``do_step`` [m])."""
    from hybridmarl.engine.native.search import search_batch

    m = actions.shape[0]
    n = args.utype.shape[1]
    if base.ndim == 1:
        base = np.broadcast_to(base, (m, base.shape[0]))
    vecs = _writable(base, np.int32)
    codes = script_codes(info_scripts)
    pcodes = script_codes(playout_scripts)
    s = len(info_scripts)
    child = np.empty((m, vecs.shape[1]), np.int32)
    step_moves = np.empty((m, 2), np.int32)
    movers = np.empty((m, 2), np.bool_)
    acting = np.empty((m, 2, n), np.bool_)
    legal = np.empty((m, 2, n, K.R.ATTACK_BASE + n), np.bool_)
    order = np.empty((m, 2, n), np.int32)
    scripts = np.empty((m, s, 2, n), np.int32)
    terminal = np.empty(m, np.bool_)
    ev = np.empty((m, 2), np.int32)
    hash_mat = np.empty((m, 2, n, 6), np.int32)
    value = np.empty(m, np.int32)
    pmoves = np.empty(m, np.int32)
    both_dead = np.empty(m, np.bool_)
    search_batch(
        vecs,
        _writable(actions, np.int32),
        _writable(mask, np.bool_),
        _writable(do_step, np.bool_),
        np.full(m, player, np.int32),
        int(cap),
        bool(use_ltd),
        args.utype,
        args.uid,
        args.ltd_total,
        args.ltd2_total,
        args.walkable,
        codes,
        int(pcodes[0]),
        int(pcodes[1]),
        args.overkill_pass,
        args.stalemate_limit,
        int(seed),
        _chunks(m),
        child,
        step_moves,
        movers,
        acting,
        legal,
        order,
        scripts,
        terminal,
        ev,
        hash_mat,
        value,
        pmoves,
        both_dead,
    )
    return {
        "child": child,
        "step_moves": step_moves,
        "info": {
            "movers": movers,
            "acting": acting,
            "legal": legal,
            "order": order,
            "scripts": scripts,
            "terminal": terminal,
            "ev": ev,
            "hash": hash_mat,
        },
        "value": value,
        "playout_moves": pmoves,
        "both_dead": both_dead,
    }


def pgs_call(
    args: NativeArgs,
    vec: np.ndarray,
    assign: np.ndarray,
    player: np.ndarray,
    scripts: tuple[str, ...],
    turns: int,
    seed: int,
) -> np.ndarray:
    """``kernels.pgs_fn``'s values for ``m`` assignments (``assign`` [m, 2, U], ``player`` [m])."""
    from hybridmarl.engine.native.search import pgs_batch

    m = assign.shape[0]
    out = np.empty(m, np.int32)
    pgs_batch(
        _writable(vec, np.int32),
        _writable(assign, np.int32),
        _writable(player, np.int32),
        int(turns),
        args.utype,
        args.uid,
        args.ltd2_total,
        args.walkable,
        script_codes(scripts),
        args.overkill_pass,
        args.stalemate_limit,
        int(seed),
        _chunks(m),
        out,
    )
    return out
