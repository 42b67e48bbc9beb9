"""The DQfD / OGTL baselines: their losses and n-step returns against hand-computed values, the
prioritised replay (sampling proportions, importance weights, the protected demonstration
region), the per-agent rewards on a hand-made 2v2 state, and one smoke run of each learner
through ``hybridmarl train`` / ``hybridmarl eval`` on combat m3v3 (they share every compiled
function, so the second run costs about a second; m3v3 with 4 games and 8 evaluation battles
also shares the start-state and evaluation functions that ``test_algos_cli`` compiles)."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybridmarl.algos.dqfd import PrioritizedReplay
from hybridmarl.cli.main import main
from hybridmarl.engine.state import UnitSpec, build_state
from hybridmarl.envs.combat import CombatState
from hybridmarl.envs.combat.rewards import agent_rewards as combat_agent_rewards
from hybridmarl.envs.combat.rewards import damage_dealt as combat_damage_dealt
from hybridmarl.training.checkpoint import latest_checkpoint, load_checkpoint, subtree
from hybridmarl.training.losses import (
    double_q_bootstrap,
    greedy_agreement,
    huber,
    l2_penalty,
    large_margin_loss,
    legal_max,
    linear_decay,
    nstep_returns,
    reward_unit,
)
from tests.cli.test_learn import _one_json


def _latest(run_dir: Path) -> Path:
    path = latest_checkpoint(run_dir)
    assert path is not None, f"no checkpoint in {run_dir}"
    return path


# -- losses ------------------------------------------------------------------------------------------


def test_double_q_bootstrap_and_legal_max_by_hand():
    q_on = jnp.asarray([[1.0, 5.0, 3.0], [0.0, 0.0, 0.0]])
    q_tg = jnp.asarray([[10.0, 20.0, 30.0], [7.0, 8.0, 9.0]])
    legal = jnp.asarray([[True, False, True], [False, False, False]])
    # Row 0: online argmax over the legal {0: 1, 2: 3} is action 2 -> target net's Q = 30
    # (not the target's own max 20 at the illegal action 1). Row 1: nothing legal -> 0.
    np.testing.assert_allclose(double_q_bootstrap(q_on, q_tg, legal), [30.0, 0.0])
    np.testing.assert_allclose(legal_max(q_on, legal), [3.0, 0.0])


def test_large_margin_loss_by_hand():
    q = jnp.asarray([[1.0, 2.0, 0.5], [1.0, 2.0, 0.5], [3.0, 2.0, 0.5]])
    a_e = jnp.asarray([0, 0, 0])
    legal = jnp.asarray([[True, True, True], [True, False, True], [True, True, True]])
    # Row 0: max(1 + 0, 2 + 0.8, 0.5 + 0.8) - Q(a_E) = 2.8 - 1 = 1.8
    # Row 1: action 1 illegal: max(1, 0.5 + 0.8) - 1 = 0.3
    # Row 2: a_E leads by more than the margin: max(3, 2.8, 1.3) - 3 = 0
    np.testing.assert_allclose(large_margin_loss(q, a_e, legal, 0.8), [1.8, 0.3, 0.0], atol=1e-6)


def test_huber_and_l2_by_hand():
    # |x| <= 1: x^2 / 2 -> 0.125; |x| > 1: |x| - 1/2 -> 1.5
    np.testing.assert_allclose(huber(jnp.asarray([0.5, -2.0])), [0.125, 1.5])
    # 1 + 4 + 9 = 14
    assert float(
        l2_penalty({"a": jnp.asarray([1.0, 2.0]), "b": jnp.asarray([[3.0]])})
    ) == pytest.approx(14.0)


def test_reward_unit_and_the_scaled_losses_by_hand():
    # Per-agent rewards of two agents over three steps: shots of 6 HP of H0 = 200 (0.03), one
    # double hit (0.06), a terminal reward 0.5, zeros; agent 1 is out of play at the last step
    # (its -9 is not counted). Non-zero, in play: 0.03, 0.03, 0.06, 0.03, 0.5 -> median 0.03.
    r = np.asarray([[0.03, 0.0], [-0.03, 0.06], [0.03, 0.5], [0.0, -9.0]])
    valid = np.asarray([[True, True], [True, True], [True, True], [True, False]])
    assert reward_unit(r, valid) == pytest.approx(0.03)
    assert reward_unit(np.zeros((2, 2)), np.ones((2, 2), bool)) == 1.0
    # What the unit does to DQfD's loss. Q of the raw rewards: the demonstrator's action 0 leads
    # by one shot (0.03) on a return scale of 0.1. The Atari margin 0.8 is 27 shots: J_E =
    # 0.8 + 0.07 - 0.10 = 0.77 and its gradient (+1 on Q(a), -1 on Q(a_E)) is 26 times the TD
    # error of a one-shot mistake (huber'(0.03) = 0.03).
    q_raw = jnp.asarray([[0.10, 0.07, -0.2]])
    legal = jnp.ones((1, 3), bool)
    a_e = jnp.asarray([0])
    np.testing.assert_allclose(large_margin_loss(q_raw, a_e, legal, 0.8), [0.77], atol=1e-6)
    np.testing.assert_allclose(jax.grad(lambda x: huber(x))(0.03), 0.03, atol=1e-7)
    # In reward units (divided by 0.03) the same Q-values are 3.33 and 2.33: the margin 0.8 is now
    # most of one shot, J_E = max(3.33, 2.33 + 0.8) - 3.33 = 0 (the lead of one shot already
    # satisfies it), and a TD error of one shot has gradient 1, the margin loss's own size.
    q_units = q_raw / 0.03
    np.testing.assert_allclose(large_margin_loss(q_units, a_e, legal, 0.8), [0.0], atol=1e-6)
    np.testing.assert_allclose(
        large_margin_loss(q_units, jnp.asarray([1]), legal, 0.8), [1.0 + 0.8 - 0.0], atol=1e-5
    )
    np.testing.assert_allclose(jax.grad(lambda x: huber(x))(1.0), 1.0)


def test_linear_decay_and_greedy_agreement_by_hand():
    assert [linear_decay(1.0, e, 100) for e in (0, 25, 100, 300)] == pytest.approx(
        [1.0, 0.75, 0.0, 0.0]
    )
    assert linear_decay(0.5, 10_000, 0) == 0.5
    q = jnp.asarray([[1.0, 3.0, 2.0], [5.0, 1.0, 0.0], [0.0, 0.0, 9.0], [1.0, 1.0, 0.0]])
    legal = jnp.asarray(
        [[True, False, True], [True, True, True], [True, True, False], [True, True, True]]
    )
    expert = jnp.asarray([2, 0, 0, 1])
    choice = jnp.asarray([True, True, False, True])
    # Row 0: legal greedy is 2 (action 1 is illegal) = expert; row 1: 0 = expert; row 2 has no
    # choice (not counted); row 3: tie -> lowest index 0 != 1.  2 of 3.
    matches, count = greedy_agreement(q, legal, expert, choice)
    assert (float(matches), float(count)) == (2.0, 3.0)


def test_nstep_returns_by_hand():
    gamma, n = 0.5, 2
    # One episode of 4 rows, two agents. Agent 0 lives to the end (the game ends with row 3);
    # agent 1 dies in row 1 (its episode ends there).
    r = np.asarray([[1.0, 1.0], [2.0, 1.0], [3.0, 0.0], [4.0, 0.0]])
    ends = np.asarray([[False, False], [False, True], [False, False], [True, True]])
    ret, disc, last = nstep_returns(r, ends, np.zeros(4, int), gamma, n)
    # Agent 0: t0 = 1 + .5*2 = 2 (bootstrap after row 1, gamma^2 = .25); t1 = 2 + .5*3 = 3.5
    # (after row 2); t2 = 3 + .5*4 = 5 but row 3 ends it: no bootstrap; t3 = 4, ended.
    np.testing.assert_allclose(ret[:, 0], [2.0, 3.5, 5.0, 4.0])
    np.testing.assert_allclose(disc[:, 0], [0.25, 0.25, 0.0, 0.0])
    np.testing.assert_array_equal(last[:, 0], [1, 2, 3, 3])
    # Agent 1: t0 = 1 + .5*1 = 1.5, ended at row 1: no bootstrap; t1 = 1, ended.
    np.testing.assert_allclose(ret[:2, 1], [1.5, 1.0])
    np.testing.assert_allclose(disc[:2, 1], [0.0, 0.0])
    # A segment cut short (a dataset's last episode, not ended): bootstrap from its last row.
    ret, disc, last = nstep_returns(
        np.asarray([[1.0], [1.0]]), np.zeros((2, 1), bool), np.asarray([7, 7]), 0.5, 3
    )
    # t0 = 1 + .5*1 = 1.5 over 2 steps -> disc .25, bootstrap after row 1; t1 = 1, disc .5
    np.testing.assert_allclose(ret[:, 0], [1.5, 1.0])
    np.testing.assert_allclose(disc[:, 0], [0.25, 0.5])
    np.testing.assert_array_equal(last[:, 0], [1, 1])


# -- prioritised replay ---------------------------------------------------------------------------------

TEMPLATE = {"x": jax.ShapeDtypeStruct((1,), jnp.int32)}


def _rows(m: int, n: int, start: int) -> dict[str, np.ndarray]:
    return {
        "state.x": np.arange(start, start + m, dtype=np.int32)[:, None],
        "next.x": np.arange(start + 1, start + m + 1, dtype=np.int32)[:, None],
        "actions": np.zeros((m, n), np.int32),
        "agent_reward": np.ones((m, n), np.float32),
        "active": np.ones((m, n), bool),
        "active_next": np.ones((m, n), bool),
    }


def test_per_sampling_proportions_weights_and_protected_demos():
    alpha, beta = 0.4, 0.6
    buf = PrioritizedReplay(4, 3, 2, TEMPLATE, alpha=alpha, eps_agent=0.001, eps_demo=1.0)
    key = next(iter(buf.states))
    buf.add(_rows(3, 2, 100), np.asarray([False, False, True]), np.zeros(3), 0.9, 10, demo=True)
    buf.add(_rows(2, 2, 0), np.asarray([False, True]), np.zeros(2), 0.9, 10)
    # Priorities from TD errors: demo rows get eps_d = 1, agent rows eps_a = 0.001.
    rows = np.asarray([0, 0, 1, 1, 2, 2, 3, 3, 4, 4])
    agents = np.tile([0, 1], 5)
    td = np.asarray([0.0, 1.0, 2.0, 3.0, 0.5, 0.0, 4.0, 0.1, 0.0, 9.0])
    buf.update_priorities(rows, agents, td)
    eps = np.where(rows < 3, 1.0, 0.001)
    p = (td + eps) ** alpha
    np.testing.assert_allclose(buf.cols["prio"][rows, agents], p)
    expect = p / p.sum()
    r, a, w = buf.sample(np.random.default_rng(0), 200_000, beta)
    flat = r * 2 + a
    freq = np.bincount(flat, minlength=14)[[0, 1, 2, 3, 4, 5, 6, 7, 8, 9]] / flat.size
    np.testing.assert_allclose(freq, expect, atol=0.005)
    assert np.all(np.isin(r, [0, 1, 2, 3, 4]))  # only live rows (agent rows 5, 6 are empty)
    # IS weights: (M P(i))^-beta normalised by the largest possible weight (the smallest P).
    m = 10
    w_expect = (m * expect) ** (-beta) / (m * expect.min()) ** (-beta)
    np.testing.assert_allclose(w[:50], w_expect[flat[:50]], rtol=1e-5)
    # Overflow the agent region (capacity 4) twice over: the demonstrations stay as they were.
    demo_before = buf.states[key][:3].copy()
    for start in (10, 20, 30):
        buf.add(_rows(3, 2, start), np.asarray([False, False, True]), np.full(3, start), 0.9, 10)
    np.testing.assert_array_equal(buf.states[key][:3], demo_before)
    assert buf.demo_size == 3 and buf.size == 4
    # The agent region holds the newest 4 rows (30..32 and 22), each pointing at live rows.
    assert sorted(buf.states[key][3:, 0].tolist()) == [22, 30, 31, 32]
    assert set(buf.cols["nidx"][3:].ravel().tolist()) <= {3, 4, 5, 6}
    # drop_demos (OGTL's RL stage): demonstrations are no longer sampled.
    buf.drop_demos()
    r, _, _ = buf.sample(np.random.default_rng(1), 1000, beta)
    assert r.min() >= 3


# -- per-agent rewards (a hand-made 2v2 battle) ---------------------------------------------------------


def _state(hp, last, steps, init_hp=(70, 44)) -> CombatState:
    # Ids interleave: ours slot 0 = id 0, enemy slot 0 = id 1, ours slot 1 = id 2, enemy slot 1 = id 3.
    units = [
        UnitSpec("Terran_Marine", 0, 100, 100),
        UnitSpec("Terran_Marine", 1, 150, 100),
        UnitSpec("Terran_Marine", 0, 100, 120),
        UnitSpec("Terran_Marine", 1, 150, 120),
    ]
    game = dataclasses.replace(build_state(units, 2), hp=jnp.asarray(hp, jnp.int32))
    return CombatState(
        game=game,
        last_actions=jnp.asarray(last, jnp.int32),
        init_hp=jnp.asarray(init_hp, jnp.int32),
        steps=jnp.asarray(steps, jnp.int32),
    )


def test_per_agent_rewards_by_hand():
    # Marines deal 6 per hit. Start: ours HP [40, 30] (H0 = 70), enemy [4, 40]. Both our units
    # attack enemy slot 0 (engine code 6 + 0); the enemy (attack-weakest) hits our slot 1 twice.
    # (This is exactly what the engine does from this state: checked with Combat.step, which
    # gives HP [[40, 18], [0, 40]] and last_actions [[6, 6], [7, 7]], global reward -8/70.)
    s = _state([[40, 30], [4, 40]], [[-1, -1], [-1, -1]], 0)
    s2 = _state([[40, 18], [0, 40]], [[6, 6], [7, 7]], 1)
    # Unit 0 (id 0) fires first: min(6, 4) = 4 dealt. Unit 1's shot finds the target dead: 0.
    np.testing.assert_allclose(combat_damage_dealt(s.game, s2.last_actions[0]), [4.0, 0.0])
    r = combat_agent_rewards(s, s2, jnp.asarray(False), 2)
    # r_0 = (4 - 0) / 70, r_1 = (0 - 12) / 70; they sum to the env's global reward -8/70.
    np.testing.assert_allclose(r, [4 / 70, -12 / 70], rtol=1e-6)
    # A terminal step: enemy HP [4, 3]; unit 0 attacks slot 1 (3 HP), unit 1 attacks slot 0 (4 HP):
    # both die. Ours end with [40, 18]. Shared terminal reward R = (58 - 0) / 70.
    s = _state([[40, 30], [4, 3]], [[-1, -1], [-1, -1]], 5)
    s2 = _state([[40, 18], [0, 0]], [[7, 6], [7, 7]], 6)
    r = combat_agent_rewards(s, s2, jnp.asarray(True), 2)
    # r_0 = 3/70 + 58/70 = 61/70; r_1 = (4 - 12)/70 + 58/70 = 50/70
    np.testing.assert_allclose(r, [61 / 70, 50 / 70], rtol=1e-6)
    # Stepping a finished game (steps unchanged) pays nothing.
    np.testing.assert_allclose(combat_agent_rewards(s2, s2, jnp.asarray(True), 2), [0.0, 0.0])


# -- smoke runs through the CLI ---------------------------------------------------------------------------

TOY = [
    "--preset",
    "toy",
    "--no-progress",
    "--scenario",
    "m3v3",
    "--demonstrator",
    "attack-closest",
    "--enemy",
    "attack-weakest",
]


def test_dqfd_and_ogtl_train_resume_and_eval_m3v3(tmp_path, capsys):
    run = tmp_path / "dqfd"
    assert main(["train", "--algo", "dqfd", *TOY, "--run-dir", str(run)]) == 0
    out = capsys.readouterr().out
    assert (
        "64 demonstration records" in out
        and "pre-trained on demonstrations: 8 updates" in out
        and "eval vs attack-weakest" in out
    )
    for f in ("config.json", "train.csv", "episodes.csv", "eval.json"):
        assert (run / f).is_file(), f
    assert json.loads((run / "eval.json").read_text())["n"] == 8
    with open(run / "train.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows[0]["episodes"] == "0" and {
        "loss",
        "margin_loss",
        "nstep_loss",
        "won_100",
        "epsilon",
        "updates",
    } <= set(rows[0])
    arrays, meta = load_checkpoint(_latest(run))
    assert meta["phase"] == "online" and meta["episodes"] >= 4 and meta["updates"] > 8
    buf = subtree(arrays, "buffer")
    cap, demo_cap, demo_size, _, size = buf["counters"].tolist()
    assert demo_cap == demo_size == 64 and size > 0 and buf["valid"][:64].any()
    # The per-agent damage terms of the real engine's transitions sum to the env's global reward:
    # sum_i r_i - N * [done] R_T = ((hp0' - hp1') - (hp0 - hp1)) / H0 (rows that hold data).
    live = np.r_[np.arange(demo_size), demo_cap + np.arange(size)]
    hp, hp2 = buf["state.game.hp"][live], buf["next.game.hp"][live]
    h0 = buf["state.init_hp"][live, 0].astype(np.float64)
    env_r = ((hp2[:, 0].sum(-1) - hp2[:, 1].sum(-1)) - (hp[:, 0].sum(-1) - hp[:, 1].sum(-1))) / h0
    terminal = (hp2[:, 0].sum(-1) - hp2[:, 1].sum(-1)) / h0
    ended = buf["disc1"][live].max(axis=1) == 0  # game over: every agent's episode ended
    n = buf["reward"].shape[1]
    # The buffer holds the rewards in reward units (the median |r| of the non-zero
    # demonstration rewards; one Marine shot at m3v3 is 6 HP of the 120 allied HP).
    unit = meta["reward_unit"]
    assert unit == pytest.approx(6 / 120, rel=0.02)
    np.testing.assert_allclose(
        buf["reward"][live].sum(1) * unit - np.where(ended, n * terminal, 0.0), env_r, atol=1e-5
    )
    assert env_r.min() < 0 or env_r.max() > 0  # some damage happened
    # --resume continues the same run to a larger budget.
    first = meta
    assert (
        main(
            [
                "train",
                "--algo",
                "dqfd",
                "--run-dir",
                str(run),
                "--resume",
                "--total-episodes",
                "8",
                "--no-progress",
            ]
        )
        == 0
    )
    assert "resumed" in capsys.readouterr().out
    _, meta = load_checkpoint(_latest(run))
    assert meta["episodes"] >= 8
    # Wall and CPU time count across the resume (the first process's time is carried over).
    assert meta["wall_s"] > first["wall_s"] > 0 and meta["cpu_s"] > first["cpu_s"] > 0
    # OGTL: same machinery; with a final margin weight of 0 the demonstrations leave the buffer
    # once the margin loss has decayed (over 2 episodes in 'toy'). With the
    # agreement bonus (constant 0.5 here) every stage-2 agent reward is the per-agent damage
    # reward plus 0.5 per agent that played the script's action.
    og = tmp_path / "ogtl"
    assert (
        main(
            [
                "train",
                "--algo",
                "ogtl",
                *TOY,
                "--run-dir",
                str(og),
                "--agreement-bonus",
                "0.5",
                "--eval-every",
                "2",
                "--lambda-margin-final",
                "0",
            ]
        )
        == 0
    )
    assert "best checkpoint (episode " in capsys.readouterr().out
    # --eval-every kept the best periodically evaluated Q-network; eval --checkpoint best plays it.
    best = json.loads((og / "eval.json").read_text())["best"]
    assert best["n"] == 8 and 0.0 <= best["W"] <= 1.0 and best["selection"]["n"] == 8
    assert main(["eval", "--run-dir", str(og), "--checkpoint", "best", "--n", "8", "--json"]) == 0
    assert _one_json(capsys.readouterr().out)["episodes"] == best["episodes"]
    with open(og / "evals.csv") as f:
        assert {"episodes", "W", "R", "best"} <= set(next(csv.DictReader(f)))
    arrays, meta = load_checkpoint(_latest(og))
    buf = subtree(arrays, "buffer")
    assert not buf["valid"][:64].any()
    cfg = json.loads((og / "config.json").read_text())
    assert (
        cfg["algo"] == "ogtl"
        and cfg["config"]["keep_demos"] is False
        and cfg["config"]["margin_decay_episodes"] == 2
    )
    assert cfg["config"]["agreement_bonus"] == 0.5
    size = int(buf["counters"][4])
    live = demo_cap + np.arange(size)
    hp, hp2 = buf["state.game.hp"][live], buf["next.game.hp"][live]
    h0 = buf["state.init_hp"][live, 0].astype(np.float64)
    env_r = ((hp2[:, 0].sum(-1) - hp2[:, 1].sum(-1)) - (hp[:, 0].sum(-1) - hp[:, 1].sum(-1))) / h0
    terminal = (hp2[:, 0].sum(-1) - hp2[:, 1].sum(-1)) / h0
    ended = buf["disc1"][live].max(axis=1) == 0
    agreeing = (
        buf["reward"][live].sum(1) * meta["reward_unit"]
        - np.where(ended, n * terminal, 0.0)
        - env_r
    ) / 0.5
    np.testing.assert_allclose(agreeing, np.round(agreeing), atol=1e-4)
    assert agreeing.min() > -1e-4 and agreeing.max() <= n + 1e-4 and agreeing.max() >= 1
    with open(og / "train.csv") as f:
        assert {float(r["agreement_bonus"]) for r in list(csv.DictReader(f))[1:]} == {0.5}
    for d in (run, og):
        assert main(["eval", "--run-dir", str(d), "--n", "8", "--json"]) == 0
        res = _one_json(capsys.readouterr().out)
        assert (
            res["n"] == 8
            and res["scenario"] == "m3v3"
            and res["enemy"] == "attack-weakest"
            and 0.0 <= res["W"] <= 1.0
        )


def test_ogtl_agreement_schedule_decays_linearly_and_is_off_by_default():
    from hybridmarl.algos import ogtl

    assert ogtl.agreement_schedule(ogtl.OGTLConfig()) is None
    w = ogtl.agreement_schedule(
        ogtl.OGTLConfig().replace(agreement_bonus=0.2, agreement_decay_episodes=100)
    )
    assert w is not None
    assert [w(0), w(50), w(100), w(500)] == pytest.approx([0.2, 0.1, 0.0, 0.0])
    const = ogtl.agreement_schedule(ogtl.OGTLConfig().replace(agreement_bonus=0.2))
    assert const is not None and const(10_000) == pytest.approx(0.2)


def test_ogtl_leaves_imitation_without_unlearning_it_m3v3(tmp_path, capsys):
    # Stage 1 long enough to imitate (200 updates on the 64 demonstration records), then stage 2
    # with the margin loss's weight decaying from 1 to 0.1 over 2 episodes (the defaults). The
    # train.csv 'agreement' column (greedy action = demonstrator's, on the fixed probe of
    # demonstration states) is in [0, 1] on every row and does not fall at the switch.
    run = tmp_path / "ogtl"
    assert (
        main(
            [
                "train",
                "--algo",
                "ogtl",
                *TOY,
                "--run-dir",
                str(run),
                "--pretrain-updates",
                "200",
                "--total-episodes",
                "8",
            ]
        )
        == 0
    )
    capsys.readouterr()
    with open(run / "train.csv") as f:
        rows = list(csv.DictReader(f))
    agreement = np.asarray([float(r["agreement"]) for r in rows])
    lam = np.asarray([float(r["lambda_margin"]) for r in rows])
    assert np.all((agreement >= 0.0) & (agreement <= 1.0))
    assert rows[0]["episodes"] == "0" and agreement[0] > 0.8  # imitation learned the tactic
    assert lam[1] == 1.0 and lam[-1] == pytest.approx(0.1)  # annealed, not switched
    np.testing.assert_allclose(agreement[1], agreement[0], atol=0.05)  # right after the switch
    assert agreement[1:].min() >= agreement[0] - 0.1  # and through the rest of stage 2


def test_dqfd_team_reward_gives_every_agent_the_global_reward_m3v3(tmp_path, capsys):
    run = tmp_path / "team"
    assert main(["train", "--algo", "dqfd", *TOY, "--run-dir", str(run), "--team-reward"]) == 0
    capsys.readouterr()
    arrays, meta = load_checkpoint(_latest(run))
    buf = subtree(arrays, "buffer")
    _, demo_cap, demo_size, _, size = buf["counters"].tolist()
    live = np.r_[np.arange(demo_size), demo_cap + np.arange(size)]
    hp, hp2 = buf["state.game.hp"][live], buf["next.game.hp"][live]
    h0 = buf["state.init_hp"][live, 0].astype(np.float64)
    # The env's global reward: the change of the HP difference (no terminal term).
    env_r = ((hp2[:, 0].sum(-1) - hp2[:, 1].sum(-1)) - (hp[:, 0].sum(-1) - hp[:, 1].sum(-1))) / h0
    valid = buf["valid"][live]
    got = buf["reward"][live] * meta["reward_unit"]
    np.testing.assert_allclose(
        got[valid], np.broadcast_to(env_r[:, None], got.shape)[valid], atol=1e-5
    )
    assert np.abs(env_r).max() > 0  # some damage happened
