"""The search players on the native engine (``engine=native``) against the JAX engine
(``engine=jax``): the engine calls return equal arrays, and with deterministic budgets the three
players choose exactly the same moves on the same states.

States: Marine and mixed-type armies padded to 6 slots (start states, where both sides act, and
states a few turns into a game), on the open map and a walled map."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from hybridmarl.engine import rules as R
from hybridmarl.engine.scenarios import state_symmetric
from hybridmarl.engine.state import UnitSpec, build_state, make_rules
from hybridmarl.search import kernels as K
from hybridmarl.search import make_player, play_game_with_players
from hybridmarl.search.base import DeviceArgs, Engine, SearchStats
from hybridmarl.search.native import NativeArgs, pack_state_host, pgs_call, search_call

SLOTS = 6
TYPES = ("Terran_Marine", "Protoss_Zealot", "Protoss_Dragoon", "Terran_Vulture")


def _mixed(rng: np.random.Generator, n: int) -> list[UnitSpec]:
    units = []
    for p in (0, 1):
        for _ in range(n):
            t = TYPES[int(rng.integers(len(TYPES)))]
            units.append(
                UnitSpec(t, p, int(640 + rng.integers(-90, 90)), int(360 + rng.integers(-90, 90)))
            )
    return units


def _walled() -> np.ndarray:
    grid = np.ones((88, 160), bool)
    grid[40:50, 70:85] = False
    grid[30:44, 76:78] = False
    return grid


@pytest.fixture(scope="module")
def cases():
    """(state, rules) decision points on two maps, mixed unit types included."""
    out = []
    open_rules = make_rules()
    wall_rules = make_rules(_walled())
    rng = np.random.default_rng(3)
    starts = [
        (state_symmetric(np.random.default_rng(1), 64, 64, [("Terran_Marine", 3)]), open_rules),
        (state_symmetric(np.random.default_rng(2), 96, 96, [("Terran_Marine", 5)]), open_rules),
        (_mixed(rng, 4), open_rules),
        (_mixed(rng, 6), wall_rules),
    ]
    for i, (units, rules) in enumerate(starts):
        st = build_state(units, SLOTS)
        out.append((st, rules))
        mid = play_game_with_players(
            st, rules, "nokdps", "kiter-dps", max_turns=5 + 4 * i
        ).final_state
        out.append((mid, rules))
    return out


def _movers(state, rules) -> list[int]:
    m = np.asarray(R.turn_context(state, rules).movers)
    return [p for p in (0, 1) if m[p]]


def _decisions(spec: str, cases, seed: int = 7) -> list[tuple[list[int], int, int]]:
    player = make_player(spec)
    player.reset(seed)
    out = []
    for state, rules in cases:
        for p in _movers(state, rules):
            a = player.decide(state, rules, p)
            st = player.stats
            assert st is not None
            out.append((a.tolist(), st.nodes + st.traversals, st.playouts))
    return out


def test_engine_option_resolves():
    assert make_player("uct:engine=jax").engine == "jax"  # type: ignore[attr-defined]
    assert make_player("abcd:engine=native,nodes=5").engine == "native"  # type: ignore[attr-defined]
    auto = "native" if jax.default_backend() == "cpu" else "jax"
    assert make_player("pgs").engine == auto  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="engine"):
        make_player("uct:engine=gpu")


def test_host_packing_matches_jax(cases):
    for state, _ in cases:
        a, ca = K.pack_state(state)
        b, cb = pack_state_host(state)
        assert np.array_equal(a, b)
        for x, y in zip(ca.as_args(), cb.as_args(), strict=True):
            assert np.array_equal(x, y) and x.dtype == y.dtype


def _random_rows(rng, info, m, n):
    """Random legal joint actions (random masks) from a node info."""
    actions = np.zeros((m, 2, n), np.int32)
    mask = rng.random((m, 2)) < 0.75
    for k in range(m):
        for p in (0, 1):
            for u in range(n):
                codes = np.flatnonzero(info["legal"][p, u])
                if len(codes):
                    actions[k, p, u] = rng.choice(codes)
    return actions, mask


@pytest.mark.parametrize(
    ("cap", "use_ltd", "variant"),
    [(0, False, None), (200, False, None), (7, True, None), (200, False, "classic")],
)
def test_search_call_matches_jax(cases, cap, use_ltd, variant):
    """Children, node info (masked to acting units where scripts leave others undefined),
    step / playout MOVE counts and leaf values of random joint actions are equal (``classic``:
    DC-CLASSIC overkill and a stalemate limit of 3 turns)."""
    rng = np.random.default_rng(cap)
    info_scripts = ("nokdps", "kiter-dps", "attack-closest", "cluster")
    playout = ("nokdps", "kiter")
    m = 6
    for state, rules in cases:
        if variant == "classic":
            rules = make_rules(np.asarray(rules.walkable), overkill="classic", stalemate_limit=3)
        root, consts = K.pack_state(state)
        player = make_player("uct:engine=jax")
        jdev = DeviceArgs(consts, rules, "jax")
        eng = Engine(player, jdev, info_scripts, playout, SearchStats())  # type: ignore[arg-type]
        info = eng.info(root)
        actions, mask = _random_rows(rng, info, m, SLOTS)
        do_step = rng.random(m) < 0.9
        for p in (0, 1):
            want = eng.run(m, root, actions, mask, do_step, p, cap, use_ltd)
            got = search_call(
                NativeArgs(consts, rules),
                root,
                actions,
                mask,
                do_step,
                p,
                cap,
                use_ltd,
                info_scripts,
                playout,
                0,
            )
            for key in ("child", "step_moves", "value", "playout_moves", "both_dead"):
                assert np.array_equal(got[key], want[key]), key
            gi, wi = got["info"], want["info"]
            for key in ("movers", "acting", "legal", "order", "terminal", "ev", "hash"):
                assert np.array_equal(gi[key], wi[key]), key
            acting = wi["acting"][:, None]  # [m, 1, 2, U]
            assert np.array_equal(
                np.where(acting, gi["scripts"], 0), np.where(acting, wi["scripts"], 0)
            )


def test_pgs_call_matches_jax(cases):
    rng = np.random.default_rng(5)
    scripts = ("nokdps", "kiter-dps", "attack-weakest")
    k = 9
    for state, rules in cases:
        root, consts = K.pack_state(state)
        assign = rng.integers(0, len(scripts), size=(k, 2, SLOTS)).astype(np.int32)
        player = rng.integers(0, 2, size=k).astype(np.int32)
        fn = K.pgs_fn(SLOTS, k, scripts, 100, K.rules_static(rules))
        want = np.asarray(
            fn(np.zeros(2, np.uint32), root, assign, player, *DeviceArgs(consts, rules, "jax").args)
        )
        got = pgs_call(NativeArgs(consts, rules), root, assign, player, scripts, 100, 0)
        assert np.array_equal(got, want)


SPECS = [
    "uct:time_ms=0,traversals=40",
    "uct:time_ms=0,traversals=80,batch=1",
    "uct:time_ms=0,traversals=60,eval=ltd2,max_children=6",
    "abcd:time_ms=0,nodes=60",
    "abcd:time_ms=0,nodes=150,batch=1",
    "abcd:time_ms=0,nodes=100,eval=ltd,opponent_model=nokdps",
    "pgs:time_ms=0",
    "pgs:time_ms=0,playouts=9,responses=1,lookahead=2",
]


@pytest.mark.parametrize("spec", SPECS)
def test_same_decisions_on_both_engines(spec, cases):
    assert _decisions(f"{spec},engine=native", cases) == _decisions(f"{spec},engine=jax", cases)
