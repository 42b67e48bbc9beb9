"""The hybrid method's compiled learner: networks, optimisers and the jitted functions of one
(task, compile key) pair.

- 'demo_chunk': Phase 2's data, A^D playing from random start states;
- 'fit_critic': Eq. 3 on the buffer B (minibatch SGD on (V(s) - V^D(s))^2);
- 'train_chunk': 'chunk_steps' steps of Alg. 2 for all B games as one 'lax.scan': at every step
  Alg. 1 ('brd.best_response_dynamics') on the critic, the advantages of Eq. 7, the actor's SGD
  step on Eq. 8 (or the cross-entropy toward ã_g, 'actor_target=best'), and every agent playing
  the legal argmax of the updated actor;
- 'brd_q_fn': Alg. 1's Q estimate (Eq. 2's one step, K steps, or to the end).

With the native engine ('engine', resolved by 'Learner.engine'), 'train_chunk' runs the same
steps as a host loop instead of one 'lax.scan': per env step one jitted call for the actor's
actions, one host call for the whole of Alg. 1 on the native engine ('brd_native'), and one
jitted call for the actor update (on the rows of the agents that have a choice only, gathered
and padded to a few fixed sizes: the same loss) and the env step; and with a script A^D,
'demo_chunk' plays Phase 2's games on the native engine ('training.rollout_native': the same chunk).

'build_learner' caches learners under 'training.config.compile_key' of the config, so runs that
differ only in run-only fields (seed, budgets, paths, cadences) share compiled programs.
"""

from __future__ import annotations

import functools
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from hybridmarl.algos.hybrid.brd import best_response_dynamics, make_q_fn
from hybridmarl.algos.hybrid.config import HybridConfig
from hybridmarl.training import networks as nets
from hybridmarl.training.config import compile_key
from hybridmarl.training.losses import actor_loss, advantages, bc_loss, critic_loss
from hybridmarl.training.rollout import Pool, pool_steps, select_tree
from hybridmarl.training.task import Task


class Learner:
    """Networks, optimisers and the jitted functions of one (task, static settings) pair."""

    def __init__(self, task: Task, cfg: HybridConfig, demo_script: str | None) -> None:
        self.task = task
        self.actor_mod = nets.actor_module(task.num_actions, cfg.actor_hidden)
        self.critic_mod = nets.critic_module(cfg.critic_hidden)
        self.actor_tx = nets.make_optimizer(cfg.optimizer, cfg.actor_lr)
        self.critic_tx = nets.make_optimizer(cfg.optimizer, cfg.critic_lr)
        self.b = cfg.num_envs
        demo = task.demonstrator(demo_script) if demo_script else None
        self.demo_script_fn = demo
        actor_mod = self.actor_mod

        def demo_act(clone_vars, key, states, obs, legal):
            """A^D(s) for a batch: the script, or the clone's legal argmax."""
            if demo is not None:
                return jax.vmap(demo)(jax.random.split(key, self.b), states).astype(jnp.int32)
            return nets.actor_actions(actor_mod, clone_vars, obs, legal)

        self.demo_act = demo_act
        self.demo_chunk = jax.jit(functools.partial(self._demo_chunk, steps=cfg.chunk_steps))
        self.train_chunk = jax.jit(
            functools.partial(
                self._train_chunk,
                steps=cfg.chunk_steps,
                gamma=cfg.gamma,
                iterations=cfg.brd_iterations,
                start=cfg.brd_start,
                continuation=continuation_policy(cfg),
                lookahead=simulated_steps(cfg),
                actor_steps=cfg.actor_steps,
                target=cfg.actor_target,
                work_batch=cfg.brd_work_batch,
            )
        )
        self.fit_critic = jax.jit(functools.partial(self._fit_critic, batch=cfg.critic_batch_size))
        self.critic_values = jax.jit(self._critic_values)
        self.engine, self.engine_note = resolve_brd_engine(task, cfg, demo_script)
        #: Seconds spent per part of the native chunk (bench/train_step.py reads them).
        self.timing: dict[str, float] = {}
        if self.engine == "native":
            from hybridmarl.algos.hybrid.brd_native import NativeBRD
            from hybridmarl.training.rollout_native import (
                NativeScriptRollout,
                native_rollout_support,
            )

            lookahead = simulated_steps(cfg)
            self.native_brd = NativeBRD(
                task,
                gamma=cfg.gamma,
                iterations=cfg.brd_iterations,
                lookahead=lookahead,
                continuation=demo_script if lookahead > 1 else None,
            )
            self._native_pre = jax.jit(functools.partial(self._native_pre_fn, start=cfg.brd_start))
            self._native_post = jax.jit(
                functools.partial(
                    self._native_post_fn, actor_steps=cfg.actor_steps, target=cfg.actor_target
                )
            )
            self._chunk_steps = cfg.chunk_steps
            self.train_chunk = self._train_chunk_native
            # Phase 2 with a script A^D plays on the native engine too (same chunk, same pool).
            if demo_script is not None and native_rollout_support(task, demo_script) is None:
                self.demo_chunk = NativeScriptRollout(
                    task, demo_script, num_envs=cfg.num_envs, steps=cfg.chunk_steps
                )

    # Phase 2's data: A^D plays from random start states.
    def _demo_chunk(self, pool: Pool, clone_vars: Any, *, steps: int):
        def act(carry, key, states, obs, legal):
            return self.demo_act(carry, key, states, obs, legal), carry, {}

        pool, _, out = pool_steps(self.task, act, pool, clone_vars, steps)
        return pool, out

    def value_fn(self, critic_vars: Any):
        def v(states: Any) -> jax.Array:
            feats = jax.vmap(self.task.value_features)(states)
            return nets.apply_eval(self.critic_mod, critic_vars, feats)[:, 0]

        return v

    def _critic_values(self, critic_vars: Any, states: Any) -> jax.Array:
        return self.value_fn(critic_vars)(states)

    # Eq. 3 on the buffer B: minibatch SGD on (V(s) - V^D(s))^2.
    def _fit_critic(
        self,
        critic: nets.NetState,
        states: Any,
        returns: jax.Array,
        size: jax.Array,
        key: jax.Array,
        num_steps: jax.Array,
        *,
        batch: int,
    ):
        mod, tx, task = self.critic_mod, self.critic_tx, self.task

        def one(i, c):
            critic, total = c
            idx = jax.random.randint(jax.random.fold_in(key, i), (batch,), 0, jnp.maximum(size, 1))
            feats = jax.vmap(task.value_features)(jax.tree.map(lambda x: x[idx], states))

            def loss_fn(params, batch_stats):
                v, bs = nets.apply_train(mod, params, batch_stats, feats)
                return critic_loss(v[:, 0], returns[idx]), (bs, None)

            critic, loss, _ = nets.sgd_step(critic, tx, loss_fn)
            return critic, total + loss

        critic, total = jax.lax.fori_loop(0, num_steps, one, (critic, jnp.zeros((), jnp.float32)))
        return critic, total / jnp.maximum(num_steps, 1).astype(jnp.float32)

    # Eq. 8 (or the cross-entropy toward ã_g): 'actor_steps' SGD steps on the rows of weight 1
    # (batch norm's statistics over those rows only); no update when no row has weight.
    def _update_actor(
        self,
        actor: nets.NetState,
        x: jax.Array,
        legal: jax.Array,
        best: jax.Array,
        adv: jax.Array,
        w: jax.Array,
        lr_scale: ArrayLike | None,
        *,
        actor_steps: int,
        target: str,
    ):
        mod, tx = self.actor_mod, self.actor_tx
        any_w = jnp.any(w)
        bn_mask = jnp.where(any_w, w, jnp.ones_like(w))

        def loss_fn(params, batch_stats):
            logits, bs = nets.apply_train(mod, params, batch_stats, x, mask=bn_mask)
            if target == "best":
                loss = bc_loss(logits, best, legal, w)
            else:
                loss = actor_loss(logits, adv, legal, w)
            return loss, (bs, None)

        def sgd_step(_, c):
            net, _ = c
            net, loss, _ = nets.sgd_step(net, tx, loss_fn, lr_scale)
            return net, loss

        new, loss = jax.lax.fori_loop(0, actor_steps, sgd_step, (actor, jnp.zeros((), jnp.float32)))
        return jax.tree.map(lambda a, b: jnp.where(any_w, a, b), new, actor), loss

    # Phase 3, K steps of Alg. 2 for all B games.
    def brd_q_fn(
        self,
        actor: Any,
        critic_vars: Any,
        clone_vars: Any,
        *,
        gamma: float,
        lookahead: int,
        continuation: str,
    ):
        """Alg. 1's Q estimate for B games: ``lookahead`` simulated steps (1: Eq. 2's one step;
        ``TO_THE_END``: to the end, critic unused), the later ones played by ``continuation``
        (``actor``: the actor's legal argmax; ``demonstrator``: A^D, the script or the clone)."""
        task, mod = self.task, self.actor_mod

        def batch_step_fn(keys, states, actions):
            _, s2, r, d, _ = task.batch_step(keys, states, actions)
            return r, s2, d

        def policy(keys, flat_states):
            if continuation == "demonstrator" and self.demo_script_fn is not None:
                return jax.vmap(self.demo_script_fn)(keys, flat_states).astype(jnp.int32)
            fobs = jax.vmap(task.observe)(flat_states)
            flegal = jax.vmap(task.avail)(flat_states)
            return nets.actor_actions(
                mod, actor if continuation == "actor" else clone_vars, fobs, flegal
            )

        value_fn = (
            self.value_fn(critic_vars)
            if lookahead < TO_THE_END
            else (lambda s: jnp.zeros(jax.tree.leaves(s)[0].shape[0]))
        )
        return make_q_fn(
            task.lookahead,
            value_fn,
            gamma,
            steps=lookahead,
            policy_fn=policy,
            batch_step_fn=batch_step_fn,
        )

    def _train_chunk(
        self,
        pool: Pool,
        actor: nets.NetState,
        critic_vars: Any,
        clone_vars: Any,
        lr_scale: ArrayLike | None = None,
        *,
        steps: int,
        gamma: float,
        iterations: int,
        start: str,
        continuation: str,
        lookahead: int,
        actor_steps: int,
        target: str,
        work_batch: int,
    ):
        task, b, mod = self.task, self.b, self.actor_mod

        def act(actor, key, states, obs, legal):
            q_fn = self.brd_q_fn(
                actor,
                critic_vars,
                clone_vars,
                gamma=gamma,
                lookahead=lookahead,
                continuation=continuation,
            )
            k_demo, k_sim = jax.random.split(key)
            n, na = legal.shape[1], legal.shape[2]
            a_actor = nets.actor_actions(mod, actor, obs, legal)
            # Alg. 1 from the actor's actions (Section 4.3) or from A^D.
            a0 = (
                a_actor
                if start == "actor"
                else self.demo_act(clone_vars, k_demo, states, obs, legal)
            )
            res = best_response_dynamics(
                q_fn,
                jax.random.split(k_sim, b),
                states,
                a0,
                legal,
                iterations,
                work_batch=work_batch,
            )
            # Eq. 7: advantage of every legal action of every agent that has a choice.
            adv = advantages(res.q, legal)
            weight = res.q_valid & (jnp.sum(legal, -1) >= 2)
            flat_w = weight.reshape(-1)
            actor, loss = self._update_actor(
                actor,
                obs.reshape(b * n, -1),
                legal.reshape(b * n, na),
                res.actions.reshape(b * n),
                adv.reshape(b * n, na),
                flat_w,
                lr_scale,
                actor_steps=actor_steps,
                target=target,
            )
            # Perform the updated actor's legal argmax (Alg. 2).
            actions = nets.actor_actions(mod, actor, obs, legal)
            aux = step_aux(
                loss,
                res.sweeps,
                res.evaluated,
                res.simulated,
                res.changes,
                res.q_init,
                res.q_final,
                adv,
                a_actor,
                res.actions,
                weight,
            )
            return actions, actor, aux

        pool, actor, out = pool_steps(task, act, pool, actor, steps)
        return pool, actor, out

    # Phase 3 on the native engine: a host loop over the chunk's env steps.
    def _native_pre_fn(self, pool: Pool, actor: nets.NetState, clone_vars: Any, *, start: str):
        """The step's keys (split as in 'pool_steps'), legal actions, the actor's legal argmax
        and Alg. 1's start actions."""
        key = jax.random.wrap_key_data(pool.key)
        key, k_act, k_step, k_reset = jax.random.split(key, 4)
        legal = jax.vmap(self.task.avail)(pool.states)
        k_demo, _ = jax.random.split(k_act)
        a_actor = nets.actor_actions(self.actor_mod, actor, pool.obs, legal)
        a0 = (
            a_actor
            if start == "actor"
            else self.demo_act(clone_vars, k_demo, pool.states, pool.obs, legal)
        )
        return jax.random.key_data(key), k_step, k_reset, legal, a_actor, a0

    def _native_post_fn(
        self,
        pool: Pool,
        actor: nets.NetState,
        key_data: jax.Array,
        k_step: jax.Array,
        k_reset: jax.Array,
        legal: jax.Array,
        a_actor: jax.Array,
        brd: dict[str, jax.Array],
        rows: jax.Array,
        valid: jax.Array,
        lr_scale: ArrayLike | None,
        *,
        actor_steps: int,
        target: str,
    ):
        """Eq. 7, the actor's update (Eq. 8, or cross-entropy toward ã_g) on the gathered rows of
        the agents with a choice, the updated actor's legal argmax, the env step and resets."""
        task, mod = self.task, self.actor_mod
        b, n, na = legal.shape
        obs = pool.obs
        adv = advantages(brd["q"], legal)
        weight = brd["q_valid"] & (jnp.sum(legal, -1) >= 2)
        actor, loss = self._update_actor(
            actor,
            obs.reshape(b * n, -1)[rows],
            legal.reshape(b * n, na)[rows],
            brd["actions"].reshape(b * n)[rows],
            adv.reshape(b * n, na)[rows],
            valid,
            lr_scale,
            actor_steps=actor_steps,
            target=target,
        )
        actions = nets.actor_actions(mod, actor, obs, legal)
        # The env step and the resets of 'pool_steps'.
        obs2, s2, r, d, info = jax.vmap(task.step)(
            jax.random.split(k_step, b), pool.states, actions
        )
        stats = jax.vmap(task.episode_stats)(s2, info)
        obs_r, s_r = jax.vmap(task.reset)(jax.random.split(k_reset, b))
        pool2 = Pool(states=select_tree(d, s_r, s2), obs=select_tree(d, obs_r, obs2), key=key_data)
        aux = step_aux(
            loss,
            brd["sweeps"],
            brd["evaluated"],
            brd["simulated"],
            brd["changes"],
            brd["q_init"],
            brd["q_final"],
            adv,
            a_actor,
            brd["actions"],
            weight,
        )
        out = {"state": pool.states, "reward": r, "done": d, "stats": stats, "aux": aux}
        return pool2, actor, out

    def _train_chunk_native(
        self,
        pool: Pool,
        actor: nets.NetState,
        critic_vars: Any,
        clone_vars: Any,
        lr_scale: ArrayLike | None = None,
    ):
        """'train_chunk' on the native engine: the same steps, one host call of Alg. 1 each."""
        from hybridmarl.algos.hybrid.brd_native import NativeMLP, bucket

        value = (
            None if self.native_brd.steps >= TO_THE_END else NativeMLP(jax.device_get(critic_vars))
        )
        outs = []
        timing = self.timing
        for _ in range(self._chunk_steps):
            t0 = time.perf_counter()
            key_data, k_step, k_reset, legal, a_actor, a0 = self._native_pre(
                pool, actor, clone_vars
            )
            legal_np, a0_np, states_np = jax.device_get((legal, a0, pool.states))
            t1 = time.perf_counter()
            res = self.native_brd(states_np, a0_np, legal_np, value)
            t2 = time.perf_counter()
            weight = res.q_valid & (legal_np.sum(-1) >= 2)
            flat = np.flatnonzero(weight.reshape(-1))
            size = bucket(flat.size, weight.size)
            rows = np.zeros(size, np.int32)
            rows[: flat.size] = flat
            valid = np.arange(size) < flat.size
            brd = {
                "actions": res.actions,
                "q": res.q,
                "q_valid": res.q_valid,
                "q_init": res.q_init,
                "q_final": res.q_final,
                "changes": res.changes,
                "sweeps": np.float32(res.sweeps),
                "evaluated": np.float32(res.evaluated),
                "simulated": np.float32(res.simulated),
            }
            pool, actor, out = self._native_post(
                pool, actor, key_data, k_step, k_reset, legal, a_actor, brd, rows, valid, lr_scale
            )
            outs.append(jax.device_get(out))
            t3 = time.perf_counter()
            for k, v in (
                ("host_in", t1 - t0),
                ("brd", t2 - t1),
                ("brd_simulation", res.seconds_simulation),
                ("brd_critic", res.seconds_critic),
                ("update_and_step", t3 - t2),
            ):
                timing[k] = timing.get(k, 0.0) + v
            timing["steps"] = timing.get("steps", 0.0) + 1
        stacked = jax.tree.map(lambda *xs: np.stack(xs), *outs)
        return pool, actor, stacked


def step_aux(
    loss, sweeps, evaluated, simulated, changes, q_init, q_final, adv, a_actor, actions, weight
) -> dict[str, jax.Array]:
    """The per-step diagnostics of Alg. 1 and the actor update that 'train.csv' logs."""
    b = weight.shape[0]
    wf = weight.astype(jnp.float32)
    nw = jnp.maximum(jnp.sum(wf), 1.0)
    return {
        "actor_loss": loss,
        "brd_sweeps": jnp.asarray(sweeps, jnp.float32),
        "brd_visits": jnp.asarray(evaluated, jnp.float32) / b,
        "brd_simulated": jnp.asarray(simulated, jnp.float32) / b,
        "brd_changes": jnp.mean(changes.astype(jnp.float32)),
        "q_gain": jnp.nanmean(q_final - q_init),
        "q_final": jnp.nanmean(q_final),
        "adv_max": jnp.sum(jnp.max(adv, -1) * wf) / nw,
        "agree": jnp.sum((a_actor == actions) * wf) / nw,
        "deciders": jnp.sum(wf) / b,
    }


#: Simulated steps that stand for "to the end of the episode" (``lookahead_steps=0``); the Q
#: loop stops early once every simulated game has ended.
TO_THE_END = 1_000_000


def simulated_steps(cfg: HybridConfig) -> int:
    """Steps of Alg. 1's Q simulation: ``lookahead_steps``, where 0 means ``TO_THE_END``."""
    return cfg.lookahead_steps if cfg.lookahead_steps > 0 else TO_THE_END


def continuation_policy(cfg: HybridConfig) -> str:
    """Who plays a lookahead's continuation steps: ``lookahead_policy``, where ``start`` means
    the policy Alg. 1 starts from."""
    return cfg.brd_start if cfg.lookahead_policy == "start" else cfg.lookahead_policy


def resolve_brd_engine(task: Task, cfg: HybridConfig, demo_script: str | None) -> tuple[str, str]:
    """The engine Alg. 1 runs on for ``cfg.engine`` ('auto': native on a CPU where it applies)
    and a note saying why when 'auto' fell back to jax. Raises ``ValueError`` when 'native' was
    asked for and does not apply."""
    if cfg.engine == "jax":
        return "jax", ""
    from hybridmarl.algos.hybrid.brd_native import native_support
    from hybridmarl.engine.backend import resolve_engine

    why = native_support(
        task,
        lookahead=simulated_steps(cfg),
        continuation=continuation_policy(cfg),
        demo_script=demo_script,
    )
    if cfg.engine == "native":
        if why:
            raise ValueError(f"--engine native: {why}")
        return "native", ""
    if resolve_engine("auto") != "native":
        return "jax", ""
    return ("jax", f"Alg. 1 runs on the jax engine: {why}") if why else ("native", "")


def build_learner(task: Task, cfg: HybridConfig, demo_script: str | None) -> Learner:
    """The learner of a task and config, compiled once per (task, compile key, demonstrator
    script)."""
    return _cached_learner(task, compile_key(cfg), demo_script)


@functools.lru_cache(maxsize=8)
def _cached_learner(task: Task, key: HybridConfig, demo_script: str | None) -> Learner:
    return Learner(task, key, demo_script)


__all__ = [
    "TO_THE_END",
    "Learner",
    "build_learner",
    "continuation_policy",
    "resolve_brd_engine",
    "simulated_steps",
]
