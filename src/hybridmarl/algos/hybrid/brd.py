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
- **Only the needed candidates are simulated.** Each visit (a decider position ``k`` of a
  sweep) gathers the (game, action) pairs it needs, the legal actions of the visited agent in
  every game that still needs the visit, and simulates them ``work_batch x A`` at a time (``A``
  = the number of actions). The cost follows the legal candidates Alg. 1 actually evaluates, not
  ``B x A x`` the busiest game's deciders: at m5v5 under a learning actor, a game has about 1.7
  deciders out of 5 per step, and an illegal action (an enemy out of range) is never simulated.
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
    q: jax.Array  # float32 [B, N, A]: Q(s, a, Ã_-g) at the final Ã (0: illegal or not computed)
    q_valid: jax.Array  # bool [B, N]: agent g's row of ``q`` was computed (it has a choice)
    q_init: jax.Array  # float32 [B]: Q(s, A_start) (NaN if no agent has a choice)
    q_final: jax.Array  # float32 [B]: Q(s, Ã)
    sweeps: jax.Array  # int32 []: update sweeps run (<= iterations)
    changes: jax.Array  # int32 [B]: single-agent switches made
    trace: jax.Array  # float32 [iterations * N, B]: Q(s, Ã) after each update (NaN: no update)
    visits: jax.Array  # int32 []: calls of q_fn (each on ``work_batch x A`` candidates)
    evaluated: jax.Array  # int32 []: (game, agent) Q rows computed: the work Alg. 1 needed
    simulated: jax.Array  # int32 []: candidate joint actions simulated (padding included): the cost


def make_q_fn(
    lookahead: Callable[[jax.Array, Any, jax.Array], tuple[jax.Array, Any, jax.Array]],
    value_fn: Callable[[Any], jax.Array],
    gamma: float,
    *,
    steps: int = 1,
    step_fn: Callable[[jax.Array, Any, jax.Array], tuple[jax.Array, Any, jax.Array]] | None = None,
    policy_fn: Callable[[jax.Array, Any], jax.Array] | None = None,
    batch_step_fn: Callable[[jax.Array, Any, jax.Array], tuple[jax.Array, Any, jax.Array]]
    | None = None,
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

    ``batch_step_fn(keys [M], states [M], actions [M, N]) -> (r, s', done)``, if given, replaces
    ``lookahead`` and ``jax.vmap(step_fn)`` with a batched step that gives the same results
    (combat: ``Combat.batch_step``, which does not advance the whole batch in lockstep with its
    slowest game's enemy-only turns).
    """

    def q_fn(keys: jax.Array, states: Any, cand: jax.Array) -> jax.Array:
        b, a = cand.shape[:2]
        if batch_step_fn is None:
            r, s2, done = jax.vmap(lookahead)(keys, states, cand)
            flat = jax.tree.map(lambda x: x.reshape((b * a,) + x.shape[2:]), s2)
        else:
            rep = (lambda x: x) if a == 1 else (lambda x: jnp.repeat(x, a, axis=0))
            r, flat, done = batch_step_fn(
                rep(keys), jax.tree.map(rep, states), cand.reshape((b * a,) + cand.shape[2:])
            )
        ret = r.reshape(-1)
        disc = jnp.full((b * a,), gamma, jnp.float32)
        ended = done.reshape(-1)
        if steps > 1:
            if (step_fn is None and batch_step_fn is None) or policy_fn is None:
                raise ValueError("steps > 1 needs step_fn (or batch_step_fn) and policy_fn")
            play = policy_fn
            if batch_step_fn is not None:
                sim = batch_step_fn
            else:
                assert step_fn is not None
                sim = jax.vmap(step_fn)
            game_keys = jnp.repeat(keys, a, axis=0)  # one key per game: common random numbers

            def cond(c: tuple) -> jax.Array:
                i, _, _, _, ended = c
                return (i < steps - 1) & ~jnp.all(ended)

            def body(c: tuple) -> tuple:
                i, ret, disc, s, ended = c
                ks = jax.vmap(lambda k: jax.random.fold_in(k, i + 1))(game_keys)
                acts = play(ks, s)
                r2, s_next, d2 = sim(ks, s, acts)
                live = ~ended
                ret = ret + jnp.where(live, disc * r2, 0.0)
                disc = jnp.where(live, disc * gamma, disc)
                s = jax.tree.map(
                    lambda x, y: jnp.where(live.reshape(live.shape + (1,) * (x.ndim - 1)), x, y),
                    s_next,
                    s,
                )
                return i + 1, ret, disc, s, ended | d2

            _, ret, disc, flat, ended = jax.lax.while_loop(
                cond, body, (jnp.zeros((), jnp.int32), ret, disc, flat, ended)
            )
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
        work_batch: ``q_fn`` calls simulate ``work_batch x A`` candidates each (None or <= 0, or
            >= B: the dense schedule, every game's A candidates in one call per visit, in place).
            Otherwise each visit gathers the legal (game, action) pairs of the games that still
            need it and simulates only those, so the cost follows the candidates Alg. 1 needs
            rather than ``B x A x`` the busiest game's deciders. It does not change the result
            (up to float rounding of ``q_fn`` at another batch size).
    """
    b, n, na = legal.shape
    wb = 0 if work_batch is None else int(work_batch)
    dense = wb <= 0 or wb >= b
    # Compact schedule: each q_fn call simulates ``pairs`` (game, legal action) candidates.
    pairs = b * na if dense else wb * na
    max_passes = -(-(b * na) // pairs)
    a_init = a_init.astype(jnp.int32)
    actions_range = jnp.arange(na, dtype=jnp.int32)
    bidx = jnp.arange(b)
    decider = jnp.sum(legal, axis=-1) >= 2  # [B, N]
    # Deciders first, in agent order (stable sort on "not a decider").
    perm = jnp.argsort(~decider, axis=1, stable=True).astype(jnp.int32)  # [B, N]
    n_dec = jnp.sum(decider, axis=1).astype(jnp.int32)  # [B]
    # An illegal start action (e.g. a demonstrator that ignores a mask) becomes the first legal one.
    start_ok = jnp.take_along_axis(legal, a_init[..., None], axis=-1)[..., 0]
    a_init = jnp.where(start_ok, a_init, jnp.argmax(legal, axis=-1)).astype(jnp.int32)
    t_last = max(iterations, 1) * n - 1

    def q_rows_dense(act: jax.Array, g: jax.Array, need: jax.Array) -> tuple[jax.Array, jax.Array]:
        """[B, A] Q(s, a, Ã_-g) of every action: one call on all games in place (no gather)."""
        cand = jnp.broadcast_to(act[:, None, :], (b, na, n))
        cand = jnp.where(
            jnp.arange(n)[None, None, :] == g[:, None, None], actions_range[None, :, None], cand
        )
        calls = jnp.any(need).astype(jnp.int32)
        q = jax.lax.cond(
            calls > 0, lambda: q_fn(keys, states, cand), lambda: jnp.zeros((b, na), jnp.float32)
        )
        return q, calls

    def q_rows_compact(
        act: jax.Array, g: jax.Array, need: jax.Array, lg: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        """[B, A] Q(s, a, Ã_-g) of the legal actions of the games that need this visit (0
        elsewhere): those (game, action) pairs are gathered and simulated ``pairs`` at a time."""
        flat = (need[:, None] & lg).reshape(-1)  # [B * A]
        order = jnp.argsort(~flat, stable=True).astype(jnp.int32)
        order = jnp.concatenate(
            [order, jnp.zeros((max_passes * pairs - b * na,), jnp.int32)]
        )  # [passes x P]
        count = jnp.sum(flat).astype(jnp.int32)
        calls = (count + pairs - 1) // pairs

        def one_pass(p: jax.Array, q_flat: jax.Array) -> jax.Array:
            idx = jax.lax.dynamic_slice(order, (p * pairs,), (pairs,))  # [P]
            valid = p * pairs + jnp.arange(pairs) < count
            ic = jnp.where(valid, idx, order[0])  # padding repeats a needed (legal) pair
            gi, ai = ic // na, ic % na
            joint = act[gi].at[jnp.arange(pairs), g[gi]].set(ai)  # [P, N]
            sub = jax.tree.map(lambda x: x[gi], states)
            q = q_fn(keys[gi], sub, joint[:, None, :])[:, 0]  # [P]
            return q_flat.at[jnp.where(valid, ic, b * na)].set(q, mode="drop")

        q_flat = jax.lax.fori_loop(0, calls, one_pass, jnp.zeros((b * na,), jnp.float32))
        return q_flat.reshape(b, na), calls

    def visit(k: jax.Array, carry: tuple) -> tuple:
        """Decider position ``k`` of a sweep: agent ``perm[b, k]`` of every game that needs it."""
        tables, active, sweep, update, visits, evaluated, simulated = carry
        act, qtab, qval, qcur, late, changes, q_init, trace = tables
        need = active & (k < n_dec)  # [B]: games whose k-th decider is visited now
        g = perm[:, jnp.minimum(k, n - 1)]  # [B]: the agent visited in each game
        lg = legal[bidx, g]  # [B, A]
        q, calls = q_rows_dense(act, g, need) if dense else q_rows_compact(act, g, need, lg)
        q = jnp.where(lg, q, 0.0)
        ql = jnp.where(lg, q, -jnp.inf)
        best = jnp.argmax(ql, axis=-1).astype(jnp.int32)
        cur = act[bidx, g]
        q_cur = jnp.where(lg[bidx, cur], q[bidx, cur], -jnp.inf)
        q_best = ql[bidx, best]
        improve = need & (q_best > q_cur) & update
        q_now = jnp.where(improve, q_best, q_cur)
        w = jnp.where(need, bidx, b)  # scatter index: out of range (dropped) unless needed
        act = act.at[w, g].set(jnp.where(improve, best, cur), mode="drop")
        qtab = qtab.at[w, g].set(q, mode="drop")
        qval = qval.at[w, g].set(True, mode="drop")
        qcur = jnp.where(need, q_now, qcur)
        q_init = jnp.where(need & jnp.isnan(q_init), q_cur, q_init)
        late = late | (improve & (k > 0))
        changes = changes + improve.astype(jnp.int32)
        t = jnp.minimum(sweep * n + k, t_last)
        trace = trace.at[t].set(jnp.where(need & update, q_now, trace[t]))
        tables = (act, qtab, qval, qcur, late, changes, q_init, trace)
        count = jnp.sum(need).astype(jnp.int32)
        return (
            tables,
            active,
            sweep,
            update,
            visits + calls,
            evaluated + count,
            simulated + calls * pairs,
        )

    def sweep_fn(carry: tuple) -> tuple:
        """One pass over the agents of the games still active: an update sweep while fewer
        than ``iterations`` were run, else an evaluation-only sweep (the cap was hit: refresh
        the table at the final Ã)."""
        tables, active, sweep, visits, evaluated, simulated = carry
        act, qtab, qval, qcur, _, changes, q_init, trace = tables
        update = sweep < iterations
        tables = (act, qtab, qval, qcur, jnp.zeros((b,), bool), changes, q_init, trace)
        max_dec = jnp.max(jnp.where(active, n_dec, 0))
        tables, _, _, _, visits, evaluated, simulated = jax.lax.fori_loop(
            0, max_dec, visit, (tables, active, sweep, update, visits, evaluated, simulated)
        )
        # A game is done when its sweep changed nothing, or only its first decider changed
        # (every row was then computed at the final Ã, which is a fixed point), or after the
        # evaluation sweep; a further sweep would repeat the same Q rows and change nothing.
        late = tables[4]  # a decider after the first switched in this sweep
        active = active & update & late
        return tables, active, sweep + update.astype(jnp.int32), visits, evaluated, simulated

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
    carry = jax.lax.while_loop(
        lambda c: jnp.any(c[1]), sweep_fn, (tables, n_dec > 0, zero, zero, zero, zero)
    )
    (act, qtab, qval, qcur, _, changes, q_init, trace), _, sweep, visits, evaluated, simulated = (
        carry
    )
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
        simulated=simulated,
    )
