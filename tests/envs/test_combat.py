"""The combat Dec-POMDP (paper Sections 3 and 5.1) on the JAX SparCraft engine.

Compiled functions are module-level and shared (m3v3, 3 slots per side), so the file compiles each
entry point once; hand-built 2v2 states are padded into the same 3-slot layout.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from hybridmarl import envs
from hybridmarl.engine import game as G
from hybridmarl.engine import rules as R
from hybridmarl.engine.scripts import get_script
from hybridmarl.engine.state import UnitSpec
from hybridmarl.envs.base import MultiAgentEnv
from hybridmarl.envs.combat import (
    ATTACK_OFFSET,
    NOOP,
    SELF_FIELDS,
    UNIT_FIELDS,
    Combat,
    camera_window,
    disk_offsets,
)
from hybridmarl.envs.pettingzoo import PettingZooAdapter
from hybridmarl.envs.traffic_junction import TrafficJunction


class Compiled:
    """``jax.jit(fn)``, compiled on first call for that call's argument shapes with XLA's LLVM
    backend optimisation off: the same optimised HLO program (same semantics), about a third
    less compile time, which dominates this file's runtime on a 2-core machine. Every call of
    one instance must use the same shapes."""

    def __init__(self, fn):
        self.fn = fn
        self.compiled = None

    def __call__(self, *args):
        if self.compiled is None:
            lowered = jax.jit(self.fn).lower(*args)
            self.compiled = lowered.compile({"xla_backend_optimization_level": 0})
        return self.compiled(*args)


ENV = Combat("m3v3")  # enemy: attack-weakest
N = ENV.num_agents
A = ENV.num_actions
STEP = Compiled(ENV.step)
RESET_TO = Compiled(ENV.reset_to)
AVAIL = Compiled(ENV.get_avail_actions)
OBSERVE = Compiled(ENV.observe)
CRITIC = Compiled(ENV.critic_features)
FALLBACK = Compiled(ENV.fallback_actions)
TO_ENGINE = Compiled(ENV.env_to_engine_actions)
TO_ENV = Compiled(ENV.engine_to_env_actions)
SAMPLE = Compiled(ENV.sample_game)
VRESET = Compiled(jax.vmap(ENV.reset))
# Alg. 1's look-ahead over a batch of states, the documented way: vmap(lookahead, (0, 0, 0)).
LOOKAHEAD_B = Compiled(jax.vmap(ENV.lookahead, in_axes=(0, 0, 0)))
BATCH_STEP = Compiled(lambda k, s, a: ENV.batch_step(k, s, a, sub_batch=2))
ENGINE_LEGAL = Compiled(
    lambda g: (
        R.legal_actions(R.turn_context(g, ENV.rules), 0),
        R.turn_context(g, ENV.rules).acting[0],
    )
)
KEY = jax.random.key(0)
M = "Terran_Marine"


def start(units, **timers):
    """A hand-built start state (3 slots per side) with optional per-slot overrides:
    ``hp``/``t_attack``/``t_move`` as ``{(player, slot): value}``."""
    g = ENV.game_state([UnitSpec(M, p, x, y) for p, x, y in units])
    for field, values in timers.items():
        arr = np.asarray(getattr(g, field)).copy()
        for (p, s), v in values.items():
            arr[p, s] = v
        g = g.replace(**{field: jnp.asarray(arr)})
    hp = np.maximum(np.asarray(g.hp), 0)
    return g.replace(prev_hp_sum=jnp.asarray(hp.sum(axis=1), jnp.int32))


def same(a, b) -> bool:
    """Two pytrees of arrays are equal leaf by leaf (compared on the host)."""
    a, b = jax.device_get((a, b))
    return all(
        np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    )


def random_legal(key, mask):
    logits = jnp.where(mask, 0.0, -jnp.inf)
    return jax.random.categorical(key, logits, axis=-1).astype(jnp.int32)


RANDOM_LEGAL = Compiled(random_legal)

# Three-unit geometry used by several tests (ids: A=0, E0=1, B=2, E1=3, C=4, E2=5). Marine range
# is 128 + 32 = 160 px. A reaches E0 (100 px) and E1 (120 px), B reaches E1 (80 px), C nothing.
GEOMETRY = [
    (0, 400, 300),  # A
    (1, 500, 300),  # E0
    (0, 400, 500),  # B
    (1, 400, 420),  # E1
    (0, 250, 300),  # C
    (1, 700, 300),  # E2
]
HPS = {(1, 0): 30, (1, 1): 10, (1, 2): 20}  # ascending HP: E1 (k=0), E2 (k=1), E0 (k=2)


# -- API -------------------------------------------------------------------------------------


def test_spaces_and_protocol():
    assert isinstance(ENV, MultiAgentEnv)
    assert ENV.agents == ("unit_0", "unit_1", "unit_2")
    assert A == 1 + 4 + 3
    assert ENV.observation_shape == (len(SELF_FIELDS) + len(UNIT_FIELDS) * 20,) == (301,)
    assert ENV.critic_feature_size == 35
    assert Combat("m18v20").num_actions == 25 and Combat("m18v20").num_agents == 18


def test_make_and_make_pettingzoo():
    env = envs.make("combat", scenario="m5v5", enemy="attack-closest")
    assert isinstance(env, Combat) and env.num_agents == 5 and env.enemy_name == "attack-closest"
    assert isinstance(envs.make("traffic_junction"), TrafficJunction)
    assert isinstance(envs.make("combat_v0"), Combat)
    pz = envs.make_pettingzoo("combat", scenario="m3v3")
    assert isinstance(pz, PettingZooAdapter) and pz.possible_agents == list(ENV.agents)
    assert isinstance(envs.make_pettingzoo("traffic_junction").env, TrafficJunction)
    with pytest.raises(
        ValueError, match=r"unknown environment 'starcraft'.*combat.*traffic_junction"
    ):
        envs.make("starcraft")
    with pytest.raises(ValueError, match="unknown enemy script"):
        Combat("m3v3", enemy="rush")


# -- reset -----------------------------------------------------------------------------------


def test_reset_is_jittable_vmappable_and_samples_the_disks():
    obs, st = VRESET(jax.random.split(KEY, 64))
    g = st.game
    assert obs.shape == (64, N, 301) and obs.dtype == jnp.float32
    sc = ENV.scenario
    assert sc is not None
    x, y = np.asarray(g.x), np.asarray(g.y)
    for p, (cx, cy), r in ((0, sc.center0, sc.radius0), (1, sc.center1, sc.radius1)):
        assert (((x[:, p] - cx) ** 2 + (y[:, p] - cy) ** 2) <= r * r).all()
    # Ids interleave P0, P1, P0, ... like the host generator.
    assert np.asarray(g.uid)[0].tolist() == [[0, 2, 4], [1, 3, 5]]
    # Every episode starts at a decision point of ours (frame 0: both sides act).
    assert (np.asarray(g.time) == 0).all() and np.asarray(jax.vmap(ENV.agent_active)(st)).all()
    assert np.asarray(st.init_hp).tolist() == [[120, 120]] * 64
    # Different keys, different states; same key, same state.
    assert len({tuple(x[i].ravel()) for i in range(64)}) == 64
    _, again = VRESET(jax.random.split(KEY, 64))
    assert (np.asarray(again.game.x) == x).all()
    # The offset table is exactly the integer disk.
    off = disk_offsets(3)
    assert len(off) == 29 and ((off**2).sum(1) <= 9).all()


def test_reset_from_bank_and_reset_to():
    units = [UnitSpec(M, p, x, y) for p, x, y in GEOMETRY]
    env = Combat(start_states=[units, units[:4]])
    assert env.num_agents == 3 and env.num_enemies == 3 and env.scenario is None
    bank = env.default_params.bank
    assert bank is not None and bank.hp.shape == (2, 2, 3)
    g = jax.jit(env.sample_game)(KEY)
    assert g.hp.shape == (2, 3)
    _, st = RESET_TO(ENV.game_state(units), KEY)
    assert np.asarray(st.game.x).tolist() == [[400, 400, 250], [500, 400, 700]]
    with pytest.raises(ValueError, match="slots"):
        ENV.reset_to(
            Combat("m5v5").game_state([UnitSpec(M, i % 2, 100 + i, 100) for i in range(10)])
        )


# -- rewards, masks, ranks --------------------------------------------------------------------


def test_hand_computed_reward_one_attack_lands():
    """2v2 Marines: A hits E1 (6 damage); E1 is in cooldown and reloads, the rest walk."""
    g = start(
        [(0, 400, 300), (1, 500, 300), (0, 400, 600), (1, 1000, 600)],
        t_attack={(1, 0): 10},
    )
    obs, st = RESET_TO(g, KEY)
    assert np.asarray(st.init_hp).tolist() == [80, 80]
    mask = np.asarray(AVAIL(st))
    assert mask[0, ATTACK_OFFSET + 0] and not mask[0, ATTACK_OFFSET + 1]  # E2 is out of range
    assert mask[2].tolist() == [True] + [False] * (A - 1)  # unit_2 never existed: noop only
    actions = jnp.asarray(
        [ATTACK_OFFSET + 0, 2, NOOP], jnp.int32
    )  # E1 (HP tie -> lower id), B right
    obs, st2, reward, done, info = STEP(KEY, st, actions)
    assert float(reward) == pytest.approx((0 - (-6)) / 80)
    assert np.asarray(st2.game.hp).tolist() == [[40, 40, 0], [34, 40, 0]]
    assert not bool(done) and int(info["illegal_actions"]) == 0
    assert int(info["engine_turns"]) == 1 and int(info["time"]) == 4  # both sides move again at 4
    assert float(info["terminal_hp_reward"]) == pytest.approx(6 / 80)
    assert int(info["allied_hp"]) == 80 and int(info["enemy_hp"]) == 74
    last = np.asarray(st2.last_actions)  # engine codes issued during the step, -1 = none
    assert last[0].tolist() == [R.ATTACK_BASE + 0, 3, -1]
    assert last[1, 0] == R.RELOAD_ACTION and 2 <= last[1, 1] <= 5 and last[1, 2] == -1


def test_masks_and_hp_ranks():
    g = start(GEOMETRY, hp=HPS)
    _, st = RESET_TO(g, KEY)
    mask = np.asarray(AVAIL(st))
    atk = slice(ATTACK_OFFSET, ATTACK_OFFSET + 3)
    assert mask[0, atk].tolist() == [True, False, True]  # k=0 -> E1, k=1 -> E2 (far), k=2 -> E0
    assert mask[1, atk].tolist() == [True, False, False]  # B reaches E1 only
    assert mask[2, atk].tolist() == [False, False, False]
    assert not mask[:, NOOP].any()  # every unit can fire now: SparCraft has no "wait"
    assert mask[:, 1:5].all()
    eng = np.asarray(TO_ENGINE(st, jnp.asarray([5, 6, 7])))
    assert eng.tolist() == [R.ATTACK_BASE + 1, R.ATTACK_BASE + 2, R.ATTACK_BASE + 0]
    assert np.asarray(TO_ENV(st, jnp.asarray(eng))).tolist() == [5, 6, 7]
    assert np.asarray(TO_ENGINE(st, jnp.asarray([1, 2, 4]))).tolist() == [2, 3, 5]
    # Attacking k=0 hits E1 (slot 1), the weakest.
    _, st2, *_ = STEP(KEY, st, jnp.asarray([5, 1, 1]))
    assert int(st2.game.hp[1, 1]) == 10 - 6

    # E1 dead: ranks shift (k=0 -> E2, k=1 -> E0), k=2 no longer exists.
    _, st = RESET_TO(start(GEOMETRY, hp={**HPS, (1, 1): 0}), KEY)
    assert np.asarray(AVAIL(st))[0, atk].tolist() == [False, True, False]

    # A in weapon cooldown (acts now, cannot fire): no attack, noop (= RELOAD) legal.
    # B busy until frame 7: it does not act now, only noop.
    _, st = RESET_TO(
        start(GEOMETRY, hp=HPS, t_attack={(0, 0): 5, (0, 1): 7}, t_move={(0, 1): 7}), KEY
    )
    mask = np.asarray(AVAIL(st))
    assert mask[0].tolist() == [True, True, True, True, True, False, False, False]
    assert mask[1].tolist() == [True] + [False] * (A - 1)
    assert np.asarray(TO_ENGINE(st, jnp.zeros(3, jnp.int32)))[0] == R.RELOAD_ACTION
    assert np.asarray(FALLBACK(st)).tolist() == [NOOP, NOOP, 1]  # C: first move (left)


def test_illegal_actions_fall_back_and_are_counted():
    _, st = RESET_TO(start(GEOMETRY, hp=HPS), KEY)
    bad = jnp.asarray([ATTACK_OFFSET + 1, NOOP, 99], jnp.int32)  # E2 out of range; no wait; junk
    _, s1, r1, _, info = STEP(KEY, st, bad)
    assert int(info["illegal_actions"]) == 3
    fb = FALLBACK(st)
    # A's fallback is SparCraft's first legal action: the first attack in enemy unit order (E0).
    assert np.asarray(fb).tolist() == [ATTACK_OFFSET + 2, ATTACK_OFFSET + 0, 1]
    _, s2, r2, _, info2 = STEP(KEY, st, fb)
    assert int(info2["illegal_actions"]) == 0 and float(r1) == float(r2)
    assert same(s1, s2)


def test_debug_mode_raises_on_illegal_actions():
    dbg = Combat("m3v3", debug=True)
    _, st = RESET_TO(start(GEOMETRY, hp=HPS), KEY)
    mask = AVAIL(st)
    # Concrete (eager) values: a host check raising ValueError at once.
    a = jnp.asarray([6, 5, 1], jnp.int32)
    ok = np.asarray(mask)[np.arange(3), np.asarray(a)]
    with pytest.raises(
        ValueError,
        match=r"illegal action 6 for agent 'unit_0' \(legal actions: \[1, 2, 3, 4, 5, 7\]",
    ):
        dbg._check_legal(a, mask, jnp.asarray(~ok))

    # Traced (under jit / vmap): the same check in a jax.debug.callback.
    @jax.jit
    def check(a):
        ok = jnp.take_along_axis(mask, a[:, None], axis=1)[:, 0]
        dbg._check_legal(a, mask, ~ok)
        return a

    check(jnp.asarray([5, 5, 1], jnp.int32))
    with pytest.raises(Exception, match="illegal action 7 for agent 'unit_1'"):
        jax.block_until_ready(check(jnp.asarray([5, 7, 1], jnp.int32)))
    # dbg.step carries the check (tracing only, no compile); the default env does not.
    a0 = jnp.zeros(3, jnp.int32)
    assert "debug_callback" in str(jax.make_jaxpr(dbg.step)(KEY, st, a0))
    assert "debug_callback" not in str(jax.make_jaxpr(ENV.step)(KEY, st, a0))


def test_masks_agree_with_engine_legal_actions():
    key = jax.random.key(7)
    checked = 0
    for _ in range(3):
        key, k0 = jax.random.split(key)
        _, st = RESET_TO(SAMPLE(k0), k0)
        for _ in range(25):
            mask = np.asarray(AVAIL(st))
            legal, acting = (np.asarray(v) for v in ENGINE_LEGAL(st.game))
            sk = np.sort(
                np.where(
                    np.asarray(st.game.hp[1]) > 0,
                    np.asarray(st.game.hp[1]) * 512 + np.arange(3),
                    1 << 30,
                )
            )
            for i in range(N):
                if not acting[i]:
                    assert mask[i].tolist() == [True] + [False] * (A - 1)
                    continue
                checked += 1
                assert mask[i, NOOP] == (legal[i, R.PASS_ACTION] or legal[i, R.RELOAD_ACTION])
                assert mask[i, 1:5].tolist() == legal[i, 2:6].tolist()
                env_targets = {int(sk[k] % 512) for k in range(3) if mask[i, ATTACK_OFFSET + k]}
                assert env_targets == set(np.flatnonzero(legal[i, R.ATTACK_BASE :]).tolist())
            key, ka, ks = jax.random.split(key, 3)
            _, st, _, done, _ = STEP(ks, st, RANDOM_LEGAL(ka, AVAIL(st)))
            if bool(done):
                break
    assert checked > 20


# -- observations and critic features --------------------------------------------------------


def test_observation_layout():
    _, st = RESET_TO(start(GEOMETRY, hp=HPS), KEY)
    obs = np.asarray(OBSERVE(st))
    o = obs[0]  # unit A at (400, 300)

    def own(f):
        return o[ENV.obs_slice("self", 0, f)]

    assert (
        own("alive") == 1
        and own("x") == pytest.approx(400 / 1280)
        and own("y") == pytest.approx(300 / 704)
    )
    assert own("hp_frac") == 1 and own("hp") == pytest.approx(0.4) and own("can_fire") == 1
    assert own("acting") == 1 and own("moving") == 0 and own("range") == pytest.approx(160 / 256)
    assert own("move_len") == 1 and own("allies_alive") == 1 and own("enemies_alive") == 1
    assert own("type_Terran_Marine") == 1 and own("type_Protoss_Zealot") == 0

    def unit(part, k, f):
        return o[ENV.obs_slice(part, k, f)]

    # Allies by distance: C (150 px, left), then B (200 px, below).
    assert unit("ally", 0, "dx") == pytest.approx(-150 / 256) and unit("ally", 0, "dy") == 0
    assert (
        unit("ally", 0, "dist") == pytest.approx(150 / 256) and unit("ally", 0, "in_my_range") == 1
    )
    assert (
        unit("ally", 1, "dy") == pytest.approx(200 / 256) and unit("ally", 1, "in_its_range") == 0
    )
    assert unit("ally", 0, "hp_rank") == 0 and unit("ally", 0, "ready") == 1
    assert (o[ENV.obs_slice("ally", 2)] == 0).all()  # only two allies: zero padding
    # Enemies by distance: E0 (100), E1 (120), E2 (300); HP ranks E1=0, E2=1, E0=2 of M=3.
    assert unit("enemy", 0, "dx") == pytest.approx(100 / 256)
    assert unit("enemy", 0, "hp") == pytest.approx(0.3) and unit(
        "enemy", 0, "hp_frac"
    ) == pytest.approx(0.75)
    assert [unit("enemy", k, "hp_rank") for k in range(3)] == pytest.approx([3 / 3, 1 / 3, 2 / 3])
    assert [unit("enemy", k, "ready") for k in range(3)] == [1, 1, 0]
    assert [unit("enemy", k, "in_its_range") for k in range(3)] == [1, 1, 0]
    assert unit("enemy", 1, "dy") == pytest.approx(120 / 256)
    assert (o[ENV.obs_slice("enemy", 3)] == 0).all()
    # Own fields sit first, then 10 ally blocks, then 10 enemy blocks of 14.
    assert ENV.obs_slice("ally", 0) == slice(21, 35) and ENV.obs_slice("enemy", 0) == slice(
        161, 175
    )
    # A dead agent's observation is all zero.
    _, st = RESET_TO(start(GEOMETRY, hp={**HPS, (0, 2): 0}), KEY)
    obs = np.asarray(OBSERVE(st))
    assert (obs[2] == 0).all() and obs[
        0, ENV.obs_slice("self", 0, "allies_alive")
    ] == pytest.approx(0.5)


def test_critic_features():
    _, st = RESET_TO(start(GEOMETRY, hp=HPS, t_attack={(1, 2): 8}), KEY)
    f = np.asarray(CRITIC(st, jnp.zeros(3, jnp.int32)))
    assert f.shape == (35,)

    def stats(v):
        v = np.asarray(v, np.float64)
        return [v.mean(), v.var(), v.min(), v.max()]

    ours = [
        1.0,
        *stats([0.4] * 3),
        *stats([0] * 3),
        *stats(np.array([400, 400, 250]) / 256),
        *stats(np.array([300, 500, 300]) / 256),
    ]
    theirs = [
        1.0,
        *stats([0.3, 0.1, 0.2]),
        *stats([0, 0, 8 / 32]),
        *stats(np.array([500, 400, 700]) / 256),
        *stats(np.array([300, 420, 300]) / 256),
    ]
    dist = np.hypot(ours[9] - theirs[9], ours[13] - theirs[13])
    assert f == pytest.approx(np.array([*ours, *theirs, dist]), abs=1e-5)


# -- dynamics --------------------------------------------------------------------------------


def run_episode(key, steps=30):
    key, k0 = jax.random.split(key)
    obs, st = RESET_TO(SAMPLE(k0), k0)
    out = []
    for _ in range(steps):
        key, ka, ks = jax.random.split(key, 3)
        obs, st, r, d, info = STEP(ks, st, RANDOM_LEGAL(ka, AVAIL(st)))
        out.append((np.asarray(obs), float(r), bool(d), int(info["turn"])))
    return out


def test_same_key_same_trajectory():
    a, b = run_episode(jax.random.key(11)), run_episode(jax.random.key(11))
    assert all((x[0] == y[0]).all() and x[1:] == y[1:] for x, y in zip(a, b, strict=True))
    c = run_episode(jax.random.key(12))
    assert any(not (x[0] == y[0]).all() for x, y in zip(a, c, strict=True))


def test_lookahead_equals_individual_steps():
    _, st = RESET_TO(start(GEOMETRY, hp=HPS), KEY)
    mask = AVAIL(st)
    cands = jnp.stack(
        [RANDOM_LEGAL(k, mask) for k in jax.random.split(jax.random.key(3), 5)]
        + [jnp.asarray([ATTACK_OFFSET + 0, ATTACK_OFFSET + 0, 2]), jnp.asarray([7, 0, 99])]
    )
    batch = jax.tree.map(lambda x: jnp.stack([x, x]), st)  # B = 2 copies of the state
    rewards, nxt, dones = LOOKAHEAD_B(jnp.stack([KEY, KEY]), batch, jnp.stack([cands, cands[::-1]]))
    assert rewards.shape == (2, 7) and dones.shape == (2, 7) and nxt.game.hp.shape == (2, 7, 2, 3)
    rewards, nxt, dones = jax.device_get((rewards, nxt, dones))
    for a in range(7):
        _, s, r, d, _ = STEP(KEY, st, cands[a])
        for b, i in ((0, a), (1, 6 - a)):
            # (XLA may vectorise the division differently: equal up to float rounding.)
            assert float(r) == pytest.approx(float(rewards[b, i]), rel=1e-6)
            assert bool(d) == bool(dones[b, i])
            assert same(jax.tree.map(lambda x, b=b, i=i: x[b, i], nxt), s)
    assert len(set(np.asarray(rewards[0]).tolist())) > 1  # candidates differ in outcome


def test_batch_step_equals_vmapped_step():
    """batch_step (compacted enemy-only turns, here in sub-batches of 2) = step game by game."""
    b = 5
    key = jax.random.key(21)
    games = []
    for i in range(b):
        key, k0 = jax.random.split(key)
        _, st = RESET_TO(SAMPLE(k0), k0)
        for _ in range(3 * i):  # spread the games over different phases of a battle
            key, ka, ks = jax.random.split(key, 3)
            _, st, *_ = STEP(ks, st, RANDOM_LEGAL(ka, AVAIL(st)))
        games.append(st)
    states = jax.tree.map(lambda *xs: jnp.stack(xs), *games)
    extra = 0
    for t in range(10):
        keys = jax.random.split(jax.random.fold_in(key, t), b)
        acts = jnp.stack([RANDOM_LEGAL(k, AVAIL(g)) for k, g in zip(keys, games, strict=True)])
        if t % 4 == 1:
            acts = acts.at[0].set(jnp.asarray([99, 0, 7], jnp.int32))  # illegal: fallback
        out = BATCH_STEP(keys, states, acts)
        states = out[1]
        obs, batch, rewards, dones, info = jax.device_get(out)
        for i in range(b):
            o, g, r, d, inf = jax.device_get(STEP(keys[i], games[i], acts[i]))
            assert np.array_equal(o, obs[i]) and bool(d) == bool(dones[i])
            assert float(r) == pytest.approx(float(rewards[i]), rel=1e-6)
            assert all(inf[k] == info[k][i] for k in inf)
            assert same(jax.tree.map(lambda x, i=i: x[i], batch), g)
            games[i] = g
        extra += int((info["engine_turns"] > 1).sum())
    assert extra > 0  # some steps did play enemy-only turns


def test_script_policy_reproduces_the_engine_game():
    """Our side played by attack-closest through the env = the engine's own game, turn for turn;
    a finished game then stays put."""
    g0 = SAMPLE(jax.random.key(5))
    policy = Compiled(ENV.script_policy("attack-closest"))
    _, st = RESET_TO(g0, KEY)
    total, steps, done = 0.0, 0, False
    while not done:
        _, st, r, d, info = STEP(KEY, st, policy(KEY, st))
        assert int(info["illegal_actions"]) == 0
        total, steps, done = total + float(r), steps + 1, bool(d)
    final, _ = Compiled(
        lambda g: G.play_game(
            KEY, g, ENV.rules, get_script("attack-closest"), get_script("attack-weakest")
        )
    )(g0)
    assert np.asarray(st.game.hp).tolist() == np.asarray(final.hp).tolist()
    assert int(st.game.turn) == int(final.turn) and int(info["turn"]) == int(final.turn)
    assert total == pytest.approx(float(info["terminal_hp_reward"]), abs=1e-5)  # balanced start
    assert bool(info["won"]) + bool(info["lost"]) + bool(info["draw"]) == 1
    _, st2, r, d, info2 = STEP(KEY, st, jnp.zeros(N, jnp.int32))
    assert float(r) == 0 and bool(d) and int(info2["engine_turns"]) == 0
    assert same(st.game, st2.game)
    assert not np.asarray(AVAIL(st))[:, 1:].any()


# -- PettingZoo, render ----------------------------------------------------------------------


def test_pettingzoo_parallel_api():
    # The array form: the harness samples from the unmasked space and the adapter's default
    # replaces illegal actions by the fallback. tests/envs/test_pettingzoo.py runs the defaults.
    parallel_api_test(PettingZooAdapter(ENV, obs_format="array"), num_cycles=100)


def test_pettingzoo_seed():
    parallel_seed_test(lambda: PettingZooAdapter(ENV, obs_format="array"), num_cycles=50)


def test_pettingzoo_illegal_raises_and_dead_agents_leave():
    env = PettingZooAdapter(ENV, render_mode="rgb_array", illegal_action="raise")
    obs, infos = env.reset(seed=4)
    assert env.agents == list(ENV.agents)
    assert infos["unit_0"]["action_mask"][NOOP] == 0  # frame 0: every unit can fire
    with pytest.raises(ValueError, match=r"illegal action 0 for agent 'unit_0'"):
        env.step({"unit_0": 0})
    removed: list[str] = []
    while env.agents:
        before = list(env.agents)
        # Attack the weakest enemy in range if possible, else the first legal action.
        legal = {a: np.flatnonzero(infos[a]["action_mask"]) for a in before}
        actions = {
            a: int(next((k for k in legal[a] if k >= ATTACK_OFFSET), legal[a][0])) for a in before
        }
        obs, rewards, terms, truncs, infos = env.step(actions)
        assert set(obs) == set(rewards) == set(terms) == set(infos) == set(before)
        assert not any(truncs.values())
        if env.agents:
            gone = [a for a in before if a not in env.agents]
            assert all(terms[a] and not infos[a]["active"] for a in gone)
            assert all((obs[a]["observation"] == 0).all() for a in gone)
            removed += gone
    assert all(terms.values())
    assert removed  # some of our units died before the end
    frame = env.render()
    assert frame is not None and frame.shape == (376, 640, 3)
    assert env.state().shape == (35,)


def test_render_draws_units_and_attacks():
    g = start([(0, 400, 300), (1, 500, 300), (0, 400, 600), (1, 1000, 600)], t_attack={(1, 0): 10})
    _, st = RESET_TO(g, KEY)
    _, st2, *_ = STEP(KEY, st, jnp.asarray([ATTACK_OFFSET, 2, NOOP], jnp.int32))
    img = ENV.render(st2)
    assert img.shape == (376, 640, 3) and img.dtype == np.uint8
    red = (img[..., 0] > 180) & (img[..., 1] < 80) & (img[..., 2] < 80)
    green = (img[..., 1] > 140) & (img[..., 0] < 90) & (img[..., 2] < 110)
    assert red.sum() > 50 and green.sum() > 50
    # The attack line from A (400,300) to E1 (500,300) at half scale: row 24 + 150, x 200..250.
    line = img[24 + 150, 208:242]
    assert ((line[:, 0] > 200) & (line[:, 1] > 100)).any()
    win = camera_window([st.game, st2.game])
    img2 = ENV.render(st2, window=win)
    assert img2.shape[1] == 640 and img2.shape[0] == 24 + round(win[3] * 640 / win[2])
