"""Failure rate of the Traffic Junction demonstrators (paper Section 5.3, Table 2 "D").

Runs ``--episodes`` full 40-step episodes per demonstrator at ``p_arrive`` (0.2, the
evaluation value), batched with ``jax.vmap`` over episode keys and ``jax.lax.scan`` over steps,
under one ``jax.jit``. Prints one JSON object::

    {"p_arrive": 0.2, "episodes": 1000,
     "always_gas": {"failure_rate": ..., "mean_arrivals": ..., ...},
     "yield_before_junction": {...}, "compile_s": ..., "run_s": ...}

``compile_s`` / ``run_s`` are summed over the demonstrators. Usage::

    python bench/tj_demonstrators.py [--episodes 1000] [--p-arrive 0.2] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp

from hybridmarl.envs.base import Policy
from hybridmarl.envs.traffic_junction import (
    TJParams,
    TrafficJunction,
    always_gas,
    yield_before_junction,
)


def make_eval(env: TrafficJunction, policy: Policy, episodes: int):
    def episode(key: jax.Array, params: TJParams) -> dict[str, jax.Array]:
        k_reset, k_run = jax.random.split(key)
        _, state = env.reset(k_reset, params)

        def body(carry, step_key):
            state, ret = carry
            k_act, k_env = jax.random.split(step_key)
            actions = policy(k_act, state)
            _, state, reward, _, _ = env.step(k_env, state, actions, params)
            return (state, ret + reward), None

        keys = jax.random.split(k_run, env.default_params.max_steps)
        (state, ret), _ = jax.lax.scan(body, (state, jnp.zeros((), jnp.float32)), keys)
        return {
            "failed": state.failed,
            "arrivals": state.total_arrivals,
            "collisions": state.total_collisions,
            "return": ret,
        }

    @jax.jit
    def run(key: jax.Array, params: TJParams) -> dict[str, jax.Array]:
        out = jax.vmap(episode, in_axes=(0, None))(jax.random.split(key, episodes), params)
        return {
            "failure_rate": jnp.mean(out["failed"].astype(jnp.float32)),
            "mean_arrivals": jnp.mean(out["arrivals"].astype(jnp.float32)),
            "mean_collisions": jnp.mean(out["collisions"].astype(jnp.float32)),
            "mean_return": jnp.mean(out["return"]),
        }

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--p-arrive", type=float, default=0.2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    env = TrafficJunction()
    params = env.default_params.replace(p_arrive=args.p_arrive)
    key = jax.random.key(args.seed)
    result: dict[str, object] = {"p_arrive": args.p_arrive, "episodes": args.episodes}
    compile_s = run_s = 0.0
    for name, policy in (
        ("always_gas", always_gas),
        ("yield_before_junction", yield_before_junction),
    ):
        t0 = time.perf_counter()
        compiled = make_eval(env, policy, args.episodes).lower(key, params).compile()
        t1 = time.perf_counter()
        stats = jax.block_until_ready(compiled(key, params))
        t2 = time.perf_counter()
        compile_s += t1 - t0
        run_s += t2 - t1
        result[name] = {k: round(float(v), 4) for k, v in stats.items()}
    result["compile_s"] = round(compile_s, 2)
    result["run_s"] = round(run_s, 2)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
