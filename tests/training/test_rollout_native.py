"""Phase 2's demonstrator games on the native engine against the JAX ones: from the same pool
(so the same start states and the same fresh start states after every finished game) the
native chunk records the JAX chunk's states field by field, and its rewards, dones and episode
metrics; it is deterministic; and --engine jax keeps the JAX path."""

from __future__ import annotations

import functools

import jax
import numpy as np

from hybridmarl.algos.hybrid.config import PRESETS
from hybridmarl.training.rollout import EpisodeAssembler, new_pool, pool_steps
from hybridmarl.training.rollout_native import NativeScriptRollout, native_rollout_support
from hybridmarl.training.task import flatten_named, make_task

NUM_ENVS, STEPS = 12, 16


@functools.lru_cache(maxsize=4)
def _task(enemy: str):
    cfg = PRESETS["quick-paper"]("combat").replace(scenario="m5v5", enemy=enemy)
    return make_task(cfg.task_spec())


@functools.lru_cache(maxsize=4)
def _jax_chunk(enemy: str, script: str):
    """``Learner.demo_chunk``'s JAX path: ``pool_steps`` with the script acting."""
    task = _task(enemy)
    policy = jax.vmap(task.demonstrator(script))

    def act(carry, key, states, obs, legal):
        return policy(jax.random.split(key, NUM_ENVS), states).astype(np.int32), carry, {}

    def chunk(pool):
        pool, _, out = pool_steps(task, act, pool, None, STEPS)
        return pool, out

    return jax.jit(chunk)


def test_native_chunk_equals_pool_steps(enemy="attack-weakest", script="attack-closest"):
    task = _task(enemy)
    native = NativeScriptRollout(task, script, num_envs=NUM_ENVS, steps=STEPS)
    pool_j = pool_n = new_pool(task, jax.random.key(5), NUM_ENVS)
    asm_j, asm_n = EpisodeAssembler(NUM_ENVS, 0.995), EpisodeAssembler(NUM_ENVS, 0.995)
    finished = 0
    for chunk in range(3):  # across chunk boundaries: the pools carry on
        pool_j, out_j = jax.device_get(_jax_chunk(enemy, script)(pool_j))
        pool_n, out_n = native(pool_n)
        ref, got = flatten_named(out_j["state"]), flatten_named(out_n["state"])
        assert sorted(got) == sorted(ref)
        for name in ref:
            np.testing.assert_array_equal(
                got[name], ref[name], err_msg=f"chunk {chunk}: state.{name}"
            )
        np.testing.assert_array_equal(out_n["reward"], out_j["reward"])
        np.testing.assert_array_equal(out_n["done"], out_j["done"])
        assert list(out_n["stats"]) == list(out_j["stats"])
        for name, v in out_j["stats"].items():
            np.testing.assert_array_equal(out_n["stats"][name], v, err_msg=name)
        for a, b in zip(jax.tree.leaves(pool_n), jax.tree.leaves(pool_j), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        # What the buffer receives: the same rows, returns and metrics.
        (s_j, r_j, st_j), (s_n, r_n, st_n) = asm_j.add(out_j), asm_n.add(out_n)
        np.testing.assert_array_equal(r_n, r_j)
        for name in s_j:
            np.testing.assert_array_equal(s_n[name], s_j[name], err_msg=name)
        for name in st_j:
            np.testing.assert_array_equal(st_n[name], st_j[name], err_msg=name)
        finished += int(out_j["done"].sum())
    assert finished > 0  # episodes ended, so the resets were exercised
    assert np.any(flatten_named(out_j["state"])["last_actions"] >= 0)


def test_native_chunk_is_deterministic_with_the_random_script():
    task = _task("random")
    native = NativeScriptRollout(task, "random", num_envs=NUM_ENVS, steps=STEPS)
    pool = new_pool(task, jax.random.key(1), NUM_ENVS)
    runs = [native(pool) for _ in range(2)]
    for a, b in zip(jax.tree.leaves(runs[0]), jax.tree.leaves(runs[1]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # The generator follows the pool's key stream: another pool key, other games.
    other = native(new_pool(task, jax.random.key(2), NUM_ENVS))
    assert not np.array_equal(other[1]["state"].game.hp, runs[0][1]["state"].game.hp)


def test_learner_picks_the_engine_of_phase_2():
    from hybridmarl.algos.hybrid.learner import build_learner

    cfg = PRESETS["quick-paper"]("combat").replace(scenario="m5v5", num_envs=NUM_ENVS)
    task = make_task(cfg.task_spec())
    assert isinstance(
        build_learner(task, cfg.replace(engine="native"), "attack-closest").demo_chunk,
        NativeScriptRollout,
    )
    assert not isinstance(
        build_learner(task, cfg.replace(engine="jax"), "attack-closest").demo_chunk,
        NativeScriptRollout,
    )
    assert native_rollout_support(task, "attack-closest") is None
    assert "script" in (native_rollout_support(task, "dataset:demos.npz") or "")


def test_demos_collect_same_dataset_on_both_engines():
    from hybridmarl.training import demos as D

    # Other scripts than the chunk test's, on both sides.
    spec = PRESETS["quick-paper"]("combat").replace(scenario="m5v5", enemy="attack-dps").task_spec()
    runs = {
        e: D.collect(spec, "nokdps", 300, seed=3, num_envs=NUM_ENVS, chunk=STEPS, engine=e)
        for e in ("native", "jax")
    }
    native, ref = runs["native"], runs["jax"]
    assert sorted(native.arrays) == sorted(ref.arrays)
    for name, v in ref.arrays.items():
        np.testing.assert_array_equal(native.arrays[name], v, err_msg=name)
    assert native.meta == ref.meta
    assert D._native_collect(make_task(spec), "nokdps", "auto") == (jax.default_backend() == "cpu")
    assert not D._native_collect(make_task(spec), "random", "native")
