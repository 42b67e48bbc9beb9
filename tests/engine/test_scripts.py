"""Hand-built situations for script semantics and tie-breaks (docs/engine.md#scripts)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hybridmarl.engine import rules as R
from hybridmarl.engine import scripts as S
from hybridmarl.engine.state import UnitSpec, build_state

M = "Terran_Marine"
KEY = jax.random.PRNGKey(0)


def _decide(name, units, rules, p=0, **fields):
    st = build_state(units)
    if fields:
        st = st.replace(**{k: jnp.asarray(v, jnp.int32) for k, v in fields.items()})
    ctx = R.turn_context(st, rules)
    return [int(a) for a in S.get_script(name)(KEY, st, ctx, p)], st, ctx


def test_attack_closest_vs_weakest_targets(rules):
    # P0 at (100,100); enemies at (200,100) [id 1, full HP] and (100,250) [id 2, 10 HP]; both in range.
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 200, 100), UnitSpec(M, 1, 100, 250)]
    hp = [[40, 0], [40, 10]]
    a, _, _ = _decide("attack-closest", units, rules, hp=hp)
    assert a[0] == R.ATTACK_BASE + 0
    a, _, _ = _decide("attack-weakest", units, rules, hp=hp)
    assert a[0] == R.ATTACK_BASE + 1
    a, _, _ = _decide("attack-dps", units, rules, hp=hp)
    assert a[0] == R.ATTACK_BASE + 1


def test_closest_tie_goes_to_lower_id(rules):
    units = [UnitSpec(M, 0, 500, 300), UnitSpec(M, 1, 500, 800 - 400), UnitSpec(M, 1, 500, 200)]
    # Enemies at distance 100 (id 1 below, id 2 above): equal -> lower id -> slot 0 -> move down (+y).
    a, _, _ = _decide("attack-closest", units, rules, t_attack=[[0, 0], [0, 0]])
    assert a[0] == R.ATTACK_BASE + 0


def test_move_toward_prefers_axis_with_larger_gap_and_tie_order(rules):
    # Enemy 300 px right, 100 px down: step right. Equal |dx| = |dy|: left/right is scored first.
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 400, 200)]
    a, _, _ = _decide("attack-closest", units, rules)
    assert a[0] == 3
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 400, 400)]
    a, _, _ = _decide("attack-closest", units, rules)
    assert a[0] == 3  # right (dist^2 improves equally for right and down; right comes first)


def test_reload_when_in_cooldown_and_closest_in_range(rules):
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 200, 100)]
    a, _, _ = _decide("attack-closest", units, rules, t_attack=[[9], [0]])
    assert a[0] == R.RELOAD_ACTION
    # Kiter retreats instead (moves left, away from the enemy).
    a, _, _ = _decide("kiter", units, rules, t_attack=[[9], [0]])
    assert a[0] == 2
    # Kiter_NOKDPS stops at RELOAD before scoring moves.
    a, _, _ = _decide("kiter-nokdps", units, rules, t_attack=[[9], [0]])
    assert a[0] == R.RELOAD_ACTION


def test_nokdps_avoids_overkill(rules):
    # Two P0 Marines, one enemy at 6 HP and one at 40: the first shoots the 6-HP one (highest
    # dpf/hp), the second sees it reserved (6 - 6 = 0) and shoots the other.
    units = [
        UnitSpec(M, 0, 100, 100),
        UnitSpec(M, 1, 200, 100),
        UnitSpec(M, 0, 100, 120),
        UnitSpec(M, 1, 200, 120),
    ]
    a, _, _ = _decide("nokdps", units, rules, hp=[[40, 40], [6, 40]])
    assert a == [R.ATTACK_BASE + 0, R.ATTACK_BASE + 1]
    a, _, _ = _decide("attack-weakest", units, rules, hp=[[40, 40], [6, 40]])
    assert a == [R.ATTACK_BASE + 0, R.ATTACK_BASE + 0]


def test_attack_weakest_global(rules):
    # Weakest enemy overall (id 3, 5 HP) is out of range: step toward it even though another
    # enemy is in range; in range and able to fire: attack; in range but cooling down: RELOAD.
    units = [
        UnitSpec(M, 0, 100, 100),
        UnitSpec(M, 1, 200, 100),
        UnitSpec(M, 0, 600, 600),
        UnitSpec(M, 1, 100, 500),
    ]
    a, _, _ = _decide("attack-weakest-global", units, rules, hp=[[40, 40], [40, 5]])
    assert a[0] == 4  # down (+y) toward (100, 500)
    assert a[1] == 2  # the unit at (600,600) steps left (|dx| = 500 > |dy| = 100)
    a, _, _ = _decide("attack-weakest", units, rules, hp=[[40, 40], [40, 5]])
    assert a[0] == R.ATTACK_BASE + 0
    units = [
        UnitSpec(M, 0, 100, 100),
        UnitSpec(M, 1, 200, 100),
        UnitSpec(M, 0, 600, 600),
        UnitSpec(M, 1, 100, 150),
    ]
    a, _, _ = _decide("attack-weakest-global", units, rules, hp=[[40, 40], [40, 5]])
    assert a[0] == R.ATTACK_BASE + 1
    a, _, _ = _decide(
        "attack-weakest-global", units, rules, hp=[[40, 40], [40, 5]], t_attack=[[7, 7], [0, 0]]
    )
    assert a[0] == R.RELOAD_ACTION


def test_cluster_moves_toward_centroid(rules):
    units = [UnitSpec(M, 0, 100, 100), UnitSpec(M, 1, 900, 600), UnitSpec(M, 0, 300, 100)]
    a, _, _ = _decide("cluster", units, rules)
    assert a == [3, 2]  # centroid (200, 100): first unit right, second left


def test_closest_enemy_beyond_1000px_falls_back_to_first_in_order(rules):
    units = [UnitSpec(M, 0, 10, 10), UnitSpec(M, 1, 1270, 690), UnitSpec(M, 1, 1200, 10)]
    st = build_state(units)
    ctx = R.turn_context(st, rules)
    # Enemy id 2 is 1190 px away (> 1000): SparCraft's search starts at 1,000,000 and finds
    # nothing, so it returns the first enemy in unit order (slot 0, id 1) though it is further.
    assert int(S.closest_enemy(st, ctx, 0)[0]) == 0
