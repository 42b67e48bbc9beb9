"""Cost of one call of Alg. 1 (best-response dynamics) for B games, as a function of the number
of agents N (paper Section 4.2: "Iterations x N computations ... linear complexity").

For each scenario (default m5v5, m18v20, m30v30: N = 5, 18, 30 agents) it draws B random start
states (every unit acts at frame 0, so every agent has a choice: the worst case), starts from
the attack-closest demonstrator's actions and runs ``best_response_dynamics`` with the paper's
critic architecture (random weights) and one-step simulation, under ``jax.jit``. Printed as one
JSON object::

    {"batch": 32, "iterations": 7, "results": [
       {"scenario": "m5v5", "agents": 5, "actions": 10, "compile_s": ..., "call_s_min": ...,
        "call_s_median": ..., "visits": ..., "sweeps": ..., "s_per_visit": ...,
        "s_per_agent_sweep": ..., "us_per_simulated_step": ...}, ...]}

``visits`` = calls of the batched Q estimate in one call of Alg. 1 (default ``--work-batch 0``:
the dense schedule, each call simulates all B games x A candidates; every game has all N agents
deciding here, so this is the (game, agent) visits over all sweeps, including the final
evaluation sweep, divided by B). With a work batch S > 0, each call simulates S x A legal (game,
action) candidates. ``agent_visits`` = the (game, agent) visits Alg. 1 needed; ``simulated`` =
the candidate joint actions simulated (padding included), each a one-step transition plus a
critic evaluation. Linear cost in N shows as a flat ``s_per_agent_sweep`` for a fixed number of
actions; ``us_per_simulated_step`` divides out the candidates too.

    python bench/brd.py [--batch 32] [--scenarios m5v5 m18v20 m30v30] [--repeats 3] [--iterations 7] [--work-batch 0]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax
import jax.numpy as jnp

from hybridmarl.algos.hybrid.brd import best_response_dynamics, make_q_fn
from hybridmarl.training import networks as nets
from hybridmarl.training.task import TaskSpec, make_task


def bench(
    scenario: str, batch: int, repeats: int, iterations: int, seed: int = 0, work_batch: int = 0
) -> dict:
    task = make_task(TaskSpec(env="combat", scenario=scenario, enemy="attack-weakest"))
    critic = nets.critic_module()
    variables = critic.init(jax.random.key(seed), jnp.zeros((2, task.critic_dim)), train=False)
    demo = task.demonstrator("attack-closest")

    def value_fn(states):
        return nets.apply_eval(critic, variables, jax.vmap(task.value_features)(states))[:, 0]

    q_fn = make_q_fn(task.lookahead, value_fn, 0.995)

    @jax.jit
    def call(keys, states):
        legal = jax.vmap(task.avail)(states)
        a0 = jax.vmap(demo)(keys, states)
        return best_response_dynamics(
            q_fn, keys, states, a0, legal, iterations, work_batch=work_batch
        )

    keys = jax.random.split(jax.random.key(seed + 1), batch)
    _, states = jax.vmap(task.reset)(keys)
    t0 = time.perf_counter()
    res = jax.block_until_ready(call(keys, states))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = jax.block_until_ready(call(keys, states))
        times.append(time.perf_counter() - t0)
    visits = int(res.visits)
    n, a = task.num_agents, task.num_actions
    best = min(times)
    per_call = (
        batch if work_batch <= 0 else min(work_batch, batch)
    )  # candidates per call: per_call x A
    sweeps_total = int(res.evaluated) / (batch * n)
    return {
        "scenario": scenario,
        "agents": n,
        "actions": a,
        "batch": batch,
        "compile_s": round(compile_s, 3),
        "call_s_min": round(best, 4),
        "call_s_median": round(statistics.median(times), 4),
        "work_batch": per_call,
        "visits": visits,
        "agent_visits": int(res.evaluated),
        "update_sweeps": int(res.sweeps),
        "s_per_visit": round(best / visits, 6),
        "s_per_agent_sweep": round(best / max(sweeps_total, 1e-9) / n, 6),
        "simulated": int(res.simulated),
        "us_per_simulated_step": round(1e6 * best / max(int(res.simulated), 1), 3),
        "mean_changes_per_game": float(jnp.mean(res.changes)),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--scenarios", nargs="+", default=["m5v5", "m18v20", "m30v30"])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--iterations", type=int, default=7)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--work-batch",
        type=int,
        default=0,
        help="Q calls inside Alg. 1 simulate this many x |A| legal candidates (0: all games x all actions)",
    )
    args = p.parse_args()
    out = {
        "batch": args.batch,
        "iterations": args.iterations,
        "work_batch": args.work_batch,
        "device": str(jax.devices()[0]),
        "results": [
            bench(s, args.batch, args.repeats, args.iterations, args.seed, args.work_batch)
            for s in args.scenarios
        ],
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
