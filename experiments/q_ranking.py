"""Does a trained policy choose better actions than its demonstrator, one agent at a time?

A learner can beat its demonstrator D only if, in some states, it picks an action whose value
is higher than D's. This experiment measures that directly. It plays D from fresh start states
and samples states along the way. For each agent with a choice, it computes the exact value of
every legal action of that agent, Q^D(s, a): the agent plays a, every other agent plays D's
action, then D plays to the end of the episode (the team's discounted return, λ 0.995, the
"ideal" Q of the paper's Eq. 6 and of `--lookahead-steps 0`). It then asks which action the
run's network prefers: its legal argmax (Q-values for DQfD and OGTL, logits for an actor).

Prints one JSON object over all sampled decisions:

- ``demo_optimal``: how often D's own action is already the best one;
- ``improvable``: how often some action beats D's (by more than 10^-6);
- ``learner_*``: how often the network picks D's action, a better one or a worse one, and its
  mean regret (best exact value minus the value of its pick) against D's;
- ``spearman``: the mean rank correlation between the network's outputs and the exact values
  over each decision's legal actions (decisions with at least 3 legal actions and values that
  are not all equal).

    python experiments/q_ranking.py --run-dir RUN [--checkpoint EPISODES] [--games 64 --every 4]

Combat only. A deviation is judged against D's continuation, as Alg. 1 with one iteration from
A^D judges it; the run need not have been trained that way.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import rankdata

from hybridmarl.algos.hybrid.brd import make_q_fn
from hybridmarl.training import networks as nets
from hybridmarl.training.evaluate import load_policy
from hybridmarl.training.task import make_task

TOL = 1e-6


def _spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Rank correlation, ties given their average rank."""
    return float(np.corrcoef(rankdata(x), rankdata(y))[0, 1])


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--run-dir", required=True)
    ap.add_argument(
        "--checkpoint", default=None, help="episode count or name (default: the newest)"
    )
    ap.add_argument("--weights", default="auto", choices=["auto", "average", "last"])
    ap.add_argument("--games", type=int, default=64, help="games of D the states are sampled from")
    ap.add_argument(
        "--every", type=int, default=4, help="sample every this many steps of each game"
    )
    ap.add_argument("--max-steps", type=int, default=200, help="steps of D played per game")
    ap.add_argument(
        "--gamma",
        type=float,
        default=0.995,
        help="discount of the exact values (paper, Section 5.1)",
    )
    ap.add_argument("--chunk", type=int, default=32, help="states per exact-value batch")
    ap.add_argument(
        "--seed", type=int, default=3, help="start states (3: none of eval's 0-2 or the protocol's)"
    )
    args = ap.parse_args()

    t0 = time.time()
    policy = load_policy(args.run_dir, args.checkpoint, args.weights)
    task = make_task(policy.spec)
    if task.kind != "combat":
        raise SystemExit("q_ranking.py: combat runs only")
    demo = task.demonstrator(policy.demonstrator)

    # -- sample states from D's own play ------------------------------------------------------
    @jax.jit
    def reset(key):
        return jax.vmap(task.reset)(jax.random.split(key, args.games))[1]

    @jax.jit
    def play_demo(key, states):
        keys = jax.random.split(key, args.games)
        a = jax.vmap(demo)(keys, states).astype(jnp.int32)
        _, s2, _, d, _ = jax.vmap(task.step)(keys, states, a)
        return s2, d

    key = jax.random.key(args.seed)
    states = reset(key)
    done = np.zeros(args.games, bool)
    sampled = []
    for t in range(args.max_steps):
        if done.all():
            break
        if t % args.every == 0:
            live = np.nonzero(~done)[0]
            sampled.append(jax.tree.map(lambda x, live=live: np.asarray(x)[live], states))
        key, k = jax.random.split(key)
        states, d = play_demo(k, states)
        done |= np.asarray(d)
    pool = jax.tree.map(lambda *xs: np.concatenate(xs), *sampled)
    m = int(jax.tree.leaves(pool)[0].shape[0])

    # -- exact values of every legal action of every agent, D elsewhere and afterwards ---------
    def step_fn(k, s, a):
        _, s2, r, d, _ = task.step(k, s, a)
        return r, s2, d

    def continuation(keys, s):
        return jax.vmap(demo)(keys, s).astype(jnp.int32)

    def zero_value(s):
        return jnp.zeros(jax.tree.leaves(s)[0].shape[0])

    q_fn = make_q_fn(
        task.lookahead,
        zero_value,
        args.gamma,
        steps=1_000_000,
        step_fn=step_fn,
        policy_fn=continuation,
    )
    n_agents, n_actions = task.num_agents, task.num_actions

    @jax.jit
    def exact_values(key, s):
        b = jax.tree.leaves(s)[0].shape[0]
        keys = jax.random.split(key, b)
        a0 = jax.vmap(demo)(keys, s).astype(jnp.int32)
        legal = jax.vmap(task.avail)(s)
        obs = jax.vmap(task.observe)(s)
        actions = jnp.arange(n_actions, dtype=jnp.int32)

        def for_agent(i):
            cand = (
                jnp.broadcast_to(a0[:, None, :], (b, n_actions, n_agents))
                .at[:, :, i]
                .set(actions[None, :])
            )
            return q_fn(keys, s, cand)  # [b, A]

        q = jax.lax.map(for_agent, jnp.arange(n_agents))  # [N, b, A]
        return a0, legal, obs, jnp.transpose(q, (1, 0, 2))

    out_net = jax.jit(
        lambda obs: nets.apply_eval(
            policy.module, policy.variables, obs.reshape((-1, obs.shape[-1]))
        ).reshape(obs.shape[:-1] + (-1,))
    )

    counts = {
        "decisions": 0,
        "demo_optimal": 0,
        "improvable": 0,
        "learner_is_demo": 0,
        "learner_better": 0,
        "learner_worse": 0,
        "learner_optimal": 0,
    }
    regret_learner, regret_demo, rhos = [], [], []
    for start in range(0, m, args.chunk):
        s = jax.tree.map(lambda x, start=start: jnp.asarray(x[start : start + args.chunk]), pool)
        a0, legal, obs, q = (np.asarray(x) for x in exact_values(jax.random.fold_in(key, start), s))
        scores = np.asarray(out_net(jnp.asarray(obs)))
        for g, i in zip(*np.nonzero(legal.sum(-1) >= 2), strict=True):
            ok = legal[g, i]
            qe = np.where(ok, q[g, i], -np.inf)
            pick = int(np.argmax(np.where(ok, scores[g, i], -np.inf)))
            d = int(a0[g, i])
            best = float(qe.max())
            counts["decisions"] += 1
            counts["demo_optimal"] += qe[d] >= best - TOL
            counts["improvable"] += best > qe[d] + TOL
            counts["learner_is_demo"] += pick == d
            counts["learner_better"] += qe[pick] > qe[d] + TOL
            counts["learner_worse"] += qe[pick] < qe[d] - TOL
            counts["learner_optimal"] += qe[pick] >= best - TOL
            regret_learner.append(best - qe[pick])
            regret_demo.append(best - qe[d])
            if ok.sum() >= 3 and np.ptp(q[g, i][ok]) > TOL and np.ptp(scores[g, i][ok]) > 0:
                rhos.append(_spearman(scores[g, i][ok], q[g, i][ok]))

    n = max(counts["decisions"], 1)
    print(
        json.dumps(
            {
                "run_dir": args.run_dir,
                "checkpoint": args.checkpoint,
                "weights": policy.weights,
                "algo": policy.config.get("algo"),
                "scenario": policy.spec.scenario,
                "demonstrator": policy.demonstrator,
                "states": m,
                "decisions": counts["decisions"],
                **{k: round(v / n, 4) for k, v in counts.items() if k != "decisions"},
                "regret_learner": round(float(np.mean(regret_learner)), 5),
                "regret_demo": round(float(np.mean(regret_demo)), 5),
                "spearman": round(float(np.mean(rhos)), 4) if rhos else None,
                "spearman_decisions": len(rhos),
                "seconds": round(time.time() - t0, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
