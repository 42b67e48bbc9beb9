"""The PettingZoo adapter under PettingZoo's own tests with default settings, its dict
observations, masks and illegal-action handling."""

from __future__ import annotations

import gymnasium
import jax
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from hybridmarl import envs
from hybridmarl.envs.pettingzoo import PettingZooAdapter
from hybridmarl.envs.traffic_junction import TrafficJunction

TJ = TrafficJunction()


@pytest.mark.parametrize("name", ["traffic_junction", "combat"])
def test_official_api_and_seed_tests_with_defaults(name):
    # Default settings throughout: dict observations, illegal actions replaced and counted.
    # parallel_api_test samples with obs[agent]["action_mask"]; parallel_seed_test samples from
    # the unmasked Discrete space, so its random actions are often illegal.
    env = envs.make_pettingzoo(name)
    assert env.obs_format == "dict" and env.illegal_action == "fallback"
    parallel_api_test(env, num_cycles=100)
    parallel_seed_test(lambda: envs.make_pettingzoo(name), num_cycles=50)


def _check_obs_and_masks(pz, obs, infos, avail):
    mask = np.asarray(avail(pz.env_state, pz.params)).astype(np.int8)
    for agent in obs:
        i = pz.possible_agents.index(agent)
        space = pz.observation_space(agent)
        assert isinstance(space, gymnasium.spaces.Dict)
        assert set(obs[agent]) == {"observation", "action_mask"}
        assert space.contains(obs[agent]), agent
        assert obs[agent]["action_mask"].dtype == np.int8
        np.testing.assert_array_equal(obs[agent]["action_mask"], mask[i])
        np.testing.assert_array_equal(infos[agent]["action_mask"], mask[i])


def test_dict_observation_and_masks_match_get_avail_actions_tj():
    pz = PettingZooAdapter(TJ, params=TJ.default_params.replace(p_arrive=0.5))
    avail = jax.jit(TJ.get_avail_actions)
    obs, infos = pz.reset(seed=3)
    _check_obs_and_masks(pz, obs, infos, avail)
    for _ in range(12):
        actions = {a: int(pz.action_space(a).sample(mask=obs[a]["action_mask"])) for a in pz.agents}
        obs, _, _, _, infos = pz.step(actions)
        _check_obs_and_masks(pz, obs, infos, avail)
    assert pz.illegal_action_count == 0  # masked sampling never plays an illegal action


def test_dict_observation_and_masks_match_get_avail_actions_combat():
    pz = envs.make_pettingzoo("combat", scenario="m3v3")
    avail = jax.jit(pz.env.get_avail_actions)
    obs, infos = pz.reset(seed=0)
    _check_obs_and_masks(pz, obs, infos, avail)
    obs, _, _, _, infos = pz.step({a: int(np.flatnonzero(obs[a]["action_mask"])[-1]) for a in obs})
    _check_obs_and_masks(pz, obs, infos, avail)


def test_array_format_keeps_the_bare_observation():
    pz = PettingZooAdapter(TJ, obs_format="array")
    space = pz.observation_space("car_0")
    assert isinstance(space, gymnasium.spaces.Box) and space.shape == TJ.observation_shape
    obs, infos = pz.reset(seed=1)
    assert isinstance(obs["car_0"], np.ndarray) and space.contains(obs["car_0"])
    assert infos["car_0"]["action_mask"].shape == (TJ.num_actions,)
    with pytest.raises(ValueError, match="obs_format"):
        PettingZooAdapter(TJ, obs_format="tuple")
    with pytest.raises(ValueError, match="illegal_action"):
        PettingZooAdapter(TJ, illegal_action="ignore")


def test_illegal_actions_are_replaced_and_counted():
    pz = PettingZooAdapter(TJ)
    ref = PettingZooAdapter(TJ)
    obs, infos = pz.reset(seed=1)
    ref.reset(seed=1)
    assert infos["car_4"]["action_mask"].tolist() == [1, 0]  # empty slot: only action 0
    assert not infos["car_4"]["illegal_action"] and infos["car_4"]["illegal_action_count"] == 0
    for k in (1, 2):
        obs, rewards, _, _, infos = pz.step({"car_4": 1})  # gas in an empty slot: illegal
        obs_ref, rewards_ref, _, _, _ = ref.step({"car_4": 0})  # its fallback, action 0
        assert infos["car_4"]["illegal_action"] and infos["car_4"]["illegal_action_count"] == k
        assert not infos["car_0"]["illegal_action"] and infos["car_0"]["illegal_action_count"] == 0
        assert pz.illegal_action_count == k
        assert rewards == rewards_ref
        for a in obs:
            np.testing.assert_array_equal(obs[a]["observation"], obs_ref[a]["observation"])
    *_, infos = pz.step({"car_4": 0})
    assert not infos["car_4"]["illegal_action"] and infos["car_4"]["illegal_action_count"] == 2
    _, infos = pz.reset(seed=1)
    assert pz.illegal_action_count == 0 and infos["car_4"]["illegal_action_count"] == 0
    # Out of range is never an action to replace; strict checking is available for debugging.
    with pytest.raises(ValueError, match="outside"):
        pz.step({"car_0": 2})
    strict = envs.make_pettingzoo("traffic_junction", illegal_action="raise")
    strict.reset(seed=1)
    with pytest.raises(ValueError, match=r"illegal action 1 for agent 'car_4'"):
        strict.step({"car_4": 1})
    assert PettingZooAdapter(TJ, illegal_action="noop").illegal_action == "fallback"
