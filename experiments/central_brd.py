"""How good is Alg. 1's joint action Ã itself? Best-response dynamics executed centrally.

The hybrid method trains a decentralised actor toward Ã (paper Alg. 1 and Eq. 7-8). This
experiment removes the actor: at every step of B games it runs Alg. 1 from the demonstrator's
actions A^D(s) and plays Ã directly (re-planned every step), then plays A^D alone from the same
start states. If Ã does not beat A^D, no actor trained on it can; if it does, the gap between
Ã and the trained actor is the actor's to close. The Q estimate of Alg. 1 is one of:

- ``--q critic --lookahead 1``: the paper's Eq. 2, ``r + λ V(s')`` with a critic pre-trained on
  the demonstrator's returns (Eq. 3; the quick-paper preset's sample count and fit steps by default);
- ``--q critic --lookahead K``: K simulated steps of A^D, then the critic (the
  ``--lookahead-steps K`` option of ``hybridmarl train``);
- ``--q exact``: A^D simulated to the end of the episode (``--lookahead-steps 0``).

Prints one JSON object: the metric of Ã and of A^D on the same states (combat: W and R;
Traffic Junction: failure rate), how many decisions Ã changed, for combat which kinds of action
it changed into which, and for a critic its training and held-out mean squared error.

    python experiments/central_brd.py --env combat --scenario m5v5 --q exact --iterations 1
    python experiments/central_brd.py --env traffic_junction --q critic --lookahead 4
    python experiments/central_brd.py --run-dir RUN --checkpoint 0 --games 200   # a run's own critic
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.algos import hybrid as H
from hybridmarl.algos.hybrid.brd import best_response_dynamics, make_q_fn
from hybridmarl.training import networks as nets
from hybridmarl.training.checkpoint import find_checkpoint, load_checkpoint, subtree
from hybridmarl.training.config import config_from_dict
from hybridmarl.training.rollout import EpisodeAssembler, ReplayBuffer, new_pool
from hybridmarl.training.task import make_task, unflatten_named


def _kind(a: int) -> str:
    return "noop" if a == 0 else ("move" if a <= 4 else "attack")


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--env", default="combat", choices=["combat", "traffic_junction"])
    ap.add_argument("--scenario", default="m5v5")
    ap.add_argument("--enemy", default="attack-weakest")
    ap.add_argument(
        "--demonstrator", default=None, help="default: attack-closest (combat), always-gas (TJ)"
    )
    ap.add_argument("--q", default="critic", choices=["critic", "exact"])
    ap.add_argument(
        "--lookahead", type=int, default=1, help="simulated steps before the critic (--q critic)"
    )
    ap.add_argument("--iterations", type=int, default=7, help="Alg. 1 iterations (paper: 7)")
    ap.add_argument("--games", type=int, default=64, help="games played by each policy")
    ap.add_argument(
        "--pretrain-samples",
        type=int,
        default=None,
        help="critic pairs (default: the quick-paper preset's)",
    )
    ap.add_argument(
        "--fit-steps",
        type=int,
        default=None,
        help="critic SGD steps (default: the quick-paper preset's)",
    )
    ap.add_argument(
        "--holdout", type=int, default=4000, help="held-out pairs to measure the critic's error"
    )
    ap.add_argument("--max-steps", type=int, default=400, help="step cap per game (combat)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--run-dir",
        default=None,
        help="use this hybrid run's task, demonstrator and the critic of its "
        "checkpoint instead of pre-training one (--q critic)",
    )
    ap.add_argument(
        "--checkpoint",
        default=None,
        help="with --run-dir: episode count or name (default: the newest; "
        "0: the critic right after pre-training)",
    )
    args = ap.parse_args()

    if args.run_dir:
        with open(f"{args.run_dir}/config.json") as f:
            cfg = config_from_dict(H.HybridConfig, json.load(f)["config"]).replace(seed=args.seed)
        demo_name = cfg.demonstrator_name()
        args.env = cfg.env
    else:
        demo_name = args.demonstrator or (
            "attack-closest" if args.env == "combat" else "always-gas"
        )
        # The critic of docs/results.md's measurements: every visited state of A^D's episodes
        # (20,000 pairs; Traffic Junction 8,000), fitted with Adam.
        base = H.PRESETS["quick-paper"](args.env).replace(
            optimizer="adam",
            pretrain_trajectories=0,
            pretrain_samples=20_000 if args.env == "combat" else 8_000,
        )
        cfg = base.replace(
            scenario=args.scenario,
            enemy=args.enemy,
            demonstrator=demo_name,
            seed=args.seed,
            pretrain_samples=args.pretrain_samples or base.pretrain_samples,
            critic_pretrain_steps=args.fit_steps or base.critic_pretrain_steps,
        )
    task = make_task(cfg.task_spec())
    learner = H.build_learner(task, cfg, demo_name)
    demo = task.demonstrator(demo_name)
    out: dict = {
        "env": args.env,
        "scenario": args.scenario if args.env == "combat" else None,
        "demonstrator": demo_name,
        "q": args.q,
        "lookahead": args.lookahead if args.q == "critic" else None,
        "iterations": args.iterations,
        "games": args.games,
        "seed": args.seed,
    }

    # -- the critic (Eq. 3 on the demonstrator's returns), unless Q is exact ----------------------
    def zero_value(s):
        return jnp.zeros(jax.tree.leaves(s)[0].shape[0])

    value_fn = zero_value
    if args.q == "critic" and args.run_dir:
        arrays, _ = load_checkpoint(find_checkpoint(args.run_dir, args.checkpoint))
        template = nets.init_net(
            learner.critic_mod, jax.random.key(0), task.critic_dim, learner.critic_tx
        )
        critic = unflatten_named(template, subtree(arrays, "critic"))
        value_fn = learner.value_fn({"params": critic.params, "batch_stats": critic.batch_stats})
        out["critic"] = {"run_dir": args.run_dir, "checkpoint": args.checkpoint}
    elif args.q == "critic":
        t0 = time.time()
        pool = new_pool(task, jax.random.key(args.seed + 1), cfg.num_envs)
        asm = EpisodeAssembler(cfg.num_envs, cfg.gamma)
        train_buf = ReplayBuffer(cfg.pretrain_samples, task.state_template())
        held = ReplayBuffer(max(args.holdout, 1), task.state_template())
        got = 0
        while got < cfg.pretrain_samples + args.holdout:
            pool, chunk = learner.demo_chunk(pool, None)
            states, returns, _ = asm.add(chunk)
            cut = int(np.clip(cfg.pretrain_samples - got, 0, returns.size))  # the first pairs train
            train_buf.add({k: v[:cut] for k, v in states.items()}, returns[:cut])
            held.add({k: v[cut:] for k, v in states.items()}, returns[cut:])
            got += int(returns.size)
        critic = nets.init_net(
            learner.critic_mod, jax.random.key(args.seed + 2), task.critic_dim, learner.critic_tx
        )
        critic, loss = learner.fit_critic(
            critic,
            *train_buf.device_arrays(),
            jax.random.key(args.seed + 3),
            jnp.asarray(cfg.critic_pretrain_steps),
        )
        critic_vars = {"params": critic.params, "batch_stats": critic.batch_stats}
        value_fn = learner.value_fn(critic_vars)
        hs, hr, hn = held.device_arrays()
        pred = np.asarray(jax.jit(value_fn)(hs))[: int(hn)]
        target = np.asarray(hr)[: int(hn)]
        out["critic"] = {
            "pairs": int(train_buf.size),
            "fit_steps": cfg.critic_pretrain_steps,
            "train_mse": float(loss),
            "heldout_mse": float(np.mean((pred - target) ** 2)),
            "heldout_return_var": float(np.var(target)),
            "seconds": round(time.time() - t0, 1),
        }

    def step_fn(key, s, a):
        _, s2, r, d, _ = task.step(key, s, a)
        return r, s2, d

    def continuation(keys, states):
        return jax.vmap(demo)(keys, states).astype(jnp.int32)

    steps = 1_000_000 if args.q == "exact" else max(args.lookahead, 1)
    q_fn = make_q_fn(
        task.lookahead, value_fn, cfg.gamma, steps=steps, step_fn=step_fn, policy_fn=continuation
    )
    b = args.games

    @jax.jit
    def act(key, states):
        keys = jax.random.split(key, b)
        a0 = jax.vmap(demo)(keys, states).astype(jnp.int32)
        legal = jax.vmap(task.avail)(states)
        res = best_response_dynamics(q_fn, keys, states, a0, legal, args.iterations)
        return a0, res.actions, jnp.sum(legal, -1) >= 2

    @jax.jit
    def act_demo(key, states):
        a0 = jax.vmap(demo)(jax.random.split(key, b), states).astype(jnp.int32)
        return a0, a0, jnp.sum(jax.vmap(task.avail)(states), -1) >= 2

    @jax.jit
    def env_step(key, states, a):
        return jax.vmap(task.step)(jax.random.split(key, b), states, a)

    def play(use_brd: bool) -> dict:
        t0 = time.time()
        key = jax.random.key(args.seed + 100)
        _, states = jax.vmap(task.reset)(jax.random.split(key, b))
        done = np.zeros(b, bool)
        result = {k: np.zeros(b) for k in ("won", "R", "failed")}
        decisions, changes = 0, Counter()
        limit = args.max_steps if task.kind == "combat" else 10_000
        t = 0
        while not done.all() and t < limit:
            key, k_act, k_env = jax.random.split(key, 3)
            a0, a, decider = (np.asarray(x) for x in (act if use_brd else act_demo)(k_act, states))
            live = decider & ~done[:, None]
            decisions += int(live.sum())
            for g, i in zip(*np.nonzero(live & (a != a0)), strict=True):
                changes[
                    f"{_kind(int(a0[g, i]))}->{_kind(int(a[g, i]))}"
                    if task.kind == "combat"
                    else f"{int(a0[g, i])}->{int(a[g, i])}"
                ] += 1
            _, states, _, d, info = env_step(k_env, states, jnp.asarray(a))
            d = np.asarray(d)
            new = d & ~done
            if task.kind == "combat":
                result["won"][new] = np.asarray(info["won"])[new]
                result["R"][new] = np.asarray(info["terminal_hp_reward"])[new]
            else:
                result["failed"][new] = np.asarray(states.failed)[new]
            done |= d
            t += 1
        res: dict = {"seconds": round(time.time() - t0, 1), "unfinished": int((~done).sum())}
        if task.kind == "combat":
            res.update(W=float(result["won"].mean()), R=float(result["R"].mean()))
        else:
            res.update(failure_rate=float(result["failed"].mean()))
        if use_brd:
            res.update(
                decisions=decisions,
                changed=int(sum(changes.values())),
                changed_frac=sum(changes.values()) / max(decisions, 1),
                changes=dict(changes.most_common()),
            )
        return res

    out["demonstrator_play"] = play(False)
    out["brd_play"] = play(True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
