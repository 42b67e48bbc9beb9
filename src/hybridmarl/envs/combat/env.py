"""SparCraft combat as a cooperative Dec-POMDP (Peng, Xing & Cao, IJCAI 2020, Sections 3 and 5.1).

.. list-table::

   * - Import
     - ``from hybridmarl.envs.combat import Combat`` (or ``hybridmarl.envs.make("combat")``)
   * - Agents
     - ``unit_0`` .. ``unit_{n0-1}``: one per unit of player 0 (ours), in ascending SparCraft id
   * - Actions
     - ``Discrete(1 + 4 + M)``, ``M`` = number of enemy units at the start (10 for m5v5)
   * - Observation shape
     - ``(21 + 14 * (10 + 10),) = (301,)`` float32
   * - Critic features
     - ``(35,)`` float32
   * - Enemy
     - a SparCraft script (default ``attack-weakest``) played inside the environment
   * - Version
     - ``combat_v0``

Description
-----------
Our side (player 0) is a team of learning agents, one per unit; the enemy (player 1) is
scripted and "modeled as a part of the environment" (Section 5.1). The simulator is the
frame-exact JAX SparCraft engine (``hybridmarl.engine``, DC-HEAD rules, sparcraft.md §2), so
one environment *step* is one of **our decision turns**:

1. The engine computes the turn context once (who acts, positions, ranges, legal actions).
2. Our acting units' actions and, on a simultaneous turn, the enemy script's actions for its
   acting units are applied together by ``rules.apply_actions`` (P1's first, then P0's, damage
   at once: exactly SparCraft's ``Game::playNextTurn``).
3. Turns on which only the enemy acts are then played at once (``lax.while_loop``) until one of
   our units can act again or the game is over. ``info["engine_turns"]`` counts the engine
   turns a step played (1 + enemy-only turns).

``reset`` does the same enemy-only advance, so every non-terminal state an agent sees is a
decision point of ours. (From the scenario generators every game starts with a simultaneous
turn at frame 0; only a hand-made start state can begin with enemy-only turns, whose damage is
then part of the start, not of any reward.) Stepping a finished game changes nothing (reward 0,
``engine_turns`` 0); there is no auto-reset.

Units that do not act at a decision point keep doing what they were doing (a Marine in the
middle of a move or attack animation); their agents have only ``noop`` legal, and it changes
nothing. A dead unit's agent gets an all-zero observation and only ``noop``.

Start states
------------
``reset(key)`` draws a start state inside JAX (jittable, vmappable):

- from the scenario generator (default): for ``m<A>v<B>`` two disks of integer pixels, each
  unit uniform over the disk of its side (the host generator ``Scenario.generate``'s
  distribution, made exact and jittable by precomputing, in NumPy at construction, the table of
  all integer offsets with ``dx^2 + dy^2 <= r^2`` and choosing among them with
  ``jax.random.randint``); units interleave P0, P1, P0, ... so ids alternate like SparCraft's
  generators. ``separated`` and ``symmetric`` scenario kinds are sampled the same way;
- or uniformly from a bank of fixed start states (``Combat(start_states=...)`` with unit lists or
  a stacked ``GameState``, ``Combat.from_states_file(path)`` for a ``{"states": [...]}`` JSON
  file; the bank is ``params.bank``, a pytree leaf, so swapping banks of one shape does not
  recompile).

``reset_to(game, key)`` starts from one explicit ``GameState`` (jittable; use it to evaluate on
fixed states, e.g. ``jax.vmap(env.reset_to)(stacked_states, keys)``). ``env.game_state(units)``
builds a correctly padded ``GameState`` from ``UnitSpec`` lists.

Action space (Section 5.1: "noop, move[1, ..., directions] and attack[1, ..., enemy_ids]")
-----------------------------------------------------------------------------------------
``Discrete(1 + 4 + M)`` per agent:

- ``0`` **noop**. The engine action it stands for is SparCraft's only way of not acting:
  RELOAD ("wait until the weapon is ready") when the unit is in weapon cooldown, PASS when the
  engine would generate PASS (nothing else is possible). **noop is legal exactly when that
  engine action is legal**: SparCraft generates RELOAD iff the unit cannot fire now and PASS
  only if nothing else is legal, so a unit that *can fire now* has no noop (sparcraft.md §2.5:
  "A unit that can attack but has nothing in range gets only MOVE actions. It cannot wait.").
  This keeps the env's legal set a bijection of the engine's, so scripted demonstrations map
  to env actions and back exactly. For units that do not act this turn (or are dead, or the
  game is over) noop is the only legal action and does nothing.
- ``1..4`` **move** left (-x), right (+x), down (+y), up (-y): the engine's MOVE 2..5 in
  SparCraft's direction order (``Constants::Move_Dir``); the length is the engine's (16 px for
  a Marine, shorter just before it can fire again). Legal iff the unit acts now and the
  destination is walkable.
- ``5 + k`` **attack** the k-th *living* enemy in ascending order of current HP, ties to the
  lower unit id (Section 5.1: "arranged in ascending order of the remaining hit points").
  Legal iff that enemy exists and is alive, is in the unit's range now, and the unit acts now
  and can fire now (not in cooldown). ``k`` past the number of living enemies is illegal.

``get_avail_actions(state)`` is the bool mask ``[n0, 1 + 4 + M]``; for acting units it is
the engine's ``rules.legal_actions`` re-indexed (tested).

Illegal actions. The pure ``step`` (under ``jit``/``vmap``) replaces an illegal (or out of
range) action by the engine's fallback ``rules.first_legal_action`` (SparCraft's scripts'
"first legal action": the first attack in enemy unit order, else RELOAD, else the first
walkable move, else PASS). Whenever noop is legal this fallback *is* noop, so in practice:
illegal -> noop where noop is legal, else the first legal action. ``info["illegal_actions"]``
counts the replaced actions of the step; ``fallback_actions(state)`` gives the replacement per
agent as env actions. With ``Combat(debug=True)`` an illegal action is an error instead: a
``ValueError`` naming the agent, its action and its legal actions when ``step`` runs eagerly,
or (under ``jit``) the same message raised from a ``jax.debug.callback``, which surfaces as a
``JaxRuntimeError``. The PettingZoo adapter raises ``ValueError`` by default.

Observation (per agent, float32, length ``21 + 14 * (K_a + K_e)``, ``K_a = K_e = 10``)
-----------------------------------------------------------------------------------
Section 5.1: "the attributes of the corresponding unit, the ten closest allied units and ten
closest enemy units ... in ascending order of the distance to the corresponding unit ...
filled with 0". Scales: positions and distances in units of 256 px (``POS_SCALE``), HP in
units of 100 (``HP_SCALE``), frame counts in units of 32 frames (``TIME_SCALE``, about a
Marine's cooldown plus the move penalty). Positions are *current* (mid-move units
interpolated, as the engine and the scripts see them).

``obs[0:21]`` own unit (:data:`SELF_FIELDS`):

==== ==================== ==========================================================
 0   ``alive``            1 (a dead agent's whole observation is 0)
 1   ``x``                x / map width (px)
 2   ``y``                y / map height (px)
 3   ``hp_frac``          HP / max HP
 4   ``hp``               HP / 100
 5   ``move_wait``        frames until it can move, / 32 (clipped at 0)
 6   ``attack_wait``      frames until it can attack (weapon cooldown), / 32 (clipped at 0)
 7   ``moving``           1 while in the middle of a move
 8   ``can_fire``         1 if it can attack now (``timeCanAttack <= timeCanMove``)
 9   ``acting``           1 if it chooses an action at this decision point
 10  ``range``            weapon range + 32 px (SparCraft's range addition), / 256
 11  ``move_len``         length of a move generated now, / 16 px
 12  ``allies_alive``     living allies other than itself / max(n0 - 1, 1)
 13  ``enemies_alive``    living enemies / M
 14+ ``type_*``           one-hot of the unit type (7 SparCraft types, ``units.TYPE_NAMES``)
==== ==================== ==========================================================

then ``K_a`` ally blocks and ``K_e`` enemy blocks of 14 values (:data:`UNIT_FIELDS`); block ``b``
of the allies starts at ``21 + 14 * b``, block ``b`` of the enemies at ``21 + 14 * (K_a + b)``.
Blocks hold the closest living units (allies: other than itself), nearest first (squared
distance, ties to the lower id); missing units give all-zero blocks:

==== ==================== ==========================================================
 0   ``alive``            1 for a real, living unit
 1   ``hp_frac``          HP / max HP
 2   ``hp``               HP / 100
 3   ``move_wait``        frames until it can move, / 32
 4   ``attack_wait``      frames until it can attack, / 32
 5   ``moving``           1 while in the middle of a move
 6   ``range``            its weapon range + 32 px, / 256
 7   ``hp_rank``          enemies: (k + 1) / M where ``5 + k`` is the action attacking it; allies: 0
 8   ``dx``               (its x - my x) / 256
 9   ``dy``               (its y - my y) / 256
 10  ``dist``             distance / 256
 11  ``in_my_range``      it is within my weapon range
 12  ``in_its_range``     I am within its weapon range
 13  ``ready``            enemies: attacking it is legal for me now; allies: it acts now
==== ==================== ==========================================================

Critic features (Sections 4 and 5.1; ``(35,)`` float32)
-------------------------------------------------------
"the statistical properties of all allied and enemy units, respectively, such as the mean and
variance of the current HP, weapon cooldown, and positions". For ours (``[0:17]``) then the
enemy's (``[17:34]``), over living units (all 0 for a side with none):

- ``[0]`` living units / slots of that side (n0 or M);
- ``[1:5]`` HP / 100: mean, variance, min, max;
- ``[5:9]`` remaining cooldown ``max(timeCanAttack - now, 0)`` / 32: mean, variance, min, max;
- ``[9:13]`` x / 256: mean, variance, min, max;
- ``[13:17]`` y / 256: mean, variance, min, max;

and ``[34]`` the distance between the two sides' centroids / 256 (0 if a side is empty).
Variances are population variances of the scaled values. ``critic_features(state, actions)``
ignores ``actions``: the paper's critic is a state-value network ``V(s)``; Alg. 1's
``Q(s, A) = r + lambda V(s')`` comes from :meth:`Combat.lookahead` (one-step simulation).

Rewards (Section 5.1)
---------------------
Global and shared: ``reward = [change of allied HP sum - change of enemy HP sum] / initial
allied HP sum`` over the step (every engine turn it played), i.e. the change of (allied HP - enemy HP) "compared to
the previous state, normalised by dividing the sum of all allied units' HP at the initial
state". It is 0 while units only move. The terminal hit-points reward of Table 1 (footnote 1),
``R = (allied HP - enemy HP) / initial allied HP``, is ``info["terminal_hp_reward"]`` (valid at
every step; the metric is its value when ``done``). From a generated start state the
undiscounted return equals ``R - (initial allied HP - initial enemy HP) / initial allied HP``
(``R`` itself for balanced scenarios).

Termination
-----------
``done`` when the engine's game is over (``rules.game_over``): a side has no living unit that
can deal damage, or more than 50 consecutive engine turns without HP change (DC-HEAD
stalemate), or ``max_turns`` engine turns were played (default 1000: scripted m30v30 battles
take 100-250 engine turns; SparCraft's experiments use 20,000). ``info["truncated"]`` marks the
turn cap. ``info["won"]`` / ``info["lost"]`` / ``info["draw"]`` (valid when done): won = the
enemy has no unit left that can deal damage and we do (``rules.winner == 0``), lost = the
reverse, draw = anything else (both dead, stalemate or turn cap with both sides alive).

Info (same keys every step, scalars)
------------------------------------
``won``, ``lost``, ``draw``, ``truncated``, ``terminal_hp_reward``, ``allied_hp``,
``enemy_hp`` (HP sums), ``allied_alive``, ``enemy_alive``, ``turn`` (engine turns so far),
``time`` (frame), ``steps`` (env steps so far), ``illegal_actions``, ``engine_turns``.

Batches
-------
Every function is pure and fixed-shape, so ``jax.vmap(env.step)`` steps a batch. Under ``vmap``
the enemy-only turns run in lockstep, so the batch pays for as many loop iterations as its
slowest game (about 1.1 engine turns per step on average in m30v30, but 3 for the slowest of
1024 games). :meth:`Combat.batch_step` gives the same results for a batch (tested against
``step`` game by game) and advances only the games that owe enemy-only turns, gathered into
sub-batches. On a 2-core CPU at m30v30, B = 1024 (``bench/envs.py``), one engine turn takes
about 18 ms, ``batch_step`` about 7x that and ``vmap(step)`` about 9x: the observation alone
(``n0 x 301`` float32 per game, 14x the size of the game state, 37 MB per batch) costs about 5
engine turns, memory-bound in XLA:CPU; the step without it about 3.

PettingZoo
----------
``hybridmarl.envs.make_pettingzoo("combat", ...)`` (``PettingZooAdapter``): the agents are our
living units; a unit's agent gets ``terminations[agent] = True`` on the step it dies and leaves
``agents`` (``Combat.remove_inactive_agents``); the action mask is
``infos[agent]["action_mask"]``; an agent missing from the action dict plays its
:meth:`Combat.fallback_actions` entry; an illegal action raises ``ValueError`` (or, with
``illegal_action="noop"``, is replaced by the fallback action).

One-step look-ahead (paper Section 4.2, Alg. 1)
-----------------------------------------------
``lookahead(key, state, candidate_actions [A, n0]) -> (reward [A], next_state [A], done [A])``
plays the A candidate joint actions from ``state`` in one vmapped call, each exactly as ``step``
would (same key, so the enemy's reply to each candidate is computed from the same random
stream; the scripts other than ``random`` are deterministic). Over a batch of B states:
``jax.vmap(env.lookahead, in_axes=(0, 0, 0))(keys [B], states [B], candidates [B, A, n0])``.

Rendering
---------
:meth:`Combat.render` (Pillow, outside ``jit``): a header with env step, engine turn, frame
and both sides' living units and HP,
then the map (default the whole 1280x704 map at half scale; ``window=`` crops, see
:func:`camera_window`): units as filled circles, ours red and the enemy green as in the paper's
Figure 2, an HP bar over each, a white ring on our units that act now, lines from attackers to
their targets for the attacks issued during the last step (``state.last_actions``), dead units
as grey crosses.

Version history
---------------
- v0: initial.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax import lax

from hybridmarl.engine import rules as R
from hybridmarl.engine import units as UT
from hybridmarl.engine.scenarios import Scenario, load_states_file, named_scenario
from hybridmarl.engine.scripts import SCRIPTS, Script, canonical_name, get_script
from hybridmarl.engine.state import (
    DEFAULT_MAP_HEIGHT_PX,
    DEFAULT_MAP_WIDTH_PX,
    MOVE,
    PAD_ID_BASE,
    WALK_TILE,
    GameState,
    UnitSpec,
    build_state,
    make_rules,
    stack_states,
)
from hybridmarl.envs.base import MultiAgentEnv

__all__ = [
    "ATTACK_OFFSET",
    "HP_SCALE",
    "K_ALLIES",
    "K_ENEMIES",
    "NOOP",
    "POS_SCALE",
    "SELF_FIELDS",
    "TIME_SCALE",
    "UNIT_FIELDS",
    "Combat",
    "CombatParams",
    "CombatState",
    "EnvPolicy",
    "camera_window",
]

NOOP = 0
#: Env actions 1..4 are the engine's MOVE 2..5 (left, right, down, up).
MOVE_OFFSET = 1
#: Env action ``5 + k`` attacks the k-th living enemy by ascending HP.
ATTACK_OFFSET = 5
#: Section 5.1: "the ten closest allied units and ten closest enemy units".
K_ALLIES = 10
K_ENEMIES = 10
POS_SCALE = 256.0
HP_SCALE = 100.0
TIME_SCALE = 32.0
_MAX_WAIT = 64  # frames; remaining times are clipped here before scaling

SELF_FIELDS: tuple[str, ...] = (
    "alive",
    "x",
    "y",
    "hp_frac",
    "hp",
    "move_wait",
    "attack_wait",
    "moving",
    "can_fire",
    "acting",
    "range",
    "move_len",
    "allies_alive",
    "enemies_alive",
) + tuple(f"type_{name}" for name in UT.TYPE_NAMES)

UNIT_FIELDS: tuple[str, ...] = (
    "alive",
    "hp_frac",
    "hp",
    "move_wait",
    "attack_wait",
    "moving",
    "range",
    "hp_rank",
    "dx",
    "dy",
    "dist",
    "in_my_range",
    "in_its_range",
    "ready",
)

CRITIC_SIDE_FIELDS: tuple[str, ...] = (
    "alive_frac",
    "hp_mean",
    "hp_var",
    "hp_min",
    "hp_max",
    "cooldown_mean",
    "cooldown_var",
    "cooldown_min",
    "cooldown_max",
    "x_mean",
    "x_var",
    "x_min",
    "x_max",
    "y_mean",
    "y_var",
    "y_min",
    "y_max",
)

_BIG = jnp.iinfo(jnp.int32).max
_D2_CAP = (1 << (31 - R.SLOT_BITS)) - 1  # squared distances packed with a slot must fit int32

#: An env-level policy: ``(key, state) -> int32 env actions [n0]``.
EnvPolicy = Callable[[jax.Array, "CombatState"], jax.Array]


# --------------------------------------------------------------------------------------------
# State and parameters.
# --------------------------------------------------------------------------------------------


class CombatParams(struct.PyTreeNode):
    """Environment parameters (pytree leaves: new values of the same shape do not recompile).

    ``bank``: a stacked ``GameState`` ``[K, 2, U]`` of start states that ``reset`` draws from
    uniformly, or ``None`` to sample the scenario's generator.
    """

    bank: GameState | None = None


class CombatState(struct.PyTreeNode):
    """One environment state: the engine's game plus what the env adds around it."""

    game: GameState
    last_actions: jax.Array  # int32 [2, U] engine action each unit issued during the last step
    #                           (the latest one if it acted more than once), -1 if none
    init_hp: jax.Array  # int32 [2] HP sums at the episode's start state (reward normaliser)
    steps: jax.Array  # int32 [] env steps taken this episode


@dataclass(frozen=True)
class _Sampler:
    """Static data for drawing scenario start states inside JAX (built once, in NumPy)."""

    kind: str
    template: GameState  # unit types, ids, HP, LTD totals; positions are filled in by reset
    present: np.ndarray  # bool [2, U]
    offsets: tuple[np.ndarray, np.ndarray]  # disks: int32 [P_p, 2] integer offsets per side
    centers: tuple[tuple[int, int], tuple[int, int]]
    spread: tuple[int, int]


class _View(struct.PyTreeNode):
    """Per-decision-point quantities shared by masks, action conversion and observations."""

    ctx: R.TurnContext
    legal: jax.Array  # bool [U, 6 + U] engine legal actions of player 0
    rank_slot: jax.Array  # int32 [U] enemy slot of HP rank k (valid where rank_valid)
    rank_valid: jax.Array  # bool [U]
    rank_of_slot: jax.Array  # int32 [U] HP rank of each enemy slot (meaningless if dead)
    over: jax.Array  # bool [] game over


def _materialise(tree: Any, guard: jax.Array) -> Any:
    """Identity on ``tree`` that XLA cannot fuse through.

    XLA:CPU fuses cheap producers into their consumers and recomputes them per consumer
    element; for a reduction that reads each input element U times (the rank counts below) that
    turns O(U^2) work into O(U^3). ``lax.optimization_barrier`` would stop it but is removed on
    CPU before fusion, so the values go through a while loop whose condition (``guard < 0``,
    false for a frame counter) is false at run time but unknown at compile time: zero
    iterations, and its result is a materialised buffer. (The never-run body changes every
    value, so XLA cannot forward the loop's input to its output either.)"""

    def bump(x: jax.Array) -> jax.Array:
        return ~x if x.dtype == jnp.bool_ else x + jnp.ones((), x.dtype)

    def body(c: tuple[jax.Array, Any]) -> tuple[jax.Array, Any]:
        return c[0] + 1, jax.tree.map(bump, c[1])

    return lax.while_loop(lambda c: jnp.any(c[0] < 0), body, (guard, tree))[1]


# --------------------------------------------------------------------------------------------
# Host helpers.
# --------------------------------------------------------------------------------------------


def _walkable_np(grid: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Vectorised ``is_walkable_np``: C truncating division, off-map tiles unwalkable."""
    tx = np.fix(np.asarray(x) / WALK_TILE).astype(np.int64)
    ty = np.fix(np.asarray(y) / WALK_TILE).astype(np.int64)
    h, w = grid.shape
    inside = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
    return inside & grid[np.clip(ty, 0, h - 1), np.clip(tx, 0, w - 1)]


def disk_offsets(radius: int) -> np.ndarray:
    """int32 ``[P, 2]``: every integer offset ``(dx, dy)`` with ``dx^2 + dy^2 <= radius^2``."""
    r = int(radius)
    d = np.arange(-r, r + 1)
    dx, dy = np.meshgrid(d, d, indexing="xy")
    keep = dx * dx + dy * dy <= r * r
    return np.stack([dx[keep], dy[keep]], axis=1).astype(np.int32)


def _expand(side: Sequence[tuple[str, int]]) -> list[str]:
    out: list[str] = []
    for t, c in side:
        UT.type_id(t)
        out += [t] * int(c)
    return out


def _interleave(types0: list[str], types1: list[str]) -> list[UnitSpec]:
    """Units in SparCraft generator order (P0, P1, P0, ...), all at the origin."""
    out: list[UnitSpec] = []
    for i in range(max(len(types0), len(types1))):
        if i < len(types0):
            out.append(UnitSpec(types0[i], 0, 0, 0))
        if i < len(types1):
            out.append(UnitSpec(types1[i], 1, 0, 0))
    return out


def _side_types(sc: Scenario) -> tuple[list[str], list[str]]:
    t0 = _expand(sc.side0)
    # SparCraft's separated and symmetric generators give both players player 0's units.
    t1 = t0 if sc.kind in ("separated", "symmetric") else _expand(sc.side1)
    return t0, t1


def camera_window(
    states: GameState | Sequence[GameState],
    margin: int = 96,
    aspect: float = DEFAULT_MAP_WIDTH_PX / DEFAULT_MAP_HEIGHT_PX,
    min_width: int = 480,
) -> tuple[int, int, int, int]:
    """A fixed ``(x0, y0, w, h)`` map window (px) around every real unit of ``states``.

    Pass all states of an episode so the camera stays put; the box is widened to ``aspect``,
    at least ``min_width`` wide and clamped to the map where it fits.
    """
    games = [states] if isinstance(states, GameState) else list(states)
    xs, ys = [], []
    for g in games:
        real = np.asarray(g.uid) < PAD_ID_BASE
        xs.append(np.asarray(g.x)[real])
        ys.append(np.asarray(g.y)[real])
        xs.append(np.asarray(g.px)[real])
        ys.append(np.asarray(g.py)[real])
    x = np.concatenate(xs) if xs else np.zeros(1)
    y = np.concatenate(ys) if ys else np.zeros(1)
    x0, x1 = float(x.min()) - margin, float(x.max()) + margin
    y0, y1 = float(y.min()) - margin, float(y.max()) + margin
    w, h = max(x1 - x0, float(min_width)), y1 - y0
    w, h = max(w, h * aspect), max(h, w / aspect)
    cx, cy = (float(x.min()) + float(x.max())) / 2, (float(y.min()) + float(y.max())) / 2
    x0, y0 = cx - w / 2, cy - h / 2
    if w <= DEFAULT_MAP_WIDTH_PX:
        x0 = min(max(x0, 0.0), DEFAULT_MAP_WIDTH_PX - w)
    if h <= DEFAULT_MAP_HEIGHT_PX:
        y0 = min(max(y0, 0.0), DEFAULT_MAP_HEIGHT_PX - h)
    return round(x0), round(y0), round(w), round(h)


# Approximate Brood War unit half-sizes in px, for drawing only.
_DRAW_RADIUS = {
    "Terran_Marine": 8,
    "Terran_Firebat": 9,
    "Terran_Vulture": 12,
    "Protoss_Zealot": 10,
    "Protoss_Dragoon": 15,
    "Zerg_Zergling": 7,
    "Zerg_Hydralisk": 10,
}
_PLAYER_COLOURS = ((214, 48, 49), (46, 170, 70))  # ours red, enemy green (paper Figure 2)
_LINE_COLOURS = ((255, 140, 130), (150, 245, 150))
_HEADER_PX = 24


# --------------------------------------------------------------------------------------------
# The environment.
# --------------------------------------------------------------------------------------------


class Combat(MultiAgentEnv[CombatState, CombatParams]):
    """SparCraft combat, our units as agents against a scripted enemy (see the module docstring).

    Args:
        scenario: a scenario name (``"m5v5"``, ``"m18v20"``, ``"m30v30-apart"``, ...) or a
            ``Scenario``; default ``"m5v5"`` unless ``start_states`` is given (then ``None``:
            reset draws only from the bank).
        enemy: the enemy's policy: a script name (``hybridmarl.engine.scripts.SCRIPTS``) or a
            function with the script signature ``(key, state, ctx, p) -> int32 [U]``. Default
            ``attack-weakest``, one of the paper's two heuristics (Section 5.1).
        max_turns: cap on *engine* decision turns per episode (default 1000; see Termination).
        debug: raise on illegal actions instead of replacing them (see Action space).
        start_states: a bank of start states: a list of unit lists (``UnitSpec``) or a stacked
            ``GameState``; becomes ``default_params.bank``.
        stalemate_limit: DC-HEAD's limit on turns without HP change (50).
        walkable: the walk-tile map (default SparCraft's 1280x704 all-walkable map).
        num_allies_obs, num_enemies_obs: allies / enemies in the observation (10 / 10).
    """

    #: Dead units never come back, so the PettingZoo adapter terminates and removes their agents.
    remove_inactive_agents = True

    def __init__(
        self,
        scenario: str | Scenario | None = None,
        enemy: str | Script = "attack-weakest",
        max_turns: int = 1000,
        debug: bool = False,
        start_states: Sequence[Sequence[UnitSpec]] | GameState | None = None,
        *,
        stalemate_limit: int = 50,
        walkable: np.ndarray | None = None,
        num_allies_obs: int = K_ALLIES,
        num_enemies_obs: int = K_ENEMIES,
    ) -> None:
        if scenario is None and start_states is None:
            scenario = "m5v5"
        sc = named_scenario(scenario) if isinstance(scenario, str) else scenario
        if int(max_turns) < 1:
            raise ValueError(f"max_turns must be >= 1, got {max_turns}")
        self.rules = make_rules(walkable, stalemate_limit=stalemate_limit, max_turns=int(max_turns))
        self.max_turns = int(max_turns)
        self.debug = bool(debug)
        self.scenario = sc
        if isinstance(enemy, str):
            try:
                self.enemy_name = canonical_name(enemy)
            except KeyError:
                raise ValueError(
                    f"unknown enemy script {enemy!r} (known: {', '.join(SCRIPTS)})"
                ) from None
            self.enemy: Script = get_script(self.enemy_name)
        elif callable(enemy):
            self.enemy_name = getattr(enemy, "__name__", "custom")
            self.enemy = enemy
        else:
            raise ValueError(f"enemy must be a script name or a policy function, got {enemy!r}")

        # Shapes: agents = the largest P0 side, M = the largest P1 side of scenario and bank.
        counts: list[tuple[int, int]] = []
        if sc is not None:
            t0, t1 = _side_types(sc)
            counts.append((len(t0), len(t1)))
        bank: GameState | None = None
        bank_units: list[list[UnitSpec]] | None = None
        if start_states is not None:
            if isinstance(start_states, GameState):
                bank = start_states if start_states.hp.ndim == 3 else stack_states([start_states])
                real = np.asarray(bank.uid) < PAD_ID_BASE
                counts.append((int(real[:, 0].sum(1).max()), int(real[:, 1].sum(1).max())))
            else:
                bank_units = [list(s) for s in start_states]
                if not bank_units:
                    raise ValueError("start_states is empty")
                for s in bank_units:
                    counts.append((sum(u.player == 0 for u in s), sum(u.player == 1 for u in s)))
        n0 = max(c[0] for c in counts)
        n1 = max(c[1] for c in counts)
        if n0 < 1 or n1 < 1:
            raise ValueError("each side needs at least one unit")
        self.num_slots = max(n0, n1)
        if bank is not None and bank.hp.shape[-1] != self.num_slots:
            raise ValueError(
                f"start-state bank has {bank.hp.shape[-1]} slots per side, expected {self.num_slots}"
            )
        if bank_units is not None:
            bank = stack_states([build_state(s, self.num_slots) for s in bank_units])
        self.num_agents = n0
        self.num_enemies = n1
        self.agents = tuple(f"unit_{i}" for i in range(n0))
        self.num_actions = ATTACK_OFFSET + n1
        self.k_allies = int(num_allies_obs)
        self.k_enemies = int(num_enemies_obs)
        self.self_size = len(SELF_FIELDS)
        self.unit_size = len(UNIT_FIELDS)
        self.observation_shape = (
            self.self_size + self.unit_size * (self.k_allies + self.k_enemies),
        )
        self.critic_feature_size = 2 * len(CRITIC_SIDE_FIELDS) + 1
        self.name = "combat_v0"
        self.default_params = CombatParams(bank=bank)
        self._sampler = self._build_sampler(sc) if sc is not None else None
        walk = np.asarray(self.rules.walkable)
        self._map_px = (walk.shape[1] * WALK_TILE, walk.shape[0] * WALK_TILE)

    @classmethod
    def from_states_file(cls, path: str | Path, **kwargs: Any) -> Combat:
        """An env whose ``reset`` draws from the start states of a ``{"states": [...]}`` JSON file
        (validated by ``engine.scenarios.load_states_file``; bad input raises ``InputError``)."""
        walkable = kwargs.get("walkable")
        states = load_states_file(path, walkable=walkable)
        return cls(start_states=states, **kwargs)

    def _build_sampler(self, sc: Scenario) -> _Sampler:
        t0, t1 = _side_types(sc)
        u = self.num_slots
        template = build_state(_interleave(t0, t1), u)
        present = np.zeros((2, u), bool)
        present[0, : len(t0)] = True
        present[1, : len(t1)] = True
        grid = np.asarray(self.rules.walkable)
        centers = (
            (int(sc.center0[0]), int(sc.center0[1])),
            (int(sc.center1[0]), int(sc.center1[1])),
        )
        if sc.kind == "disks":
            offsets = (disk_offsets(sc.radius0), disk_offsets(sc.radius1))
            for p in (0, 1):
                cx, cy = centers[p]
                pts = offsets[p] + np.array([cx, cy], np.int32)
                if not _walkable_np(grid, pts[:, 0], pts[:, 1]).all():
                    raise ValueError(
                        f"scenario {sc.name!r}: player {p}'s disk (centre {centers[p]}, radius "
                        f"{(sc.radius0, sc.radius1)[p]}) is not entirely on walkable map tiles"
                    )
        elif sc.kind in ("separated", "symmetric"):
            offsets = (np.zeros((1, 2), np.int32), np.zeros((1, 2), np.int32))
            mx, my = sc.spread
            dx, dy = np.meshgrid(np.arange(-mx, mx), np.arange(-my, my))
            anchors = (
                [(640, 360), (640, 360)] if sc.kind == "symmetric" else [centers[0], centers[1]]
            )
            for ax, ay in anchors:
                for sgn in (1, -1):
                    if not _walkable_np(grid, ax + sgn * dx, ay + sgn * dy).all():
                        raise ValueError(
                            f"scenario {sc.name!r}: spread {sc.spread} around {(ax, ay)} leaves "
                            "the walkable map"
                        )
        else:
            raise ValueError(f"scenario {sc.name!r}: unknown kind {sc.kind!r}")
        return _Sampler(
            kind=sc.kind,
            template=template,
            present=present,
            offsets=offsets,
            centers=centers,
            spread=(int(sc.spread[0]), int(sc.spread[1])),
        )

    # -- start states -----------------------------------------------------------------------------

    def game_state(self, units: Sequence[UnitSpec]) -> GameState:
        """A ``GameState`` padded to this env's slot count (host side; for ``reset_to``)."""
        n0 = sum(u.player == 0 for u in units)
        n1 = sum(u.player == 1 for u in units)
        if n0 > self.num_agents or n1 > self.num_enemies:
            raise ValueError(
                f"state has {n0} vs {n1} units; this env has {self.num_agents} agents and "
                f"{self.num_enemies} enemies"
            )
        return build_state(units, self.num_slots)

    def sample_game(self, key: jax.Array, params: CombatParams | None = None) -> GameState:
        """Draw a start ``GameState`` (bank if ``params.bank`` is set, else the generator)."""
        params = self.default_params if params is None else params
        if params.bank is not None:
            k = params.bank.hp.shape[0]
            i = jax.random.randint(key, (), 0, k)
            return jax.tree.map(lambda a: a[i], params.bank)
        s = self._sampler
        if s is None:
            raise ValueError(
                "this env has no scenario generator: pass params with a start-state bank"
            )
        u = self.num_slots
        k0, k1, k2 = jax.random.split(key, 3)
        if s.kind == "disks":
            xy = []
            for p, kp in ((0, k0), (1, k1)):
                table = jnp.asarray(s.offsets[p])
                idx = jax.random.randint(kp, (u,), 0, table.shape[0])
                xy.append(table[idx] + jnp.asarray(s.centers[p], jnp.int32))
            pos = jnp.stack(xy)  # [2, U, 2]
        else:
            mx, my = s.spread
            off = jnp.stack(
                [
                    jax.random.randint(k0, (u,), -mx, mx),
                    jax.random.randint(k1, (u,), -my, my),
                ],
                axis=-1,
            ).astype(jnp.int32)
            if s.kind == "symmetric":
                c = jnp.asarray([640, 360], jnp.int32)
                pos = jnp.stack([c + off, c - off])
            else:
                a = jnp.asarray(s.centers[0], jnp.int32) + off
                b = jnp.asarray(s.centers[1], jnp.int32) - off
                # The host generator yields a pair, (a, b) and its mirror (b, a): pick one.
                swap = jax.random.bernoulli(k2)
                pos = jnp.where(swap, jnp.stack([b, a]), jnp.stack([a, b]))
        present = jnp.asarray(s.present)
        x = jnp.where(present, pos[..., 0], 0).astype(jnp.int32)
        y = jnp.where(present, pos[..., 1], 0).astype(jnp.int32)
        return dataclasses.replace(s.template, x=x, y=y, px=x, py=y)

    # -- core API ---------------------------------------------------------------------------------

    def reset(
        self, key: jax.Array, params: CombatParams | None = None
    ) -> tuple[jax.Array, CombatState]:
        k_sample, k_adv = jax.random.split(key)
        return self.reset_to(self.sample_game(k_sample, params), k_adv)

    def reset_to(
        self, game: GameState, key: jax.Array | None = None
    ) -> tuple[jax.Array, CombatState]:
        """Start an episode from ``game`` (advancing enemy-only turns first). Jittable."""
        if game.hp.shape[-1] != self.num_slots:
            raise ValueError(
                f"state has {game.hp.shape[-1]} slots per side, this env uses {self.num_slots} "
                "(build it with env.game_state(units))"
            )
        key = jax.random.key(0) if key is None else key
        init_hp = R.hp_sums(game).astype(jnp.int32)
        u = self.num_slots
        last = jnp.full((2, u), -1, jnp.int32)
        game, last, _ = self._play(key, game, last, jnp.zeros((u,), jnp.int32), force_first=False)
        state = CombatState(
            game=game, last_actions=last, init_hp=init_hp, steps=jnp.zeros((), jnp.int32)
        )
        return self.observe(state), state

    def step(
        self,
        key: jax.Array,
        state: CombatState,
        actions: jax.Array,
        params: CombatParams | None = None,
    ) -> tuple[jax.Array, CombatState, jax.Array, jax.Array, dict[str, jax.Array]]:
        del params
        new_state, reward, done, info = self._step_core(key, state, actions)
        return self.observe(new_state), new_state, reward, done, info

    def lookahead(
        self, key: jax.Array, state: CombatState, candidate_actions: jax.Array
    ) -> tuple[jax.Array, CombatState, jax.Array]:
        """Alg. 1's one-step forward simulation of A joint actions (int32 ``[A, n0]``) from one
        state, as one vmapped call: ``(reward [A], next_state [A], done [A])``; each entry equals
        ``step(key, state, candidate_actions[a])``. Batch over states with
        ``jax.vmap(env.lookahead, in_axes=(0, 0, 0))``."""

        def one(actions: jax.Array) -> tuple[jax.Array, CombatState, jax.Array]:
            s, r, d, _ = self._step_core(key, state, actions)
            return r, s, d

        return jax.vmap(one)(jnp.asarray(candidate_actions, jnp.int32))

    def get_avail_actions(
        self, state: CombatState, params: CombatParams | None = None
    ) -> jax.Array:
        del params
        return self._mask(self._view(state.game))

    def agent_active(self, state: CombatState) -> jax.Array:
        """bool ``[n0]``: the agent's unit is alive."""
        return state.game.hp[0, : self.num_agents] > 0

    def fallback_actions(self, state: CombatState) -> jax.Array:
        """int32 ``[n0]``: the env action an illegal action is replaced by (noop where legal,
        else the engine's first legal action; noop for units that do not act)."""
        view = self._view(state.game)
        first = R.first_legal_action(view.ctx, 0)
        env_first = self._engine_to_env(view, first)
        acting = view.ctx.acting[0, : self.num_agents] & ~view.over
        return jnp.where(acting, env_first, NOOP).astype(jnp.int32)

    def is_done(self, state: CombatState) -> jax.Array:
        return R.game_over(state.game, self.rules)

    # -- the step ---------------------------------------------------------------------------------

    def _our_turn(self, game: GameState) -> jax.Array:
        pmin = R.player_minimum_free_time(game)
        return (pmin[0] <= pmin[1]) & (pmin[0] < _BIG)

    def _turn(
        self, key: jax.Array, game: GameState, last: jax.Array, ours: jax.Array, n: jax.Array
    ) -> tuple[GameState, jax.Array]:
        """One engine turn, the ``n``-th of a step: our engine actions ``ours`` [U] (ignored for
        units that do not act) and the enemy script's, with key ``fold_in(key, n)``."""
        ctx = R.turn_context(game, self.rules)
        a1 = self.enemy(jax.random.fold_in(key, n), game, ctx, 1).astype(jnp.int32)
        joint = jnp.stack([ours, a1])
        return R.apply_actions(game, ctx, joint, self.rules), jnp.where(ctx.acting, joint, last)

    def _needs_enemy_turn(self, game: GameState) -> jax.Array:
        return ~R.game_over(game, self.rules) & ~self._our_turn(game)

    def _play(
        self,
        key: jax.Array,
        game: GameState,
        last: jax.Array,
        ours: jax.Array,
        force_first: bool,
        n_start: int = 0,
        active: jax.Array | bool = True,
    ) -> tuple[GameState, jax.Array, jax.Array]:
        """Engine turns under one ``lax.while_loop``: the first turn with our engine actions
        ``ours`` [U] if ``force_first`` (on later turns none of our units acts, so their entries
        are ignored), then enemy-only turns until one of our units acts or the game is over
        (none at all if not ``active``). One loop body (one copy of the enemy script and
        ``apply_actions``) keeps compile times down. Turns are numbered from ``n_start`` (the
        enemy's key). Returns the game, the updated ``last_actions`` and the turns played."""
        pass_all = jnp.full_like(ours, R.PASS_ACTION)

        def cond(carry: tuple[GameState, jax.Array, jax.Array]) -> jax.Array:
            g, _, n = carry
            more = active & self._needs_enemy_turn(g)
            return (n == 0) | more if force_first else more

        def body(
            carry: tuple[GameState, jax.Array, jax.Array],
        ) -> tuple[GameState, jax.Array, jax.Array]:
            g, last, n = carry
            a0 = jnp.where(n == 0, ours, pass_all) if force_first else pass_all
            g2, last = self._turn(key, g, last, a0, n + n_start)
            return g2, last, n + 1

        return lax.while_loop(cond, body, (game, last, jnp.zeros((), jnp.int32)))

    def _our_engine_actions(
        self, state: CombatState, actions: jax.Array
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(engine actions [U] for our side with illegal ones replaced, illegal [n0], over)."""
        n0, u = self.num_agents, self.num_slots
        view = self._view(state.game)
        mask = self._mask(view)
        a = jnp.asarray(actions).astype(jnp.int32).reshape((n0,))
        in_bounds = (a >= 0) & (a < self.num_actions)
        ok = (
            in_bounds
            & jnp.take_along_axis(mask, jnp.clip(a, 0, self.num_actions - 1)[:, None], axis=1)[:, 0]
        )
        illegal = ~ok
        if self.debug:
            self._check_legal(a, mask, illegal)
        first = R.first_legal_action(view.ctx, 0)[:n0]
        codes = jnp.where(illegal, first, self._env_to_engine(view, a))
        eng0 = jnp.full((u,), R.PASS_ACTION, jnp.int32).at[:n0].set(codes)
        return eng0, illegal, view.over

    def _step_core(
        self, key: jax.Array, state: CombatState, actions: jax.Array
    ) -> tuple[CombatState, jax.Array, jax.Array, dict[str, jax.Array]]:
        eng0, illegal, over0 = self._our_engine_actions(state, actions)
        last0 = jnp.full_like(state.last_actions, -1)
        # The loop's first turn recomputes this turn's context from the same game: same values.
        g2, last, n_turns = self._play(key, state.game, last0, eng0, force_first=True)
        return self._finish(state, g2, last, n_turns, illegal, over0)

    def _finish(
        self,
        state: CombatState,
        g2: GameState,
        last: jax.Array,
        n_turns: jax.Array,
        illegal: jax.Array,
        over0: jax.Array,
    ) -> tuple[CombatState, jax.Array, jax.Array, dict[str, jax.Array]]:
        g = state.game
        # A finished game stays as it is.
        g_new = jax.tree.map(lambda old, new: jnp.where(over0, old, new), g, g2)
        last = jnp.where(over0, state.last_actions, last)
        new_state = CombatState(
            game=g_new,
            last_actions=last,
            init_hp=state.init_hp,
            steps=state.steps + jnp.where(over0, 0, 1).astype(jnp.int32),
        )
        norm = jnp.maximum(state.init_hp[0], 1).astype(jnp.float32)
        hp_old = R.hp_sums(g)
        hp_new = R.hp_sums(g_new)
        diff_old = (hp_old[0] - hp_old[1]).astype(jnp.float32)
        diff_new = (hp_new[0] - hp_new[1]).astype(jnp.float32)
        reward = (diff_new - diff_old) / norm
        done = R.game_over(g_new, self.rules)
        info = self._info(new_state, done, norm, illegal, jnp.where(over0, 0, n_turns))
        return new_state, reward.astype(jnp.float32), done, info

    def batch_step(
        self,
        keys: jax.Array,
        states: CombatState,
        actions: jax.Array,
        params: CombatParams | None = None,
        *,
        sub_batch: int | None = None,
    ) -> tuple[jax.Array, CombatState, jax.Array, jax.Array, dict[str, jax.Array]]:
        """``jax.vmap(env.step)(keys, states, actions)`` (same results), faster for large batches.

        Under ``vmap`` the enemy-only turns of a step run in lockstep: the whole batch pays for
        as many loop iterations as its slowest game (3-4 at B = 1024 while the mean is ~1.1).
        Here every game plays its decision turn at once, then only the games that still owe
        enemy-only turns are gathered into sub-batches of ``sub_batch`` games (default
        ceil(B / 8)) and advanced there, round after round until none is left.
        """
        del params
        b = keys.shape[0]
        size = max(1, min(b, sub_batch if sub_batch is not None else -(-b // 8)))

        def first_turn(
            k: jax.Array, state: CombatState, a: jax.Array
        ) -> tuple[GameState, jax.Array, jax.Array, jax.Array, jax.Array]:
            eng0, illegal, over0 = self._our_engine_actions(state, a)
            last0 = jnp.full_like(state.last_actions, -1)
            g1, last1 = self._turn(k, state.game, last0, eng0, jnp.int32(0))
            return g1, last1, illegal, over0, self._needs_enemy_turn(g1) & ~over0

        g1, last1, illegal, over0, pending = jax.vmap(first_turn)(keys, states, actions)
        turns = jnp.ones((b,), jnp.int32)

        def more(carry: tuple[Any, ...]) -> jax.Array:
            return jnp.any(carry[3])

        def round_(carry: tuple[Any, ...]) -> tuple[Any, ...]:
            g, last, turns, pending = carry
            idx = jnp.nonzero(pending, size=size, fill_value=b)[0]
            take = jnp.minimum(idx, b - 1)
            sub = jax.tree.map(lambda a: a[take], g)
            g2, last2, n = jax.vmap(
                lambda k, gg, ll, act: self._play(
                    k, gg, ll, jnp.zeros((self.num_slots,), jnp.int32), False, 1, act
                )
            )(keys[take], sub, last[take], idx < b)
            g = jax.tree.map(lambda a, v: a.at[idx].set(v, mode="drop"), g, g2)
            last = last.at[idx].set(last2, mode="drop")
            turns = turns.at[idx].add(n, mode="drop")
            pending = pending.at[idx].set(False, mode="drop")
            return g, last, turns, pending

        g2, last2, turns, _ = lax.while_loop(more, round_, (g1, last1, turns, pending))

        def finish(*args: Any) -> tuple[Any, ...]:
            new, reward, done, info = self._finish(*args)
            return self.observe(new), new, reward, done, info

        return jax.vmap(finish)(states, g2, last2, turns, illegal, over0)

    def _info(
        self,
        state: CombatState,
        done: jax.Array,
        norm: jax.Array,
        illegal: jax.Array,
        engine_turns: jax.Array,
    ) -> dict[str, jax.Array]:
        g = state.game
        hp = R.hp_sums(g)
        w = R.winner(g)
        won = done & (w == 0)
        lost = done & (w == 1)
        alive = g.hp > 0
        return {
            "won": won,
            "lost": lost,
            "draw": done & ~won & ~lost,
            "truncated": done & ~R.is_terminal(g, self.rules),
            "terminal_hp_reward": ((hp[0] - hp[1]).astype(jnp.float32) / norm).astype(jnp.float32),
            "allied_hp": hp[0].astype(jnp.int32),
            "enemy_hp": hp[1].astype(jnp.int32),
            "allied_alive": jnp.sum(alive[0], dtype=jnp.int32),
            "enemy_alive": jnp.sum(alive[1], dtype=jnp.int32),
            "turn": g.turn,
            "time": g.time,
            "steps": state.steps,
            "illegal_actions": jnp.sum(illegal, dtype=jnp.int32),
            "engine_turns": engine_turns.astype(jnp.int32),
        }

    def _check_legal(self, a: jax.Array, mask: jax.Array, illegal: jax.Array) -> None:
        agents = self.agents

        def report(a_np: Any, mask_np: Any, illegal_np: Any) -> None:
            a_np, mask_np, illegal_np = (
                np.asarray(a_np),
                np.asarray(mask_np),
                np.asarray(illegal_np),
            )
            if not illegal_np.any():
                return
            a2 = a_np.reshape(-1, a_np.shape[-1])
            m2 = mask_np.reshape(-1, *mask_np.shape[-2:])
            bad = illegal_np.reshape(-1, illegal_np.shape[-1])
            b, i = (int(v) for v in np.argwhere(bad)[0])
            legal = np.flatnonzero(m2[b, i]).tolist()
            raise ValueError(
                f"combat: illegal action {int(a2[b, i])} for agent {agents[i]!r} "
                f"(legal actions: {legal}; {int(bad.sum())} illegal in all)"
            )

        try:  # concrete values (eager call): check on the host right away
            concrete = (np.asarray(a), np.asarray(mask), np.asarray(illegal))
        except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
            jax.debug.callback(report, a, mask, illegal)  # traced: check when it runs
        else:
            report(*concrete)

    # -- actions ----------------------------------------------------------------------------------

    def _view(self, game: GameState) -> _View:
        ctx = R.turn_context(game, self.rules)
        u = self.num_slots
        slot = jnp.arange(u, dtype=jnp.int32)
        alive1 = ctx.alive[1]
        # Packed (HP, slot) keys order living enemies by ascending HP, ties to the lower id.
        keys = jnp.where(alive1, (jnp.maximum(game.hp[1], 0) << R.SLOT_BITS) | slot, _BIG)
        # Ranks by counting (no sort): rank = number of living enemies with a smaller key.
        rank_of_slot = jnp.sum(keys[None, :] < keys[:, None], axis=1).astype(jnp.int32)
        hit = (rank_of_slot[None, :] == slot[:, None]) & alive1[None, :]  # [k, slot]
        rank_slot = jnp.sum(jnp.where(hit, slot[None, :], 0), axis=1).astype(jnp.int32)
        rank_valid = slot < jnp.sum(alive1)
        return _View(
            ctx=ctx,
            legal=R.legal_actions(ctx, 0),
            rank_slot=rank_slot,
            rank_valid=rank_valid,
            rank_of_slot=rank_of_slot,
            over=R.game_over(game, self.rules),
        )

    def _mask(self, view: _View) -> jax.Array:
        n0, m = self.num_agents, self.num_enemies
        legal = view.legal[:n0]
        acting = view.ctx.acting[0, :n0]
        noop = ~acting | legal[:, R.PASS_ACTION] | legal[:, R.RELOAD_ACTION]
        moves = legal[:, R.MOVE_ACTIONS[0] : R.MOVE_ACTIONS[-1] + 1]
        by_slot = legal[:, R.ATTACK_BASE :]
        attacks = by_slot[:, view.rank_slot[:m]] & view.rank_valid[:m][None, :]
        live = jnp.concatenate([moves, attacks], axis=1) & ~view.over
        noop = noop | view.over
        return jnp.concatenate([noop[:, None], live], axis=1)

    def _env_to_engine(self, view: _View, a: jax.Array) -> jax.Array:
        m = self.num_enemies
        can_fire = view.ctx.can_attack_now[0, : self.num_agents]
        noop = jnp.where(can_fire, R.PASS_ACTION, R.RELOAD_ACTION)
        move = a - MOVE_OFFSET + R.MOVE_ACTIONS[0]
        target = view.rank_slot[jnp.clip(a - ATTACK_OFFSET, 0, m - 1)]
        return jnp.where(
            a < MOVE_OFFSET, noop, jnp.where(a < ATTACK_OFFSET, move, R.ATTACK_BASE + target)
        ).astype(jnp.int32)

    def _engine_to_env(self, view: _View, codes: jax.Array) -> jax.Array:
        codes = codes[: self.num_agents].astype(jnp.int32)
        u = self.num_slots
        move = codes - R.MOVE_ACTIONS[0] + MOVE_OFFSET
        attack = ATTACK_OFFSET + view.rank_of_slot[jnp.clip(codes - R.ATTACK_BASE, 0, u - 1)]
        return jnp.where(
            codes <= R.RELOAD_ACTION, NOOP, jnp.where(codes < R.ATTACK_BASE, move, attack)
        ).astype(jnp.int32)

    def env_to_engine_actions(self, state: CombatState, actions: jax.Array) -> jax.Array:
        """int32 ``[n0]`` engine action codes for env ``actions`` at ``state`` (no legality check)."""
        return self._env_to_engine(self._view(state.game), jnp.asarray(actions, jnp.int32))

    def engine_to_env_actions(self, state: CombatState, codes: jax.Array) -> jax.Array:
        """int32 ``[n0]`` env actions for player 0's engine codes (``[U]`` or ``[n0]``) at
        ``state``; non-acting units get noop. Inverse of :meth:`env_to_engine_actions` on legal
        actions."""
        view = self._view(state.game)
        env = self._engine_to_env(view, jnp.asarray(codes, jnp.int32))
        acting = view.ctx.acting[0, : self.num_agents] & ~view.over
        return jnp.where(acting, env, NOOP).astype(jnp.int32)

    def script_policy(self, script: str | Script) -> EnvPolicy:
        """Our side played by an engine script, as a pure env policy ``(key, state) -> [n0]``
        (scripted demonstrations, Section 5.1's heuristics c and w)."""
        fn = get_script(script) if isinstance(script, str) else script

        def policy(key: jax.Array, state: CombatState) -> jax.Array:
            ctx = R.turn_context(state.game, self.rules)
            return self.engine_to_env_actions(state, fn(key, state.game, ctx, 0))

        return policy

    # -- observations -----------------------------------------------------------------------------

    def observe(self, state: CombatState) -> jax.Array:
        """float32 ``[n0, obs]`` (layout in the module docstring)."""
        return self._observe(state.game, self._view(state.game))

    def _unit_table(self, game: GameState, ctx: R.TurnContext, view: _View) -> jax.Array:
        """float32 [2, U, 8]: the per-unit fields ``UNIT_FIELDS[:8]`` of every slot."""
        t = game.time
        f32 = jnp.float32
        max_hp = jnp.asarray(UT.TABLES.max_hp)[game.utype].astype(f32)
        hp = jnp.maximum(game.hp, 0).astype(f32)
        range_px = jnp.sqrt(jnp.asarray(UT.TABLES.range_sq)[game.utype].astype(f32))
        rank = jnp.stack(
            [
                jnp.zeros((self.num_slots,), f32),
                (view.rank_of_slot + 1).astype(f32) / self.num_enemies,
            ]
        )
        cols = [
            ctx.alive.astype(f32),
            hp / jnp.maximum(max_hp, 1.0),
            hp / HP_SCALE,
            jnp.clip(game.t_move - t, 0, _MAX_WAIT).astype(f32) / TIME_SCALE,
            jnp.clip(game.t_attack - t, 0, _MAX_WAIT).astype(f32) / TIME_SCALE,
            ((game.last == MOVE) & (t < game.t_move)).astype(f32),
            range_px / POS_SCALE,
            rank,
        ]
        return jnp.stack(cols, axis=-1)

    def _observe(self, game: GameState, view: _View) -> jax.Array:
        # Materialise the turn context first: XLA would otherwise fuse (recompute) pieces of it,
        # such as the interpolated positions, into every consumer below, including the
        # O(U^3) rank reductions.
        game, view = _materialise((game, view), game.time)
        ctx = view.ctx
        n0, u, m = self.num_agents, self.num_slots, self.num_enemies
        f32 = jnp.float32
        table = self._unit_table(game, ctx, view)  # [2, U, 8]
        range_sq = jnp.asarray(UT.TABLES.range_sq)[game.utype]
        alive = ctx.alive
        me = jnp.arange(n0)
        slot = jnp.arange(u, dtype=jnp.int32)
        cx, cy = ctx.cx, ctx.cy

        # Own block: the shared per-unit fields, then the rest in SELF_FIELDS order.
        width, height = self._map_px
        mine = table[0, :n0]
        n_allies = jnp.sum(alive[0]) - alive[0, :n0]
        n_enemies = jnp.sum(alive[1])
        own_arr = jnp.concatenate(
            [
                jnp.stack(
                    [
                        mine[:, 0],
                        cx[0, :n0].astype(f32) / width,
                        cy[0, :n0].astype(f32) / height,
                        mine[:, 1],
                        mine[:, 2],
                        mine[:, 3],
                        mine[:, 4],
                        mine[:, 5],
                        ctx.can_attack_now[0, :n0].astype(f32),
                        ctx.acting[0, :n0].astype(f32),
                        mine[:, 6],
                        ctx.move_dist[0, :n0].astype(f32) / UT.MOVE_DISTANCE,
                        n_allies.astype(f32) / max(n0 - 1, 1),
                        jnp.broadcast_to(n_enemies.astype(f32) / m, (n0,)),
                    ],
                    axis=-1,
                ),
                jax.nn.one_hot(game.utype[0, :n0], UT.NUM_TYPES, dtype=f32),
            ],
            axis=-1,
        )

        can_fire = (ctx.can_attack_now[0, :n0] & ctx.acting[0, :n0]).astype(f32)
        # Per-unit columns gathered once per selected unit: the 8 shared fields, then the
        # position and squared weapon range the pair fields need.
        ext = jnp.concatenate(
            [
                table,
                jnp.stack([cx, cy, range_sq], axis=-1).astype(f32),  # exact: all < 2^24
                ctx.acting[..., None].astype(f32),
            ],
            axis=-1,
        )  # [2, U, 12]

        # Packed (squared distance, slot) keys of the candidates; materialised, so the rank
        # reductions below read them instead of recomputing distances per comparison.
        ax = cx[0, :n0, None] - cx[0][None, :]
        ay = cy[0, :n0, None] - cy[0][None, :]
        d2_allies = ax * ax + ay * ay
        cand = (
            alive[0][None, :] & (slot[None, :] != me[:, None]),
            jnp.broadcast_to(alive[1][None, :], (n0, u)),
        )
        keys = tuple(
            jnp.where(c, (jnp.minimum(d2, _D2_CAP) << R.SLOT_BITS) | slot[None, :], _BIG)
            for c, d2 in zip(cand, (d2_allies, ctx.d2[:n0]), strict=True)
        )
        keys = _materialise(keys, game.time)

        def select(key: jax.Array, c: jax.Array, k: int) -> tuple[jax.Array, jax.Array]:
            """Slots [n0, k] of the k closest candidates, nearest first, and their validity.

            No sort (XLA's CPU sort of many short rows is slow): a candidate's rank is the
            number of candidates with a smaller key, and the k-th closest slot is read off the
            rank == k one-hot."""
            rank = jnp.sum(key[:, :, None] < key[:, None, :], axis=1)  # [n0, U]
            ks = jnp.arange(k, dtype=jnp.int32)
            hit = (rank[:, None, :] == ks[None, :, None]) & c[:, None, :]  # [n0, k, U]
            j = jnp.sum(jnp.where(hit, slot[None, None, :], 0), axis=-1)
            valid = ks[None, :] < jnp.sum(c, axis=-1, keepdims=True)
            return j, valid

        sel = _materialise(
            (select(keys[0], cand[0], self.k_allies), select(keys[1], cand[1], self.k_enemies)),
            game.time,
        )
        gathered = _materialise(
            tuple(ext[q][sel[q][0]] for q in (0, 1)), game.time
        )  # [n0, k, 12] per side

        my_x = cx[0, :n0, None].astype(f32)
        my_y = cy[0, :n0, None].astype(f32)
        my_r2 = range_sq[0, :n0, None].astype(f32)
        outs = []
        for q in (0, 1):
            g_ = gathered[q]
            valid = sel[q][1] & alive[0, :n0, None]  # a dead agent's observation is all zero
            dx = g_[..., 8] - my_x
            dy = g_[..., 9] - my_y
            d2 = dx * dx + dy * dy  # exact in float32: integers < 2^24
            in_mine = (d2 <= my_r2).astype(f32)
            ready = in_mine * can_fire[:, None] if q == 1 else g_[..., 11]
            block = jnp.concatenate(
                [
                    g_[..., :8],
                    jnp.stack(
                        [
                            dx / POS_SCALE,
                            dy / POS_SCALE,
                            jnp.sqrt(d2) / POS_SCALE,
                            in_mine,
                            (d2 <= g_[..., 10]).astype(f32),
                            ready,
                        ],
                        axis=-1,
                    ),
                ],
                axis=-1,
            )
            outs.append((block * valid[..., None]).reshape(n0, -1))
        own_arr = own_arr * alive[0, :n0, None]
        return jnp.concatenate([own_arr, *outs], axis=-1)

    def obs_slice(self, part: str, index: int = 0, field: str | None = None) -> slice | int:
        """Where ``field`` of the ``index``-th ``part`` ("self", "ally", "enemy") block sits in an
        observation (a slice over the whole block if ``field`` is None)."""
        if part == "self":
            names, start = SELF_FIELDS, 0
        elif part in ("ally", "enemy"):
            names = UNIT_FIELDS
            k = self.k_allies if part == "ally" else self.k_enemies
            if not 0 <= index < k:
                raise IndexError(f"{part} block {index} out of range 0..{k - 1}")
            base = self.self_size + (0 if part == "ally" else self.unit_size * self.k_allies)
            start = base + self.unit_size * index
        else:
            raise ValueError(f"part must be 'self', 'ally' or 'enemy', got {part!r}")
        if field is None:
            return slice(start, start + len(names))
        return start + names.index(field)

    # -- critic -----------------------------------------------------------------------------------

    def critic_features(self, state: CombatState, actions: jax.Array | None = None) -> jax.Array:
        """float32 ``[35]`` global statistics (module docstring); ``actions`` is ignored."""
        del actions
        g = state.game
        cx, cy = R.current_positions(g, g.time)
        alive = g.hp > 0
        sizes = (self.num_agents, self.num_enemies)
        values = {
            "hp": jnp.maximum(g.hp, 0).astype(jnp.float32) / HP_SCALE,
            "cooldown": jnp.clip(g.t_attack - g.time, 0, None).astype(jnp.float32) / TIME_SCALE,
            "x": cx.astype(jnp.float32) / POS_SCALE,
            "y": cy.astype(jnp.float32) / POS_SCALE,
        }
        feats = []
        centroids = []
        for p in (0, 1):
            mask = alive[p]
            n = jnp.sum(mask)
            nf = jnp.maximum(n, 1).astype(jnp.float32)
            any_ = n > 0
            feats.append((n.astype(jnp.float32) / sizes[p])[None])
            for name in ("hp", "cooldown", "x", "y"):
                v = values[name][p]
                mean = jnp.sum(jnp.where(mask, v, 0.0)) / nf
                var = jnp.sum(jnp.where(mask, (v - mean) ** 2, 0.0)) / nf
                vmin = jnp.where(any_, jnp.min(jnp.where(mask, v, jnp.inf)), 0.0)
                vmax = jnp.where(any_, jnp.max(jnp.where(mask, v, -jnp.inf)), 0.0)
                feats.append(jnp.stack([mean, var, vmin, vmax]))
                if name in ("x", "y"):
                    centroids.append(mean)
        both = (jnp.sum(alive[0]) > 0) & (jnp.sum(alive[1]) > 0)
        dist = jnp.sqrt((centroids[0] - centroids[2]) ** 2 + (centroids[1] - centroids[3]) ** 2)
        feats.append(jnp.where(both, dist, 0.0)[None])
        return jnp.concatenate(feats).astype(jnp.float32)

    # -- rendering --------------------------------------------------------------------------------

    def _render_facts(self, game: GameState) -> tuple[jax.Array, ...]:
        """(cx, cy, acting, over, winner) for drawing, from one jitted call (compiled once per
        env; eager op-by-op dispatch would cost more per frame)."""
        fn = self.__dict__.get("_render_jit")
        if fn is None:

            def facts(g: GameState) -> tuple[jax.Array, ...]:
                ctx = R.turn_context(g, self.rules)
                return ctx.cx, ctx.cy, ctx.acting, R.game_over(g, self.rules), R.winner(g)

            fn = jax.jit(facts)
            self.__dict__["_render_jit"] = fn
        return fn(game)

    def render(
        self,
        state: CombatState,
        params: CombatParams | None = None,
        *,
        window: tuple[int, int, int, int] | None = None,
        width: int = 640,
    ) -> np.ndarray:
        """uint8 ``[24 + h, width, 3]`` picture of ``state``: a header, then the map ``window``
        (``(x0, y0, w, h)`` in map px, default the whole map) scaled to ``width`` px."""
        del params
        from PIL import Image, ImageDraw, ImageFont

        g = jax.device_get(state.game)
        last = np.asarray(jax.device_get(state.last_actions))
        init_hp = np.asarray(jax.device_get(state.init_hp))
        mw, mh = self._map_px
        x0, y0, ww, wh = window if window is not None else (0, 0, mw, mh)
        scale = width / ww
        out_h = round(wh * scale)
        img = Image.new("RGB", (width, _HEADER_PX + out_h), (28, 30, 34))
        draw = ImageDraw.Draw(img)

        def to_px(x: float, y: float) -> tuple[float, float]:
            return (x - x0) * scale, _HEADER_PX + (y - y0) * scale

        # Faint 64-px grid so motion is visible, and the map border.
        grid_col = (40, 43, 48)
        for gx in range(0, mw + 1, 64):
            if x0 <= gx <= x0 + ww:
                px_, _ = to_px(gx, 0)
                draw.line([(px_, _HEADER_PX), (px_, _HEADER_PX + out_h)], fill=grid_col)
        for gy in range(0, mh + 1, 64):
            if y0 <= gy <= y0 + wh:
                _, py_ = to_px(0, gy)
                draw.line([(0, py_), (width, py_)], fill=grid_col)

        t = int(g.time)
        cx, cy, acting, over, winner = (np.asarray(v) for v in self._render_facts(g))
        over = bool(over)
        hp = np.asarray(g.hp)
        utype = np.asarray(g.utype)
        real = np.asarray(g.uid) < PAD_ID_BASE
        max_hp = UT.TABLES.max_hp[utype]

        # Attack lines of the last step, under the units.
        for p in (0, 1):
            q = 1 - p
            for s in np.flatnonzero(real[p] & (last[p] >= R.ATTACK_BASE)):
                j = int(last[p, s]) - R.ATTACK_BASE
                a = to_px(cx[p, s], cy[p, s])
                b = to_px(cx[q, j], cy[q, j])
                draw.line([a, b], fill=_LINE_COLOURS[p], width=max(1, round(2 * scale)))
        for p in (0, 1):
            for s in np.flatnonzero(real[p]):
                x, y = to_px(cx[p, s], cy[p, s])
                r = max(3.0, _DRAW_RADIUS.get(UT.TYPE_NAMES[utype[p, s]], 8) * scale)
                if hp[p, s] <= 0:
                    c = (95, 95, 100)
                    k = r * 0.6
                    draw.line([(x - k, y - k), (x + k, y + k)], fill=c, width=2)
                    draw.line([(x - k, y + k), (x + k, y - k)], fill=c, width=2)
                    continue
                outline = (255, 255, 255) if (p == 0 and acting[p, s] and not over) else None
                draw.ellipse(
                    [x - r, y - r, x + r, y + r],
                    fill=_PLAYER_COLOURS[p],
                    outline=outline,
                    width=max(1, round(scale * 1.5)),
                )
                frac = float(hp[p, s]) / max(float(max_hp[p, s]), 1.0)
                bw, bh = 2 * r + 2, max(2.0, 3 * scale)
                bx, by = x - bw / 2, y - r - bh - 2
                draw.rectangle([bx, by, bx + bw, by + bh], fill=(20, 20, 20))
                colour = (
                    (70, 210, 70)
                    if frac > 0.5
                    else (235, 200, 40)
                    if frac > 0.25
                    else (230, 60, 50)
                )
                draw.rectangle([bx, by, bx + bw * frac, by + bh], fill=colour)

        # Header.
        draw.rectangle([0, 0, width, _HEADER_PX - 1], fill=(12, 12, 14))
        sums = hp.clip(min=0).sum(axis=1)
        n_alive = (hp > 0).sum(axis=1)
        status = ""
        if over:
            w = int(winner)
            status = "  WON" if w == 0 else "  LOST" if w == 1 else "  DRAW"
        text = (
            f"step {int(state.steps)}  turn {int(g.turn)}  t={t}f  ours {n_alive[0]}u {sums[0]}/{init_hp[0]}hp"
            f"  enemy {n_alive[1]}u {sums[1]}/{init_hp[1]}hp{status}"
        )
        try:
            font: Any = ImageFont.load_default(size=14)
        except TypeError:  # pragma: no cover - Pillow without FreeType
            font = ImageFont.load_default()
        draw.text((6, 4), text, fill=(235, 235, 235), font=font)
        return np.asarray(img, dtype=np.uint8).copy()
