"""Alg. 1 on the native engine against the JAX one: the host sweep gives brd's result for the
same Q; the simulated env steps, returns and critic features equal the JAX env's; the NumPy
critic equals Flax's up to rounding; the native training chunk is deterministic."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybridmarl.algos.hybrid import brd_native as BN
from hybridmarl.algos.hybrid.brd import best_response_dynamics, make_q_fn
from hybridmarl.algos.hybrid.config import PRESETS
from hybridmarl.envs.combat.native import critic_features, env_step, state_arrays
from hybridmarl.training import networks as nets
from hybridmarl.training.task import make_task

from .test_brd import _pairwise_q, _toy


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_host_sweep_equals_jit_sweep(seed):
    w, legal = _toy(seed)
    a0 = (
        jnp.zeros(legal.shape[:2], jnp.int32).at[1, 2].set(0)
    )  # game 1 starts from an illegal action
    ref = jax.jit(lambda k, s, a, lg: best_response_dynamics(_pairwise_q(w), k, s, a, lg, 7))(
        jax.random.split(jax.random.key(0), w.shape[0]), jnp.asarray(w), a0, legal
    )
    na = legal.shape[-1]

    def q_pairs(games, joint):
        oh = np.eye(na, dtype=np.float32)[joint]  # [M, N, A]
        return np.einsum("mia,miajc,mjc->m", oh, np.asarray(w)[games], oh).astype(np.float32)

    got = BN.best_response_dynamics(q_pairs, np.asarray(a0), np.asarray(legal), 7)
    np.testing.assert_array_equal(got.actions, np.asarray(ref.actions))
    np.testing.assert_array_equal(got.q_valid, np.asarray(ref.q_valid))
    np.testing.assert_allclose(got.q, np.asarray(ref.q), atol=1e-5)
    np.testing.assert_allclose(got.q_final, np.asarray(ref.q_final), atol=1e-5)
    np.testing.assert_array_equal(got.changes, np.asarray(ref.changes))
    assert got.sweeps == int(ref.sweeps)
    assert got.evaluated == int(ref.evaluated)


@pytest.fixture(scope="module")
def midgame():
    """16 m5v5 games (quick preset's task) after 5 steps of random legal actions, and random
    candidate joint actions for them, some with illegal entries."""
    cfg = PRESETS["quick"]("combat").replace(scenario="m5v5")
    task = make_task(cfg.task_spec())
    b = 16
    _, states = jax.vmap(task.reset)(jax.random.split(jax.random.key(7), b))
    rng = np.random.default_rng(0)
    step = jax.jit(jax.vmap(task.step))
    avail = jax.jit(jax.vmap(task.avail))
    for t in range(5):
        legal = np.asarray(avail(states))
        acts = np.array(
            [[rng.choice(np.flatnonzero(lg)) for lg in game] for game in legal], np.int32
        )
        _, states, _, _, _ = step(jax.random.split(jax.random.key(t), b), states, jnp.asarray(acts))
    legal = np.asarray(avail(states))
    na = legal.shape[-1]
    cand = np.array(
        [
            [[rng.choice(np.flatnonzero(lg)) for lg in legal[g]] for _ in range(na)]
            for g in range(b)
        ],
        np.int32,
    )
    cand[:, 0, 0] = na - 1  # often illegal: the env's fallback must match
    return cfg, task, states, legal, cand


def test_env_step_equals_combat_step(midgame):
    _, task, states, _, cand = midgame
    b = cand.shape[0]
    acts = cand[:, 0]
    _, s2, r, d, _ = jax.vmap(task.step)(
        jax.random.split(jax.random.key(0), b), states, jnp.asarray(acts)
    )
    env = task.env
    batch = state_arrays(jax.device_get(states))
    fields = batch["fields"]
    rules = env.rules
    walk = np.array(rules.walkable, np.bool_)
    from hybridmarl.engine.native.kernels import SCRIPT_CODES, make_workspace

    n = env.num_slots
    for g in range(b):
        f = [a[g] for a in fields]
        reward, done = env_step(
            g,
            *f,
            batch["time"],
            batch["turn"],
            batch["stale"],
            batch["prev_hp_sum"],
            walk,
            acts[g].astype(np.int64),
            env.num_agents,
            env.num_actions,
            SCRIPT_CODES[env.enemy_name],
            rules.overkill == "pass",
            rules.stalemate_limit,
            rules.max_turns,
            batch["init_hp0"][g],
            0,
            g,
            make_workspace(n),
            np.zeros(n, np.int64),
            np.zeros(n, np.int64),
            False,
        )
        assert reward == float(r[g]) and done == bool(d[g]), g
    names = ("utype", "uid", "x", "y", "px", "py", "t_act", "last", "hp", "t_move", "t_attack")
    for name, arr in zip(names, fields, strict=True):
        np.testing.assert_array_equal(arr, np.asarray(getattr(s2.game, name)), err_msg=name)
    for name in ("time", "turn", "stale", "prev_hp_sum"):
        np.testing.assert_array_equal(batch[name], np.asarray(getattr(s2.game, name)), err_msg=name)


@pytest.mark.parametrize("steps", [1, 4])
def test_simulated_returns_equal_jax(midgame, steps):
    """Alg. 1's simulated returns (the critic set to 0) are those of the JAX env, exactly."""
    cfg, task, states, _, cand = midgame
    b, na, n = cand.shape
    demo = task.demonstrator("attack-closest")

    def batch_step(keys, st, actions):
        _, s2, r, d, _ = task.batch_step(keys, st, actions)
        return r, s2, d

    q_fn = make_q_fn(
        task.lookahead,
        lambda s: jnp.zeros(jax.tree.leaves(s)[0].shape[0]),
        cfg.gamma,
        steps=steps,
        policy_fn=lambda keys, s: jax.vmap(demo)(keys, s).astype(jnp.int32),
        batch_step_fn=batch_step,
    )
    ref = np.asarray(
        jax.jit(q_fn)(jax.random.split(jax.random.key(1), b), states, jnp.asarray(cand))
    )
    sim = BN.NativeBRD(
        task, gamma=cfg.gamma, iterations=7, lookahead=steps, continuation="attack-closest"
    )
    ret, _, _, _ = sim.simulate(
        state_arrays(jax.device_get(states)), np.repeat(np.arange(b), na), cand.reshape(b * na, n)
    )
    np.testing.assert_array_equal(ret.reshape(b, na), ref)


def test_critic_features_and_mlp(midgame):
    cfg, task, states, _, _ = midgame
    ref = np.asarray(jax.vmap(task.value_features)(states))
    batch = state_arrays(jax.device_get(states))
    env = task.env
    got = np.zeros_like(ref)
    scratch = np.zeros((2, env.num_slots), np.float32)
    for g in range(ref.shape[0]):
        f = [a[g] for a in batch["fields"]]
        critic_features(batch["time"][g], *f[2:], env.num_agents, env.num_enemies, scratch, got[g])
    np.testing.assert_allclose(got, ref, atol=1e-6)
    module = nets.critic_module(cfg.critic_hidden)
    net = nets.init_net(
        module, jax.random.key(3), task.critic_dim, nets.make_optimizer("adam", 1e-3)
    )
    stats = jax.tree.map(
        lambda x: x + 0.3 * jax.random.uniform(jax.random.key(4), x.shape), net.batch_stats
    )
    variables = {"params": net.params, "batch_stats": stats}
    want = np.asarray(nets.apply_eval(module, variables, jnp.asarray(ref)))
    np.testing.assert_allclose(
        BN.NativeMLP(jax.device_get(variables))(ref), want, rtol=1e-4, atol=1e-5
    )


def test_native_chunk_is_deterministic():
    from hybridmarl.algos.hybrid.learner import build_learner
    from hybridmarl.algos.hybrid.train import _vars
    from hybridmarl.training.rollout import new_pool

    cfg = PRESETS["toy"]("combat").replace(
        engine="native",
        lookahead_steps=3,
        lookahead_policy="demonstrator",
        brd_start="demonstrator",
    )
    task = make_task(cfg.task_spec())
    learner = build_learner(task, cfg, "attack-closest")
    assert learner.engine == "native"
    actor = nets.init_net(learner.actor_mod, jax.random.key(0), task.obs_dim, learner.actor_tx)
    critic = nets.init_net(
        learner.critic_mod, jax.random.key(1), task.critic_dim, learner.critic_tx
    )
    pool = new_pool(task, jax.random.key(2), cfg.num_envs)
    runs = [learner.train_chunk(pool, actor, _vars(critic), None) for _ in range(2)]
    for a, b in zip(jax.tree.leaves(runs[0]), jax.tree.leaves(runs[1]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    out = runs[0][2]
    assert out["reward"].shape == (cfg.chunk_steps, cfg.num_envs)
    assert np.all(np.isfinite(out["aux"]["actor_loss"]))
    # The actor's learning-rate factor (actor_lr_decay_from): 1 is the unscaled step exactly,
    # 0 leaves the parameters where they were (batch-norm statistics and Adam's moments move).
    for a, b in zip(
        jax.tree.leaves(learner.train_chunk(pool, actor, _vars(critic), None, np.float32(1.0))),
        jax.tree.leaves(runs[0]),
        strict=True,
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    frozen = learner.train_chunk(pool, actor, _vars(critic), None, np.float32(0.0))[1]
    for a, b in zip(jax.tree.leaves(frozen.params), jax.tree.leaves(actor.params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert not all(
        np.array_equal(a, b)
        for a, b in zip(
            jax.tree.leaves(frozen.params), jax.tree.leaves(runs[0][1].params), strict=True
        )
    )


def test_native_engine_refused_where_it_does_not_apply():
    from hybridmarl.algos.hybrid.learner import resolve_brd_engine

    cfg = PRESETS["toy"]("combat").replace(
        engine="native", lookahead_steps=3, lookahead_policy="actor"
    )
    with pytest.raises(ValueError, match="native"):
        resolve_brd_engine(make_task(cfg.task_spec()), cfg, "attack-closest")
    engine, note = resolve_brd_engine(
        make_task(cfg.task_spec()), cfg.replace(engine="auto"), "attack-closest"
    )
    assert engine == "jax" and "continuation" in note


def test_script_evaluation_same_on_both_engines():
    """`eval --script`: the native engine plays the JAX engine's start states to the same
    episode metrics (return summed step by step, steps, W, R)."""
    from hybridmarl.training import evaluate as E

    task = make_task(PRESETS["toy"]("combat").replace(scenario="m5v5").task_spec())
    key = jax.random.key(3)
    ref = E.run_episodes(task, E._script_policy_cached(task, "attack-closest"), None, key, 24)
    got = E.run_scripted_episodes_native(task, "attack-closest", key, 24)
    for name in ("won", "lost", "draw", "terminal_hp_reward", "return", "steps"):
        np.testing.assert_array_equal(got[name], ref[name], err_msg=name)


def test_each_env_step_kernel_is_compiled_once(midgame):
    """Compiled callers pass the game index and the flags as runtime values, never as literals:
    Numba compiles a function again for every literal argument value (``Literal[int](0)``) and
    for a ``prange`` loop's unsigned index, and each such copy is the whole turn loop again.

    A caller compiled in this process has resolved its callees for exactly the argument types
    it passes. One loaded from Numba's disk cache has not, so it is compiled again here,
    uncached, for the types it was called with."""
    import numba

    from hybridmarl.envs.combat import native as CN

    cfg, task, states, _, cand = midgame
    b, na, n = cand.shape
    sim = BN.NativeBRD(
        task, gamma=cfg.gamma, iterations=7, lookahead=2, continuation="attack-closest"
    )
    sim.simulate(
        state_arrays(jax.device_get(states)), np.repeat(np.arange(b), na), cand.reshape(b * na, n)
    )

    def callees_of(caller, sig, parallel=False):
        if not caller._cache_misses[sig]:  # loaded, not compiled, in this process
            numba.njit(sig, parallel=parallel, _nrt=parallel)(caller.py_func)

    def one(callee):
        assert len(callee.signatures) == 1, (callee.py_func.__name__, callee.signatures)
        return callee.signatures[0]

    callees_of(BN.simulate_candidates, one(BN.simulate_candidates), parallel=True)
    callees_of(
        BN._simulate_chunk, one(BN._simulate_chunk)
    )  # the first env step, then the look-ahead's
    step_sig = one(CN.env_step)
    one(CN.script_env_actions)
    callees_of(CN.env_step, step_sig)
    callees_of(CN.env_step_keeping_last_actions, (*step_sig, numba.types.int32[:, ::1]))
    one(CN._env_step)
