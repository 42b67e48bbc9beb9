"""Alg. 1's work schedule: the cost of one call for several ``--work-batch`` values, in one process.

Builds the hybrid learner of a preset (default ``quick``: the preset's own Q estimate),
plays B games for ``--warm-steps`` steps with the actor (a trained one with ``--checkpoint
RUN_DIR/checkpoints/ckpt_N``: its actor and critic are loaded; otherwise random weights), and times
``best_response_dynamics`` from the actor's actions on those states for each work batch (0: all B
games in every call, the dense schedule). Repeated on ``--state-sets`` successive sets of states.
Prints one JSON object; per state set and work batch: ``s_min``/``s_median`` of ``--repeats``
calls, ``compile_s``, ``calls`` (q_fn calls), ``agent_visits`` (the (game, agent) visits Alg. 1
needed), ``simulated`` (candidate joint actions simulated, padding included), and how the result compares with the dense schedule's (``same_actions``, ``max_q_diff``
over the rows both computed).

    python bench/brd_schedule.py [--checkpoint DIR] [--scenario m5v5] [--work-batches 0 16 8 4 2 1]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax
import jax.numpy as jnp

from hybridmarl.algos.hybrid.brd import best_response_dynamics
from hybridmarl.algos.hybrid.config import PRESETS
from hybridmarl.algos.hybrid.learner import build_learner, continuation_policy, simulated_steps
from hybridmarl.algos.hybrid.train import _vars
from hybridmarl.training import networks as nets
from hybridmarl.training.checkpoint import load_checkpoint, subtree
from hybridmarl.training.rollout import new_pool
from hybridmarl.training.task import make_task, unflatten_named


def main() -> None:
    p = argparse.ArgumentParser(
        description="Alg. 1's work schedule: one call's cost for several work batches."
    )
    p.add_argument("--scenario", default="m5v5")
    p.add_argument("--preset", default="quick")
    p.add_argument("--checkpoint", help="a checkpoint directory whose actor and critic to load")
    p.add_argument("--work-batches", type=int, nargs="+", default=[0, 16, 8, 4, 2, 1])
    p.add_argument("--state-sets", type=int, default=3)
    p.add_argument("--warm-steps", type=int, default=10)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args()
    cfg = PRESETS[args.preset]("combat").replace(scenario=args.scenario)
    task = make_task(cfg.task_spec())
    learner = build_learner(task, cfg, cfg.demonstrator_name())
    b = cfg.num_envs
    actor = nets.init_net(learner.actor_mod, jax.random.key(0), task.obs_dim, learner.actor_tx)
    critic = nets.init_net(
        learner.critic_mod, jax.random.key(1), task.critic_dim, learner.critic_tx
    )
    if args.checkpoint:
        arrays, _ = load_checkpoint(args.checkpoint)
        actor = unflatten_named(actor, subtree(arrays, "actor"))
        critic = unflatten_named(critic, subtree(arrays, "critic"))
    q_fn = learner.brd_q_fn(
        actor,
        _vars(critic),
        None,
        gamma=cfg.gamma,
        lookahead=simulated_steps(cfg),
        continuation=continuation_policy(cfg),
    )

    @jax.jit
    def play(states, key):
        def body(s, k):
            obs, legal = jax.vmap(task.observe)(s), jax.vmap(task.avail)(s)
            a = nets.actor_actions(learner.actor_mod, actor, obs, legal)
            return jax.vmap(task.step)(jax.random.split(k, b), s, a)[1], None

        return jax.lax.scan(body, states, jax.random.split(key, args.warm_steps))[0]

    calls = {
        wb: jax.jit(
            lambda k, s, a, lg, wb=wb: best_response_dynamics(
                q_fn, k, s, a, lg, cfg.brd_iterations, wb
            )
        )
        for wb in args.work_batches
    }
    states = new_pool(task, jax.random.key(2), b).states
    sets = []
    for i in range(args.state_sets):
        states = play(states, jax.random.key(10 + i))
        obs, legal = jax.vmap(task.observe)(states), jax.vmap(task.avail)(states)
        keys = jax.random.split(jax.random.key(3 + i), b)
        a0 = nets.actor_actions(learner.actor_mod, actor, obs, legal)
        row: dict = {
            "deciders_per_game": round(float(jnp.mean(jnp.sum(jnp.sum(legal, -1) >= 2, -1))), 3),
            "work_batch": {},
        }
        ref = None
        for wb, fn in calls.items():
            t0 = time.perf_counter()
            res = jax.block_until_ready(fn(keys, states, a0, legal))
            compile_s = time.perf_counter() - t0
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                jax.block_until_ready(fn(keys, states, a0, legal))
                times.append(time.perf_counter() - t0)
            ref = res if ref is None else ref
            both = (ref.q_valid & res.q_valid)[..., None]
            row["work_batch"][str(wb)] = {
                "s_min": round(min(times), 4),
                "s_median": round(statistics.median(times), 4),
                "compile_s": round(compile_s, 1),
                "calls": int(res.visits),
                "agent_visits": int(res.evaluated),
                "simulated": int(res.simulated),
                "sweeps": int(res.sweeps),
                "same_actions": bool(jnp.all(res.actions == ref.actions)),
                "max_q_diff": float(jnp.max(jnp.where(both, jnp.abs(res.q - ref.q), 0.0))),
            }
        sets.append(row)
    doc = {
        "scenario": args.scenario,
        "preset": args.preset,
        "batch": b,
        "lookahead_steps": cfg.lookahead_steps,
        "checkpoint": args.checkpoint,
        "device": str(jax.devices()[0]),
        "reference": str(args.work_batches[0]),
        "state_sets": sets,
    }
    print(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
