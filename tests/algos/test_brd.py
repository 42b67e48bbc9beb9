"""Alg. 1 (best-response dynamics): Q never decreases, the result is a joint local optimum
(Eq. 5), the Q table is Eq. 7's input at the final Ã, legal masking, and a real environment."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybridmarl.algos.hybrid.brd import best_response_dynamics, make_q_fn
from hybridmarl.training import networks as nets
from hybridmarl.training.task import TaskSpec, make_task

B, N, A = 4, 5, 3


def _pairwise_q(w):
    """A toy centralised Q with pairwise interactions: Q(A) = sum_{i,j} W[i, a_i, j, a_j]."""

    def q_fn(keys, states, cand):  # cand [B, A', N]
        oh = jax.nn.one_hot(cand, A)
        return jnp.einsum("bkia,biajc,bkjc->bk", oh, states, oh)

    return q_fn


def _brute_q(w, joint):
    oh = np.eye(A)[joint]
    return float(np.einsum("ia,iajc,jc->", oh, w, oh))


def _run(w, a0, legal, iterations=7, work_batch=None):
    fn = jax.jit(
        lambda k, s, a, lg: best_response_dynamics(
            _pairwise_q(w), k, s, a, lg, iterations, work_batch=work_batch
        )
    )
    return fn(jax.random.split(jax.random.key(0), B), jnp.asarray(w), a0, legal)


def _toy(seed=0):
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(B, N, A, N, A)).astype(np.float32)
    legal = np.ones((B, N, A), bool)
    legal[0, 1] = [False, True, False]  # a single legal action: never visited, never changed
    legal[1, 2, 0] = False
    legal[2, :, 2] = False
    return w, jnp.asarray(legal)


@pytest.mark.parametrize("work_batch", [None, 3, 1])
def test_q_never_decreases_and_reaches_a_local_optimum(work_batch):
    """Also with the candidates simulated a few at a time (``work_batch`` 3 or 1: 9 or 3 per call)."""
    for seed in range(3):
        w, legal = _toy(seed)
        a0 = jnp.zeros((B, N), jnp.int32).at[1, 2].set(0)  # game 1 starts from an illegal action
        res = _run(w, a0, legal, work_batch=work_batch)
        tr = np.asarray(res.trace)
        acts = np.asarray(res.actions)
        lg = np.asarray(legal)
        for b in range(B):
            seq = tr[:, b][~np.isnan(tr[:, b])]
            assert seq.size > 0
            assert np.all(np.diff(seq) >= -1e-5), seq  # Q(s, Ã) never decreases
            assert seq[-1] >= float(res.q_init[b]) - 1e-5
            assert float(res.q_final[b]) == np.float32(seq[-1])
            assert abs(float(res.q_final[b]) - _brute_q(w[b], acts[b])) < 1e-4
            for g in range(N):
                assert lg[b, g, acts[b, g]]  # legal
                # Eq. 5: no unilateral deviation improves Q.
                base = _brute_q(w[b], acts[b])
                for a in np.flatnonzero(lg[b, g]):
                    dev = acts[b].copy()
                    dev[g] = a
                    q = _brute_q(w[b], dev)
                    assert q <= base + 1e-4
                    if lg[b, g].sum() >= 2:  # the Q table is Q(s, a, Ã_-g) at the final Ã
                        assert abs(float(res.q[b, g, a]) - q) < 1e-4
        assert int(acts[0, 1]) == 1  # the only legal action
        assert bool(res.q_valid[0, 0]) and not bool(res.q_valid[0, 1])


def test_work_batch_does_not_change_the_result_and_skips_finished_games():
    """The compacted schedule gives the same Ã, table and counts for any ``work_batch``; only the
    visits Alg. 1 needs are simulated: a game without a choice costs nothing, a game with one
    decider costs one visit, and converged games are not swept again."""
    w, legal = _toy(2)
    legal = np.asarray(legal).copy()
    legal[1] = False
    legal[1, :, 0] = True  # game 1: nobody has a choice
    legal[0, 1:] = False
    legal[0, 1:, 0] = True  # game 0: one decider (agent 0)
    legal = jnp.asarray(legal)
    a0 = jnp.zeros((B, N), jnp.int32)
    ref = _run(w, a0, legal)
    for wb in (1, 2, 3):
        res = _run(w, a0, legal, work_batch=wb)
        for f in ("actions", "q_valid", "changes", "evaluated", "sweeps"):
            np.testing.assert_array_equal(
                np.asarray(getattr(res, f)), np.asarray(getattr(ref, f)), err_msg=f
            )
        for f in ("q", "q_final", "q_init"):  # the einsum rounds differently at another batch size
            np.testing.assert_allclose(
                np.asarray(getattr(res, f)),
                np.asarray(getattr(ref, f)),
                rtol=1e-5,
                atol=1e-5,
                err_msg=f,
            )
        assert int(res.visits) >= int(ref.visits)
        # Only legal candidates of the games that need a visit are simulated (padding included).
        assert int(res.simulated) < int(ref.simulated)
    assert not bool(np.asarray(ref.q_valid)[1].any()) and np.isnan(float(ref.q_init[1]))
    # Evaluated rows: game 0 one visit; games 2 and 3 at most (sweeps + 1) x their deciders.
    dec = (np.asarray(legal).sum(-1) >= 2).sum(-1)
    assert dec[0] == 1 and dec[1] == 0
    assert int(ref.evaluated) <= 1 + (int(ref.sweeps) + 1) * (dec[2] + dec[3])
    one = _run(w[:1].repeat(B, 0), a0, jnp.broadcast_to(legal[:1], legal.shape))
    assert int(one.evaluated) == B and int(one.sweeps) == 1  # one decider: one visit per game


@pytest.mark.parametrize("work_batch", [1, 2])
def test_compact_schedule_simulates_only_legal_candidates(work_batch):
    """Every candidate joint action passed to ``q_fn`` is legal for every agent of its game
    (padding rows repeat a needed pair), and the Q table is 0 at illegal actions."""
    w, legal = _toy(1)
    lg = np.asarray(legal)
    seen = []
    toy_q = _pairwise_q(w)

    def q_fn(keys, states, cand):
        jax.debug.callback(lambda s, c: seen.append((np.asarray(s), np.asarray(c))), states, cand)
        return toy_q(keys, states, cand)

    fn = jax.jit(
        lambda k, s, a, lg: best_response_dynamics(q_fn, k, s, a, lg, 7, work_batch=work_batch)
    )
    res = fn(
        jax.random.split(jax.random.key(0), B), jnp.asarray(w), jnp.zeros((B, N), jnp.int32), legal
    )
    jax.block_until_ready(res)
    assert len(seen) == int(res.visits) > 0
    rows = 0
    for states, cand in seen:
        assert cand.shape == (work_batch * A, 1, N)
        for s, c in zip(states, cand[:, 0], strict=True):
            game = next(b for b in range(B) if np.array_equal(s, w[b]))
            assert lg[game, np.arange(N), c].all(), (game, c)
            rows += 1
    assert rows == int(res.simulated)
    assert not np.any(np.asarray(res.q)[~lg])


def test_iteration_cap_and_evaluation_sweep():
    w, legal = _toy(5)
    a0 = jnp.zeros((B, N), jnp.int32)
    one = _run(w, a0, legal, iterations=1)
    assert int(one.sweeps) == 1
    acts = np.asarray(one.actions)
    # Even when stopped by the cap, the table is recomputed at the final Ã.
    for b in range(B):
        for g in range(N):
            if np.asarray(legal)[b, g].sum() >= 2:
                for a in np.flatnonzero(np.asarray(legal)[b, g]):
                    dev = acts[b].copy()
                    dev[g] = a
                    assert abs(float(one.q[b, g, a]) - _brute_q(w[b], dev)) < 1e-4
    zero = _run(w, a0, legal, iterations=0)  # no update: Ã = start, table evaluated
    np.testing.assert_array_equal(np.asarray(zero.actions)[3], 0)
    assert int(zero.sweeps) == 0 and int(zero.changes.sum()) == 0


def test_brd_on_traffic_junction_with_a_critic():
    """Real one-step simulation + a (random) critic: Q(s, Ã) never decreases along the updates."""
    task = make_task(TaskSpec(env="traffic_junction"))
    critic = nets.critic_module((16, 8, 8))
    variables = critic.init(jax.random.key(1), jnp.zeros((2, task.critic_dim)), train=False)

    def value_fn(states):
        feats = jax.vmap(task.value_features)(states)
        return nets.apply_eval(critic, variables, feats)[:, 0] * 10.0

    q_fn = make_q_fn(task.lookahead, value_fn, 0.995)
    gas = task.demonstrator("always-gas")

    @jax.jit
    def run(key):
        keys = jax.random.split(key, 8)

        def warm(s, k):  # 12 steps of always-gas so that cars are on the road
            _, s2, _, _, _ = task.step(k, s, gas(k, s))
            return s2, None

        states = jax.vmap(
            lambda k: jax.lax.scan(warm, task.reset(k)[1], jax.random.split(k, 12))[0]
        )(keys)
        legal = jax.vmap(task.avail)(states)
        a0 = jax.vmap(gas)(keys, states)
        return best_response_dynamics(q_fn, keys, states, a0, legal, 7), legal

    res, legal = run(jax.random.key(3))
    tr = np.asarray(res.trace)
    assert np.isfinite(np.asarray(res.q_final)).all()
    for b in range(tr.shape[1]):
        seq = tr[:, b][~np.isnan(tr[:, b])]
        assert np.all(np.diff(seq) >= -1e-4), seq
        assert seq.size == 0 or seq[-1] >= float(res.q_init[b]) - 1e-4
    assert np.take_along_axis(np.asarray(legal), np.asarray(res.actions)[..., None], -1).all()


def test_lookahead_continuation_is_the_chosen_policy():
    """``brd_q_fn`` with K = 3 steps and the demonstrator continuing equals r_0 + λ r_1 + λ² r_2
    + λ³ V(s_3) of (candidate, then A^D) played step by step through the environment;
    ``lookahead_policy`` picks who continues (``start`` follows ``brd_start``)."""
    from hybridmarl.algos.hybrid import PRESETS, build_learner
    from hybridmarl.algos.hybrid.learner import continuation_policy
    from hybridmarl.training.rollout import new_pool

    task = make_task(TaskSpec(env="combat", scenario="m3v3", enemy="attack-weakest"))
    cfg = PRESETS["toy"]("combat")
    assert continuation_policy(cfg) == cfg.brd_start == "actor"
    assert continuation_policy(cfg.replace(brd_start="demonstrator")) == "demonstrator"
    assert continuation_policy(cfg.replace(lookahead_policy="demonstrator")) == "demonstrator"
    learner = build_learner(task, cfg, "attack-closest")
    actor = nets.init_net(learner.actor_mod, jax.random.key(1), task.obs_dim, learner.actor_tx)
    critic = nets.init_net(
        learner.critic_mod, jax.random.key(2), task.critic_dim, learner.critic_tx
    )
    cv = {"params": critic.params, "batch_stats": critic.batch_stats}
    pool = new_pool(task, jax.random.key(3), 2)
    legal = np.asarray(jax.vmap(task.avail)(pool.states))
    cand = jnp.asarray(
        np.stack([legal.argmax(-1), legal.shape[-1] - 1 - legal[..., ::-1].argmax(-1)], 1)
    )  # [B, 2, N]
    keys = jax.random.split(jax.random.key(4), 2)
    gamma, k_steps = 0.9, 3
    q = np.asarray(
        jax.jit(
            learner.brd_q_fn(
                actor, cv, None, gamma=gamma, lookahead=k_steps, continuation="demonstrator"
            )
        )(keys, pool.states, cand)
    )

    @jax.jit
    def manual(key, state, acts):
        ret, disc, done = 0.0, 1.0, False
        for _ in range(k_steps):
            _, nxt, r, d, _ = task.step(key, state, acts)
            ret, disc = ret + jnp.where(done, 0.0, disc * r), jnp.where(done, disc, disc * gamma)
            state = jax.tree.map(lambda a, b, done=done: jnp.where(done, b, a), nxt, state)
            done = done | d
            acts = learner.demo_script_fn(key, state).astype(jnp.int32)
        v = learner.value_fn(cv)(jax.tree.map(lambda x: x[None], state))[0]
        return ret + disc * jnp.where(done, 0.0, v)

    for g in range(2):
        for k in range(2):
            expected = float(
                manual(keys[g], jax.tree.map(lambda x, g=g: x[g], pool.states), cand[g, k])
            )
            np.testing.assert_allclose(q[g, k], expected, rtol=1e-5, atol=1e-6)
