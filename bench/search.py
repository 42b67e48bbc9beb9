"""Search-player benchmark: speed per decision and a sanity experiment (prints JSON).

    python bench/search.py                          # 8v8, 32v32, 50v50 + the 8v8 sanity battles
    python bench/search.py --sizes 8 --decisions 7 --battles 40
    python bench/search.py --no-sanity --out search_bench.json

Speed, per army size n (n Marines a side, SparCraft StateSymmetric-like start states: intermixed
armies, offsets in [-128, 127] around (640, 360), 1280x704 map), each over ``--decisions``
distinct start states (the first decision of a game, where every unit of both sides acts):

- UCT-CD with a 40 ms budget (C 1.6, <= 5000 traversals, 20 children, NOKDPS playouts):
  traversals per decision;
- ABCD with a 40 ms budget (20 children, playout evaluation): nodes expanded, depth completed;
- PGS with no time limit (I = 1, R = 0): ms per decision and its playout count;

on each engine of ``--engines`` (default both: ``native``, the Numba CPU engine, and ``jax``),

each as min / median, with the compile time of each player's programs measured separately
(``warmup``), next to SparCraft's own figures measured on one core (docs/speed.md#sparcraft-reference-figures).

Sanity: on 8v8 symmetric states where NOKDPS vs NOKDPS is a draw by symmetry, UCT-CD and PGS
(and ABCD with ``--sanity-players``) play NOKDPS with their default budgets, the search player
as player 0 in the even-numbered battles and as player 1 in the odd ones; the JSON reports the
search player's wins, losses, draws and ``n``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

from hybridmarl.engine.battle import run_battles
from hybridmarl.engine.scenarios import state_symmetric
from hybridmarl.engine.state import build_state, make_rules
from hybridmarl.search import make_player, play_game_with_players

MARINE = "Terran_Marine"

#: docs/speed.md#sparcraft-reference-figures: DC-HEAD, one core, StateSymmetric-like Marine states, two runs as a range.
SPARCRAFT = {
    8: {
        "uct_traversals_40ms": [165, 240],
        "ab_nodes_40ms": [150, 350],
        "ab_depth": 3,
        "ab_ms": [40, 46],
        "pgs_ms": [4.4, 6.1],
        "pgs_playouts": 20,
    },
    16: {
        "uct_traversals_40ms": [80, 105],
        "ab_nodes_40ms": [150, 200],
        "ab_depth": 3,
        "ab_ms": [45, 52],
        "pgs_ms": [17, 17],
        "pgs_playouts": 36,
    },
    32: {
        "uct_traversals_40ms": [35, 45],
        "ab_nodes_40ms": [50, 100],
        "ab_depth": [2, 3],
        "ab_ms": [49, 65],
        "pgs_ms": [83, 116],
        "pgs_playouts": 68,
    },
    50: {
        "uct_traversals_40ms": [20, 25],
        "ab_nodes_40ms": [50, 50],
        "ab_depth": 2,
        "ab_ms": [73, 89],
        "pgs_ms": [256, 312],
        "pgs_playouts": 104,
    },
}


def _states(n: int, count: int, seed: int):
    rng = np.random.default_rng(seed)
    return [state_symmetric(rng, 128, 128, [(MARINE, n)]) for _ in range(count)]


def _min_med(xs: list[float]) -> dict:
    return {"min": min(xs), "median": statistics.median(xs), "max": max(xs)}


def bench_speed(n: int, decisions: int, time_ms: float, seed: int, engines: list[str]) -> dict:
    rules = make_rules()
    states = [build_state(s) for s in _states(n, decisions, seed)]
    row: dict = {
        "n": n,
        "decisions": decisions,
        "sparcraft": SPARCRAFT.get(n),
        "loadavg_start": [round(x, 2) for x in os.getloadavg()],
    }
    for engine in engines:
        row[engine] = _bench_engine(n, states, rules, time_ms, seed, engine)
    row["loadavg_end"] = [round(x, 2) for x in os.getloadavg()]
    return row


def _bench_engine(n: int, states: list, rules, time_ms: float, seed: int, engine: str) -> dict:
    row: dict = {}
    specs = {
        "uct": f"uct:time_ms={time_ms:g},engine={engine}",
        "abcd": f"abcd:time_ms={time_ms:g},engine={engine}",
        "pgs": f"pgs:time_ms=0,engine={engine}",
    }
    for alg, spec in specs.items():
        player = make_player(spec)
        player.reset(seed)
        compile_s = player.warmup(states[0], rules)  # type: ignore[attr-defined]
        player.decide(states[0], rules, 0)  # one untimed decision (first-call caches)
        stats = []
        for st in states:
            player.decide(st, rules, 0)
            assert player.stats is not None
            stats.append(player.stats)
        out = {
            "spec": spec,
            "compile_s": round(compile_s, 2),
            "ms": _min_med([round(s.ms, 1) for s in stats]),
            # CPU time of this process: on a shared machine wall time includes waiting for a core.
            "cpu_ms": _min_med([round(s.cpu_ms, 1) for s in stats]),
            "playouts": _min_med([s.playouts for s in stats]),
            "engine_calls": _min_med([s.calls for s in stats]),
            "batch": stats[0].extra.get("batch"),
        }
        if alg == "uct":
            out["traversals"] = _min_med([s.traversals for s in stats])
            out["traversals_per_40ms_cpu"] = _min_med(
                [round(40 * s.traversals / max(s.cpu_ms, 1e-3), 1) for s in stats]
            )
            out["tree_depth"] = _min_med([s.depth for s in stats])
        elif alg == "abcd":
            out["nodes"] = _min_med([s.nodes for s in stats])
            out["depth_completed"] = _min_med([s.depth for s in stats])
            out["nodes_per_40ms_cpu"] = _min_med(
                [round(40 * s.nodes / max(s.cpu_ms, 1e-3), 1) for s in stats]
            )
            out["fallback_decisions"] = sum(s.fallback for s in stats)
        row[alg] = out
        print(f"  {n}v{n} {engine} {alg}: {json.dumps(out)}", file=sys.stderr, flush=True)
    return row


def _range(v) -> str:
    return "-".join(f"{x:g}" for x in v) if isinstance(v, list) else f"{v:g}"


def table(speed: list[dict], engines: list[str]) -> str:
    """Markdown table: per size and engine, min / median of UCT traversals and ABCD nodes per
    decision (40 ms budget) and PGS ms per decision (no time limit), SparCraft beside."""
    lines = [
        "| n | engine | UCT traversals / 40 ms | ABCD nodes / 40 ms (depth) | PGS ms / decision | compile s (uct, abcd, pgs) |",
        "|---|---|---|---|---|---|",
    ]
    for row in speed:
        n = row["n"]
        for e in engines:
            r = row[e]
            u, a, p = r["uct"], r["abcd"], r["pgs"]
            lines.append(
                f"| {n}v{n} | {e} | {u['traversals']['min']:g} / {u['traversals']['median']:g} "
                f"| {a['nodes']['min']:g} / {a['nodes']['median']:g} ({a['depth_completed']['median']:g}) "
                f"| {p['ms']['min']:g} / {p['ms']['median']:g} | {u['compile_s']}, {a['compile_s']}, {p['compile_s']} |"
            )
        sc = row.get("sparcraft")
        if sc:
            lines.append(
                f"| {n}v{n} | SparCraft (C++) | {_range(sc['uct_traversals_40ms'])} | {_range(sc['ab_nodes_40ms'])} "
                f"({_range(sc['ab_depth'])}) | {_range(sc['pgs_ms'])} | |"
            )
    return "\n".join(lines)


def sanity(players: list[str], battles: int, seed: int) -> dict:
    rules = make_rules()
    units = _states(8, battles, seed + 1000)
    base = run_battles(units, "nokdps", "nokdps", rules=rules, progress=False).summary()
    out: dict = {
        "states": "8v8 Marines, StateSymmetric offsets [-128,127] around (640,360)",
        "nokdps_vs_nokdps": base,
    }
    for spec in players:
        wins = losses = draws = 0
        ms: list[float] = []
        t0 = time.perf_counter()
        for i, u in enumerate(units):
            side = i % 2
            p0, p1 = (spec, "nokdps") if side == 0 else ("nokdps", spec)
            g = play_game_with_players(build_state(u), rules, p0, p1, seed=seed + i)
            ms += [d.ms for d in g.decisions[side]]
            if g.winner == side:
                wins += 1
            elif g.winner == 1 - side:
                losses += 1
            else:
                draws += 1
        out[spec] = {
            "n": battles,
            "wins": wins,
            "losses": losses,
            "draws": draws,
            "win_rate": wins / battles,
            "score": (wins + 0.5 * draws) / battles,
            "ms_per_decision": _min_med([round(m, 1) for m in ms]) if ms else None,
            "seconds": round(time.perf_counter() - t0, 1),
        }
        print(f"  sanity {spec} vs nokdps: {json.dumps(out[spec])}", file=sys.stderr, flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--sizes", type=int, nargs="+", default=[8, 32, 50], help="n for n-vs-n Marine states"
    )
    ap.add_argument(
        "--decisions", type=int, default=5, help="timed decisions (distinct start states) per size"
    )
    ap.add_argument("--time-ms", type=float, default=40.0, help="UCT / ABCD budget per decision")
    ap.add_argument("--battles", type=int, default=30, help="sanity battles per search player")
    ap.add_argument(
        "--sanity-players",
        nargs="+",
        default=["uct", "pgs"],
        help="player specs for the sanity battles",
    )
    ap.add_argument("--no-sanity", action="store_true", help="skip the sanity battles")
    ap.add_argument(
        "--engines",
        nargs="+",
        default=["native", "jax"],
        choices=["native", "jax"],
        help="engines to measure, side by side",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, help="also write the JSON here")
    args = ap.parse_args(argv)

    load0 = os.getloadavg()
    t0 = time.perf_counter()
    doc: dict = {
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "jax": jax.__version__,
            "backend": jax.default_backend(),
            "loadavg_start": [round(x, 2) for x in load0],
        },
        "speed": [
            bench_speed(n, args.decisions, args.time_ms, args.seed, args.engines)
            for n in args.sizes
        ],
    }
    doc["table"] = table(doc["speed"], args.engines)
    print(doc["table"], file=sys.stderr, flush=True)
    if not args.no_sanity and args.battles > 0:
        doc["sanity"] = sanity(args.sanity_players, args.battles, args.seed)
    doc["machine"]["loadavg_end"] = [round(x, 2) for x in os.getloadavg()]
    doc["seconds"] = round(time.perf_counter() - t0, 1)
    text = json.dumps(doc, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
