"""Is a trained policy better than its demonstrator on the same start states? A paired test.

Plays a run directory's policy and its demonstrator script (from the run's config) against the
run's enemy on the same N start states, those of ``hybridmarl eval --n N --seed SEED``, and
compares them state by state:

- W of each, and the difference ΔW with a 95 % interval (normal approximation over the N
  per-state differences);
- the battles only the learner wins and those only the demonstrator wins, and McNemar's exact
  two-sided p on them.

A paired comparison is sharper than two independent intervals: both policies face the same
start states, so the state-to-state spread cancels. Prints one JSON object.

    python experiments/paired_vs_demonstrator.py --run-dir RUN --seed 20200713
    python experiments/paired_vs_demonstrator.py --run-dir RUN --checkpoint 2500 --n 1000 --seed 1
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import jax
import numpy as np

from hybridmarl.envs.stats import paired_wins
from hybridmarl.training import evaluate as E
from hybridmarl.training.task import default_enemy, make_task


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--run-dir", required=True)
    ap.add_argument(
        "--checkpoint",
        type=int,
        default=None,
        help="episode count of a kept checkpoint (default: the final policy)",
    )
    ap.add_argument("--n", type=int, default=1000, help="start states")
    ap.add_argument(
        "--seed",
        type=int,
        default=20200713,
        help="the start states of `hybridmarl eval --seed SEED` (default: the reproduction protocol's)",
    )
    args = ap.parse_args()

    bundle = E.load_policy(args.run_dir, checkpoint=args.checkpoint)
    demonstrator = bundle.config["config"]["demonstrator_name"]
    task = make_task(dataclasses.replace(bundle.spec, enemy=default_enemy(demonstrator)))
    key = jax.random.key(args.seed)
    learner = (
        E.run_episodes(task, E.actor_policy(bundle.module), bundle.variables, key, args.n)["won"]
        > 0
    )
    demo = E.run_scripted_episodes_native(task, demonstrator, key, args.n)["won"] > 0
    out = {
        "run_dir": args.run_dir,
        "checkpoint": args.checkpoint,
        "seed": args.seed,
        "demonstrator": demonstrator,
    }
    stats = paired_wins(np.asarray(learner), np.asarray(demo))
    names = {
        "W_a": "W",
        "W_b": "W_demonstrator",
        "only_a": "only_learner_wins",
        "only_b": "only_demonstrator_wins",
    }
    print(json.dumps(out | {names.get(k, k): v for k, v in stats.items()}))


if __name__ == "__main__":
    main()
