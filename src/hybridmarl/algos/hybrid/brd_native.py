"""Alg. 1 on the native engine: the same best-response dynamics as ``brd``, run on the host.

``brd.best_response_dynamics`` runs Alg. 1 under ``jit`` on the JAX engine. On a CPU the
simulation of candidate joint actions dominates it, so for combat this module runs the whole of
Alg. 1 for all games of one env step in one host call: the sweeps and their bookkeeping in
NumPy, the simulation of every (game, candidate) pair a visit needs in one parallel Numba
kernel (the env step of ``hybridmarl.envs.combat.native``, then the scripted continuation of a
look-ahead), and the critic's forward pass as a Numba MLP with the current weights
(:class:`NativeMLP`, batch norm folded into the dense layers).

The schedule, tie rules, early exit and outputs are those of ``brd`` (see its docstring): the
same games visited in the same order, the same strict-improvement rule, the same Ã. The
simulated returns are those of the JAX env exactly (tested); the critic's values agree to float
rounding (XLA and NumPy sum in different orders), which can flip a near-tie between two
actions. Supported Q estimates (:func:`native_support`): Eq. 2's one step, or K steps with the
demonstrator script playing the continuation (the ``quick`` preset), against a scripted enemy.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numba import njit, prange

from hybridmarl.engine.native.kernels import SCRIPT_CODES, make_workspace, njit_without_refcount
from hybridmarl.envs.combat.native import (
    CRITIC_FEATURES,
    critic_features,
    env_step,
    script_env_actions,
    state_arrays,
)


@njit(cache=True, parallel=True)
def simulate_candidates(
    fields,
    time,
    turn,
    stale,
    prev_hp_sum,
    init_hp0,
    walkable,
    games,
    joint,
    num_agents,
    num_enemies,
    num_actions,
    enemy,
    continuation,
    steps,
    gamma,
    overkill_pass,
    stalemate_limit,
    max_turns,
    seed,
    n_chunks,
    ret_out,
    disc_out,
    ended_out,
    feats_out,
):
    """For every pair ``i``: game ``games[i]`` of the batch plays ``joint[i]`` for one env step,
    then ``continuation`` (our side's script) for up to ``steps - 1`` more, against the
    ``enemy`` script. Writes the discounted return ``sum_t γ^t r_t``, the discount ``γ^K`` at
    the end, whether the game ended, and the critic features of the last state (when it did not
    end). The batch's states are read, never written. Pairs ``c, c + n_chunks, ...`` form chunk
    ``c``; the chunks run in parallel."""
    n = fields[8].shape[2]
    # Every chunk's scratch is allocated here, so that the chunk itself allocates nothing and
    # is compiled without reference counting (see _simulate_chunk).
    game = np.empty((n_chunks, 11, 2, n), np.int32)
    clock = np.empty((n_chunks, 5), np.int32)
    ranks = np.empty((n_chunks, 2, n), np.int64)
    acts = np.empty((n_chunks, num_agents), np.int64)
    values = np.empty((n_chunks, 2, n), np.float32)
    for c in prange(n_chunks):
        # A plain (serial) function per chunk: Numba compiles it as such, not as a parfor body.
        # np.int64(c): the parfor's index is unsigned, and another argument type is another compile.
        _simulate_chunk(
            np.int64(c),
            n_chunks,
            fields,
            time,
            turn,
            stale,
            prev_hp_sum,
            init_hp0,
            walkable,
            games,
            joint,
            num_agents,
            num_enemies,
            num_actions,
            enemy,
            continuation,
            steps,
            gamma,
            overkill_pass,
            stalemate_limit,
            max_turns,
            seed,
            ret_out,
            disc_out,
            ended_out,
            feats_out,
            game[c],
            clock[c],
            make_workspace(n),
            ranks[c],
            acts[c],
            values[c],
        )


@njit_without_refcount
def _simulate_chunk(
    c,
    n_chunks,
    fields,
    time,
    turn,
    stale,
    prev_hp_sum,
    init_hp0,
    walkable,
    games,
    joint,
    num_agents,
    num_enemies,
    num_actions,
    enemy,
    continuation,
    steps,
    gamma,
    overkill_pass,
    stalemate_limit,
    max_turns,
    seed,
    ret_out,
    disc_out,
    ended_out,
    feats_out,
    game,
    clock,
    ws,
    ranks,
    acts,
    values,
):
    """Chunk ``c`` of :func:`simulate_candidates` in the given scratch: ``game`` ``[11, 2, U]``
    (one state's unit fields), ``clock`` ``[5]`` (time, turn, stale, prev_hp_sum), ``ws`` (an
    engine workspace), ``ranks`` ``[2, U]``, ``acts`` ``[N]``, ``values`` ``[2, U]``.

    Compiled without Numba's reference counting (``_nrt=False``): it allocates nothing, and the
    atomic reference-count updates on every array it passes on were most of its run time."""
    m = games.shape[0]
    n = game.shape[2]
    s_utype, s_uid, s_x, s_y, s_px, s_py = game[0], game[1], game[2], game[3], game[4], game[5]
    s_tact, s_last, s_hp, s_tmove, s_tatk = game[6], game[7], game[8], game[9], game[10]
    s_time, s_turn, s_stale = clock[0:1], clock[1:2], clock[2:3]
    s_prev = clock[3:5].reshape((1, 2))
    rank_slot, rank_of = ranks[0], ranks[1]
    g0 = np.int64(0)  # the scratch state's index
    for i in range(c, m, n_chunks):
        g = games[i]
        for f in range(11):  # a plain loop: a slice assignment may allocate a temporary
            src = fields[f]
            for p in range(2):
                for u in range(n):
                    game[f, p, u] = src[g, p, u]
        s_time[0] = time[g]
        s_turn[0] = turn[g]
        s_stale[0] = stale[g]
        s_prev[0, 0] = prev_hp_sum[g, 0]
        s_prev[0, 1] = prev_hp_sum[g, 1]
        for u in range(num_agents):
            acts[u] = joint[i, u]
        r, ended = env_step(
            g0,
            s_utype,
            s_uid,
            s_x,
            s_y,
            s_px,
            s_py,
            s_tact,
            s_last,
            s_hp,
            s_tmove,
            s_tatk,
            s_time,
            s_turn,
            s_stale,
            s_prev,
            walkable,
            acts,
            num_agents,
            num_actions,
            enemy,
            overkill_pass,
            stalemate_limit,
            max_turns,
            init_hp0[g],
            seed,
            g,
            ws,
            rank_slot,
            rank_of,
            np.bool_(False),
        )
        ret = r
        disc = gamma
        k = 1
        while k < steps and not ended:
            script_env_actions(
                g0,
                s_utype,
                s_x,
                s_y,
                s_px,
                s_py,
                s_tact,
                s_last,
                s_hp,
                s_tmove,
                s_tatk,
                s_time,
                s_turn,
                s_stale,
                walkable,
                continuation,
                num_agents,
                stalemate_limit,
                max_turns,
                seed,
                g,
                ws,
                rank_slot,
                rank_of,
                acts,
            )
            r, ended = env_step(
                g0,
                s_utype,
                s_uid,
                s_x,
                s_y,
                s_px,
                s_py,
                s_tact,
                s_last,
                s_hp,
                s_tmove,
                s_tatk,
                s_time,
                s_turn,
                s_stale,
                s_prev,
                walkable,
                acts,
                num_agents,
                num_actions,
                enemy,
                overkill_pass,
                stalemate_limit,
                max_turns,
                init_hp0[g],
                seed,
                g,
                ws,
                rank_slot,
                rank_of,
                np.bool_(True),
            )
            ret = ret + disc * r
            disc = disc * gamma
            k += 1
        ret_out[i] = ret
        disc_out[i] = disc
        ended_out[i] = ended
        if not ended:
            critic_features(
                s_time[0],
                s_x,
                s_y,
                s_px,
                s_py,
                s_tact,
                s_last,
                s_hp,
                s_tmove,
                s_tatk,
                num_agents,
                num_enemies,
                values,
                feats_out[i],
            )


@njit(cache=True, fastmath=True)
def _affine(x, w, b, relu, out):
    """``out = x @ w + b`` (then ReLU): rows one at a time, the inner loop over contiguous
    outputs so that it vectorises; one thread, no BLAS thread pool beside XLA's and Numba's."""
    m, k = x.shape
    n = w.shape[1]
    for i in range(m):
        for j in range(n):
            out[i, j] = b[j]
        for kk in range(k):
            xv = x[i, kk]
            for j in range(n):
                out[i, j] += xv * w[kk, j]
        if relu:
            for j in range(n):
                if out[i, j] < 0:
                    out[i, j] = 0


class NativeMLP:
    """``training.networks.MLP`` in eval mode on the host, float32: each hidden layer is
    Dense → BatchNorm (running statistics) → ReLU, folded into one affine map. Equal to the
    Flax module up to float rounding."""

    def __init__(self, variables: dict[str, Any], epsilon: float = 1e-5) -> None:
        params, stats = variables["params"], variables.get("batch_stats", {})
        dense = sorted(
            (k for k in params if k.startswith("Dense_")), key=lambda k: int(k.split("_")[1])
        )
        self.layers: list[tuple[np.ndarray, np.ndarray, bool]] = []
        for i, name in enumerate(dense):
            w = np.asarray(params[name]["kernel"], np.float32)
            b = np.asarray(params[name]["bias"], np.float32)
            bn = f"BatchNorm_{i}"
            if bn in params:
                mul = np.asarray(params[bn]["scale"], np.float32) / np.sqrt(
                    np.asarray(stats[bn]["var"], np.float32) + np.float32(epsilon)
                )
                shift = (
                    np.asarray(params[bn]["bias"], np.float32)
                    - np.asarray(stats[bn]["mean"], np.float32) * mul
                )
                self.layers.append(
                    (
                        np.ascontiguousarray(w * mul[None, :]),
                        (b * mul + shift).astype(np.float32),
                        True,
                    )
                )
            else:
                self.layers.append((np.ascontiguousarray(w), b, False))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        h = np.ascontiguousarray(x, np.float32)
        for w, b, relu in self.layers:
            out = np.empty((h.shape[0], w.shape[1]), np.float32)
            _affine(h, w, b, relu, out)
            h = out
        return h


def native_support(
    task: Any, *, lookahead: int, continuation: str, demo_script: str | None
) -> str | None:
    """Why Alg. 1 cannot run natively for this task and Q estimate (None: it can)."""
    if getattr(task, "kind", None) != "combat":
        return f"the native Alg. 1 simulates combat only (this task is {task.kind!r})"
    env = task.env
    if getattr(env, "enemy_name", None) not in SCRIPT_CODES:
        return "the native Alg. 1 needs a scripted enemy"
    if lookahead > 1 and (continuation != "demonstrator" or demo_script not in SCRIPT_CODES):
        return "a multi-step Q on the native engine needs the demonstrator script as its continuation (lookahead_policy=demonstrator, a script demonstrator)"
    return None


@dataclass
class NativeBRDResult:
    """``brd.BRDResult``'s fields, as NumPy arrays."""

    actions: np.ndarray
    q: np.ndarray
    q_valid: np.ndarray
    q_init: np.ndarray
    q_final: np.ndarray
    sweeps: int
    changes: np.ndarray
    visits: int
    evaluated: int
    simulated: int
    seconds_simulation: float = 0.0
    seconds_critic: float = 0.0


class NativeBRD:
    """Alg. 1 for the games of a combat task on the native engine (see the module docstring).

    ``lookahead``: simulated steps (1: Eq. 2); ``continuation``: our side's script for the later
    steps; ``value`` maps critic features ``[M, 35]`` to ``V`` ``[M]``.
    """

    def __init__(
        self,
        task: Any,
        *,
        gamma: float,
        iterations: int,
        lookahead: int,
        continuation: str | None,
        seed: int = 0,
    ) -> None:
        env = task.env
        rules = env.rules
        self.num_agents = int(env.num_agents)
        self.num_enemies = int(env.num_enemies)
        self.num_actions = int(env.num_actions)
        self.enemy = SCRIPT_CODES[env.enemy_name]
        self.continuation = SCRIPT_CODES[continuation] if continuation is not None else 0
        self.steps = int(min(lookahead, 2**31 - 1))
        self.gamma = np.float32(gamma)
        self.iterations = int(iterations)
        self.overkill_pass = rules.overkill == "pass"
        self.stalemate_limit = int(rules.stalemate_limit)
        self.max_turns = int(rules.max_turns)
        self.walkable = np.array(rules.walkable, dtype=np.bool_, order="C", copy=True)
        self.seed = int(seed)

    def simulate(
        self, batch: dict[str, np.ndarray], games: np.ndarray, joint: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(returns, discounts, ended, features)`` of the pairs ``(games[i], joint[i])``."""
        m = int(games.shape[0])
        ret = np.zeros(m, np.float32)
        disc = np.zeros(m, np.float32)
        ended = np.zeros(m, np.bool_)
        feats = np.zeros((m, CRITIC_FEATURES), np.float32)
        if m:
            chunks = max(1, min(m, numba.get_num_threads() * 4))
            simulate_candidates(
                batch["fields"],
                batch["time"],
                batch["turn"],
                batch["stale"],
                batch["prev_hp_sum"],
                batch["init_hp0"],
                self.walkable,
                games.astype(np.int64),
                joint.astype(np.int64),
                self.num_agents,
                self.num_enemies,
                self.num_actions,
                self.enemy,
                self.continuation,
                self.steps,
                self.gamma,
                self.overkill_pass,
                self.stalemate_limit,
                self.max_turns,
                self.seed,
                chunks,
                ret,
                disc,
                ended,
                feats,
            )
        return ret, disc, ended, feats

    def q_values(
        self, batch: dict[str, np.ndarray], games: np.ndarray, joint: np.ndarray, value: Any
    ) -> tuple[np.ndarray, float, float]:
        """Eq. 2's Q (or its K-step form) of each pair; and the seconds spent simulating and in
        the critic."""
        t0 = time.perf_counter()
        ret, disc, ended, feats = self.simulate(batch, games, joint)
        t1 = time.perf_counter()
        v = np.zeros_like(ret)
        live = ~ended
        if value is not None and live.any():
            v[live] = np.asarray(value(feats[live]), np.float32).reshape(-1)
        t2 = time.perf_counter()
        return ret + disc * v, t1 - t0, t2 - t1

    def __call__(
        self, states: Any, a_init: np.ndarray, legal: np.ndarray, value: Any
    ) -> NativeBRDResult:
        """Alg. 1 for B games (``states``: a batch of ``CombatState``, host or device arrays)."""
        batch = state_arrays(states)
        seconds = [0.0, 0.0]

        def q_pairs(games: np.ndarray, joint: np.ndarray) -> np.ndarray:
            q, ts, tc = self.q_values(batch, games, joint, value)
            seconds[0] += ts
            seconds[1] += tc
            return q

        res = best_response_dynamics(q_pairs, a_init, legal, self.iterations)
        res.seconds_simulation, res.seconds_critic = seconds
        return res


def best_response_dynamics(
    q_pairs: Any, a_init: np.ndarray, legal: np.ndarray, iterations: int = 7
) -> NativeBRDResult:
    """``brd.best_response_dynamics`` on the host, for any ``q_pairs(games [M], joint [M, N]) ->
    Q [M]`` (the same schedule, rules and outputs; see ``brd``)."""
    legal = np.asarray(legal, bool)
    b, n, na = legal.shape
    bidx = np.arange(b)
    decider = legal.sum(-1) >= 2
    perm = np.argsort(~decider, axis=1, kind="stable").astype(np.int64)
    n_dec = decider.sum(1)
    act = np.asarray(a_init, np.int64).copy()
    start_ok = np.take_along_axis(legal, act[..., None], axis=-1)[..., 0]
    act = np.where(start_ok, act, np.argmax(legal, axis=-1))
    qtab = np.zeros((b, n, na), np.float32)
    qval = np.zeros((b, n), bool)
    qcur = np.full(b, np.nan, np.float32)
    q_init = np.full(b, np.nan, np.float32)
    changes = np.zeros(b, np.int64)
    active = n_dec > 0
    sweep = visits = evaluated = simulated = 0
    while active.any():
        # One sweep over the deciders of the games still active (an evaluation-only sweep once
        # 'iterations' update sweeps have run: the table at the final Ã).
        update = sweep < iterations
        late = np.zeros(b, bool)
        for k in range(int(n_dec[active].max())):
            need = active & (k < n_dec)
            g = perm[:, min(k, n - 1)]
            lg = legal[bidx, g]  # [B, A]
            gi, ai = np.nonzero(need[:, None] & lg)
            joint = act[gi].copy()
            joint[np.arange(gi.size), g[gi]] = ai
            q = np.zeros((b, na), np.float32)
            if gi.size:
                q[gi, ai] = q_pairs(gi, joint)
            ql = np.where(lg, q, np.float32(-np.inf))
            best = np.argmax(ql, axis=-1)
            cur = act[bidx, g]
            q_cur = np.where(lg[bidx, cur], q[bidx, cur], np.float32(-np.inf))
            q_best = ql[bidx, best]
            improve = need & (q_best > q_cur) & update
            q_now = np.where(improve, q_best, q_cur)
            rows = np.nonzero(need)[0]
            act[rows, g[rows]] = np.where(improve, best, cur)[rows]
            qtab[rows, g[rows]] = q[rows]
            qval[rows, g[rows]] = True
            qcur = np.where(need, q_now, qcur).astype(np.float32)
            q_init = np.where(need & np.isnan(q_init), q_cur, q_init).astype(np.float32)
            late |= improve & (k > 0)
            changes += improve
            visits += int(gi.size > 0)
            evaluated += int(need.sum())
            simulated += int(gi.size)
        # Done: a sweep that changed nothing, or only its first decider (see 'brd').
        active = active & update & late
        sweep += int(update)
    return NativeBRDResult(
        actions=act.astype(np.int32),
        q=qtab,
        q_valid=qval,
        q_init=q_init,
        q_final=qcur,
        sweeps=sweep,
        changes=changes.astype(np.int32),
        visits=visits,
        evaluated=evaluated,
        simulated=simulated,
    )


def bucket(count: int, total: int, smallest: int = 64) -> int:
    """A padded size for ``count`` rows out of ``total``: the next power of two (at least
    ``smallest``, at most ``total``), so that a jitted update compiles for a few sizes only."""
    size = max(smallest, 1 << max(0, math.ceil(math.log2(max(count, 1)))))
    return min(size, total)


__all__ = [
    "NativeBRD",
    "NativeBRDResult",
    "NativeMLP",
    "best_response_dynamics",
    "bucket",
    "native_support",
    "simulate_candidates",
]
