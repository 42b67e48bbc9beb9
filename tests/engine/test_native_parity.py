"""Differential tests: the native engine against the JAX engine on random start states (mixed
unit types, a map with walls and the open default map, both overkill modes, every pair of
deterministic scripts, several army sizes), turn by turn and whole games; conversions, the
NumPy batch builder, input errors, and importing numba and jax in either order."""

from __future__ import annotations

import subprocess
import sys

import jax
import numpy as np
import pytest

from hybridmarl.engine import native
from hybridmarl.engine.battle import run_battles as jax_run_battles
from hybridmarl.engine.native import parity as P
from hybridmarl.engine.scenarios import InputError, named_scenario, parse_states_document
from hybridmarl.engine.state import (
    UnitSpec,
    build_batch,
    build_batch_arrays,
    build_state,
    make_rules,
    stack_states,
)


def _assert_same_tree(a, b):
    for f in a.__dataclass_fields__:
        x, y = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        assert x.dtype == y.dtype and x.shape == y.shape, f
        np.testing.assert_array_equal(x, y, err_msg=f)


def test_lockstep_every_pair_walled_map_overkill_pass():
    """81 games (every ordered pair of the 9 deterministic scripts), 1-6 mixed units a side, on a
    small map with walls: the full state is equal after every turn until every game is over."""
    rng = np.random.default_rng(0)
    grid = P.random_walkable(rng)
    rules = make_rules(grid, overkill="pass")
    p0, p1 = P.all_pairs()
    states = native.build_native_states(P.random_states(rng, len(p0), 6, grid))
    final, turns = P.lockstep(states, rules, p0, p1)
    assert P.games_over(final, rules).all() and turns > 50


def test_lockstep_k_turns_open_map_overkill_classic():
    """Step-by-step equality for the first 30 turns, DC-CLASSIC overkill, up to 12 units a side."""
    rng = np.random.default_rng(1)
    rules = make_rules(overkill="classic")
    p0, p1 = P.all_pairs()
    states = native.build_native_states(
        P.random_states(rng, len(p0), 12, np.asarray(rules.walkable))
    )
    P.lockstep(states, rules, p0, p1, max_turns=30)


@pytest.mark.parametrize(
    ("overkill", "max_side", "walls", "seed"),
    [("classic", 12, False, 2), ("pass", 12, True, 3)],
)
def test_whole_games_every_pair(overkill, max_side, walls, seed):
    """Whole games: final state, winner, final frame, turns and unit actions (LTD2 within 2)."""
    rng = np.random.default_rng(seed)
    grid = P.random_walkable(rng) if walls else None
    rules = make_rules(grid, overkill=overkill)
    p0, p1 = P.all_pairs()
    states = native.build_native_states(
        P.random_states(rng, 2 * len(p0), max_side, np.asarray(rules.walkable))
    )
    cmp = P.compare_whole_games(states, rules, p0 * 2, p1 * 2)
    assert cmp.mismatches == 0, cmp.first_mismatch


def test_run_battles_equals_jax_m30v30():
    """``native.run_battles`` returns what ``battle.run_battles`` returns (m30v30 Marines)."""
    states = named_scenario("m30v30").generate(6, seed=5)
    want = jax_run_battles(states, "attack-closest", "attack-weakest", progress=False)
    got = native.run_battles(states, "attack-closest", "attack-weakest", progress=False)
    assert got.to_document() == want.to_document()
    # LTD2 sums float32 terms; XLA's reduction order may differ from the unit-by-unit sum, so
    # each side's score may be 1 off, and the evaluation (their difference) up to 2.
    assert np.abs(got.ltd2_eval.astype(np.int64) - want.ltd2_eval).max() <= 2
    np.testing.assert_array_equal(got.unit_actions, want.unit_actions)


def test_conversion_round_trip():
    states = P.random_states(np.random.default_rng(6), 5, 7, np.asarray(make_rules().walkable))
    batch = build_batch(states)
    ns = native.from_jax(batch)
    _assert_same_tree(native.to_jax(ns), batch)
    rules = make_rules()
    played = native.advance(ns, rules, "kiter", "nokdps", 25)  # non-trivial timers and positions
    assert P.first_difference(native.from_jax(native.to_jax(played)), played) is None
    single = build_state(states[0], 7)
    _assert_same_tree(native.to_jax(native.from_jax(single), batched=False), single)


def test_numpy_batch_builder_equals_stack_states():
    states = P.random_states(np.random.default_rng(7), 9, 5, np.asarray(make_rules().walkable))
    _assert_same_tree(build_batch(states, 6), stack_states([build_state(s, 6) for s in states]))
    _assert_same_tree(native.to_jax(native.build_native_states(states, 6)), build_batch(states, 6))


def test_single_step_with_external_actions_equals_scripted():
    """``native.step`` with caller-given actions plays exactly what the script would have."""
    rules = make_rules()
    states = native.build_native_states(named_scenario("m5v5").generate(2, seed=1))
    scripted, external = states.copy(), states.copy()
    for _ in range(20):
        acts, _, _ = native.step(scripted, 0, rules, "attack-closest", "nokdps")
        native.apply_actions(external, 0, acts, rules)
    assert P.first_difference(scripted, external) is None


def _error(fn) -> tuple[type, str]:
    with pytest.raises(Exception) as e:  # noqa: B017, PT011
        fn()
    return e.type, str(e.value)


def test_bad_input_same_error_as_jax_path():
    too_many = [UnitSpec("Terran_Marine", 0, 100, 100)] * 513 + [
        UnitSpec("Terran_Marine", 1, 200, 100)
    ]
    doc = {
        "states": [
            {"units": [{"type": u.type, "player": u.player, "x": u.x, "y": u.y} for u in too_many]}
        ]
    }
    assert _error(
        lambda: native.run_battles([too_many], "attack-closest", "kiter", progress=False)
    ) == _error(lambda: parse_states_document(doc))
    unknown = [UnitSpec("Zerg_Ultralisk", 0, 100, 100), UnitSpec("Terran_Marine", 1, 200, 100)]
    doc["states"][0]["units"] = [
        {"type": u.type, "player": u.player, "x": u.x, "y": u.y} for u in unknown
    ]
    kind, message = _error(
        lambda: native.run_battles([unknown], "attack-closest", "kiter", progress=False)
    )
    assert (kind, message) == _error(lambda: parse_states_document(doc))
    assert kind is InputError
    assert _error(lambda: native.run_battles([], "kiter", "kiter", progress=False)) == _error(
        lambda: jax_run_battles([], "kiter", "kiter", progress=False)
    )
    assert _error(lambda: native.run_battles([unknown], "nope", "kiter", progress=False)) == _error(
        lambda: jax_run_battles([unknown], "nope", "kiter", progress=False)
    )


def test_random_script_reproducible_and_legal():
    states = named_scenario("m4v5").generate(16, seed=3)
    a = native.run_battles(states, "random", "attack-closest", seed=7, progress=False)
    b = native.run_battles(states, "random", "attack-closest", seed=7, progress=False)
    c = native.run_battles(states, "random", "attack-closest", seed=8, progress=False)
    assert a.to_document() == b.to_document()
    assert a.to_document() != c.to_document()


@pytest.mark.parametrize("first", ["numba", "jax"])
def test_import_order(first):
    """numba and jax load in either order and both work in one process (the native engine
    runs on its threading layer beside a jitted JAX computation)."""
    second = "jax" if first == "numba" else "numba"
    code = (
        f"import {first}, {second}\n"
        "import jax.numpy as jnp\n"
        "from hybridmarl.engine import native\n"
        "from hybridmarl.engine.scenarios import named_scenario\n"
        "r = native.run_battles(named_scenario('m3v3').generate(4, 0), 'kiter', 'nokdps', progress=False)\n"
        "assert len(r) == 4 and float(jax.jit(lambda x: x * 2)(jnp.float32(2))) == 4.0\n"
        "print(native.threading_layer())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() in ("omp", "tbb", "workqueue")


def test_jax_still_usable_after_native_run():
    native.run_battles(named_scenario("m2v2").generate(3, 0), "kiter", "kiter", progress=False)
    assert float(jax.jit(lambda x: x + 1)(1.0)) == 2.0


@pytest.mark.parametrize("name", ["m5v5", "m3v7", "m18v20-apart"])
def test_generate_arrays_equals_generate(name):
    """The fast array generator draws the same states as ``Scenario.generate``."""
    sc = named_scenario(name)
    want = build_batch_arrays(sc.generate(40, 3))
    got = sc.generate_arrays(40, 3)
    assert got.keys() == want.keys()
    for k in want:
        assert got[k].dtype == want[k].dtype, k
        np.testing.assert_array_equal(got[k], want[k], err_msg=k)


def test_run_battles_from_native_arrays_equals_unit_lists():
    sc = named_scenario("m4v6")
    a = native.run_battles(sc.generate(20, 1), "nokdps", "kiter", progress=False)
    b = native.run_battles(
        native.from_arrays(sc.generate_arrays(20, 1)), "nokdps", "kiter", progress=False
    )
    assert a.to_document() == b.to_document()
