"""Which start geometry reproduces the paper's demonstrator rows (Table 1, D_c and D_w)?

For each contact geometry (disk centre separation, radius) and each paper scenario, plays
attack-closest (c, ours) vs w and w (ours) vs attack-closest, for both readings of the paper's
"w" (attack-weakest: weakest enemy *in range*; attack-weakest-global: weakest enemy overall), and
prints one JSON line per (geometry, scenario) with our win rates next to the paper's, plus a final
summary line ranking geometries by squared error. Default: 500 states per setting.

    python experiments/demonstrator_geometry.py --n 500
"""

from __future__ import annotations

import argparse
import json

from hybridmarl.engine.battle import run_battles
from hybridmarl.engine.scenarios import Scenario

# Paper Table 1: W of D_c (ours = attack-closest vs enemy w) and D_w (ours = w vs enemy c).
PAPER = {"m5v5": (0.43, 0.61), "m30v30": (0.75, 0.13), "m18v20": (0.32, 0.03), "m24v30": (0.12, 0.00)}
SIZES = {"m5v5": (5, 5), "m30v30": (30, 30), "m18v20": (18, 20), "m24v30": (24, 30)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--geometries", default="100:75,150:100,150:50,175:125", help="sep:radius,...")
    args = ap.parse_args()
    geoms = [tuple(int(v) for v in g.split(":")) for g in args.geometries.split(",")]
    errors: dict[str, float] = {}
    for sep, r in geoms:
        for name, (a, b) in SIZES.items():
            sc = Scenario(
                name=f"{name}-sep{sep}-r{r}",
                side0=(("Terran_Marine", a),),
                side1=(("Terran_Marine", b),),
                center0=(640 - sep // 2, 352),
                center1=(640 + sep // 2, 352),
                radius0=r,
                radius1=r,
            )
            states = sc.generate(args.n, args.seed)
            row = {"separation": sep, "radius": r, "scenario": name, "n": args.n, "paper_Dc": PAPER[name][0], "paper_Dw": PAPER[name][1]}
            for w in ("attack-weakest", "attack-weakest-global"):
                dc = run_battles(states, "attack-closest", w, progress=False).summary()["p0_win_rate"]
                dw = run_battles(states, w, "attack-closest", progress=False).summary()["p0_win_rate"]
                row[f"Dc_vs_{w}"] = dc
                row[f"Dw_{w}"] = dw
                key = f"sep{sep}-r{r}/{w}"
                errors[key] = errors.get(key, 0.0) + (dc - PAPER[name][0]) ** 2 + (dw - PAPER[name][1]) ** 2
            print(json.dumps(row), flush=True)
    print(json.dumps({"squared_error_by_geometry": dict(sorted(errors.items(), key=lambda kv: kv[1]))}))


if __name__ == "__main__":
    main()
