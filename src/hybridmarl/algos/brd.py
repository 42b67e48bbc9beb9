"""Alg. 1: best-response dynamics on the centralised critic, batched over games, under jit.

For one state ``s`` and a start joint action ``Ã = A^D(s)`` (the demonstrator's, or the current
actor's: Section 4.3), every iteration goes over the agents in turn; for the current agent ``g``
and every action ``a`` it computes

    Q(s, a, Ã_-g) = r(s, a, Ã_-g) + λ V(s')          (Eq. 2, one-step forward simulation)

takes the best legal action and writes it into ``Ã``. Here all ``A`` candidate joint actions of
all ``B`` games are simulated by **one** vmapped call (``q_fn`` below), so one iteration costs
``N`` such calls: linear in the number of agents (Section 4.2, "Iterations × N computations").

Implementation choices (none changes the fixed point Alg. 1 reaches):

- **Only agents with a choice are visited.** An agent with a single legal action (a unit that
  does not act at this decision point, an empty Traffic Junction slot) cannot change ``Ã``.
  Each game lists its deciding agents first (in agent order); the sweep visits position
  ``k = 0 .. max_b(#deciders_b) - 1``, i.e. agent ``perm[b, k]`` in game ``b``.
- **An agent switches only on a strict improvement** (``Q(best) > Q(current)``): ties keep the
  current action (so a converged ``Ã`` is a fixed point and float noise cannot make ``Q`` go
  down). ``Q(s, Ã)`` therefore never decreases (Section 4.2: "In each iteration ... Q increases").
- **Early exit.** When a whole sweep changes nothing in any game, the remaining iterations
  would be no-ops and the loop stops (``Iterations`` = 7 is the cap, Section 5.1).
- **Eq. 7 needs ``Q(s, a, Ã_-g)`` at the final ``Ã``.** The table of the last sweep is exact if
  that sweep changed nothing; otherwise (the cap was hit) one extra evaluation sweep, with no
  updates, recomputes it.
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
    visits: jax.Array  # int32 []: batched Q evaluations made (= one-step simulations of B x A)


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
    """
    b, n, na = legal.shape
    a_init = a_init.astype(jnp.int32)
    bidx = jnp.arange(b)
    actions_range = jnp.arange(na, dtype=jnp.int32)
    decider = jnp.sum(legal, axis=-1) >= 2  # [B, N]
    # Deciders first, in agent order (stable sort on "not a decider").
    perm = jnp.argsort(~decider, axis=1, stable=True).astype(jnp.int32)  # [B, N]
    n_dec = jnp.sum(decider, axis=1).astype(jnp.int32)  # [B]
    max_dec = jnp.max(n_dec)
    # An illegal start action (e.g. a demonstrator that ignores a mask) becomes the first legal one.
    start_ok = jnp.take_along_axis(legal, a_init[..., None], axis=-1)[..., 0]
    a_init = jnp.where(start_ok, a_init, jnp.argmax(legal, axis=-1)).astype(jnp.int32)

    def visit(k: jax.Array, carry: tuple) -> tuple:
        act, qtab, qval, qcur, changed, changes, q_init, trace, sweep, update, visits = carry
        g = perm[:, jnp.minimum(k, n - 1)]  # [B]: the agent visited in each game
        valid = k < n_dec  # [B]
        cand = jnp.broadcast_to(act[:, None, :], (b, na, n))
        cand = jnp.where(jnp.arange(n)[None, None, :] == g[:, None, None], actions_range[None, :, None], cand)
        q = q_fn(keys, states, cand)  # [B, A]: Q(s, a, Ã_-g) for every action a
        lg = legal[bidx, g]  # [B, A]
        ql = jnp.where(lg, q, -jnp.inf)
        best = jnp.argmax(ql, axis=-1).astype(jnp.int32)
        cur = act[bidx, g]
        q_cur = jnp.where(lg[bidx, cur], q[bidx, cur], -jnp.inf)
        q_best = ql[bidx, best]
        improve = valid & (q_best > q_cur + min_gain) & update
        act = act.at[bidx, g].set(jnp.where(improve, best, cur))
        qtab = qtab.at[bidx, g].set(jnp.where(valid[:, None], q, qtab[bidx, g]))
        qval = qval.at[bidx, g].set(qval[bidx, g] | valid)
        q_now = jnp.where(improve, q_best, q_cur)
        qcur = jnp.where(valid, q_now, qcur)
        q_init = jnp.where(valid & jnp.isnan(q_init), q_cur, q_init)
        changed = changed | improve
        changes = changes + improve.astype(jnp.int32)
        idx = jnp.minimum(sweep * n + k, max(iterations, 1) * n - 1)
        trace = trace.at[idx].set(jnp.where(update, jnp.where(valid, q_now, jnp.nan), trace[idx]))
        return act, qtab, qval, qcur, changed, changes, q_init, trace, sweep, update, visits + 1

    def sweep_fn(carry: tuple) -> tuple:
        """One pass over the agents; an update sweep while fewer than ``iterations`` were run,
        else an evaluation-only sweep (the cap was hit: refresh the table at the final Ã)."""
        act, qtab, qval, qcur, _, changes, q_init, trace, sweep, _, _, visits = carry
        update = sweep < iterations
        inner = (act, qtab, qval, qcur, jnp.zeros((b,), bool), changes, q_init, trace, sweep, update, visits)
        inner = jax.lax.fori_loop(0, max_dec, visit, inner)
        act, qtab, qval, qcur, changed, changes, q_init, trace, sweep, update, visits = inner
        # Done when a sweep changed nothing (the table is exact) or after the evaluation sweep.
        finished = ~jnp.any(changed) | ~update
        return act, qtab, qval, qcur, changed, changes, q_init, trace, sweep + update.astype(jnp.int32), update, finished, visits

    init = (
        a_init,
        jnp.zeros((b, n, na), jnp.float32),
        jnp.zeros((b, n), bool),
        jnp.full((b,), jnp.nan, jnp.float32),
        jnp.zeros((b,), bool),
        jnp.zeros((b,), jnp.int32),
        jnp.full((b,), jnp.nan, jnp.float32),
        jnp.full((max(iterations, 1) * n, b), jnp.nan, jnp.float32),
        jnp.zeros((), jnp.int32),
        jnp.asarray(True),
        jnp.asarray(False),
        jnp.zeros((), jnp.int32),
    )
    carry = jax.lax.while_loop(lambda c: ~c[-2], sweep_fn, init)
    act, qtab, qval, qcur, _, changes, q_init, trace, sweep, _, _, visits = carry
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
    )
