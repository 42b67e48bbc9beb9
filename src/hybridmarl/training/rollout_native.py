"""Script games on the native engine, in the chunks of ``training.rollout.pool_steps``: a script
against the enemy script, for Phase 2's demonstrator games (the hybrid learner's ``demo_chunk``)
and for recording demonstrations (``training.demos``).

On the JAX engine such a chunk is ``pool_steps`` with the script acting: ``chunk_steps`` steps of
all B games in one ``lax.scan``, a finished game replaced at once by a fresh start state.
:class:`NativeScriptRollout` plays the same chunk on the native engine: one parallel Numba call
per env step for all games (``envs.combat.native.step_scripted_games``), the pre-step state of
every game recorded on the host.

The pool semantics are those of ``pool_steps``: the chunk's start states come from the task's own
``reset``, drawn in one jitted call per chunk from the pool's key stream split exactly as
``pool_steps`` splits it (step ``t`` of slot ``g`` that finishes is replaced by the ``g``-th of
step ``t``'s ``B`` reset states). With deterministic scripts the chunk therefore equals the JAX
one (states, rewards, ``done`` and episode metrics; tested); the ``random`` script draws from the
native engine's generator instead of JAX's (docs/engine-backends.md), seeded per step from the
pool's key stream.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numba
import numpy as np

from hybridmarl.engine.native.kernels import FIELDS, SCRIPT_CODES
from hybridmarl.envs.combat.native import step_scripted_games
from hybridmarl.training.rollout import Pool
from hybridmarl.training.task import Task, flatten_named, unflatten_named


def native_rollout_support(task: Task, demo_script: str | None) -> str | None:
    """Why Phase 2 cannot play on the native engine (None: it can)."""
    if getattr(task, "kind", None) != "combat":
        return f"the native engine plays combat only (this task is {getattr(task, 'kind', None)!r})"
    if getattr(task.env, "enemy_name", None) not in SCRIPT_CODES:
        return "the native demonstrator games need a scripted enemy"
    if demo_script not in SCRIPT_CODES:
        return "the native demonstrator games need a script demonstrator without exploration"
    return None


class NativeScriptRollout:
    """``Learner.demo_chunk`` for a script demonstrator on the native engine (module docstring):
    ``(pool, clone_vars) -> (pool, out)`` with ``out`` time-major ``[K, B]``: ``state`` (a
    ``CombatState`` of NumPy arrays), ``actions`` (the script's env actions ``[K, B, N]``),
    ``reward``, ``done`` and ``stats`` (the env's episode metrics, valid where done)."""

    def __init__(self, task: Task, script: str, *, num_envs: int, steps: int) -> None:
        env = task.env
        rules = env.rules
        self.task = task
        self.num_envs = int(num_envs)
        self.steps = int(steps)
        self.script = SCRIPT_CODES[script]
        self.enemy = SCRIPT_CODES[env.enemy_name]
        self.num_agents = int(env.num_agents)
        self.num_actions = int(env.num_actions)
        self.overkill_pass = rules.overkill == "pass"
        self.stalemate_limit = int(rules.stalemate_limit)
        self.max_turns = int(rules.max_turns)
        self.walkable = np.array(rules.walkable, dtype=np.bool_, order="C", copy=True)
        self.template = task.state_template()
        self._draw = _reset_draw_fn(task, self.num_envs, self.steps)
        self._observe = jax.jit(jax.vmap(task.observe))

    def __call__(self, pool: Pool, clone_vars: Any = None) -> tuple[Pool, dict[str, Any]]:
        del clone_vars  # the demonstrator is a script
        key_data, resets, seeds = jax.device_get(self._draw(pool.key))
        resets = flatten_named(resets)  # {name: [K, B, ...]}
        state = {
            k: np.array(v, order="C", copy=True)
            for k, v in flatten_named(jax.device_get(pool.states)).items()
        }
        k_steps, b = self.steps, self.num_envs
        recorded = {k: np.empty((k_steps,) + v.shape, v.dtype) for k, v in state.items()}
        actions = np.zeros((k_steps, b, self.num_agents), np.int32)
        reward = np.zeros((k_steps, b), np.float32)
        done = np.zeros((k_steps, b), np.bool_)
        won = np.zeros((k_steps, b), np.bool_)
        lost = np.zeros((k_steps, b), np.bool_)
        terminal = np.zeros((k_steps, b), np.float32)
        chunks = max(1, min(b, numba.get_num_threads() * 4))
        for t in range(k_steps):
            for k, v in state.items():
                recorded[k][t] = v
            # The kernel works in place on these arrays; each step's 'where' below writes into
            # them, so they stay the same objects from step to step.
            init_hp0 = np.ascontiguousarray(state["init_hp"][:, 0])
            step_scripted_games(
                tuple(state["game." + f] for f in FIELDS),
                state["game.time"],
                state["game.turn"],
                state["game.stale"],
                state["game.prev_hp_sum"],
                state["last_actions"],
                state["steps"],
                init_hp0,
                self.walkable,
                self.script,
                self.enemy,
                self.num_agents,
                self.num_actions,
                self.overkill_pass,
                self.stalemate_limit,
                self.max_turns,
                int(seeds[t]),
                chunks,
                actions[t],
                reward[t],
                done[t],
                won[t],
                lost[t],
                terminal[t],
            )
            if done[t].any():  # pool_steps' resets: slot g takes step t's g-th fresh start state
                for k, v in state.items():
                    d = done[t].reshape((b,) + (1,) * (v.ndim - 1))
                    np.copyto(v, resets[k][t], where=d)
        states = unflatten_named(self.template, state, batch_dims=1)
        pool = Pool(states=states, obs=self._observe(states), key=key_data)
        stats = {  # the names, and their order, of the JAX chunk's (jit returns dicts sorted by key)
            "draw": (done & ~won & ~lost).astype(np.float32),
            "lost": lost.astype(np.float32),
            "terminal_hp_reward": terminal,
            "won": won.astype(np.float32),
        }
        out = {
            "state": unflatten_named(self.template, recorded, batch_dims=2),
            "actions": actions,
            "reward": reward,
            "done": done,
            "stats": stats,
        }
        return pool, out


@functools.lru_cache(maxsize=8)
def _reset_draw_fn(task: Task, num_envs: int, steps: int):
    """A jitted ``key_data -> (key_data, resets [K, B], seeds [K])``: the reset states of
    ``pool_steps``' K steps (its key split, step by step) and a native generator seed per step
    (from the step's action key, which a script demonstrator's JAX path would use)."""

    def draw(key_data: jax.Array):
        def body(key: jax.Array, _: Any):
            key, k_act, _k_step, k_reset = jax.random.split(key, 4)
            _, states = jax.vmap(task.reset)(jax.random.split(k_reset, num_envs))
            seed = jax.random.bits(k_act, (), jnp.uint32)
            return key, (states, seed)

        key, (resets, seeds) = jax.lax.scan(
            body, jax.random.wrap_key_data(key_data), None, length=steps
        )
        return jax.random.key_data(key), resets, seeds

    return jax.jit(draw)


__all__ = ["NativeScriptRollout", "native_rollout_support"]
