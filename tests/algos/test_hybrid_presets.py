"""The hybrid method's presets as the paper writes them (Section 5.1), and the one-sample-per-
trajectory critic data of 'pretrain_trajectories'."""

from __future__ import annotations

import numpy as np
import pytest

from hybridmarl.algos.hybrid.config import PRESETS
from hybridmarl.algos.hybrid.train import actor_lr_scale, one_state_per_episode


def test_paper_presets_are_the_papers_method():
    for name, trajectories, episodes in (
        ("paper", 100_000, 20_000),
        ("quick-paper", 20_000, 3_000),
    ):
        cfg = PRESETS[name]("combat")
        assert cfg.pretrain_trajectories == trajectories and cfg.total_episodes == episodes
        assert cfg.brd_start == "demonstrator"  # Alg. 1's input is A^D
        assert (cfg.optimizer, cfg.actor_lr, cfg.critic_lr) == ("sgd", 1e-3, 1e-3)
        assert (cfg.e_update, cfg.brd_iterations, cfg.gamma, cfg.lookahead_steps) == (
            500,
            7,
            0.995,
            1,
        )
        assert (cfg.actor_target, cfg.actor_init, cfg.actor_average_from) == (
            "advantage",
            "random",
            None,
        )


def test_quick_keeps_its_recipe():
    cfg = PRESETS["quick"]("combat")
    assert (cfg.lookahead_steps, cfg.lookahead_policy, cfg.actor_target, cfg.num_envs) == (
        8,
        "demonstrator",
        "best",
        128,
    )
    assert (
        cfg.optimizer,
        cfg.e_update,
        cfg.pretrain_samples,
        cfg.pretrain_trajectories,
        cfg.brd_start,
    ) == ("adam", 100, 20_000, 0, "actor")


def test_one_state_per_episode():
    keys = np.array([4, 4, 4, 5, 6, 6])
    states = {"episode_key": keys, "x": np.arange(6) * 10}
    returns = np.array([0.3, 0.2, 0.1, 0.9, 0.5, 0.4], np.float32)
    picked, ret = one_state_per_episode(states, returns, np.random.default_rng(0))
    assert picked["episode_key"].tolist() == [4, 5, 6]
    np.testing.assert_array_equal(ret, returns[picked["x"] // 10])  # each row keeps its own return
    seen = {
        int(i)
        for _ in range(50)
        for i in one_state_per_episode(states, returns, np.random.default_rng(_))[0]["x"][:1] // 10
    }
    assert seen == {0, 1, 2}  # uniform over the first episode's three states


def test_actor_lr_scale_falls_linearly_to_zero():
    cfg = PRESETS["quick"]("combat")
    assert cfg.actor_lr_decay_from is None and actor_lr_scale(cfg, 2_000) is None  # off by default
    cfg = cfg.replace(actor_lr_decay_from=1_500)  # total_episodes 3,000
    got = [actor_lr_scale(cfg, e) for e in (0, 1_500, 1_800, 2_250, 2_700, 3_000, 3_128)]
    assert got == pytest.approx([1.0, 1.0, 0.8, 0.5, 0.2, 0.0, 0.0], abs=1e-12)
    assert (
        actor_lr_scale(cfg.replace(actor_lr_decay_from=3_000), 3_010) == 0.0
    )  # E = total: no division by 0
