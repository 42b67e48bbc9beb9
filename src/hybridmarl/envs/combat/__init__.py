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
frame-exact JAX SparCraft engine (``hybridmarl.engine``, DC-HEAD rules; ``docs/engine.md``), so
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
  only if nothing else is legal, so a unit that *can fire now* has no noop: one that can attack
  but has nothing in range gets only MOVE actions and cannot wait (SparCraft's
  ``GameState::generateMoves``, github.com/davechurchill/ualbertabot, directory SparCraft).
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
``JaxRuntimeError``. The PettingZoo adapter replaces an illegal action by the fallback and
counts it in ``infos`` by default (``illegal_action="raise"`` raises instead).

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
stalemate; 200 under the ``paper`` setting, docs/engine.md#settings), or ``max_turns`` engine turns were played (default 1000: scripted m30v30 battles
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
``agents`` (``Combat.remove_inactive_agents``); an observation is
``{"observation": ..., "action_mask": ...}`` as in PettingZoo's classic environments
(``obs_format="array"``: the bare vector), and the mask is also ``infos[agent]["action_mask"]``;
an agent missing from the action dict plays its :meth:`Combat.fallback_actions` entry; an
illegal action is replaced by that fallback and counted in ``infos`` (with
``illegal_action="raise"``, it raises ``ValueError``). docs/environments.md has the details.

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

Modules
-------
``state`` (:class:`CombatParams`, :class:`CombatState`, the start-state sampler), ``view`` (HP
ranks, masks, env <-> engine actions), ``observe`` (observations, critic features, field tables),
``env`` (:class:`Combat`), ``rewards`` (per-agent rewards of DQfD and OGTL), ``render``
(:func:`camera_window`, drawing) and ``opponents`` (enemy scripts, a trained policy as the enemy).

Version history
---------------
- v0: initial.
"""

from hybridmarl.engine.scenarios import disk_offsets
from hybridmarl.envs.combat.env import Combat
from hybridmarl.envs.combat.observe import (
    CRITIC_SIDE_FIELDS,
    HP_SCALE,
    K_ALLIES,
    K_ENEMIES,
    POS_SCALE,
    SELF_FIELDS,
    TIME_SCALE,
    UNIT_FIELDS,
)
from hybridmarl.envs.combat.opponents import cross_enemy, learned_enemy, mirror_game
from hybridmarl.envs.combat.render import camera_window
from hybridmarl.envs.combat.state import CombatParams, CombatState
from hybridmarl.envs.combat.view import ATTACK_OFFSET, MOVE_OFFSET, NOOP

__all__ = [
    "ATTACK_OFFSET",
    "CRITIC_SIDE_FIELDS",
    "HP_SCALE",
    "K_ALLIES",
    "K_ENEMIES",
    "MOVE_OFFSET",
    "NOOP",
    "POS_SCALE",
    "SELF_FIELDS",
    "TIME_SCALE",
    "UNIT_FIELDS",
    "Combat",
    "CombatParams",
    "CombatState",
    "camera_window",
    "cross_enemy",
    "disk_offsets",
    "learned_enemy",
    "mirror_game",
]
