"""Long differential run of the native engine against the JAX engine (prints JSON).

    python bench/engine_parity.py                      # 100,000 games
    python bench/engine_parity.py --games 20000 --max-side 8 --batch 4096

Random start states (1..``--max-side`` units of random types a side) are played to the end by
both engines, in batches that cycle through every ordered pair of deterministic scripts, both
overkill modes, and the open default map or a small map with random walls. A game matches when
its final state (every field of every unit), winner, final frame, turns, LTD2 evaluation and
unit actions are equal and the LTD2 evaluations within 2 (each side's LTD2 within 1: float32
summation order; counted apart as ``ltd2_rounding``); the first mismatch is replayed turn by turn to name the first differing
turn and field.
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import sys
import time

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--games", type=int, default=100_000)
    ap.add_argument("--batch", type=int, default=2 * 81 * 16, help="games per compared batch")
    ap.add_argument(
        "--max-side", type=int, default=10, help="most units a side (slots of every state)"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="also write the JSON here")
    args = ap.parse_args(argv)

    from hybridmarl.engine import native
    from hybridmarl.engine.native import parity as P
    from hybridmarl.engine.state import make_rules

    native.compile_kernels()
    rng = np.random.default_rng(args.seed)
    p0_all, p1_all = P.all_pairs()
    configs = [(ok, walls) for ok in ("pass", "classic") for walls in (False, True)]
    per_config = {
        f"{ok}/{'walls' if walls else 'open'}": {"games": 0, "mismatches": 0, "ltd2_rounding": 0}
        for ok, walls in configs
    }
    total = mismatches = 0
    first = None
    start = time.perf_counter()
    batch_no = 0
    while total < args.games:
        overkill, walls = configs[batch_no % len(configs)]
        batch_no += 1
        grid = P.random_walkable(rng) if walls else None
        rules = make_rules(grid, overkill=overkill)
        n = min(args.batch, args.games - total)
        units = P.random_states(rng, n, args.max_side, np.asarray(rules.walkable))
        states = native.build_native_states(units, args.max_side)
        p0 = [p0_all[i % len(p0_all)] for i in range(n)]
        p1 = [p1_all[i % len(p1_all)] for i in range(n)]
        cmp = P.compare_whole_games(states, rules, p0, p1)
        key = f"{overkill}/{'walls' if walls else 'open'}"
        per_config[key]["games"] += n
        per_config[key]["mismatches"] += cmp.mismatches
        per_config[key]["ltd2_rounding"] += cmp.ltd2_rounding
        total += n
        mismatches += cmp.mismatches
        if cmp.first_mismatch and first is None:
            first = f"{key}: {cmp.first_mismatch}"
        print(f"{total}/{args.games} games, {mismatches} mismatches", file=sys.stderr, flush=True)
    doc = {
        "benchmark": "engine-parity",
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "games": total,
        "mismatches": mismatches,
        "first_mismatch": first,
        "scripts": list(P.DETERMINISTIC_SCRIPTS),
        "max_side": args.max_side,
        "seed": args.seed,
        "per_config": per_config,
        "seconds": round(time.perf_counter() - start, 1),
        "uptime": subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip(),
    }
    text = json.dumps(doc, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    return 0 if mismatches == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
