"""Behavioural cloning (the paper's BC baseline, Section 5.2, and its θ^D of Section 3).

Phase 1  demonstrations: a dataset file, or demo_observations recorded from the script;
Phase 2  supervised fit of the actor architecture (Section 5.1) by cross-entropy on the
         records where the agent has a choice;
Phase 3  evaluation (Section 5.1) and a checkpoint loadable by 'hybridmarl eval'.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import jax
from tyro.conf import OmitArgPrefixes

from hybridmarl.training import networks as nets
from hybridmarl.training.checkpoint import prefixed, save_checkpoint
from hybridmarl.training.config import Options, TrainConfig, check_finite
from hybridmarl.training.run import Run, TrainResult
from hybridmarl.training.task import flatten_named

ALGO = "bc"


@dataclass(frozen=True)
class CloningOptions(Options):
    """The demonstrations and the supervised fit."""

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
    gamma: float = 0.995
    """Discount recorded with the dataset's returns (Section 5.1: 0.995)."""
    actor_hidden: tuple[int, ...] = nets.ACTOR_HIDDEN
    """Actor FC widths (Section 5.1: 512, 256, 256)."""


@dataclass(frozen=True)
class BCConfig(TrainConfig):
    """Behavioural cloning of the demonstrator with the actor network."""

    cloning: OmitArgPrefixes[CloningOptions] = dataclasses.field(default_factory=CloningOptions)


def _paper(env: str) -> BCConfig:
    """'paper': 10,000 demonstration observations (Section 5.1), 5,000 SGD steps at 10^-3.
    Budget: BC plays no training episodes; its data is the 10,000 demonstration observations
    every learner gets (the hybrid 'paper' preset's 20,000 episodes have no counterpart)."""
    return BCConfig().replace(
        env=env, demonstrator="always-gas" if env == "traffic_junction" else "attack-closest"
    )


def _quick(env: str) -> BCConfig:
    """'quick': 'paper' with 2,000 Adam steps. Budget: no training episodes (the hybrid
    'quick' preset's 3,000 have no counterpart), the same 10,000 demonstration observations."""
    return _paper(env).replace(bc_steps=2_000, optimizer="adam")


def _toy(env: str) -> BCConfig:
    """'toy', seconds: 64 observations, 20 steps, a tiny network (tests, CI)."""
    return _paper(env).replace(
        demo_observations=64,
        bc_steps=20,
        actor_hidden=(16, 16, 16),
        eval_episodes=8,
        tensorboard=False,
    )


#: Preset name -> '(env) -> BCConfig' ('--preset').
PRESETS = {"paper": _paper, "quick": _quick, "toy": _toy}
#: The config class of '--algo bc'.
CONFIG = BCConfig


def train(cfg: BCConfig) -> TrainResult:
    """Clone the demonstrator and evaluate the clone. Raises a 'UserError' for bad input and
    'TrainingDiverged' when the loss becomes NaN/inf."""
    from hybridmarl.training import demos as D

    with Run(ALGO, cfg, resumable=False) as run:
        task, spec = run.task, run.spec
        run.log.write_config(run.config_document())

        # ---- Phase 1: demonstrations ----------------------------------------------------------------
        if cfg.demonstrator_is_dataset():
            ds = D.load_dataset(cfg.demonstrator, expect=task)
        else:
            ds = D.collect(
                spec, cfg.demonstrator_name(), cfg.demo_observations, seed=cfg.seed, gamma=cfg.gamma
            )
        rows = D.bc_rows(ds)

        # ---- Phase 2: the supervised fit --------------------------------------------------------------
        module = nets.actor_module(task.num_actions, cfg.actor_hidden)
        k_init, k_fit = jax.random.split(jax.random.key(cfg.seed))
        actor = nets.init_net(
            module, k_init, task.obs_dim, nets.make_optimizer(cfg.optimizer, cfg.actor_lr)
        )
        actor, losses = D.fit_bc(
            actor,
            module,
            (cfg.optimizer, cfg.actor_lr),
            rows,
            k_fit,
            cfg.bc_steps,
            cfg.bc_batch_size,
        )
        check_finite("behavioural-cloning loss", float(losses[-1]), "the end of cloning")
        acc = D.bc_accuracy(actor, module, rows)
        every = max(1, cfg.bc_steps // 200)
        # 'agreement' (with the demonstrator, on every demonstration decision; as DQfD's and
        # OGTL's column) is measured once, on the last row.
        steps = list(range(0, len(losses), every))
        if steps[-1] != len(losses) - 1:
            steps.append(len(losses) - 1)
        run.log.train.write(
            [
                {
                    "episodes": 0,
                    "step": i + 1,
                    "bc_loss": float(losses[i]),
                    "agreement": acc if i == len(losses) - 1 else float("nan"),
                }
                for i in steps
            ]
        )
        print(
            f"cloned {ds.size} observations ({rows[0].shape[0]} agent decisions): loss {losses[-1]:.4f}, accuracy {acc:.3f}"
        )
        save_checkpoint(
            run.run_dir,
            0,
            prefixed(flatten_named(actor), "actor"),
            {"algo": ALGO, "phase": "done", "bc_accuracy": acc, "task": spec.to_dict()},
            keep=cfg.keep_checkpoints,
        )

        # ---- Phase 3: evaluation ------------------------------------------------------------------------
        run.module = module
        res = run.evaluate({"params": actor.params, "batch_stats": actor.batch_stats})
        res.update(bc_accuracy=acc, enemy=run.eval_task.enemy, wall_s=run.clock.elapsed()["wall_s"])
        return run.report(res)


__all__ = ["ALGO", "CONFIG", "PRESETS", "BCConfig", "train"]
