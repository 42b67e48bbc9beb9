"""Where the time of one training step of the hybrid method goes (Phase 3 of ``algos.hybrid``).

Times, for the given preset and scenario, each part of one Alg. 2 step for B games separately
(all jitted, min over repeats): Alg. 1 with the preset's Q estimate (``brd``: the simulated steps,
the continuation policy of a lookahead preset and the critic), the actor's
Eq. 8 update (``actor_update``), the env step with resets (``env_step``), the whole compiled
chunk (``chunk``, per step), the host-side episode assembly and buffer insertion per chunk
(``host``), and one critic refit (``critic_fit``, per SGD step). Prints one JSON object.

    python bench/train_step.py [--scenario m5v5] [--preset quick] [--env combat] [--repeats 3]
    python bench/train_step.py --preset quick-paper        # the paper's one-step Alg. 1
    python bench/train_step.py --compare --repeats 5       # the whole step, jax vs native engine
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import jax
import jax.numpy as jnp
import numba
import optax

from hybridmarl.algos.hybrid.brd import best_response_dynamics
from hybridmarl.algos.hybrid.config import PRESETS
from hybridmarl.algos.hybrid.learner import build_learner, continuation_policy, simulated_steps
from hybridmarl.algos.hybrid.train import _vars
from hybridmarl.training import networks as nets
from hybridmarl.training.losses import actor_loss, advantages
from hybridmarl.training.rollout import EpisodeAssembler, ReplayBuffer, new_pool
from hybridmarl.training.task import make_task


def timed(fn, *args, repeats=3):
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best, compile_s


def compare_engines(task, cfg, jax_learner, pool, actor, cv, repeats):
    """Per training step (a chunk / chunk_steps) on both engines, interleaved repeat by repeat
    so that both see the same machine load; the native step's split from its learner's timing."""
    native = build_learner(task, cfg.replace(engine="native"), cfg.demonstrator_name())
    learners = {"jax": jax_learner, "native": native}
    compile_s, per_step = {}, {name: [] for name in learners}
    for name, lr in learners.items():
        t0 = time.perf_counter()
        jax.block_until_ready(lr.train_chunk(pool, actor, cv, None))
        compile_s[name] = round(time.perf_counter() - t0, 1)
    native.timing.clear()
    for _ in range(repeats):
        for name, lr in learners.items():
            t0 = time.perf_counter()
            jax.block_until_ready(lr.train_chunk(pool, actor, cv, None))
            per_step[name].append((time.perf_counter() - t0) / cfg.chunk_steps)
    split = {
        k: round(v / native.timing["steps"], 5) for k, v in native.timing.items() if k != "steps"
    }
    summary = {
        name: {"min": round(min(v), 5), "median": round(statistics.median(v), 5)}
        for name, v in per_step.items()
    }
    return {
        "seconds_per_step": summary,
        "speedup_native_over_jax": {
            "min": round(summary["jax"]["min"] / summary["native"]["min"], 2),
            "median": round(summary["jax"]["median"] / summary["native"]["median"], 2),
        },
        "native_split_seconds_per_step": split,
        "first_call_s (compile + one chunk)": compile_s,
        "repeats": repeats,
        "load": os.getloadavg(),
        "numba_threads": numba.get_num_threads(),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="combat")
    p.add_argument("--scenario", default="m5v5")
    p.add_argument("--preset", default="quick")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument(
        "--work-batch",
        type=int,
        help="override the preset's brd_work_batch (0: the dense schedule)",
    )
    p.add_argument(
        "--lookahead-policy",
        choices=["start", "actor", "demonstrator"],
        help="override the preset's lookahead_policy",
    )
    p.add_argument(
        "--compare",
        action="store_true",
        help="also time the whole training step on both engines, interleaved (engine=jax vs engine=native)",
    )
    args = p.parse_args()
    cfg = PRESETS[args.preset](args.env).replace(scenario=args.scenario)
    if args.work_batch is not None:
        cfg = cfg.replace(brd_work_batch=args.work_batch)
    if args.lookahead_policy:
        cfg = cfg.replace(lookahead_policy=args.lookahead_policy)
    task = make_task(cfg.task_spec())
    learner = build_learner(task, cfg.replace(engine="jax"), cfg.demonstrator_name())
    b = cfg.num_envs
    actor = nets.init_net(learner.actor_mod, jax.random.key(0), task.obs_dim, learner.actor_tx)
    critic = nets.init_net(
        learner.critic_mod, jax.random.key(1), task.critic_dim, learner.critic_tx
    )
    pool = new_pool(task, jax.random.key(2), b)
    # Warm the pool up to mid-game states with the demonstrator.
    for _ in range(2):
        pool, _ = learner.demo_chunk(pool, None)
    cv = _vars(critic)
    # The preset's own Q estimate (lookahead steps and continuation policy), as in the chunk.
    q_fn = learner.brd_q_fn(
        actor,
        cv,
        None,
        gamma=cfg.gamma,
        lookahead=simulated_steps(cfg),
        continuation=continuation_policy(cfg),
    )
    keys = jax.random.split(jax.random.key(3), b)
    legal = jax.vmap(task.avail)(pool.states)

    @jax.jit
    def brd(states, obs, legal):
        a0 = nets.actor_actions(learner.actor_mod, actor, obs, legal)
        return best_response_dynamics(
            q_fn, keys, states, a0, legal, cfg.brd_iterations, work_batch=cfg.brd_work_batch
        )

    res = brd(pool.states, pool.obs, legal)
    t_brd, c_brd = timed(brd, pool.states, pool.obs, legal, repeats=args.repeats)
    adv = advantages(res.q, legal)
    w = res.q_valid.reshape(-1)

    @jax.jit
    def update(actor, obs):
        def loss_fn(params):
            logits, bs = nets.apply_train(
                learner.actor_mod,
                params,
                actor.batch_stats,
                obs.reshape(b * task.num_agents, -1),
                mask=w,
            )
            return actor_loss(
                logits,
                adv.reshape(b * task.num_agents, -1),
                legal.reshape(b * task.num_agents, -1),
                w,
            ), bs

        (loss, bs), g = jax.value_and_grad(loss_fn, has_aux=True)(actor.params)
        upd, opt = learner.actor_tx.update(g, actor.opt_state, actor.params)
        return actor.replace(
            params=optax.apply_updates(actor.params, upd), batch_stats=bs, opt_state=opt
        )

    t_upd, _ = timed(update, actor, pool.obs, repeats=args.repeats)

    @jax.jit
    def env_step(states):
        a = jnp.zeros((b, task.num_agents), jnp.int32)
        return jax.vmap(task.step)(keys, states, a)

    t_env, _ = timed(env_step, pool.states, repeats=args.repeats)
    t_chunk, c_chunk = timed(learner.train_chunk, pool, actor, cv, None, repeats=args.repeats)
    _, _, out = learner.train_chunk(pool, actor, cv, None)
    asm = EpisodeAssembler(b, cfg.gamma)
    buf = ReplayBuffer(cfg.buffer_size, task.reset(jax.random.key(0))[1])
    t0 = time.perf_counter()
    s, r, _ = asm.add(out)
    buf.add(s, r)
    t_host = time.perf_counter() - t0
    steps = 200
    t_fit, _ = timed(
        lambda: learner.fit_critic(
            critic, *buf.device_arrays(), jax.random.key(4), jnp.asarray(steps)
        ),
        repeats=1,
    )
    per_step = t_chunk / cfg.chunk_steps
    doc = {
        "env": args.env,
        "scenario": args.scenario if args.env == "combat" else None,
        "preset": args.preset,
        "lookahead_steps": cfg.lookahead_steps,
        "lookahead_policy": continuation_policy(cfg),
        "batch": b,
        "agents": task.num_agents,
        "actions": task.num_actions,
        "chunk_steps": cfg.chunk_steps,
        "brd_work_batch": cfg.brd_work_batch,
        "brd_calls": int(res.visits),
        "brd_agent_visits": int(res.evaluated),
        "brd_simulated": int(res.simulated),
        "brd_update_sweeps": int(res.sweeps),
        "seconds": {
            "brd": round(t_brd, 5),
            "actor_update": round(t_upd, 5),
            "env_step": round(t_env, 5),
            "chunk_per_step": round(per_step, 5),
            "host_per_chunk": round(t_host, 5),
            "critic_fit_per_sgd_step": round(t_fit / steps, 6),
        },
        "share_of_step": {
            "brd": round(t_brd / per_step, 3),
            "actor_update": round(t_upd / per_step, 3),
            "env_step": round(t_env / per_step, 3),
        },
        "env_steps_per_s": round(b / per_step, 1),
        "compile_s": {"brd": round(c_brd, 1), "chunk": round(c_chunk, 1)},
    }
    if args.compare:
        doc["engines"] = compare_engines(task, cfg, learner, pool, actor, cv, args.repeats)
    print(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
