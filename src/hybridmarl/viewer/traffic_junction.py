"""A Traffic Junction episode recorded step by step, as the JSON the HTML viewer reads.

Frame 0 is the reset state; frame ``t`` is the state after step ``t``. A frame lists every car
slot: the car it holds now (route, cell along the route, steps on the road), the action its
previous car took in step ``t`` (gas or brake), and whether that car collided or arrived in
step ``t``. Collisions are drawn at the cells where the colliding cars stood after moving.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from hybridmarl.viewer.combat import alg1_entry

__all__ = ["record_tj_timeline"]

TJ_ACTION_NAMES = ("brake", "gas")


def _hex(rgb: Any) -> str:
    return "#{:02x}{:02x}{:02x}".format(*(int(c) for c in rgb))


def record_tj_timeline(
    policy: Callable[[jax.Array, Any], jax.Array],
    params: Any,
    seed: int = 0,
    max_steps: int = 40,
    *,
    probs_fn: Callable[[Any], jax.Array] | None = None,
    alg1_fn: Callable[[jax.Array, Any], dict[str, jax.Array]] | None = None,
    num_agents: int = 10,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Play one episode with ``policy`` ``(key, TJState) -> int32 [N]`` under ``params``
    (``TJParams``) and record every step. The keys are those of
    ``hybridmarl.cli.replay.record_tj_episode``, so a seed plays the same episode as the GIF.
    ``probs_fn(state) -> float32 [N, 2]`` adds each active car's brake/gas probabilities,
    ``alg1_fn`` Alg. 1's joint action (:data:`hybridmarl.viewer.combat.Alg1Fn`).

    Returns ``(timeline, last)`` like :func:`hybridmarl.viewer.combat.record_combat_timeline`.
    """
    from hybridmarl.envs.traffic_junction import TrafficJunction
    from hybridmarl.envs.traffic_junction.env import (
        GRID_SIZE,
        JUNCTION_CELLS,
        ROAD_MASK,
        ROUTE_CELLS,
        ROUTE_LENGTHS,
        ROUTE_NAMES,
        car_cells,
    )
    from hybridmarl.envs.traffic_junction.render import ROUTE_COLOURS

    if max_steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    env = TrafficJunction(num_agents)
    step = jax.jit(env.step)
    act = jax.jit(policy)
    probs = jax.jit(probs_fn) if probs_fn is not None else None
    cells_of = jax.jit(car_cells)
    lengths = np.asarray(ROUTE_LENGTHS)

    def cars(state: Any) -> dict[str, list[Any]]:
        cells = np.asarray(cells_of(state))
        return {
            "active": [bool(a) for a in np.asarray(state.active)],
            "route": [int(r) for r in np.asarray(state.route)],
            "pos": [int(p) for p in np.asarray(state.pos)],
            "row": [int(c) for c in cells[:, 0]],
            "col": [int(c) for c in cells[:, 1]],
            "tau": [int(t) for t in np.asarray(state.tau)],
        }

    key = jax.random.key(seed)
    key, k0 = jax.random.split(key)
    _, state = env.reset(k0, params)
    frames: list[dict[str, Any]] = [
        {"t": 0, **cars(state), "action": [None] * num_agents, "collisions": 0, "arrivals": 0}
    ]
    total, done = 0.0, False
    while not done and len(frames) <= max_steps:
        key, k_act, k_env = jax.random.split(key, 3)
        actions = np.asarray(act(k_act, state))
        active0 = np.asarray(state.active)
        route0, pos0 = np.asarray(state.route), np.asarray(state.pos)
        p = np.asarray(probs(state)) if probs is not None else None
        alg1 = alg1_fn(k_env, state) if alg1_fn is not None else None
        _, new, reward, d, info = step(k_env, state, actions, params)
        collided = np.asarray(info["collided"])
        arrived = np.asarray(info["arrived"])
        # Where each car stood after this step's move (before arrivals left the road).
        moved = np.where(active0 & (actions == 1), np.minimum(pos0 + 1, lengths[route0] - 1), pos0)
        hit_cells = sorted(
            {
                tuple(int(v) for v in ROUTE_CELLS[route0[i], moved[i]])
                for i in np.flatnonzero(collided)
            }
        )
        stayed = active0 & ~arrived
        frame: dict[str, Any] = {
            "t": int(new.t),
            **cars(new),
            "action": [
                TJ_ACTION_NAMES[int(actions[i])] if active0[i] else None for i in range(num_agents)
            ],
            "collided": [bool(c) for c in collided],
            "arrived": [bool(a) for a in arrived],
            "spawned": [bool(new.active[i]) and not bool(stayed[i]) for i in range(num_agents)],
            "collision_cells": [list(c) for c in hit_cells],
            "collisions": int(info["collisions"]),
            "arrivals": int(info["arrivals"]),
            "reward": round(float(reward), 6),
            "failed": bool(new.failed),
        }
        if p is not None:
            frame["probs"] = [
                [round(float(p[i, 0]), 4), round(float(p[i, 1]), 4)] if active0[i] else None
                for i in range(num_agents)
            ]
        if alg1 is not None:
            cars_in_play = [i for i in range(num_agents) if active0[i]]
            entry = alg1_entry(alg1, [list(TJ_ACTION_NAMES)] * num_agents, cars_in_play)
            chosen, started = entry.pop("actions"), entry.pop("start")
            entry["actions"] = [None] * num_agents
            entry["start"] = [None] * num_agents
            for i, a, s in zip(cars_in_play, chosen, started, strict=True):
                entry["actions"][i], entry["start"][i] = a, s
            frame["alg1"] = entry
        frames.append(frame)
        total += float(reward)
        done = bool(d)
        state = new
    timeline = {
        "kind": "traffic_junction",
        "grid": {
            "size": GRID_SIZE,
            "road": np.asarray(ROAD_MASK).astype(int).tolist(),
            "junction": [list(c) for c in JUNCTION_CELLS],
        },
        "routes": [
            {
                "id": r,
                "name": ROUTE_NAMES[r],
                "colour": _hex(ROUTE_COLOURS[r]),
                "cells": np.asarray(ROUTE_CELLS[r, : lengths[r]]).tolist(),
            }
            for r in range(len(ROUTE_NAMES))
        ],
        "num_cars": num_agents,
        "frames": frames,
    }
    return timeline, {"state": state, "return": total, "done": done, "steps": len(frames) - 1}
