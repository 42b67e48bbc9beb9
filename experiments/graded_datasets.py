"""Generate graded demonstration datasets for a combat scenario (default m5v5 against
attack-weakest): SparCraft scripts of different strengths, each recorded clean and with
ε-random actions, ranked by their measured win rate W (``hybridmarl.training.datasets``;
docs/datasets.md lists the tiers and the file format).

Writes ``OUT/<name>.safetensors`` (one ``hybridmarl-demos`` file per demonstrator) and
``OUT/manifest.json``, prints a line per demonstrator and, at the end, the tier table in
Markdown.

    python experiments/graded_datasets.py --out data/m5v5-graded
    python experiments/graded_datasets.py --out /tmp/tiny --scripts attack-closest,nokdps \
        --observations 500 --eval-battles 50
"""

from __future__ import annotations

import argparse
import sys

from hybridmarl.errors import UserError
from hybridmarl.training.datasets import (
    DEFAULT_NOISE,
    DEFAULT_SCRIPTS,
    GradedSpec,
    generate_graded,
    scripts_arg,
    tier_table,
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for the datasets and manifest.json")
    ap.add_argument("--scenario", default="m5v5")
    ap.add_argument("--enemy", default="attack-weakest")
    ap.add_argument(
        "--setting", default="sparcraft", help="named setting (docs/engine.md#settings)"
    )
    ap.add_argument(
        "--scripts", default=",".join(DEFAULT_SCRIPTS), help="comma-separated engine scripts"
    )
    ap.add_argument(
        "--noise", type=float, default=DEFAULT_NOISE, help="ε of the noisy versions (0: none)"
    )
    ap.add_argument("--observations", type=int, default=10_000, help="joint states per dataset")
    ap.add_argument("--eval-battles", type=int, default=200, help="battles per demonstrator for W")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--num-envs", type=int, default=64)
    args = ap.parse_args(argv)
    spec = GradedSpec(
        scenario=args.scenario,
        enemy=args.enemy,
        setting=args.setting,
        scripts=scripts_arg(args.scripts),
        noise=args.noise,
        num_observations=args.observations,
        eval_battles=args.eval_battles,
        seed=args.seed,
        num_envs=args.num_envs,
    )
    try:
        manifest = generate_graded(args.out, spec)
    except UserError as e:
        print(f"graded_datasets: error: {str(e).splitlines()[0]}", file=sys.stderr)
        return 2
    print(tier_table(manifest))
    return 0


if __name__ == "__main__":
    sys.exit(main())
