"""Hand-computed dynamics (docs/engine.md#unit-types; docs/engine.md#turn-structure; docs/engine.md#reference-traces): damage, timing, move lengths, ranges,
interpolation, overkill, walkability, evaluations and game end."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybridmarl.engine import rules as R
from hybridmarl.engine import units as U
from hybridmarl.engine.battle import run_battles
from hybridmarl.engine.state import (
    ATTACK,
    MOVE,
    UnitSpec,
    build_state,
    is_walkable_np,
    make_rules,
    parse_ascii_map,
)
from hybridmarl.engine.trace import record_trace

M = "Terran_Marine"

# docs/engine.md#unit-types: rows attackers, columns targets.
DAMAGE_TABLE = {
    "Terran_Marine": [6, 5, 5, 6, 5, 6, 6],
    "Protoss_Zealot": [16, 14, 14, 16, 14, 16, 16],
    "Protoss_Dragoon": [10, 9, 19, 10, 9, 15, 15],
    "Zerg_Zergling": [5, 4, 4, 5, 4, 5, 5],
    "Terran_Firebat": [16, 14, 4, 16, 14, 8, 8],
    "Terran_Vulture": [20, 19, 4, 20, 19, 10, 10],
    "Zerg_Hydralisk": [5, 4, 9, 5, 4, 7, 7],
}
COLUMNS = [
    "Terran_Marine",
    "Protoss_Zealot",
    "Protoss_Dragoon",
    "Zerg_Zergling",
    "Terran_Firebat",
    "Terran_Vulture",
    "Zerg_Hydralisk",
]


def test_full_damage_table():
    for attacker, row in DAMAGE_TABLE.items():
        for target, want in zip(COLUMNS, row, strict=True):
            got = U.TABLES.damage[U.type_id(attacker), U.type_id(target)]
            assert got == want, (attacker, target)


def test_unit_constants():
    m = U.UNIT_TYPES[U.type_id(M)]
    assert m.max_hp == 40 and U.TABLES.range_sq[U.type_id(M)] == 160**2
    assert U.UNIT_TYPES[U.type_id("Protoss_Zealot")].max_hp == 160
    assert U.UNIT_TYPES[U.type_id("Protoss_Dragoon")].max_hp == 180
    assert float(U.TABLES.dpf[U.type_id(M)]) == pytest.approx(0.375)
    assert float(U.TABLES.dpf[U.type_id("Protoss_Zealot")]) == pytest.approx(16 / 23, rel=1e-6)


@pytest.mark.parametrize(
    ("t_atk", "dist", "dur"),
    [(0, 16, 4), (1, 4, 1), (2, 8, 2), (3, 12, 3), (4, 16, 4), (9, 16, 4), (15, 16, 4)],
)
def test_marine_move_length_near_end_of_cooldown(t_atk, dist, dur):
    """16 px in 4 frames normally, int(t_atk * 4) px when the unit can fire in fewer than 4 frames;
    t_atk == 0 means the unit can fire now and uses its cooldown (15) instead."""
    t = U.type_id(M)
    assert U.TABLES.move_dist[t, t_atk] == dist
    assert U.TABLES.move_dur[t, t_atk] == dur


def test_move_lengths_of_other_units_use_double_precision():
    # Zergling: 16/5.49 frames * 5.49 px/frame, truncated in double; Dragoon 16/5 = 3.2 frames.
    assert U.TABLES.move_dist[U.type_id("Protoss_Dragoon"), 0] == int(16 / 5.0 * 5.0)
    assert U.TABLES.move_dist[U.type_id("Zerg_Zergling"), 0] == int((16 / 5.49) * 5.49)
    assert U.TABLES.move_dist[U.type_id("Zerg_Zergling"), 2] == 10  # int(2 * 5.49)


def test_one_v_one_marines_both_die_at_frame_102(rules):
    """docs/engine.md#reference-traces: P0 at (100,100), P1 at (300,100), both AttackClosest: two 16-px moves
    each, shots at t = 8, 27, 42, 57, 72, 87, 102, both dead at t = 102 after 15 turns."""
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 300, 100)]
    tr = record_trace(units, build_state(units), rules, "attack-closest", "attack-closest")
    assert [t.time for t in tr.turns][:3] == [0, 4, 8]
    assert tr.turns[0].actions == ["1 P1 MOVE dest=(284,100)", "0 P0 MOVE dest=(116,100)"]
    assert tr.turns[1].units[0][:2] == (132, 100) and tr.turns[1].units[1][:2] == (268, 100)
    shots = [t.time for t in tr.turns if any("ATTACK" in a for a in t.actions)]
    assert shots == [8, 27, 42, 57, 72, 87, 102]
    # First shot right after a move: can move at t+10, next shot at t+19 (+4 move penalty).
    assert tr.turns[2].units[0][2:] == (18, 27)
    # HP falls by 6 per shot: 40 -> 34 after the first.
    assert tr.turns[2].hp == {0: 34, 1: 34}
    assert tr.turns[3].actions == ["1 P1 RELOAD", "0 P0 RELOAD"] and tr.turns[3].time == 18
    # Repeat shot at 27: can move at 33, next shot at 42.
    assert tr.turns[4].units[0][2:] == (33, 42)
    assert len(tr.turns) == 15 and tr.turns[-1].hp == {0: 0, 1: 0}
    res = run_battles([units], "attack-closest", "attack-closest", progress=False)
    assert int(res.winner[0]) == -1 and int(res.final_time[0]) == 102 and int(res.turns[0]) == 15
    assert int(res.ltd2_eval[0]) == 0


def _state_with(units, **overrides):
    s = build_state(units)
    return s.replace(**{k: jnp.asarray(v, jnp.int32) for k, v in overrides.items()})


def test_overkill_attack_becomes_pass(rules):
    """Two P0 Marines shoot a 6-HP enemy in one turn: the first kills it, the second (higher id)
    PASSes for 20 frames and deals nothing."""
    units = [
        UnitSpec(M, 0, 100, 100),
        UnitSpec(M, 1, 200, 100),
        UnitSpec(M, 0, 100, 110),
        UnitSpec(M, 1, 600, 600),
    ]
    st = build_state(units)
    st = st.replace(
        hp=st.hp.at[1, 0].set(6), t_move=st.t_move.at[1].set(50), t_attack=st.t_attack.at[1].set(50)
    )
    ctx = R.turn_context(st, rules)
    assert bool(ctx.acting[0, 0]) and bool(ctx.acting[0, 1]) and not bool(ctx.acting[1].any())
    actions = jnp.array([[R.ATTACK_BASE + 0, R.ATTACK_BASE + 0], [0, 0]], jnp.int32)
    new = R.apply_actions(st, ctx, actions, rules)
    assert int(new.hp[1, 0]) == 0
    # Killer: first shot (no previous action): can move at 0+8+2, attack at 0+15.
    assert (int(new.t_move[0, 0]), int(new.t_attack[0, 0])) == (10, 15)
    # Overkill: PASS timing; the attack stays its previous action (next shot is a repeat shot).
    assert (int(new.t_move[0, 1]), int(new.t_attack[0, 1])) == (20, 20)
    assert int(new.last[0, 1]) == ATTACK
    classic = make_rules(overkill="classic")
    new_c = R.apply_actions(st, ctx, actions, classic)
    assert (int(new_c.t_move[0, 1]), int(new_c.t_attack[0, 1])) == (10, 15)
    assert int(new_c.hp[1, 0]) == 0


def test_simultaneous_turn_killed_units_still_fire(rules):
    """Both sides act from the same state; a unit killed this turn still deals its damage."""
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 200, 100)]
    st = build_state(units)
    st = st.replace(hp=jnp.array([[6], [6]], jnp.int32))
    ctx = R.turn_context(st, rules)
    assert bool(ctx.movers.all())
    new = R.apply_actions(st, ctx, jnp.array([[R.ATTACK_BASE], [R.ATTACK_BASE]], jnp.int32), rules)
    assert new.hp.tolist() == [[0], [0]]
    assert int(R.winner(new)) == -1 and bool(R.is_terminal(new, rules))


def test_interpolated_position_truncates_toward_zero():
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 400, 100)]
    # Unit moved left 12 px from (100,100) to (88,100) over frames 10..13.
    st = _state_with(
        units,
        x=[[88], [400]],
        px=[[100], [400]],
        t_act=[[10], [0]],
        t_move=[[13], [0]],
        t_attack=[[13], [0]],
        last=[[MOVE], [0]],
    )
    for t, want in [(10, 100), (11, 96), (12, 92), (13, 88), (20, 88)]:
        cx, _ = R.current_positions(st, jnp.int32(t))
        # (dest - prev) * ratio = -12 * 1/3 = -4.0000005 in float32, truncated to -4.
        assert int(cx[0, 0]) == want, t


def test_range_is_centre_to_centre_squared(rules):
    units = [
        UnitSpec(M, 0, 100, 100),
        UnitSpec(M, 1, 260, 100),
        UnitSpec(M, 0, 100, 300),
        UnitSpec(M, 1, 261, 300),
    ]
    ctx = R.turn_context(build_state(units), rules)
    assert bool(ctx.in_range[0, 0, 0]) and not bool(ctx.in_range[0, 1, 1])  # 160 in, 161 out
    legal = R.legal_actions(ctx, 0)
    assert bool(legal[0, R.ATTACK_BASE + 0]) and not bool(legal[1, R.ATTACK_BASE + 1])
    # A unit that can fire but has nothing in range gets only moves (no PASS, no RELOAD).
    assert legal[1].tolist()[:6] == [False, False, True, True, True, True]


def test_walkability_uses_c_truncation():
    grid = np.ones((88, 160), bool)
    assert is_walkable_np(grid, -7, 0) and is_walkable_np(grid, 0, -1)
    assert not is_walkable_np(grid, -8, 0) and not is_walkable_np(grid, 1280, 5)
    assert is_walkable_np(grid, 1279, 703) and not is_walkable_np(grid, 0, 704)
    ok = R.walkable_at(jnp.asarray(grid), jnp.array([-7, -8, 1279, 1280]), jnp.array([0, 0, 0, 0]))
    assert ok.tolist() == [True, False, True, False]


def test_moves_blocked_by_ascii_map(rules):
    grid = parse_ascii_map("4\n3\n1101\n1111\n1111\n")
    assert grid.shape == (3, 4) and not grid[0, 2]
    r = make_rules(grid)
    units = [UnitSpec(M, 0, 12, 4), UnitSpec(M, 1, 28, 20)]
    ctx = R.turn_context(build_state(units), r)
    # From (12,4): left -> (-4,4) tile 0 ok; right -> (28,4) tile (3,0) ok; down (12,20) ok; up (12,-12) off map.
    assert ctx.move_ok[0, 0].tolist() == [True, True, True, False]
    units = [UnitSpec(M, 0, 4, 4), UnitSpec(M, 1, 28, 20)]
    ctx = R.turn_context(build_state(units), r)
    # left -> (-12,4) is tile -1: off the map; right -> (20,4) is tile (2,0): wall
    assert ctx.move_ok[0, 0].tolist() == [False, False, True, False]


def test_ltd_and_ltd2_with_win_bonus():
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 400, 100), UnitSpec(M, 0, 100, 120)]
    st = build_state(units).replace(hp=jnp.array([[40, 10], [40, 0]], jnp.int32))
    # LTD(P0) = int(1000 * (40 + 10) * .375 / (80 * .375)) = 625; P1 full = 1000.
    assert R.ltd(st).tolist() == [625, 1000]
    ltd2_p0 = int(1000 * (np.sqrt(40) + np.sqrt(10)) / (2 * np.sqrt(40)))
    assert R.ltd2(st).tolist() == [ltd2_p0, 1000]
    assert int(R.evaluate(st, 0)) == ltd2_p0 - 1000
    dead = st.replace(hp=jnp.array([[40, 10], [0, 0]], jnp.int32))
    assert int(R.evaluate(dead, 0)) == 1000 + 100000 - 0 - 1000 * 0 + (ltd2_p0 - 1000)


def test_stalemate_ends_game_after_50_unchanged_turns():
    """Two Marines out of range on a map where neither can move: every turn is a PASS (20 frames),
    no HP changes; the counter reaches 51 > 50 after turn 51 and the game ends there."""
    grid = parse_ascii_map("160\n1\n" + "1" + "0" * 158 + "1\n")
    r = make_rules(grid)
    units = [UnitSpec(M, 0, 3, 3), UnitSpec(M, 1, 1275, 3)]
    res = run_battles([units], "attack-closest", "attack-closest", rules=r, progress=False)
    assert int(res.turns[0]) == 51 and int(res.winner[0]) == -1
    assert int(res.final_time[0]) == 51 * 20


def test_turn_cap():
    r = make_rules(max_turns=7)
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 900, 100)]
    res = run_battles([units], "attack-closest", "attack-closest", rules=r, progress=False)
    assert int(res.turns[0]) == 7 and int(res.winner[0]) == -1


def test_who_moves_and_acting_block(rules):
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 400, 100), UnitSpec(M, 0, 100, 120)]
    st = _state_with(units, t_move=[[5, 9], [7, 0]], t_attack=[[5, 3], [7, 0]])
    ctx = R.turn_context(st.replace(hp=jnp.array([[40, 40], [40, 0]], jnp.int32)), rules)
    # P0 free times: 5 and 3; P1: 7 -> only P0 moves, only its unit with free time 3 acts.
    assert ctx.movers.tolist() == [True, False]
    assert ctx.acting.tolist() == [[False, True], [False, False]]


def test_first_legal_action_order(rules):
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 200, 100), UnitSpec(M, 1, 100, 200)]
    ctx = R.turn_context(build_state(units), rules)
    # Both enemies in range; same free time -> first in order is the lower id (slot 0).
    assert int(R.first_legal_action(ctx, 0)[0]) == R.ATTACK_BASE + 0
    # Enemy slot 0 busy until frame 9: SparCraft's order puts slot 1 (free at 0) first.
    st = build_state(units)
    st = st.replace(t_move=st.t_move.at[1, 0].set(9), t_attack=st.t_attack.at[1, 0].set(9))
    ctx = R.turn_context(st, rules)
    assert int(R.first_legal_action(ctx, 0)[0]) == R.ATTACK_BASE + 1
    # In cooldown: RELOAD comes first.
    st = st.replace(t_attack=st.t_attack.at[0, 0].set(5), t_move=st.t_move.at[0, 0].set(0))
    ctx = R.turn_context(st, rules)
    assert int(R.first_legal_action(ctx, 0)[0]) == R.RELOAD_ACTION


def test_no_jit_equals_jit(rules):
    from hybridmarl.engine import scripts as S

    units = [
        UnitSpec(M, 0, 421, 260),
        UnitSpec(M, 1, 567, 300),
        UnitSpec(M, 0, 431, 327),
        UnitSpec(M, 1, 581, 321),
    ]
    st = build_state(units)
    key = jax.random.PRNGKey(0)

    def turn(s):
        c = R.turn_context(s, rules)
        a = jnp.stack([S.nokdps(key, s, c, 0), S.attack_weakest(key, s, c, 1)])
        return R.apply_actions(s, c, a, rules)

    jitted = jax.jit(turn)
    a, b = st, st
    for _ in range(6):
        a = jitted(a)
        with jax.disable_jit():
            b = turn(b)
        for la, lb in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            np.testing.assert_array_equal(np.asarray(la), np.asarray(lb))


@pytest.mark.parametrize(
    ("p0", "p1", "winner", "survivor_hp", "turns", "final_time"),
    [
        ("attack-closest", "attack-weakest", 1, [4, 10], 37, 143),
        ("attack-weakest", "attack-closest", 0, [16], 58, 179),
        ("attack-closest", "attack-closest", 0, [16], 35, 154),
        ("attack-weakest", "attack-weakest", 0, [4], 48, 192),
    ],
)
def test_reference_3v3_outcomes(p0, p1, winner, survivor_hp, turns, final_time):
    """docs/engine.md#reference-traces: the 3v3 Marine state and its four script pairings."""
    units = []
    for a, b in zip(
        [(100, 80), (100, 100), (100, 130)], [(290, 90), (300, 100), (310, 110)], strict=True
    ):
        units += [UnitSpec(M, 0, *a), UnitSpec(M, 1, *b)]
    res = run_battles([units], p0, p1, progress=False)
    assert int(res.winner[0]) == winner
    assert sorted(h for h in res.unit_hp[0] if h > 0) == sorted(survivor_hp)
    assert (int(res.turns[0]), int(res.final_time[0])) == (turns, final_time)
