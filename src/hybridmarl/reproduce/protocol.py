"""The reproduction protocol, stated once: what is evaluated, on which start states, with which
budgets, and the paper's own numbers to compare with.

Evaluation
    Every reported number is an evaluation on start states drawn with :data:`EVAL_SEED`, a seed
    that no training run, preset or model selection of this package uses (training seeds are
    small integers; a run's own final evaluation uses ``seed + 1`` and its periodic selection
    evaluations ``seed + 2``). Every row of one Table 1 column, and every row of Table 2, is
    played on the same start states, so rows can be compared battle by battle (paired test).
    Combat: the demonstrator-trained model fights the other script (the paper's
    cross-validation: learned from c, it fights w; from w, it fights c); the D row is the
    demonstrator script against the other script.

Metrics
    W, the win rate, with a 95 % Wilson interval; R, the mean terminal hit-points reward, with a
    95 % Student-t interval (paper Section 5.1). A learner row is trained with every seed of the
    budget and reports the mean over seeds and each seed; its W interval is the Wilson interval
    of the pooled battles. Traffic Junction: the failure rate (Wilson) and arrivals per episode.

Paired test
    In each column, "Ours" is compared with the best other row (by W) on the shared start
    states: per start state, each row's outcome is averaged over its seeds, and a two-sided
    paired t-test on the per-state differences gives a p-value for W and for R.

Search rows
    UCT-CD, ABCD and PGS run with deterministic budgets (traversals, nodes, playouts per
    decision, with no wall-clock limit), so a row does not depend on how fast or loaded the
    machine is. At ``cpu`` and ``full`` the UCT and ABCD budgets are what SparCraft itself does
    in the paper's 40 ms on one core (:func:`sparcraft_40ms_budget`, from the army size of the
    scenario); PGS runs its one full improvement pass (I = 1, R = 0), as SparCraft does without a
    time limit. ``--search-budget wallclock`` plays them with the paper's 40 ms per decision
    instead. UCT and A-B search with the row's demonstrator (move ordering and our side's
    playouts) and model the enemy with the enemy's own script (its playouts, SparCraft's
    ``P1Script``): a SparCraft search player is configured with a playout script per side, and
    in the paper's cross-validation the enemy's script is fixed and known. Searching with the
    demonstrator on both sides instead (``--search-model demonstrator``) wins far less; also
    assuming the enemy's script inside the tree (``--search-model enemy-script``, SparCraft's
    ``OpponentModelScript``) turns the search into planning against a known opponent
    (docs/reproducing.md#search-budgets).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

#: Seed of the start states of every reported evaluation (see the module docstring): far from
#: the training seeds and from their ``seed + 1`` / ``seed + 2`` evaluation states.
EVAL_SEED = 20_200_713

#: The paper's combat scenarios (Table 1), in its column order.
SCENARIOS = ("m5v5", "m30v30", "m18v20", "m24v30")
#: Demonstrator letter -> script (Section 5.1: c = attack-closest, w = attack-weakest).
DEMONSTRATORS = {"c": "attack-closest", "w": "attack-weakest"}
#: The other script, which a model learned from this one fights (the paper's cross-validation).
CROSS_ENEMY = {"attack-closest": "attack-weakest", "attack-weakest": "attack-closest"}
#: Table 1's rows, in the paper's order.
TABLE1_ROWS = ("D", "UCT", "A-B", "Profile", "BC", "DQfD", "OGTL", "Ours")
#: Table 2's rows (Traffic Junction, demonstrator always-gas).
TABLE2_ROWS = ("D", "BC", "Ours w/o D", "Ours")
#: Fig. 3's curves and panels (terminal HP reward of training episodes, demonstrator c).
FIG3_CURVES = ("Random", "BC", "DQfD", "OGTL", "Ours")
FIG3_SCENARIOS = ("m18v20", "m24v30")
#: The scripts Profile (PGS) chooses among for each unit: the two demonstrators. The paper finds
#: profile search "limited when the candidate heuristics are both sub-optimal" (Section 5.2),
#: i.e. its candidates are c and w (SparCraft's own default portfolio is NOKDPS + KiterDPS).
PROFILE_PORTFOLIO = "attack-closest+attack-weakest"
#: Table 2's demonstrator.
TJ_DEMONSTRATOR = "always-gas"
#: Fig. 3's curves are the mean of the following this many training episodes (the paper's).
FIG3_WINDOW = 100

TABLES = ("table1", "table2", "fig3")

#: The paper's Table 1: (row, demonstrator letter) -> scenario -> (W, R). "Profile" uses both
#: scripts; its c and w entries are its rows in the c and w halves (it fights w and c).
PAPER_TABLE1: dict[tuple[str, str], dict[str, tuple[float, float]]] = {
    ("D", "c"): {
        "m5v5": (0.43, -0.02),
        "m30v30": (0.75, 0.18),
        "m18v20": (0.32, -0.11),
        "m24v30": (0.12, -0.26),
    },
    ("UCT", "c"): {
        "m5v5": (0.93, 0.06),
        "m30v30": (0.88, 0.20),
        "m18v20": (0.40, -0.14),
        "m24v30": (0.13, -0.25),
    },
    ("A-B", "c"): {
        "m5v5": (0.96, 0.07),
        "m30v30": (0.85, 0.21),
        "m18v20": (0.36, -0.17),
        "m24v30": (0.12, -0.24),
    },
    ("Profile", "c"): {
        "m5v5": (0.84, 0.14),
        "m30v30": (0.99, 0.33),
        "m18v20": (0.61, 0.06),
        "m24v30": (0.30, -0.11),
    },
    ("BC", "c"): {
        "m5v5": (0.42, -0.04),
        "m30v30": (0.76, 0.19),
        "m18v20": (0.28, -0.12),
        "m24v30": (0.10, -0.29),
    },
    ("DQfD", "c"): {
        "m5v5": (0.85, 0.16),
        "m30v30": (0.90, 0.41),
        "m18v20": (0.47, -0.10),
        "m24v30": (0.23, -0.20),
    },
    ("OGTL", "c"): {
        "m5v5": (0.89, 0.08),
        "m30v30": (0.93, 0.46),
        "m18v20": (0.48, -0.07),
        "m24v30": (0.26, -0.16),
    },
    ("Ours", "c"): {
        "m5v5": (0.98, 0.18),
        "m30v30": (1.00, 0.51),
        "m18v20": (0.87, 0.24),
        "m24v30": (0.76, 0.19),
    },
    ("D", "w"): {
        "m5v5": (0.61, 0.02),
        "m30v30": (0.13, -0.23),
        "m18v20": (0.03, -0.36),
        "m24v30": (0.00, -0.49),
    },
    ("UCT", "w"): {
        "m5v5": (0.93, 0.01),
        "m30v30": (0.73, 0.09),
        "m18v20": (0.37, -0.19),
        "m24v30": (0.00, -0.36),
    },
    ("A-B", "w"): {
        "m5v5": (0.92, 0.02),
        "m30v30": (0.71, 0.09),
        "m18v20": (0.34, -0.26),
        "m24v30": (0.00, -0.38),
    },
    ("Profile", "w"): {
        "m5v5": (0.91, 0.16),
        "m30v30": (0.96, 0.21),
        "m18v20": (0.39, -0.08),
        "m24v30": (0.02, -0.29),
    },
    ("BC", "w"): {
        "m5v5": (0.60, 0.02),
        "m30v30": (0.13, -0.23),
        "m18v20": (0.02, -0.37),
        "m24v30": (0.01, -0.49),
    },
    ("DQfD", "w"): {
        "m5v5": (0.89, 0.08),
        "m30v30": (0.81, 0.17),
        "m18v20": (0.30, -0.14),
        "m24v30": (0.03, -0.37),
    },
    ("OGTL", "w"): {
        "m5v5": (0.97, 0.09),
        "m30v30": (0.78, 0.15),
        "m18v20": (0.36, -0.12),
        "m24v30": (0.06, -0.38),
    },
    ("Ours", "w"): {
        "m5v5": (0.99, 0.19),
        "m30v30": (0.91, 0.22),
        "m18v20": (0.71, 0.16),
        "m24v30": (0.58, 0.03),
    },
}

#: The paper's Table 2: row -> failure rate (its "FR (%)" row reads 0.72, 0.72, 0.35, 0.19,
#: i.e. fractions). The paper reports no arrivals.
PAPER_TABLE2: dict[str, float] = {"D": 0.72, "BC": 0.72, "Ours w/o D": 0.35, "Ours": 0.19}


@dataclass(frozen=True)
class Learner:
    """How a learner row is trained: ``hybridmarl.train(PRESETS[preset](env).replace(**overrides))``
    of ``hybridmarl.algos.algo_module(algo)``, with the task's fields (scenario, demonstrator,
    enemy, setting, seed, run directory) set by the grid."""

    algo: str
    preset: str
    overrides: dict[str, object] = field(default_factory=dict)
    #: Extra overrides for combat scenarios other than m5v5 (the larger battles).
    large_overrides: dict[str, object] = field(default_factory=dict)


#: Alg. 1 as the actor's start stalls into draws on the larger scenarios at the 'quick' budget;
#: starting it from the demonstrator is what docs/reproducing.md uses at m18v20.
_LARGE_QUICK: dict[str, object] = {"brd_start": "demonstrator"}
#: Table 2's "w/o D" on top of any hybrid preset (as the hybrid presets 'wo-d'/'quick-wo-d').
_WITHOUT_D: dict[str, object] = {
    "pretrain_critic": False,
    "brd_start": "actor",
    "lookahead_policy": "start",
}


@dataclass(frozen=True)
class Budget:
    """What every cell of the grid gets at one budget.

    - ``eval_battles``: combat battles per evaluated policy (all rows of a column share them);
      ``eval_episodes_tj``: Traffic Junction episodes per row.
    - ``seeds``: training seeds of each learner row (Table 1, Table 2, Fig. 3).
    - ``learners``: row -> :class:`Learner` (algo, preset, overrides).
    - ``search``: search row -> player options (deterministic budgets, no wall clock);
      ``{traversals}`` and ``{nodes}`` stand for :func:`sparcraft_40ms_budget` of the scenario.
    - ``wallclock_search``: the same rows under the paper's 40 ms per decision.
    """

    name: str
    doc: str
    eval_battles: int
    eval_episodes_tj: int
    seeds: tuple[int, ...]
    learners: dict[str, Learner]
    search: dict[str, str]
    wallclock_search: dict[str, str] = field(
        default_factory=lambda: {"UCT": "time_ms=40", "A-B": "time_ms=40", "Profile": "time_ms=40"}
    )


def _learners(
    preset: str,
    hybrid: str,
    hybrid_wo_d: str,
    *,
    large: dict[str, object],
    wo_d_overrides: dict[str, object],
    random_overrides: dict[str, object] | None = None,
) -> dict[str, Learner]:
    return {
        "BC": Learner("bc", preset),
        "DQfD": Learner("dqfd", preset),
        "OGTL": Learner("ogtl", preset),
        "Ours": Learner("hybrid", hybrid, large_overrides=large),
        "Ours w/o D": Learner("hybrid", hybrid_wo_d, overrides=wo_d_overrides),
        # Fig. 3's "Random": the network starts from random weights, no demonstrations.
        "Random": Learner(
            "hybrid", hybrid_wo_d, overrides={**wo_d_overrides, **(random_overrides or {})}
        ),
    }


#: The search rows of 'cpu' and 'full': SparCraft's 40 ms as counts, per scenario.
_SEARCH_40MS: dict[str, str] = {
    "UCT": "traversals={traversals},time_ms=0",
    "A-B": "nodes={nodes},time_ms=0",
    "Profile": "time_ms=0",
}

#: The three budgets, by name.
BUDGETS: dict[str, Budget] = {
    "smoke": Budget(
        name="smoke",
        doc=(
            "Minutes on a 2-core CPU, for tests and for checking the pipeline: every learner's "
            "'toy' preset (a few episodes, tiny networks: the numbers mean nothing), one seed, "
            "8 combat battles and 16 Traffic Junction episodes per row, search players with "
            "tiny deterministic budgets (UCT 4 traversals, ABCD 8 nodes, PGS 2 playouts)."
        ),
        eval_battles=8,
        eval_episodes_tj=16,
        seeds=(0,),
        learners=_learners("toy", "toy", "toy", large={}, wo_d_overrides=_WITHOUT_D),
        search={
            "UCT": "traversals=4,time_ms=0",
            "A-B": "nodes=8,time_ms=0",
            "Profile": "playouts=2,time_ms=0",
        },
    ),
    "cpu": Budget(
        name="cpu",
        doc=(
            "Meant to fill every cell on one 2-core CPU machine: the learners' 'quick' presets "
            "(Ours: 'quick', with --brd-start demonstrator beyond m5v5; w/o D: 'quick-wo-d'; "
            "Random: 'quick-wo-d' with the one-step Q, --lookahead-steps 1), seeds 0, 1, 2, 1,000 battles (Traffic Junction: 1,000 episodes) per "
            "row, search players with fixed budgets per decision: UCT and ABCD what SparCraft "
            "searches in 40 ms on one core (m5v5: 240 traversals, 350 nodes; m18v20: 90 and 175; "
            "m30v30 and m24v30: 52 and 112), PGS its full I=1, R=0 improvement pass."
        ),
        eval_battles=1000,
        eval_episodes_tj=1000,
        seeds=(0, 1, 2),
        # Random with Eq. 2's one-step Q: quick-wo-d's look-ahead, continued by the actor's own
        # network, runs on the JAX engine at about 1.6 episodes a minute at m18v20 (30 hours for
        # 3,000 episodes); the one-step Q runs on the native engine (3,000 episodes in ~11 min).
        learners=_learners(
            "quick",
            "quick",
            "quick-wo-d",
            large=_LARGE_QUICK,
            wo_d_overrides={},
            random_overrides={"lookahead_steps": 1},
        ),
        search=dict(_SEARCH_40MS),
    ),
    "full": Budget(
        name="full",
        doc=(
            "The paper's scale: the learners' 'paper' presets (Section 5.1 hyper-parameters; "
            "hybrid 'wo-d' for w/o D and Random), seeds 0, 1, 2, 1,000 battles (Traffic "
            "Junction: 1,000 episodes) per row, search players as at 'cpu' (SparCraft's 40 ms "
            "on one core as fixed counts; PGS I=1, R=0). Days of CPU time; meant for a cluster "
            "(--address)."
        ),
        eval_battles=1000,
        eval_episodes_tj=1000,
        seeds=(0, 1, 2),
        learners=_learners("paper", "paper", "wo-d", large={}, wo_d_overrides={}),
        search=dict(_SEARCH_40MS),
    ),
}

#: SparCraft's own search in 40 ms of one core, n vs n Marines -> (UCT-CD traversals, ABCD nodes
#: expanded) per decision: the upper ends of the ranges measured on SparCraft's current build
#: (docs/reproducing.md#search-budgets).
SPARCRAFT_40MS: dict[int, tuple[int, int]] = {
    8: (240, 350),
    16: (105, 200),
    32: (45, 100),
    50: (25, 50),
}


def army_sizes(scenario: str) -> tuple[int, int]:
    """The two army sizes (A, B) of a paper scenario named ``mAvB``."""
    m = re.fullmatch(r"m(\d+)v(\d+)", scenario)
    if m is None:
        raise ValueError(f"no army size in scenario name {scenario!r}")
    return int(m.group(1)), int(m.group(2))


def sparcraft_40ms_budget(scenario: str) -> dict[str, int]:
    """``{"traversals": T, "nodes": N}``: what SparCraft searches in 40 ms for the larger army of
    ``scenario`` (``mAvB``), linearly interpolated between the measured army sizes of
    :data:`SPARCRAFT_40MS` (held at the ends: 8 below 8 units, 50 above 50)."""
    units = max(army_sizes(scenario))
    sizes = sorted(SPARCRAFT_40MS)
    # np.interp holds the end values outside the measured sizes.
    t, n = (
        round(float(np.interp(units, sizes, [SPARCRAFT_40MS[k][i] for k in sizes]))) for i in (0, 1)
    )
    return {"traversals": t, "nodes": n}


#: How the search rows are budgeted: fixed counts (the default) or the paper's wall clock.
SEARCH_BUDGETS = ("fixed", "wallclock")

#: What UCT and A-B assume of the enemy (``--search-model``; the first is the default), with the
#: words Table 1's text uses for it (docs/reproducing.md#search-budgets).
SEARCH_MODELS: dict[str, str] = {
    "enemy-playouts": "playing the enemy's own script in its playouts",
    "enemy-script": "assuming the enemy's own script in the tree and in its playouts",
    "demonstrator": "playing the row's demonstrator in the enemy's playouts",
}

__all__ = [
    "BUDGETS",
    "CROSS_ENEMY",
    "DEMONSTRATORS",
    "EVAL_SEED",
    "FIG3_CURVES",
    "FIG3_SCENARIOS",
    "FIG3_WINDOW",
    "PAPER_TABLE1",
    "PAPER_TABLE2",
    "PROFILE_PORTFOLIO",
    "SCENARIOS",
    "SEARCH_BUDGETS",
    "SEARCH_MODELS",
    "SPARCRAFT_40MS",
    "TABLE1_ROWS",
    "TABLE2_ROWS",
    "TABLES",
    "TJ_DEMONSTRATOR",
    "Budget",
    "Learner",
    "army_sizes",
    "sparcraft_40ms_budget",
]
