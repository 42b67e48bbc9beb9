"""Traffic Junction (paper Section 5.3), its PettingZoo adapter and video."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from hybridmarl.envs.base import MultiAgentEnv
from hybridmarl.envs.pettingzoo import PettingZooAdapter
from hybridmarl.envs.traffic_junction import (
    NUM_ROAD_CELLS,
    ROAD_INDEX,
    ROUTE_CELLS,
    ROUTE_LENGTHS,
    TrafficJunction,
    always_gas,
    car_cells,
    epsilon_demonstrator,
    p_arrive_curriculum,
    route_id,
    yield_before_junction,
)
from hybridmarl.envs.video import mp4_supported, write_video

ENV = TrafficJunction()
N = ENV.num_agents
PARAMS = ENV.default_params
QUIET = PARAMS.replace(p_arrive=0.0)  # no arrivals: hand-built states stay as built
STEP = jax.jit(ENV.step)
AVAIL = jax.jit(ENV.get_avail_actions)
OBSERVE = jax.jit(ENV.observe)
CRITIC = jax.jit(ENV.critic_features)
KEY = jax.random.key(0)

# The 12 routes of CommNet's medium junction (row, col), written out independently of the
# implementation's construction. Keys: (entry, turn).
_S = [(r, 6) for r in range(14)]
# fmt: off
EXPECTED_ROUTES: dict[tuple[str, str], list[tuple[int, int]]] = {
    ("N", "straight"): _S,
    ("N", "right"): [(0, 6), (1, 6), (2, 6), (3, 6), (4, 6), (5, 6), (6, 6),
                     (6, 5), (6, 4), (6, 3), (6, 2), (6, 1), (6, 0)],
    ("N", "left"): [(0, 6), (1, 6), (2, 6), (3, 6), (4, 6), (5, 6), (6, 6), (7, 6),
                    (7, 7), (7, 8), (7, 9), (7, 10), (7, 11), (7, 12), (7, 13)],
    ("S", "straight"): [(r, 7) for r in (13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0)],
    ("S", "right"): [(13, 7), (12, 7), (11, 7), (10, 7), (9, 7), (8, 7), (7, 7),
                     (7, 8), (7, 9), (7, 10), (7, 11), (7, 12), (7, 13)],
    ("S", "left"): [(13, 7), (12, 7), (11, 7), (10, 7), (9, 7), (8, 7), (7, 7), (6, 7),
                    (6, 6), (6, 5), (6, 4), (6, 3), (6, 2), (6, 1), (6, 0)],
    ("W", "straight"): [(7, c) for c in range(14)],
    ("W", "right"): [(7, 0), (7, 1), (7, 2), (7, 3), (7, 4), (7, 5), (7, 6),
                     (8, 6), (9, 6), (10, 6), (11, 6), (12, 6), (13, 6)],
    ("W", "left"): [(7, 0), (7, 1), (7, 2), (7, 3), (7, 4), (7, 5), (7, 6), (7, 7),
                    (6, 7), (5, 7), (4, 7), (3, 7), (2, 7), (1, 7), (0, 7)],
    ("E", "straight"): [(6, c) for c in (13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0)],
    ("E", "right"): [(6, 13), (6, 12), (6, 11), (6, 10), (6, 9), (6, 8), (6, 7),
                     (5, 7), (4, 7), (3, 7), (2, 7), (1, 7), (0, 7)],
    ("E", "left"): [(6, 13), (6, 12), (6, 11), (6, 10), (6, 9), (6, 8), (6, 7), (6, 6),
                    (7, 6), (8, 6), (9, 6), (10, 6), (11, 6), (12, 6), (13, 6)],
}
# fmt: on
DIR_ORDER = ("N", "E", "W", "S")  # CommNet's source order
TURN_ORDER = ("straight", "right", "left")


def random_policy(state, key):
    return ((jax.random.uniform(key, (N,)) < 0.6) & state.active).astype(jnp.int32)


def rollout(key, steps=40, params=PARAMS):
    """Random legal actions; per step: (reward, done, collisions, arrivals, active)."""
    _, state = ENV.reset(key, params)

    def body(state, k):
        k_act, k_env = jax.random.split(k)
        obs, state, reward, done, info = ENV.step(k_env, state, random_policy(state, k_act), params)
        del obs
        return state, (reward, done, info["collisions"], info["arrivals"], state.active)

    _, out = jax.lax.scan(body, state, jax.random.split(key, steps))
    return out


ROLLOUT = jax.jit(rollout)


# -- geometry --------------------------------------------------------------------------------


def test_road_cell_count_is_52():
    road = {(r, c) for r in range(14) for c in range(14) if r in (6, 7) or c in (6, 7)}
    assert len(road) == 52 == NUM_ROAD_CELLS
    assert {tuple(map(int, rc)) for rc in np.argwhere(ROAD_INDEX >= 0)} == road
    assert sorted(ROAD_INDEX[ROAD_INDEX >= 0].tolist()) == list(range(52))
    cells = {tuple(c) for r in range(12) for c in ROUTE_CELLS[r, : ROUTE_LENGTHS[r]].tolist()}
    assert cells == road  # the 12 routes cover every road cell and nothing else


@pytest.mark.parametrize(("entry", "turn"), list(EXPECTED_ROUTES))
def test_route_table_matches_reference(entry, turn):
    rid = route_id(entry, turn)
    assert rid == 3 * DIR_ORDER.index(entry) + TURN_ORDER.index(turn)
    expected = EXPECTED_ROUTES[(entry, turn)]
    assert len(expected) == {"right": 13, "straight": 14, "left": 15}[turn]
    assert ROUTE_LENGTHS[rid] == len(expected)
    assert [tuple(c) for c in ROUTE_CELLS[rid, : len(expected)].tolist()] == expected
    assert (ROUTE_CELLS[rid, len(expected) :] == -1).all()
    assert ROUTE_CELLS.shape == (12, 15, 2)


def test_every_route_is_driven_cell_by_cell():
    """A lone car on each route, always gas: visits the table's cells, then arrives (+1)."""
    states = [ENV.make_state([(0, r, 0)]) for r in range(12)]
    batch = jax.tree.map(lambda *xs: jnp.stack(xs), *states)

    def drive(state):
        def body(state, k):
            cell = car_cells(state)[0]
            _, state, reward, _, info = ENV.step(k, state, always_gas(k, state), QUIET)
            return state, (cell, reward, info["arrivals"], state.active[0])

        return jax.lax.scan(body, state, jax.random.split(KEY, 15))[1]

    cells, rewards, arrivals, active = jax.jit(jax.vmap(drive))(batch)
    for entry, turn in EXPECTED_ROUTES:
        rid = route_id(entry, turn)
        expected = EXPECTED_ROUTES[(entry, turn)]
        n = len(expected)
        # Cell before each of the first n-1 steps; the last step lands on the exit cell.
        assert [tuple(c) for c in np.asarray(cells[rid, : n - 1]).tolist()] == expected[:-1]
        assert float(rewards[rid, n - 2]) == 1.0 and int(arrivals[rid, n - 2]) == 1
        assert not bool(active[rid, n - 2])  # removed at once on arrival
        assert float(rewards[rid].sum()) == 1.0


# -- dynamics and rewards ----------------------------------------------------------------------


def test_reset_has_no_cars():
    obs, state = ENV.reset(KEY)
    assert obs.shape == (N, 259) and obs.dtype == jnp.float32
    assert not bool(state.active.any()) and float(obs.sum()) == 0.0
    assert isinstance(ENV, MultiAgentEnv)


def test_collision_gives_minus_10_and_fails():
    ns = route_id("N", "straight")
    state = ENV.make_state([(0, ns, 4), (1, ns, 5)])  # car 0 right behind car 1
    actions = jnp.array([1, 0] + [0] * (N - 2))  # rear-ends: both now in (5, 6)
    _, state, reward, done, info = STEP(KEY, state, actions, QUIET)
    assert float(reward) == -10.0
    assert int(info["collisions"]) == 2 and bool(info["failed"]) and bool(state.failed)
    assert info["collided"][:2].tolist() == [True, True]
    assert not bool(done)
    # Overlapping cars keep colliding until one moves; the episode stays failed.
    _, state, reward, _, info = STEP(KEY, state, jnp.zeros(N, jnp.int32), QUIET)
    assert float(reward) == -10.0 and bool(state.failed)
    _, state, reward, _, info = STEP(KEY, state, actions, QUIET)  # car 0 moves on
    assert float(reward) == 0.0 and int(info["collisions"]) == 0 and bool(info["failed"])
    assert int(state.total_collisions) == 4


def test_crossing_collision_in_junction():
    # N-straight at (5,6) and E-straight at (6,7) both gas into junction cell (6,6).
    state = ENV.make_state([(0, route_id("N", "straight"), 5), (1, route_id("E", "straight"), 6)])
    _, state, reward, _, info = STEP(KEY, state, jnp.array([1, 1] + [0] * (N - 2)), QUIET)
    assert [tuple(c) for c in np.asarray(car_cells(state)[:2]).tolist()] == [(6, 6), (6, 6)]
    assert float(reward) == -10.0 and bool(info["failed"])


def test_arrival_gives_plus_1_and_frees_the_slot():
    rid = route_id("W", "right")
    state = ENV.make_state([(3, rid, int(ROUTE_LENGTHS[rid]) - 2)])
    _, state, reward, _, info = STEP(KEY, state, jnp.zeros(N, jnp.int32).at[3].set(1), QUIET)
    assert float(reward) == 1.0 and int(info["arrivals"]) == 1
    assert not bool(state.active[3]) and int(info["num_active"]) == 0
    assert not bool(info["failed"])


def test_time_penalty_switch():
    state = ENV.make_state([(0, 0, 2), (5, 4, 1)], taus=[3, 7])
    brake = jnp.zeros(N, jnp.int32)
    _, _, reward, _, _ = STEP(KEY, state, brake, QUIET)
    assert float(reward) == 0.0  # default: no time penalty (sparse reward, paper Section 5.3)
    on = QUIET.replace(time_penalty=True)
    _, _, reward, _, info = STEP(KEY, state, brake, on)
    # tau is incremented first: -0.01 * (4 + 8).
    assert float(reward) == pytest.approx(-0.12)
    assert float(info["car_rewards"][0]) == pytest.approx(-0.04)
    assert float(info["car_rewards"][5]) == pytest.approx(-0.08)


def test_combined_reward_sums_terms():
    ns, wr = route_id("N", "straight"), route_id("W", "right")
    state = ENV.make_state([(0, ns, 4), (1, ns, 5), (2, wr, int(ROUTE_LENGTHS[wr]) - 2)])
    actions = jnp.array([1, 0, 1] + [0] * (N - 3))
    _, _, reward, _, info = STEP(KEY, state, actions, QUIET)
    assert float(reward) == -10.0 + 1.0
    assert int(info["collisions"]) == 2 and int(info["arrivals"]) == 1


def test_inactive_gas_is_ignored_and_masks():
    state = ENV.make_state([(3, 0, 2)])
    mask = np.asarray(AVAIL(state))
    assert mask.shape == (N, 2) and mask.dtype == bool
    assert mask[3].tolist() == [True, True]
    assert all(mask[i].tolist() == [True, False] for i in range(N) if i != 3)
    assert np.asarray(ENV.agent_active(state)).tolist() == [i == 3 for i in range(N)]
    _, new, _, _, _ = STEP(KEY, state, jnp.ones(N, jnp.int32), QUIET)
    assert np.asarray(new.active).tolist() == [i == 3 for i in range(N)]


def test_arrivals_order_and_cap():
    """p_arrive = 1: one car per entry per step, in order N, E, W, S, until 10 cars."""
    always = PARAMS.replace(p_arrive=1.0)
    _, state = ENV.reset(KEY)
    brake = jnp.zeros(N, jnp.int32)
    rewards = []
    for k in jax.random.split(KEY, 3):
        _, state, reward, _, info = STEP(k, state, brake, always)
        rewards.append(float(reward))
    assert int(info["num_active"]) == 10
    dirs = np.asarray(state.route)[np.asarray(state.active)] // 3
    assert np.bincount(dirs, minlength=4).tolist() == [3, 3, 2, 2]
    # Step 2 spawned a second car onto each entry; both braked at step 3: 8 colliding cars.
    assert rewards == [0.0, 0.0, -40.0]
    entries = {(0, 6), (6, 13), (7, 0), (13, 7)}
    assert {tuple(c) for c in np.asarray(car_cells(state)).tolist()} == entries


def test_episode_length_and_done():
    rewards, done, collisions, arrivals, _ = ROLLOUT(KEY)
    done = np.asarray(done)
    assert done.shape == (40,) and done[-1] and not done[:-1].any()
    # Global reward r_c * N_c + r_a * N_a (paper Section 5.3).
    expected = -5.0 * np.asarray(collisions) + np.asarray(arrivals)
    np.testing.assert_allclose(np.asarray(rewards), expected)


def test_determinism_same_key_same_trajectory():
    a = ROLLOUT(jax.random.key(7))
    b = ROLLOUT(jax.random.key(7))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    c = ROLLOUT(jax.random.key(8))
    assert not np.array_equal(np.asarray(a[4]), np.asarray(c[4]))


def test_vmap_matches_one_by_one():
    keys = jax.random.split(jax.random.key(3), 4)
    batched = jax.jit(jax.vmap(rollout))(keys)
    for i in range(4):
        single = ROLLOUT(keys[i])
        for x, y in zip(batched, single, strict=True):
            np.testing.assert_allclose(np.asarray(x[i]), np.asarray(y))


# -- observation and critic features -----------------------------------------------------------


def test_observation_layout():
    ns, es = route_id("N", "straight"), route_id("E", "straight")
    state = ENV.make_state([(0, ns, 5), (1, ns, 6), (7, es, 4)])  # (5,6), (6,6), (6,9)
    obs = np.asarray(OBSERVE(state))
    f = 1 + N + 12
    assert obs.shape == (N, 9 * f + 52) == (N, *ENV.observation_shape)
    vision = obs[0, : 9 * f].reshape(9, f)
    centre, below = vision[4], vision[7]
    assert centre[0] == 1 and centre[1 + 0] == 1 and centre[1 + N + ns] == 1
    assert centre.sum() == 3
    assert below[0] == 1 and below[1 + 1] == 1 and below[1 + N + ns] == 1 and below.sum() == 3
    assert vision[[0, 1, 2, 3, 5, 6, 8]].sum() == 0
    location = obs[0, 9 * f :]
    assert location.sum() == 1 and location[10] == 1  # (5,6): rows 0..4 hold 10 road cells
    # Car 7 at (6,9) sees nobody but itself.
    assert obs[7, : 9 * f].reshape(9, f)[4, 1 + 7] == 1 and obs[7, : 9 * f].sum() == 3
    inactive = [i for i in range(N) if i not in (0, 1, 7)]
    assert (obs[inactive] == 0).all()


def test_overlap_is_visible_as_count_two():
    ns = route_id("N", "straight")
    state = ENV.make_state([(0, ns, 3), (4, ns, 3)])
    cell = np.asarray(OBSERVE(state))[0, : 9 * (1 + N + 12)].reshape(9, -1)[4]
    assert cell[0] == 2 and cell[1 + 0] == 1 and cell[1 + 4] == 1 and cell[1 + N + ns] == 2


def test_critic_features_layout():
    ns, nl, es = route_id("N", "straight"), route_id("N", "left"), route_id("E", "straight")
    state = ENV.make_state([(5, ns, 2), (2, nl, 4), (9, es, 1)])
    actions = jnp.zeros(N, jnp.int32).at[5].set(1)
    feats = np.asarray(CRITIC(state, actions))
    width = ENV.observation_shape[0] + 2
    assert feats.shape == (ENV.critic_feature_size,) == (4 * N * width,)
    blocks = feats.reshape(4, N, width)
    obs = np.asarray(OBSERVE(state))
    # North: car 2 (further along) first, then car 5; their actions one-hot at the end.
    np.testing.assert_array_equal(blocks[0, 0, :-2], obs[2])
    np.testing.assert_array_equal(blocks[0, 0, -2:], [1, 0])
    np.testing.assert_array_equal(blocks[0, 1, :-2], obs[5])
    np.testing.assert_array_equal(blocks[0, 1, -2:], [0, 1])
    assert (blocks[0, 2:] == 0).all()
    np.testing.assert_array_equal(blocks[1, 0, :-2], obs[9])  # East
    assert (blocks[1, 1:] == 0).all() and (blocks[2:] == 0).all()  # no W or S cars


# -- demonstrators and curriculum ----------------------------------------------------------------


def test_demonstrators_are_legal_and_jittable():
    ns = route_id("N", "straight")
    state = ENV.make_state([(0, ns, 3), (1, ns, 4), (2, route_id("W", "straight"), 7)])
    assert np.asarray(always_gas(KEY, state)).tolist() == [1, 1, 1] + [0] * (N - 3)
    acts = np.asarray(jax.jit(yield_before_junction)(KEY, state))
    assert acts[3:].tolist() == [0] * (N - 3)
    noisy = jax.jit(epsilon_demonstrator(always_gas, 1.0))(KEY, state)
    assert (np.asarray(noisy)[3:] == 0).all()


def test_yield_rule_cases():
    yield_jit = jax.jit(yield_before_junction)
    ns, es, ws = route_id("N", "straight"), route_id("E", "straight"), route_id("W", "straight")
    # N car at the stop line (5,6), E car inside the junction at (6,7) heading to (6,6): yield.
    state = ENV.make_state([(0, ns, 5), (1, es, 6)])
    assert np.asarray(yield_jit(KEY, state))[:2].tolist() == [0, 1]
    # A platoon with a free road moves together.
    state = ENV.make_state([(0, ns, 1), (1, ns, 2), (2, ns, 3)])
    assert np.asarray(yield_jit(KEY, state))[:3].tolist() == [1, 1, 1]
    # Two stop-line cars with crossing paths: the one that entered earlier goes.
    state = ENV.make_state([(0, ns, 5), (1, ws, 5)], taus=[9, 5])
    assert np.asarray(yield_jit(KEY, state))[:2].tolist() == [1, 0]
    # ... and the car behind the waiting W car waits too.
    state = ENV.make_state([(0, ns, 5), (1, ws, 5), (2, ws, 4)], taus=[9, 5, 4])
    assert np.asarray(yield_jit(KEY, state))[:3].tolist() == [1, 0, 0]


def test_p_arrive_curriculum():
    assert float(p_arrive_curriculum(0)) == pytest.approx(0.05)
    assert float(p_arrive_curriculum(100)) == pytest.approx(0.05)
    assert float(p_arrive_curriculum(150)) == pytest.approx(0.12)  # 0.125 rounded down
    assert float(p_arrive_curriculum(200)) == pytest.approx(0.2)
    assert float(p_arrive_curriculum(10_000)) == pytest.approx(0.2)
    smooth = p_arrive_curriculum(150, start=0.1, end=0.3, start_epoch=0, end_epoch=200, quantum=0)
    assert float(smooth) == pytest.approx(0.25)


# -- PettingZoo adapter, render, video ---------------------------------------------------------


def test_pettingzoo_parallel_api():
    # The array form: the harness samples from the unmasked Discrete space and the adapter's
    # default replaces illegal actions by action 0. tests/envs/test_pettingzoo.py runs defaults.
    parallel_api_test(PettingZooAdapter(ENV, obs_format="array"), num_cycles=45)


def test_pettingzoo_seed():
    parallel_seed_test(lambda: PettingZooAdapter(ENV, obs_format="array"), num_cycles=45)


def test_pettingzoo_illegal_action_raises():
    env = PettingZooAdapter(ENV, illegal_action="raise")
    obs, infos = env.reset(seed=1)
    assert env.agents == [f"car_{i}" for i in range(N)]
    assert infos["car_4"]["action_mask"].tolist() == [1, 0]
    with pytest.raises(ValueError, match=r"illegal action 1 for agent 'car_4'"):
        env.step({"car_4": 1})
    with pytest.raises(ValueError, match="car_0"):
        env.step({"car_0": 2})
    with pytest.raises(ValueError, match="unknown agent"):
        env.step({"bus_0": 0})


def test_pettingzoo_episode_end_and_render():
    env = PettingZooAdapter(ENV, params=PARAMS.replace(p_arrive=0.5), render_mode="rgb_array")
    obs, infos = env.reset(seed=3)
    total = 0.0
    steps = 0
    while env.agents:
        actions = {a: int(infos[a]["action_mask"][1]) for a in env.agents}  # gas where legal
        obs, rewards, terms, truncs, infos = env.step(actions)
        total += rewards["car_0"]
        steps += 1
    assert steps == 40 and all(terms.values()) and not any(truncs.values())
    assert set(infos["car_0"]) >= {"action_mask", "active", "collisions", "failed", "t"}
    assert env.state().shape == (ENV.critic_feature_size,)
    frame = env.render()
    assert frame is not None and frame.shape == (336, 336, 3) and frame.dtype == np.uint8


def test_render_marks_collisions():
    ns = route_id("N", "straight")
    img = ENV.render(ENV.make_state([(0, ns, 3), (1, ns, 3)]))
    assert img.shape == (336, 336, 3) and img.dtype == np.uint8
    cell = img[3 * 24 : 4 * 24, 6 * 24 : 7 * 24]
    assert ((cell[..., 0] > 200) & (cell[..., 1] < 50)).any()  # red frame
    clean = ENV.render(ENV.make_state([(0, ns, 3)]))[3 * 24 : 4 * 24, 6 * 24 : 7 * 24]
    assert not ((clean[..., 0] > 200) & (clean[..., 1] < 50)).any()


def test_write_video(tmp_path):
    from PIL import Image

    frames = [ENV.render(ENV.make_state([(0, 0, p)])) for p in range(3)]
    path = write_video(frames, tmp_path / "sub" / "tj.gif", fps=4)
    with Image.open(path) as im:
        assert im.n_frames == 3 and im.size == (336, 336)
    assert [p.name for p in (tmp_path / "sub").iterdir()] == ["tj.gif"]  # no temp file left
    with pytest.raises(ValueError):
        write_video([], tmp_path / "x.gif")
    if not mp4_supported():
        with pytest.raises(RuntimeError, match="gif is supported"):
            write_video(frames, tmp_path / "x.mp4")
