"""Search players (UCT-CD, ABCD, PGS): legality, reproducibility, PGS's playout count, whole
games through the host loop, spec parsing, and SparCraft's child generation order.

Everything runs on 2v2-4v4 Marine states padded to 4 slots, so each compiled program is built
once for the whole module; searches use deterministic budgets."""

from __future__ import annotations

import numpy as np
import pytest

from hybridmarl.engine import rules as R
from hybridmarl.engine.scenarios import state_symmetric
from hybridmarl.engine.state import UnitSpec, build_state
from hybridmarl.search import (
    ABCDPlayer,
    PGSPlayer,
    ScriptPlayer,
    UCTPlayer,
    make_player,
    play_game_with_players,
    run_player_battles,
)
from hybridmarl.search.moves import (
    child_moves,
    odometer_vectors,
    shuffle_move_actions,
    unit_action_lists,
)

M = "Terran_Marine"
SLOTS = 4
UCT = "uct:time_ms=0,traversals=16,batch=8"
ABCD = "abcd:time_ms=0,nodes=40,batch=8,max_children=8"
PGS = "pgs:time_ms=0"


def _sym(n: int, seed: int, spread: int = 64) -> list[UnitSpec]:
    return state_symmetric(np.random.default_rng(seed), spread, spread, [(M, n)])


@pytest.fixture(scope="module")
def decision_states(rules):
    """Decision points: start states (both sides act) and states a few turns into a game."""
    out = []
    for i, n in enumerate((2, 3, 4)):
        st = build_state(_sym(n, i), SLOTS)
        out.append(st)
        mid = play_game_with_players(
            st, rules, "nokdps", "attack-closest", max_turns=6 + 3 * i
        ).final_state
        out.append(mid)
    return out


def _check_legal(state, rules, p: int, actions: np.ndarray) -> None:
    ctx = R.turn_context(state, rules)
    legal = np.asarray(R.legal_actions(ctx, p))
    acting = np.asarray(ctx.acting[p])
    assert actions.shape == (SLOTS,) and actions.dtype == np.int32
    for u in np.flatnonzero(acting):
        assert legal[u, actions[u]], (u, int(actions[u]), legal[u])


@pytest.mark.parametrize("spec", [UCT, ABCD, PGS])
def test_search_players_return_legal_actions(spec, rules, decision_states):
    player = make_player(spec)
    player.reset(3)
    for state in decision_states:
        movers = np.asarray(R.turn_context(state, rules).movers)
        for p in (0, 1):
            if movers[p]:
                _check_legal(state, rules, p, player.decide(state, rules, p))
                assert player.stats is not None and player.stats.ms > 0


@pytest.mark.parametrize("spec", [UCT, ABCD, PGS])
def test_same_seed_same_decisions(spec, rules, decision_states):
    def run(seed: int) -> list[list[int]]:
        player = make_player(spec)
        player.reset(seed)
        out = []
        for state in decision_states[:4]:
            for p in (0, 1):
                if bool(R.turn_context(state, rules).movers[p]):
                    out.append(player.decide(state, rules, p).tolist())
        return out

    assert run(11) == run(11)


def test_uct_stats_and_budget(rules, decision_states):
    player = make_player(UCT)
    player.reset(0)
    player.decide(decision_states[4], rules, 0)
    st = player.stats
    assert st is not None and st.algorithm == "uct"
    assert st.traversals == 16 and st.playouts <= 16 and not st.fallback
    assert st.nodes >= 1 and st.depth >= 1


def test_abcd_node_budget_and_fallback(rules, decision_states):
    state = decision_states[4]
    player = make_player(ABCD)
    player.reset(0)
    player.decide(state, rules, 0)
    st = player.stats
    assert st is not None and st.depth >= 1 and not st.fallback and st.nodes <= 41
    # A budget too small to finish depth 1 falls back to NOKDPS's move.
    tiny = make_player("abcd:time_ms=0,nodes=1")
    tiny.reset(0)
    got = tiny.decide(state, rules, 0)
    assert tiny.stats is not None and tiny.stats.fallback
    want = ScriptPlayer("nokdps").decide(state, rules, 0)
    acting = np.asarray(R.turn_context(state, rules).acting[0])
    assert np.array_equal(got[acting], want[acting])


def test_abcd_batching_does_not_change_the_search(rules, decision_states):
    """Leaf batches and the eldest-leaf prefetch change the engine calls, never the decisions or
    SparCraft's node count: compare with the serial search (batch 1, no prefetch)."""

    def run(batch: int, prefetch: bool) -> list[tuple[list[int], int, int]]:
        player = make_player(f"abcd:time_ms=0,nodes=120,max_children=8,batch={batch}")
        assert isinstance(player, ABCDPlayer)
        player.prefetch = prefetch
        player.reset(5)
        out = []
        for state in decision_states[2:5]:
            for p in (0, 1):
                if bool(R.turn_context(state, rules).movers[p]):
                    a = player.decide(state, rules, p)
                    assert player.stats is not None
                    out.append((a.tolist(), player.stats.nodes, player.stats.depth))
        return out

    serial = run(1, False)
    assert max(d for _, _, d in serial) >= 2
    assert run(8, True) == serial


@pytest.mark.parametrize("n", [2, 3, 4])
def test_pgs_playout_count(n, rules):
    """I = 1, R = 0: 2|P| seed playouts + |P| per living unit = 4 + 2n (docs/baselines.md#pgs)."""
    state = build_state(_sym(n, 20 + n), SLOTS)
    player = make_player(PGS)
    assert isinstance(player, PGSPlayer)
    player.reset(0)
    player.decide(state, rules, 0)
    assert player.stats is not None and player.stats.playouts == 4 + 2 * n


def test_pgs_pair_lookahead_matches_serial(rules, decision_states):
    """Speculative unit pairs (lookahead 2, one engine call per pair) choose exactly what the
    serial search (one call per unit) chooses, and count the same playouts."""

    def run(lookahead: int) -> list[tuple[list[int], int]]:
        player = make_player(f"pgs:time_ms=0,lookahead={lookahead},responses=1")
        player.reset(0)
        out = []
        for state in decision_states[::2]:
            player.decide(state, rules, 1)
            assert player.stats is not None
            out.append((player.decide(state, rules, 1).tolist(), player.stats.playouts))
        return out

    assert run(2) == run(1)


def test_pgs_playout_budget(rules):
    state = build_state(_sym(4, 5), SLOTS)
    player = make_player("pgs:time_ms=0,playouts=6")
    player.reset(0)
    _check_legal(state, rules, 1, player.decide(state, rules, 1))
    assert player.stats is not None and player.stats.playouts == 6


@pytest.mark.parametrize(("p0", "p1"), [(UCT, "nokdps"), ("attack-closest", ABCD)])
def test_whole_game_with_search_player(p0, p1, rules):
    state = build_state(_sym(2, 7, spread=48), SLOTS)
    game = play_game_with_players(state, rules, p0, p1, seed=1)
    assert bool(R.game_over(game.final_state, rules))
    assert game.winner in (-1, 0, 1)
    search_side = 0 if p0.startswith("uct") else 1
    assert len(game.decisions[search_side]) > 0


def test_run_player_battles(rules):
    states = [_sym(2, 30), _sym(4, 31)]  # padded to 4 slots, like the other tests' states
    res = run_player_battles(
        states, "pgs:time_ms=0", "attack-closest", seed=0, rules=rules, progress=False
    )
    assert len(res) == 2 and res.p0 == "pgs:time_ms=0" and res.p1 == "attack-closest"
    assert set(res.winner.tolist()) <= {-1, 0, 1}
    assert [len(h) for h in res.unit_hp] == [4, 8]
    assert (res.turns > 0).all()


def test_make_player_parses_specs():
    p = make_player("uct:time_ms=25,traversals=5000,c=1.6,children=12,playout=attack-closest")
    assert isinstance(p, UCTPlayer)
    o = p.options
    assert (o["time_ms"], o["traversals"], o["c"], o["max_children"]) == (25.0, 5000, 1.6, 12)
    assert (o["playout0"], o["playout1"], o["ordering"]) == (
        "attack-closest",
        "attack-closest",
        ("nokdps", "kiter-dps"),
    )
    uct_c = make_player("UCT:script=AttackClosest")
    assert (
        uct_c.options["ordering"] == ("attack-closest",)
        and uct_c.options["playout1"] == "attack-closest"
    )  # type: ignore[attr-defined]
    for alias in ("ab", "alphabeta", "abcd", "alpha-beta"):
        assert isinstance(make_player(alias), ABCDPlayer)
    ab = make_player("ab:ordering=none,tt=false,fallback=attack-closest", nodes=50, time_ms=0)
    assert isinstance(ab, ABCDPlayer)
    assert ab.options["ordering"] == () and ab.options["tt"] is False and ab.options["nodes"] == 50
    pgs = make_player("pgs:portfolio=nokdps+kiter-dps+attack-closest,iterations=2,responses=1")
    assert isinstance(pgs, PGSPlayer) and pgs.portfolio == ("nokdps", "kiter-dps", "attack-closest")
    assert isinstance(make_player("NOKDPS"), ScriptPlayer)
    assert make_player("attack_weakest").name == "attack-weakest"
    defaults = make_player("uct").options  # type: ignore[attr-defined]
    assert (
        defaults["c"],
        defaults["traversals"],
        defaults["max_children"],
        defaults["time_ms"],
    ) == (1.6, 5000, 20, 40.0)


@pytest.mark.parametrize(
    ("spec", "kwargs", "match"),
    [
        ("minimax", {}, "unknown player"),
        ("uct:foo=1", {}, "unknown option"),
        ("uct:c=abc", {}, "expected a number"),
        ("uct:traversals=1.5", {}, "expected an integer"),
        ("uct:traversals=0", {}, ">= 1"),
        ("uct:c", {}, "key=value"),
        ("uct:c=1,c=2", {}, "given twice"),
        ("uct:playout=nosuchscript", {}, "unknown script"),
        ("uct:player_to_move=sometimes", {}, "one of"),
        ("abcd:time_ms=0", {}, "budget"),
        ("abcd:tt=maybe", {}, "true or false"),
        ("pgs:portfolio=none", {}, "at least one script"),
        ("nokdps:time_ms=5", {}, "take no options"),
        ("nokdps", {"time_ms": 5}, "take no options"),
        ("pgs", {"c": 1.0}, "unknown option"),
        ("", {}, "non-empty"),
    ],
)
def test_make_player_rejects_bad_specs(spec, kwargs, match):
    with pytest.raises(ValueError, match=match):
        make_player(spec, **kwargs)


# ----------------------------------------------------------------------------- move generation


def test_unit_action_lists_follow_generate_moves_order():
    """ATTACK in the enemy's unit order, then RELOAD, MOVE L/R/D/U, PASS only alone."""
    n = 3
    legal = np.zeros((n, 6 + n), bool)
    legal[0, [6, 7, 8, 2, 3, 4, 5]] = True  # can fire: three targets and four moves
    legal[1, [1, 2, 5]] = True  # cooling down: RELOAD and two moves
    legal[2, [0]] = True  # nothing else: PASS
    enemy_order = np.array([30, 10, 20])  # enemy slot 1 first, then 2, then 0
    lists = unit_action_lists(legal, np.array([True, True, True]), enemy_order)
    assert [c.tolist() for c in lists] == [[7, 8, 6, 2, 3, 4, 5], [1, 2, 5], [0]]


def test_shuffle_keeps_last_move_and_shuffles_preceding_action():
    """``shuffleMoveActions`` shuffles [moveBegin, moveEnd): the last MOVE stays last and the last
    non-MOVE action before the block takes part."""
    rng = np.random.default_rng(0)
    seen_first = set()
    for _ in range(200):
        codes = shuffle_move_actions([np.array([7, 6, 2, 3, 4, 5], np.int32)], rng)[0]
        assert codes[0] == 7 and codes[-1] == 5
        assert sorted(codes[1:5].tolist()) == [2, 3, 4, 6]
        seen_first.add(int(codes[1]))
    assert seen_first == {2, 3, 4, 6}
    only_moves = shuffle_move_actions([np.array([2, 3, 4, 5], np.int32)], rng)[0]
    assert only_moves[-1] == 5
    assert shuffle_move_actions([np.array([0], np.int32)], rng)[0].tolist() == [0]


def test_odometer_and_children():
    lists = [np.array([1, 2], np.int32), np.array([3, 4, 5], np.int32)]
    vecs = odometer_vectors(lists, 10)
    assert [v.tolist() for v in vecs] == [[1, 3], [2, 3], [1, 4], [2, 4], [1, 5], [2, 5]]
    legal = np.zeros((2, 8), bool)
    legal[0, [6, 2]] = True
    legal[1, [7, 3]] = True
    acting = np.array([True, True])
    scripts = [np.array([6, 7], np.int32), np.array([6, 3], np.int32)]
    kids = child_moves(legal, acting, np.array([0, 1]), scripts, 4, np.random.default_rng(0))
    assert len(kids) == 4
    assert kids[0].tolist() == [6, 7] and kids[1].tolist() == [6, 3]
    model = child_moves(
        legal,
        acting,
        np.array([0, 1]),
        scripts,
        4,
        np.random.default_rng(0),
        model_move=np.array([2, 3]),
    )
    assert [m.tolist() for m in model] == [[2, 3]]


def test_eval_protocol_with_a_search_player(capsys):
    """``hybridmarl eval --script SPEC`` with a search player (Table 1's UCT_c, A-B_c, Profile)
    plays the protocol's own start states: the host loop with a script in that seat gives
    exactly the env's numbers, and a deterministic search budget repeats itself."""
    import json

    from hybridmarl.cli.main import main
    from hybridmarl.training import evaluate as E
    from hybridmarl.training.task import TaskSpec, make_task

    task = make_task(
        TaskSpec(env="combat", scenario="m3v4", enemy="attack-weakest")
    )  # 4 slots, as above
    by_env = E.evaluate_task(task, None, None, n=4, seed=3, script="attack-closest")
    by_host = E.evaluate_player(task, "attack-closest", n=4, seed=3)
    for k in ("W", "W_ci95", "R", "R_ci95", "losses", "draws"):
        assert by_host[k] == pytest.approx(by_env[k], abs=1e-6), (k, by_host[k], by_env[k])
    assert (
        E.is_search_spec("uct:script=attack-closest")
        and E.is_search_spec("PGS")
        and not E.is_search_spec("nokdps")
    )

    # The module's UCT spec, so its compiled search program is shared with the tests above.
    argv = ["eval", "--script", UCT, "--scenario", "m3v4", "--n", "2", "--seed", "0", "--json"]
    runs = []
    for _ in range(2):
        assert main(argv) == 0
        runs.append(json.loads(capsys.readouterr().out.strip().splitlines()[-1]))
    assert runs[0]["W"] == runs[1]["W"] and runs[0]["R"] == runs[1]["R"] and runs[0]["n"] == 2
    assert runs[0]["policy"] == f"script:{UCT}" and runs[0]["ms_per_decision"] > 0
    assert main(["eval", "--script", "uct:nope=1", "--scenario", "m3v4", "--n", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0], err
    assert main(["eval", "--script", "pgs", "--env", "traffic_junction", "--n", "2"]) == 2
    assert "combat only" in capsys.readouterr().err
    assert (
        main(
            [
                "eval",
                "--script",
                "pgs",
                "--scenario",
                "m3v4",
                "--enemy-run-dir",
                "somewhere",
                "--n",
                "2",
            ]
        )
        == 2
    )
    assert "needs a script enemy" in capsys.readouterr().err
