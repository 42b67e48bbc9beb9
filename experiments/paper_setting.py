"""Calibrate and check the ``paper`` setting (``hybridmarl.settings``, docs/engine.md#settings).

Combat (paper Table 1, rows D_c and D_w): under the paper's rules (classic overkill, stalemate
limit 200) our W of D_c (attack-closest, ours, against attack-weakest) and D_w (attack-weakest
against attack-closest) in m5v5, m30v30, m18v20 and m24v30, next to the paper's.

- ``--mode check`` (default): the ``paper`` setting as shipped (its named scenarios and rules,
  through ``named_scenario`` and ``Setting.rules``), on ``--n`` start states of seed ``--seed``
  (2026: a seed the calibration did not use). Prints one JSON object, then a Markdown table.
- ``--mode sweep``: the geometry rule "disks of radius R, centres C + K * (A + B) px apart" for
  every ``C:K:R`` in ``--rules``, on the calibration seed (1000 unless ``--seed`` says otherwise);
  one JSON line per rule with the largest distance to the paper's eight cells.
- ``--mode tj``: Traffic Junction: the always-gas demonstrator's failure rate and arrivals per
  episode for every arrival probability in ``--p-arrive`` (``--episodes`` per seed, 2000, for
  each of ``--seeds``, pooled), next to the paper's D (failure 0.72, Table 2).

All combat games run on the native engine (docs/engine-backends.md; the same games as the JAX
engine). Usage::

    python experiments/paper_setting.py                       # check, 1000 states, seed 2026
    python experiments/paper_setting.py --mode sweep --n 2000 --rules 112:1:110,150:0:100
    python experiments/paper_setting.py --mode tj --p-arrive 0.1,0.105,0.11 --seeds 0,1,2,3
"""

from __future__ import annotations

import argparse
import json
import time

#: Paper Table 1: W of D_c (ours = attack-closest vs enemy attack-weakest) and of D_w (ours =
#: attack-weakest vs enemy attack-closest).
PAPER = {
    "m5v5": (0.43, 0.61),
    "m30v30": (0.75, 0.13),
    "m18v20": (0.32, 0.03),
    "m24v30": (0.12, 0.00),
}
#: Paper Table 2: the Traffic Junction demonstrator's failure rate.
PAPER_TJ_FAILURE = 0.72
CELLS = (("D_c", "attack-closest", "attack-weakest"), ("D_w", "attack-weakest", "attack-closest"))


def play_cells(scenario, rules, n: int, seed: int) -> dict[str, dict[str, float]]:
    """W, loss and draw rates of D_c and D_w on ``n`` start states of ``scenario``."""
    from hybridmarl.engine.native import from_arrays, run_battles

    states = from_arrays(scenario.generate_arrays(n, seed))
    out = {}
    for cell, ours, enemy in CELLS:
        s = run_battles(states, ours, enemy, rules=rules, progress=False).summary()
        out[cell] = {"W": s["p0_win_rate"], "L": s["p1_win_rate"], "draws": s["draw_rate"]}
    return out


def check(n: int, seed: int) -> dict:
    from hybridmarl.engine.scenarios import named_scenario
    from hybridmarl.settings import get_setting

    setting = get_setting("paper")
    rules = setting.rules()
    rows = {}
    for name, paper in PAPER.items():
        sc = named_scenario(name, setting)
        cells = play_cells(sc, rules, n, seed)
        rows[name] = {
            "geometry": sc.description,
            **{cell: {**v, "paper_W": paper[i]} for i, (cell, v) in enumerate(cells.items())},
        }
    worst = max(abs(r[c]["W"] - r[c]["paper_W"]) for r in rows.values() for c in ("D_c", "D_w"))
    return {
        "setting": setting.to_dict(),
        "n": n,
        "seed": seed,
        "max_abs_diff": round(worst, 4),
        "scenarios": rows,
    }


def markdown(doc: dict) -> str:
    lines = [
        "| | " + " | ".join(doc["scenarios"]) + " |",
        "|---|" + "---|" * len(doc["scenarios"]),
    ]
    for cell in ("D_c", "D_w"):
        ours = [f"{r[cell]['W']:.2f}" for r in doc["scenarios"].values()]
        paper = [f"{r[cell]['paper_W']:.2f}" for r in doc["scenarios"].values()]
        lines.append(f"| {cell} W, ours | " + " | ".join(ours) + " |")
        lines.append(f"| {cell} W, paper | " + " | ".join(paper) + " |")
    draws = [
        f"{r['D_c']['draws']:.2f} / {r['D_w']['draws']:.2f}" for r in doc["scenarios"].values()
    ]
    lines.append("| draws (D_c / D_w), ours | " + " | ".join(draws) + " |")
    return "\n".join(lines)


def sweep(rules_arg: str, n: int, seed: int) -> None:
    from hybridmarl.engine.scenarios import Scenario
    from hybridmarl.settings import get_setting

    rules = get_setting("paper").rules()
    sizes = {name: tuple(int(v) for v in name[1:].split("v")) for name in PAPER}
    for spec in rules_arg.split(","):
        c, k, r = (float(v) for v in spec.split(":"))
        row: dict = {"rule": spec, "n": n, "seed": seed, "cells": {}}
        for name, (a, b) in sizes.items():
            sep = int(round(c + k * (a + b)))
            sc = Scenario(
                name=name,
                side0=(("Terran_Marine", a),),
                side1=(("Terran_Marine", b),),
                center0=(640 - sep // 2, 352),
                center1=(640 - sep // 2 + sep, 352),
                radius0=int(r),
                radius1=int(r),
            )
            cells = play_cells(sc, rules, n, seed)
            row["cells"][name] = {"separation": sep, **{cell: v["W"] for cell, v in cells.items()}}
        row["max_abs_diff"] = round(
            max(
                abs(row["cells"][name][cell] - PAPER[name][i])
                for name in PAPER
                for i, cell in enumerate(("D_c", "D_w"))
            ),
            4,
        )
        print(json.dumps(row), flush=True)


def traffic_junction(probs: list[float], episodes: int, seeds: list[int]) -> dict:
    import jax

    from hybridmarl.envs.traffic_junction import TrafficJunction, always_gas

    env = TrafficJunction()

    def episode(key, params):
        k_reset, k_run = jax.random.split(key)
        _, state = env.reset(k_reset, params)

        def body(state, step_key):
            k_act, k_env = jax.random.split(step_key)
            _, state, _, _, _ = env.step(k_env, state, always_gas(k_act, state), params)
            return state, None

        state, _ = jax.lax.scan(body, state, jax.random.split(k_run, env.default_params.max_steps))
        return state.failed, state.total_arrivals

    @jax.jit
    def run(key, params):
        failed, arrivals = jax.vmap(episode, in_axes=(0, None))(
            jax.random.split(key, episodes), params
        )
        return failed.mean(), arrivals.mean()

    rows = []
    for p in probs:
        runs = [run(jax.random.key(seed), env.default_params.replace(p_arrive=p)) for seed in seeds]
        f = [float(r[0]) for r in runs]
        a = [float(r[1]) for r in runs]
        rows.append(
            {
                "p_arrive": p,
                "failure_rate": round(sum(f) / len(f), 4),
                "mean_arrivals": round(sum(a) / len(a), 2),
                "failure_rate_by_seed": [round(v, 4) for v in f],
            }
        )
    return {
        "episodes_per_seed": episodes,
        "seeds": seeds,
        "paper_D_failure": PAPER_TJ_FAILURE,
        "rows": rows,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=("check", "sweep", "tj"), default="check")
    ap.add_argument("--n", type=int, default=1000, help="start states per cell (combat)")
    ap.add_argument("--seed", type=int, default=None, help="check: 2026; sweep: 1000")
    ap.add_argument("--seeds", default="0", help="tj: episode seeds, comma-separated (pooled)")
    ap.add_argument(
        "--rules", default="112:1:110", help="sweep: C:K:R,... (radius R, centres C + K(A+B) apart)"
    )
    ap.add_argument("--p-arrive", default="0.1,0.105,0.11", help="tj: arrival probabilities")
    ap.add_argument("--episodes", type=int, default=2000, help="tj: episodes per probability")
    args = ap.parse_args()
    t0 = time.time()
    if args.mode == "sweep":
        sweep(args.rules, args.n, 1000 if args.seed is None else args.seed)
        return
    if args.mode == "tj":
        seeds = [int(v) for v in args.seeds.split(",")]
        doc = traffic_junction([float(p) for p in args.p_arrive.split(",")], args.episodes, seeds)
        doc["wall_s"] = round(time.time() - t0, 1)
        print(json.dumps(doc))
        print()
        print("| p_arrive | always-gas failure | arrivals per episode |")
        print("|---|---|---|")
        for r in doc["rows"]:
            print(f"| {r['p_arrive']:g} | {r['failure_rate']:.3f} | {r['mean_arrivals']:.1f} |")
        return
    doc = check(args.n, 2026 if args.seed is None else args.seed)
    doc["wall_s"] = round(time.time() - t0, 1)
    print(json.dumps(doc))
    print()
    print(markdown(doc))


if __name__ == "__main__":
    main()
