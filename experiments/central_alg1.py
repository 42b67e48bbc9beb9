"""Alg. 1 executed centrally: how good is the joint action Ã it finds on a run's critic?

Alg. 2 trains the actor toward Alg. 1's Ã; if Ã itself plays worse than the demonstrator it
started from, the actor cannot do better than D by imitating it. This plays battles in which our
whole side plays Ã, computed at every step from A^D with the critic of a hybrid run's checkpoint
(Eq. 2's one-step Q, or the run's look-ahead), on the native engine, and compares its W and R with
D's on the same start states.

    python experiments/central_alg1.py --run-dir RUN [--checkpoint 0] [--iterations 1 7] [--n 200]

Prints one JSON object: for D and for Ã at each iteration count, W with its 95 % Wilson interval
and R, plus how often Ã differed from A^D. Needs a combat run against a scripted enemy with a
script demonstrator (the cases the native Alg. 1 supports).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.algos.hybrid.brd_native import NativeBRD, NativeMLP, native_support
from hybridmarl.algos.hybrid.config import HybridConfig
from hybridmarl.algos.hybrid.learner import continuation_policy, simulated_steps
from hybridmarl.envs.stats import wilson_interval
from hybridmarl.training import networks as nets
from hybridmarl.training.checkpoint import find_checkpoint, load_checkpoint, subtree
from hybridmarl.training.config import config_from_dict
from hybridmarl.training.task import make_task, unflatten_named


def load_critic(run_dir: str, checkpoint: str | None, cfg: HybridConfig, task) -> dict:
    arrays, _ = load_checkpoint(find_checkpoint(run_dir, checkpoint))
    module = nets.critic_module(cfg.critic_hidden)
    template = nets.init_net(module, jax.random.key(0), task.critic_dim, nets.make_optimizer(cfg.optimizer, cfg.critic_lr))
    critic = unflatten_named(template, subtree(arrays, "critic"))
    return {"params": critic.params, "batch_stats": critic.batch_stats}


def play(task, demo_name: str, n: int, seed: int, brd: NativeBRD | None, value) -> dict:
    """n battles from the evaluation start states of ``seed``; our side plays A^D (brd None) or
    Alg. 1's Ã started from A^D."""
    reset = jax.jit(jax.vmap(task.reset))
    step = jax.jit(jax.vmap(task.step))
    avail = jax.jit(jax.vmap(task.avail))
    demo = task.demonstrator(demo_name)
    demo_actions = jax.jit(jax.vmap(demo))
    k_reset, k_run = jax.random.split(jax.random.key(seed))
    _, states = reset(jax.random.split(k_reset, n))
    done = np.zeros(n, bool)
    won = np.zeros(n, bool)
    terminal = np.zeros(n, np.float32)
    changed = decisions = 0
    while not done.all():
        k_run, k_demo, k_step = jax.random.split(k_run, 3)
        a0 = demo_actions(jax.random.split(k_demo, n), states)
        actions = a0
        if brd is not None:
            legal = np.asarray(avail(states))
            res = brd(jax.device_get(states), np.asarray(a0), legal, value)
            deciding = legal.sum(-1) >= 2
            changed += int(((res.actions != np.asarray(a0)) & deciding & ~done[:, None]).sum())
            decisions += int((deciding & ~done[:, None]).sum())
            actions = jnp.asarray(res.actions)
        _, states, _, d, info = step(jax.random.split(k_step, n), states, actions)
        d = np.asarray(d)
        ending = d & ~done
        won[ending] = np.asarray(info["won"])[ending]
        terminal[ending] = np.asarray(info["terminal_hp_reward"])[ending]
        done |= d
    lo, hi = wilson_interval(int(won.sum()), n)
    out = {"W": float(won.mean()), "W_ci95": [lo, hi], "R": float(terminal.mean())}
    if brd is not None:
        out["changed_actions"] = changed / max(decisions, 1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--run-dir", required=True)
    ap.add_argument("--checkpoint", default=None, help="episode count or name (default: the newest)")
    ap.add_argument("--iterations", type=int, nargs="+", default=[1, 7])
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--seed", type=int, default=20200713)
    args = ap.parse_args()
    with open(os.path.join(args.run_dir, "config.json")) as f:
        cfg = config_from_dict(HybridConfig, json.load(f)["config"])
    task = make_task(cfg.task_spec())
    demo_name = cfg.demonstrator_name()
    why = native_support(task, lookahead=simulated_steps(cfg), continuation=continuation_policy(cfg), demo_script=demo_name)
    if why:
        raise SystemExit(why)
    value = NativeMLP(jax.device_get(load_critic(args.run_dir, args.checkpoint, cfg, task)))
    t0 = time.time()
    doc = {
        "run_dir": args.run_dir, "checkpoint": args.checkpoint, "scenario": cfg.scenario, "setting": cfg.setting,
        "demonstrator": demo_name, "enemy": task.enemy, "n": args.n, "seed": args.seed,
        "lookahead_steps": simulated_steps(cfg), "D": play(task, demo_name, args.n, args.seed, None, None),
    }
    lookahead = simulated_steps(cfg)
    for it in args.iterations:
        brd = NativeBRD(task, gamma=cfg.gamma, iterations=it, lookahead=lookahead, continuation=demo_name if lookahead > 1 else None)
        doc[f"alg1_iterations_{it}"] = play(task, demo_name, args.n, args.seed, brd, value)
    doc["seconds"] = round(time.time() - t0, 1)
    doc["load"] = os.getloadavg()
    print(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
