"""Traffic Junction (CommNet "medium"), as used in Peng, Xing & Cao (IJCAI 2020), Section 5.3.

.. list-table::

   * - Import
     - ``from hybridmarl.envs.traffic_junction import TrafficJunction``
   * - Agents
     - ``car_0`` .. ``car_9`` (``num_agents=10``)
   * - Actions
     - ``Discrete(2)``: 0 = brake, 1 = gas
   * - Observation shape
     - ``(259,)`` float32 for 10 agents (``9 * (1 + N + 12) + 52``)
   * - Critic features
     - ``(10440,)`` float32 for 10 agents (``4 * N * (259 + 2)``)
   * - Episode length
     - 40 steps (``TJParams.max_steps``)
   * - Version
     - ``traffic_junction_v0``

Description
-----------
A four-way junction of two two-lane roads on a 14x14 grid with right-hand traffic
(CommNet's "medium" version, Sukhbaatar, Szlam & Fergus, 2016; ``docs/environments.md``;
coordinates are ``(row, col)``, 0-indexed, row 0 at the top):

- **Road cells**: rows 6 and 7 (all columns) plus columns 6 and 7 (all rows): 52 cells. The
  junction is the 2x2 block rows 6-7 x cols 6-7. Lanes: column 6 southbound, column 7
  northbound, row 7 eastbound, row 6 westbound.
- **Entries** (spawn cells): North (0,6) heading south, East (6,13) heading west, West (7,0)
  heading east, South (13,7) heading north.
- **Routes**: 3 per entry (straight, right turn, left turn), 12 in all, stored as data in
  :data:`ROUTE_CELLS` (``[12, 15, 2]`` int32, padded with -1) and :data:`ROUTE_LENGTHS`
  (13 right / 14 straight / 15 left, counting the entry and exit cells). Route ids follow
  CommNet's global route numbering: sources in the order **N, E, W, S** and
  within a source **straight, right, left**, i.e. ``route_id = 3 * direction + turn``
  (N-straight = 0, N-right = 1, N-left = 2, E-straight = 3, ..., S-left = 11).

Dynamics (CommNet's semantics)
------------------------------
One call to :meth:`TrafficJunction.step`, in this order:

1. Every active car applies its action: gas moves it to the next cell of its route, brake keeps
   it in place. Gas requested for an inactive slot is ignored (the adapter rejects it).
2. For every car that was active at the start of the step: ``tau += 1``; the car *collides* if
   two or more such cars (at their new cells) share its cell; the car *arrives* if it now stands
   on the last cell of its route. Arriving cars are counted in the collision check of this step
   (the check is simultaneous over all cars, which removes CommNet's dependence on the loop
   order of its sequential ``update``) and are then removed at once; their slot becomes free.
   Cars are never removed for colliding and keep moving; every step they overlap counts again.
3. Arrivals: for each entry in the order N, E, W, S, if fewer than ``num_agents`` cars are
   active, with probability ``p_arrive`` a new car is placed on that entry cell with a uniformly
   random route of that entry. Its agent id is drawn **uniformly among the free slots**
   (CommNet "take a random inactive agent"; ids are recycled, so one id can drive several cars
   per episode). Spawning onto an occupied entry cell is allowed (CommNet ``add_block=false``);
   the overlap is counted as a collision at the next step if neither car moves away.
4. ``t += 1``; the episode is ``done`` when ``t == max_steps`` (40). It is never cut short.

There are no cars at ``t = 0`` (as in CommNet): the first cars appear after the first step.
``reset`` therefore does not use its key; all randomness is drawn in ``step``.

Rewards (paper Section 5.3)
---------------------------
The reward is global and shared: ``reward = r_c * N_c + r_a * N_a`` with ``r_c = -5`` per car
that is in a shared cell at this step (so a colliding pair gives -10, the same as CommNet's
per-car cost) and ``r_a = +1`` per car arriving at its destination. Optionally
(``time_penalty=True``) each car active at the start of the step also gets ``-0.01 * tau``
(``tau`` = steps since it entered, counted after this step's increment), as in CommNet/IC3Net.
The default is **off**: the paper stresses "global and sparse" rewards and lists only the
collision and arrival terms. ``info["car_rewards"]`` holds the
per-slot terms whose sum is ``reward``.

Termination and success
-----------------------
``done`` after ``max_steps`` steps. An episode **fails** if any collision happened at any step
(``state.failed`` / ``info["failed"]``); success is ``done & ~failed``.

Observation (per car, float32, length ``9 * F + 52`` with ``F = 1 + N + 12``; 259 for N = 10)
---------------------------------------------------------------------------------------------
A CommNet-style {id, location, route} encoding of the 3x3 vision window (paper Section 5.3:
"the observation of a car, which is the same to [Sukhbaatar and Fergus, 2016]"),
made compact by giving each visible car's location implicitly through the window cell
it is in plus the observer's own location:

- ``obs[0 : 9F]`` the 3x3 window centred on the car, cells in row-major order of the offsets
  ``(dr, dc)`` in ``{-1, 0, 1}^2`` (north up; ``(0, 0)``, the car's own cell, is cell 4). Each
  cell has ``F`` values: ``[0]`` number of cars in the cell (the CommNet "agent" word count;
  2 or more means a collision), ``[1 : 1+N]`` multi-hot of the agent ids of the cars there,
  ``[1+N : 1+N+12]`` number of those cars on each route id (a multi-hot unless cars on the
  same route overlap). Cells off the grid or off the road are all
  zero (CommNet does not encode walls); the car itself always appears in cell 4.
- ``obs[9F : 9F+52]`` one-hot of the car's own cell among the 52 road cells, indexed in
  row-major order of the grid (:data:`ROAD_INDEX`).

Inactive slots get an all-zero observation. Values lie in ``[0, N]``.

Critic features (paper Section 5.3; length ``4 * N * (obs + 2)``; 10440 for N = 10)
-----------------------------------------------------------------------------------
"The representation of each car combines its observation and action one-hot encoding. The
feature vector concatenates representations of all cars each way. For positions without a car,
a nominal car whose representations are 0 is assigned." Layout ``[4, N, obs_size + 2]``
flattened (C order):

- axis 0: the car's entry direction, N, E, W, S (``route_id // 3``);
- axis 1: ``N`` slots per direction (enough for every car to come from one direction), holding
  that direction's active cars sorted by progress along the route, furthest first (ties: lower
  agent id first), so the layout does not depend on which recycled id drives which car;
  unused slots are zero;
- axis 2: the car's observation (above) followed by the one-hot of its action (brake, gas).

No time feature is included (the paper does not list one).

Parameters (:class:`TJParams`, all pytree leaves, so they can change without recompiling)
---------------------------------------------------------------------------------------
``p_arrive`` (0.2, CommNet's evaluation value), ``max_steps`` (40),
``collision_reward`` (-5.0), ``arrival_reward`` (1.0), ``time_penalty`` (False),
``time_penalty_coef`` (0.01). :func:`p_arrive_curriculum` gives CommNet's linear curriculum
0.05 -> 0.2 (also IC3Net's, Singh, Jain & Sukhbaatar, 2019).

Demonstrators
-------------
Pure jittable ``(key, state) -> int32 actions [N]`` policies (``hybridmarl.envs.base.Policy``) (sub-optimal on purpose; the paper
needs sub-optimal demonstrations, Section 5.3 reports a demonstrator failing 72% of episodes):
:func:`always_gas` (fails ~97.5% of episodes at p_arrive 0.2, ~18 arrivals per episode) and
:func:`yield_before_junction` (rule documented on the function; ~0-0.3% failures but only ~13
arrivals). :func:`epsilon_demonstrator` adds controlled noise. ``bench/tj_demonstrators.py``
measures them. :data:`DEMONSTRATORS` names them (``always-gas``, ``yield-before-junction``).

Rendering and PettingZoo
------------------------
:meth:`TrafficJunction.render` draws 24-px cells: dark off-road, grey road (lighter junction),
a square per car coloured by route (one hue per entry, one shade per turn; overlapping cars as
stripes), a red frame on cells holding two or more cars, and ``t`` in the corner.
``hybridmarl.envs.pettingzoo.PettingZooAdapter(TrafficJunction())`` is a PettingZoo
``ParallelEnv``: all ``N`` car slots stay agents for the whole episode (an empty slot gets a
zero observation and only action 0 legal; the mask is in the observation dict,
``obs[agent]["action_mask"]``, and in ``infos[agent]["action_mask"]``).
``hybridmarl.envs.video.write_video`` turns rendered frames into a GIF.

Modules
-------
``env`` (geometry, dynamics, :class:`TrafficJunction`, :func:`p_arrive_curriculum`), ``render``
(the pictures) and ``demonstrators`` (:func:`always_gas`, :func:`yield_before_junction`,
:func:`epsilon_demonstrator`, :data:`DEMONSTRATORS`).

Version history
---------------
- v0: initial.
"""

from hybridmarl.envs.traffic_junction.demonstrators import (
    DEMONSTRATORS,
    always_gas,
    canonical_demonstrator,
    epsilon_demonstrator,
    yield_before_junction,
)
from hybridmarl.envs.traffic_junction.env import (
    DIRECTIONS,
    GRID_SIZE,
    JUNCTION_CELLS,
    JUNCTION_START,
    NUM_ROAD_CELLS,
    NUM_ROUTES,
    ROAD_INDEX,
    ROAD_MASK,
    ROUTE_CELLS,
    ROUTE_JUNCTION_MASK,
    ROUTE_LENGTHS,
    ROUTE_NAMES,
    TURNS,
    TJParams,
    TJState,
    TrafficJunction,
    car_cells,
    p_arrive_curriculum,
    route_id,
)

__all__ = [
    "DEMONSTRATORS",
    "DIRECTIONS",
    "GRID_SIZE",
    "JUNCTION_CELLS",
    "JUNCTION_START",
    "NUM_ROAD_CELLS",
    "NUM_ROUTES",
    "ROAD_INDEX",
    "ROAD_MASK",
    "ROUTE_CELLS",
    "ROUTE_JUNCTION_MASK",
    "ROUTE_LENGTHS",
    "ROUTE_NAMES",
    "TURNS",
    "TJParams",
    "TJState",
    "TrafficJunction",
    "always_gas",
    "canonical_demonstrator",
    "car_cells",
    "epsilon_demonstrator",
    "p_arrive_curriculum",
    "route_id",
    "yield_before_junction",
]
