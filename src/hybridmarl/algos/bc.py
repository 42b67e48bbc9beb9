"""Behavioural cloning (the paper's BC baseline, Section 5.2, and its θ^D of Section 3).

    Phase 1  demonstrations: a dataset file, or ``demo_observations`` recorded from the script;
    Phase 2  supervised fit of the actor architecture (Section 5.1) by cross-entropy on the
             records where the agent has a choice;
    Phase 3  evaluation (``algos.evaluate``) and a checkpoint loadable by ``hybridmarl eval``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Literal

import jax
import numpy as np

from hybridmarl.io import write_json_atomic
from hybridmarl.training import networks as nets
from hybridmarl.training.checkpoint import latest_checkpoint, prefixed, save_checkpoint
from hybridmarl.training.config import (
    FINAL_EVAL_SEED,
    TrainConfig,
    check_finite,
    config_to_dict,
    resolve_run_dir,
)
from hybridmarl.training.task import TaskError, flatten_named, make_task

ALGO = "bc"


@dataclass(frozen=True)
class BCConfig(TrainConfig):
    """Behavioural cloning of the demonstrator with the actor network."""

    demo_observations: int = 10_000
    """Demonstration observations recorded from a script demonstrator (Section 5.1: 10,000)."""
    bc_steps: int = 5_000
    """SGD steps (not given in the paper)."""
    bc_batch_size: int = 256
    """Minibatch size (not given in the paper)."""
    optimizer: Literal["sgd", "adam"] = "sgd"
    """Optimiser (Section 5.1: SGD)."""
    actor_lr: float = 1e-3
    """Learning rate (Section 5.1: 10^-3)."""
    momentum: float = 0.0
    """SGD momentum (0: plain SGD)."""
    gamma: float = 0.995
    """Discount recorded with the dataset's returns (Section 5.1: 0.995)."""
    actor_hidden: tuple[int, ...] = nets.ACTOR_HIDDEN
    """Actor FC widths (Section 5.1: 512, 256, 256)."""


PRESETS = {
    "paper": lambda env: BCConfig(env=env, demonstrator="always-gas" if env == "traffic_junction" else "attack-closest"),
    "quick": lambda env: dataclasses.replace(PRESETS["paper"](env), bc_steps=2_000, optimizer="adam"),
    "toy": lambda env: dataclasses.replace(
        PRESETS["paper"](env), demo_observations=64, bc_steps=20, actor_hidden=(16, 16, 16), eval_episodes=8, tensorboard=False
    ),
}


def train(cfg: BCConfig) -> int:
    from hybridmarl.training import demos as D
    from hybridmarl.training import evaluate as E
    from hybridmarl.training.logger import RunLogger

    t0 = time.time()
    spec = cfg.task_spec()
    task = make_task(spec)
    run_dir = resolve_run_dir(ALGO, cfg)
    if latest_checkpoint(run_dir) is not None and not cfg.resume:
        raise TaskError(f"{run_dir} already holds checkpoints: pass --resume (BC restarts from scratch) or choose another --run-dir")
    log = RunLogger(run_dir, tensorboard=cfg.tensorboard)
    log.write_config({"algo": ALGO, "config": {**config_to_dict(cfg), "demonstrator_name": cfg.demonstrator_name()}, "task": spec.to_dict()})

    # ---- Phase 1: demonstrations ----------------------------------------------------------------
    if cfg.demonstrator_is_dataset():
        ds = D.load_dataset(cfg.demonstrator, expect=task)
    else:
        ds = D.collect(spec, cfg.demonstrator_name(), cfg.demo_observations, seed=cfg.seed, gamma=cfg.gamma)
    rows = D.bc_rows(ds)

    # ---- Phase 2: the supervised fit --------------------------------------------------------------
    module = nets.actor_module(task.num_actions, cfg.actor_hidden)
    k_init, k_fit = jax.random.split(jax.random.key(cfg.seed))
    actor = nets.init_net(module, k_init, task.obs_dim, nets.make_optimizer(cfg.optimizer, cfg.actor_lr, cfg.momentum))
    actor, losses = D.fit_bc(actor, module, (cfg.optimizer, cfg.actor_lr), rows, k_fit, cfg.bc_steps, cfg.bc_batch_size)
    check_finite("behavioural-cloning loss", float(losses[-1]), "the end of cloning")
    acc = D.bc_accuracy(actor, module, rows)
    every = max(1, cfg.bc_steps // 200)
    log.train.write([{"episodes": 0, "step": i + 1, "bc_loss": float(losses[i])} for i in range(0, len(losses), every)])
    print(f"cloned {ds.size} observations ({rows[0].shape[0]} agent decisions): loss {losses[-1]:.4f}, accuracy {acc:.3f}")
    save_checkpoint(
        run_dir, 0, prefixed(flatten_named(actor), "actor"),
        {"algo": ALGO, "phase": "done", "bc_accuracy": acc, "task": spec.to_dict()}, keep=cfg.keep_checkpoints,
    )

    # ---- Phase 3: evaluation ------------------------------------------------------------------------
    eval_task = task.against(cfg.eval_enemy_name())
    res = E.evaluate_task(eval_task, module, {"params": actor.params, "batch_stats": actor.batch_stats}, n=cfg.eval_episodes, seed=cfg.seed + FINAL_EVAL_SEED)
    res.update(bc_accuracy=acc, enemy=eval_task.enemy, wall_s=time.time() - t0)
    write_json_atomic(run_dir / "eval.json", res)
    log.close()

    print(task.result_line(res))
    return 0


__all__ = ["ALGO", "PRESETS", "BCConfig", "train", "np"]
