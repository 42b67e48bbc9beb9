"""Alg. 1: best-response dynamics on the centralised critic, batched over games, under jit.

For one state ``s`` and a start joint action ``Ã = A^D(s)`` (the demonstrator's, or the current
actor's: Section 4.3), every iteration goes over the agents in turn; for the current agent ``g``
and every action ``a`` it computes

    Q(s, a, Ã_-g) = r(s, a, Ã_-g) + λ V(s')          (Eq. 2, one-step forward simulation)

takes the best legal action and writes it into ``Ã``. Here all ``A`` candidate joint actions of
a batch of games are simulated by **one** vmapped call (``q_fn`` below), so one iteration costs
at most ``N`` such calls per batch: linear in the number of agents (Section 4.2, "Iterations × N
computations").

Implementation choices (none changes the fixed point Alg. 1 reaches):

- **Only agents with a choice are visited.** An agent with a single legal action (a unit that
  does not act at this decision point, an empty Traffic Junction slot) cannot change ``Ã``.
  Each game lists its deciding agents first (in agent order); the sweep visits position
  ``k = 0 .. max_b(#deciders_b) - 1``, i.e. agent ``perm[b, k]`` in game ``b``.
- **An agent switches only on a strict improvement** (``Q(best) > Q(current)``): ties keep the
  current action (so a converged ``Ã`` is a fixed point and float noise cannot make ``Q`` go
  down). ``Q(s, Ã)`` therefore never decreases (Section 4.2: "In each iteration ... Q increases").
- **Early exit, per game.** A game stops sweeping once a sweep changed nothing in it, or
  changed only its first decider's action: every row of that sweep was then computed at the
  final Ã, which is a fixed point, so further sweeps would repeat the same Q rows and change
  nothing. The loop stops when no game is left (``Iterations`` = 7 is the cap, Section 5.1).
- **Only the needed visits are simulated.** Each visit (a decider position ``k`` of a sweep)
  gathers the games that still need it and calls ``q_fn`` on ``work_batch`` of them at a time,
  so the cost follows the (game, agent) visits Alg. 1 actually makes, not ``B x`` the busiest
  game's. At m5v5 under a learning actor, a game has about 1.7 deciders out of 5 per step.
- **Eq. 7 needs ``Q(s, a, Ã_-g)`` at the final Ã.** The table of a game's last sweep is exact
  if that sweep changed nothing (or only its first decider); otherwise (the cap was hit) one
  extra evaluation sweep, with no updates, recomputes it.
- An illegal start action is replaced by the agent's first legal action.
- The simulator key is the same for every candidate and every iteration of one state (common
  random numbers): ``Q(s, A)`` is a deterministic function of ``A``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

#: ``q_fn(keys [B], states [B], candidates int32 [B, A, N]) -> Q float32 [B, A]``.
QFn = Callable[[jax.Array, Any, jax.Array], jax.Array]


class BRDResult(NamedTuple):
    actions: jax.Array  # int32 [B, N]: Ã, the joint local optimum
    q: jax.Array  # float32 [B, N, A]: Q(s, a, Ã_-g) at the final Ã (0 where not computed)
    q_valid: jax.Array  # bool [B, N]: agent g's row of ``q`` was computed (it has a choice)
    q_init: jax.Array  # float32 [B]: Q(s, A_start) (NaN if no agent has a choice)
    q_final: jax.Array  # float32 [B]: Q(s, Ã)
    sweeps: jax.Array  # int32 []: update sweeps run (<= iterations)
    changes: jax.Array  # int32 [B]: single-agent switches made
    trace: jax.Array  # float32 [iterations * N, B]: Q(s, Ã) after each update (NaN: no update)
    visits: jax.Array  # int32 []: calls of q_fn (each on ``work_batch`` games x A candidates)
    evaluated: jax.Array  # int32 []: (game, agent) Q rows computed: the work Alg. 1 needed


def make_q_fn(
    lookahead: Callable[[jax.Array, Any, jax.Array], tuple[jax.Array, Any, jax.Array]],
    value_fn: Callable[[Any], jax.Array],
    gamma: float,
    *,
    steps: int = 1,
    step_fn: Callable[[jax.Array, Any, jax.Array], tuple[jax.Array, Any, jax.Array]] | None = None,
    policy_fn: Callable[[jax.Array, Any], jax.Array] | None = None,
) -> QFn:
    """Build Eq. 2's ``Q(s, A) = r + λ V(s')`` (``V(s') = 0`` at a terminal ``s'``) for B games.

    ``lookahead(key, state, cand [A, N]) -> (r [A], s' [A], done [A])`` is one game's one-step
    simulation; ``value_fn(states [M]) -> V [M]`` evaluates the critic on a flat batch.

    ``steps = K > 1`` (an option; the paper uses one step): after the first step, the
    continuation policy ``policy_fn(key, states [M]) -> actions [M, N]`` plays ``K - 1`` more
    steps (``step_fn(key, state, actions) -> (r, s', done)``) and the critic bootstraps at the
    end: ``Q = sum_{i<K} λ^i r_i + λ^K V(s_K)``, the same quantity with less weight on the
    critic's error (exact when the episode ends within K steps; the simulator is deterministic
    under the shared key). The loop stops early when every simulated game has ended.
    """

    def q_fn(keys: jax.Array, states: Any, cand: jax.Array) -> jax.Array:
        r, s2, done = jax.vmap(lookahead)(keys, states, cand)
        b, a = r.shape
        flat = jax.tree.map(lambda x: x.reshape((b * a,) + x.shape[2:]), s2)
        ret = r.reshape(-1)
        disc = jnp.full((b * a,), gamma, jnp.float32)
        ended = done.reshape(-1)
        if steps > 1:
            if step_fn is None or policy_fn is None:
                raise ValueError("steps > 1 needs step_fn and policy_fn")
            sim, play = step_fn, policy_fn
            game_keys = jnp.repeat(keys, a, axis=0)  # one key per game: common random numbers

            def cond(c: tuple) -> jax.Array:
                i, _, _, _, ended = c
                return (i < steps - 1) & ~jnp.all(ended)

            def body(c: tuple) -> tuple:
                i, ret, disc, s, ended = c
                ks = jax.vmap(lambda k: jax.random.fold_in(k, i + 1))(game_keys)
                acts = play(ks, s)
                r2, s_next, d2 = jax.vmap(sim)(ks, s, acts)
                live = ~ended
                ret = ret + jnp.where(live, disc * r2, 0.0)
                disc = jnp.where(live, disc * gamma, disc)
                s = jax.tree.map(lambda x, y: jnp.where(live.reshape(live.shape + (1,) * (x.ndim - 1)), x, y), s_next, s)
                return i + 1, ret, disc, s, ended | d2

            _, ret, disc, flat, ended = jax.lax.while_loop(cond, body, (jnp.zeros((), jnp.int32), ret, disc, flat, ended))
        v = value_fn(flat)
        return (ret + disc * jnp.where(ended, 0.0, v)).reshape(b, a)

    return q_fn


def best_response_dynamics(
    q_fn: QFn,
    keys: jax.Array,
    states: Any,
    a_init: jax.Array,
    legal: jax.Array,
    iterations: int = 7,
    min_gain: float = 0.0,
    work_batch: int | None = None,
) -> BRDResult:
    """Alg. 1 for B games at once (see the module docstring). Jittable.

    Args:
        q_fn: batched ``Q(s, A)`` (:func:`make_q_fn`).
        keys: [B] simulator keys (one per game, reused for every candidate).
        states: [B] environment states.
        a_init: int32 [B, N] start joint actions (``A^D(s)``, or the actor's).
        legal: bool [B, N, A] legal actions.
        iterations: the cap on sweeps over the agents (paper: 7).
        min_gain: an agent switches only if its best action beats its current one by more than
            this (0: any strict improvement, the paper's argmax). A positive margin keeps the
            start action where alternatives are near-ties, which makes Ã a less noisy target
            for the decentralised actor. ``Q(s, Ã)`` still never decreases.
        work_batch: games per ``q_fn`` call (None or <= 0: all B). Each visit gathers the games that
            still need that visit and simulates them ``work_batch`` at a time, so the cost
            follows the visits actually needed rather than ``B x`` the busiest game's. It does
            not change the result (up to float rounding of ``q_fn`` at another batch size).
    """
    b, n, na = legal.shape
    s_batch = b if work_batch is None or work_batch <= 0 else min(int(work_batch), b)
    max_passes = -(-b // s_batch)
    dense = s_batch == b
    a_init = a_init.astype(jnp.int32)
    actions_range = jnp.arange(na, dtype=jnp.int32)
    decider = jnp.sum(legal, axis=-1) >= 2  # [B, N]
    # Deciders first, in agent order (stable sort on "not a decider").
    perm = jnp.argsort(~decider, axis=1, stable=True).astype(jnp.int32)  # [B, N]
    n_dec = jnp.sum(decider, axis=1).astype(jnp.int32)  # [B]
    # An illegal start action (e.g. a demonstrator that ignores a mask) becomes the first legal one.
    start_ok = jnp.take_along_axis(legal, a_init[..., None], axis=-1)[..., 0]
    a_init = jnp.where(start_ok, a_init, jnp.argmax(legal, axis=-1)).astype(jnp.int32)
    t_last = max(iterations, 1) * n - 1

    def one_pass(p: jax.Array, carry: tuple) -> tuple:
        """Position k's visit for the next ``work_batch`` of the games that need it."""
        (act, qtab, qval, qcur, late, changes, q_init, trace), (k, order, need, sweep, update) = carry
        idx = jax.lax.dynamic_slice(order, (p * s_batch,), (s_batch,))  # [S]; b = padding
        gi = jnp.minimum(idx, b - 1)
        valid = (idx < b) & need[gi]
        w = jnp.where(valid, idx, b)  # scatter index: out of range (dropped) unless valid
        g = perm[gi, jnp.minimum(k, n - 1)]  # [S]: the agent visited in each game
        sidx = jnp.arange(s_batch)
        rows = act if dense else act[gi]  # [S, N]
        cand = jnp.broadcast_to(rows[:, None, :], (s_batch, na, n))
        cand = jnp.where(jnp.arange(n)[None, None, :] == g[:, None, None], actions_range[None, :, None], cand)
        sub = states if dense else jax.tree.map(lambda x: x[gi], states)
        q = q_fn(keys if dense else keys[gi], sub, cand)  # [S, A]: Q(s, a, Ã_-g) for every action a
        lg = legal[gi, g]  # [S, A]
        ql = jnp.where(lg, q, -jnp.inf)
        best = jnp.argmax(ql, axis=-1).astype(jnp.int32)
        cur = rows[sidx, g]
        q_cur = jnp.where(lg[sidx, cur], q[sidx, cur], -jnp.inf)
        q_best = ql[sidx, best]
        improve = valid & (q_best > q_cur + min_gain) & update
        q_now = jnp.where(improve, q_best, q_cur)
        act = act.at[w, g].set(jnp.where(improve, best, cur), mode="drop")
        qtab = qtab.at[w, g].set(q, mode="drop")
        qval = qval.at[w, g].set(True, mode="drop")
        qcur = qcur.at[w].set(q_now, mode="drop")
        q_init = q_init.at[w].set(jnp.where(jnp.isnan(q_init[gi]), q_cur, q_init[gi]), mode="drop")
        late = late.at[w].set(late[gi] | (improve & (k > 0)), mode="drop")
        changes = changes.at[w].add(improve.astype(jnp.int32), mode="drop")
        t = jnp.minimum(sweep * n + k, t_last)
        trace = trace.at[t, jnp.where(update, w, b)].set(q_now, mode="drop")
        return (act, qtab, qval, qcur, late, changes, q_init, trace), (k, order, need, sweep, update)

    def visit(k: jax.Array, carry: tuple) -> tuple:
        tables, active, sweep, update, visits, evaluated = carry
        need = active & (k < n_dec)  # [B]: games whose k-th decider is visited now
        count = jnp.sum(need).astype(jnp.int32)
        if dense:  # one call on all games in place (no gather)
            order = jnp.arange(b, dtype=jnp.int32)
        else:
            order = jnp.argsort(~need, stable=True).astype(jnp.int32)
            order = jnp.concatenate([order, jnp.full((max_passes * s_batch - b,), b, jnp.int32)])
        passes = (count + s_batch - 1) // s_batch
        tables, _ = jax.lax.fori_loop(0, passes, one_pass, (tables, (k, order, need, sweep, update)))
        return tables, active, sweep, update, visits + passes, evaluated + count

    def sweep_fn(carry: tuple) -> tuple:
        """One pass over the agents of the games still active: an update sweep while fewer
        than ``iterations`` were run, else an evaluation-only sweep (the cap was hit: refresh
        the table at the final Ã)."""
        tables, active, sweep, visits, evaluated = carry
        act, qtab, qval, qcur, _, changes, q_init, trace = tables
        update = sweep < iterations
        tables = (act, qtab, qval, qcur, jnp.zeros((b,), bool), changes, q_init, trace)
        max_dec = jnp.max(jnp.where(active, n_dec, 0))
        tables, _, _, _, visits, evaluated = jax.lax.fori_loop(0, max_dec, visit, (tables, active, sweep, update, visits, evaluated))
        # A game is done when its sweep changed nothing, or only its first decider changed
        # (every row was then computed at the final Ã, which is a fixed point), or after the
        # evaluation sweep; a further sweep would repeat the same Q rows and change nothing.
        late = tables[4]  # a decider after the first switched in this sweep
        active = active & update & late
        return tables, active, sweep + update.astype(jnp.int32), visits, evaluated

    tables = (
        a_init,
        jnp.zeros((b, n, na), jnp.float32),
        jnp.zeros((b, n), bool),
        jnp.full((b,), jnp.nan, jnp.float32),
        jnp.zeros((b,), bool),
        jnp.zeros((b,), jnp.int32),
        jnp.full((b,), jnp.nan, jnp.float32),
        jnp.full((max(iterations, 1) * n, b), jnp.nan, jnp.float32),
    )
    zero = jnp.zeros((), jnp.int32)
    carry = jax.lax.while_loop(lambda c: jnp.any(c[1]), sweep_fn, (tables, n_dec > 0, zero, zero, zero))
    (act, qtab, qval, qcur, _, changes, q_init, trace), _, sweep, visits, evaluated = carry
    return BRDResult(
        actions=act,
        q=qtab,
        q_valid=qval,
        q_init=q_init,
        q_final=qcur,
        sweeps=sweep,
        changes=changes,
        trace=trace,
        visits=visits,
        evaluated=evaluated,
    )
