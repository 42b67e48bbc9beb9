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
(reference notes ``shared/reference/traffic_junction_and_baselines.md`` §1.1; coordinates are
``(row, col)``, 0-indexed, row 0 at the top):

- **Road cells**: rows 6 and 7 (all columns) plus columns 6 and 7 (all rows): 52 cells. The
  junction is the 2x2 block rows 6-7 x cols 6-7. Lanes: column 6 southbound, column 7
  northbound, row 7 eastbound, row 6 westbound.
- **Entries** (spawn cells): North (0,6) heading south, East (6,13) heading west, West (7,0)
  heading east, South (13,7) heading north.
- **Routes**: 3 per entry (straight, right turn, left turn), 12 in all, stored as data in
  :data:`ROUTE_CELLS` (``[12, 15, 2]`` int32, padded with -1) and :data:`ROUTE_LENGTHS`
  (13 right / 14 straight / 15 left, counting the entry and exit cells). Route ids follow
  CommNet's global numbering (§1.1 "Route numbering"): sources in the order **N, E, W, S** and
  within a source **straight, right, left**, i.e. ``route_id = 3 * direction + turn``
  (N-straight = 0, N-right = 1, N-left = 2, E-straight = 3, ..., S-left = 11).

Dynamics (CommNet semantics, reference §1.2 A, chosen in §1.2 "Recommendation")
---------------------------------------------------------------------------------
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

There are no cars at ``t = 0`` (reference §1.2 A.6): the first cars appear after the first step.
``reset`` therefore does not use its key; all randomness is drawn in ``step``.

Rewards (paper Section 5.3; reference §1.0)
--------------------------------------------
The reward is global and shared: ``reward = r_c * N_c + r_a * N_a`` with ``r_c = -5`` per car
that is in a shared cell at this step (so a colliding pair gives -10, the same as CommNet's
per-car cost) and ``r_a = +1`` per car arriving at its destination. Optionally
(``time_penalty=True``) each car active at the start of the step also gets ``-0.01 * tau``
(``tau`` = steps since it entered, counted after this step's increment), as in CommNet/IC3Net.
The default is **off**: the paper stresses "global and sparse" rewards and lists only the
collision and arrival terms (reference §1.0 "Time penalty"). ``info["car_rewards"]`` holds the
per-slot terms whose sum is ``reward``.

Termination and success
-----------------------
``done`` after ``max_steps`` steps. An episode **fails** if any collision happened at any step
(``state.failed`` / ``info["failed"]``); success is ``done & ~failed``.

Observation (per car, float32, length ``9 * F + 52`` with ``F = 1 + N + 12``; 259 for N = 10)
---------------------------------------------------------------------------------------------
A CommNet-style {id, location, route} encoding of the 3x3 vision window (paper Section 5.3:
"the observation of a car, which is the same to [Sukhbaatar and Fergus, 2016]"; reference
§1.3), made compact by giving each visible car's location implicitly through the window cell
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
``p_arrive`` (0.2, the evaluation value, reference §1.4), ``max_steps`` (40),
``collision_reward`` (-5.0), ``arrival_reward`` (1.0), ``time_penalty`` (False),
``time_penalty_coef`` (0.01). :func:`p_arrive_curriculum` gives CommNet's linear curriculum
0.05 -> 0.2 (reference §1.4).

Demonstrators
-------------
Pure jittable ``(state, key) -> int32 actions [N]`` policies (sub-optimal on purpose; the paper
needs sub-optimal demonstrations, Section 5.3 reports a demonstrator failing 72% of episodes):
:func:`always_gas` (fails ~97.5% of episodes at p_arrive 0.2, ~18 arrivals per episode) and
:func:`yield_before_junction` (rule documented on the function; ~0-0.3% failures but only ~13
arrivals). :func:`epsilon_demonstrator` adds controlled noise. ``bench/tj_demonstrators.py``
measures them.

Rendering and PettingZoo
------------------------
:meth:`TrafficJunction.render` draws 24-px cells: dark off-road, grey road (lighter junction),
a square per car coloured by route (one hue per entry, one shade per turn; overlapping cars as
stripes), a red frame on cells holding two or more cars, and ``t`` in the corner.
``hybridmarl.envs.pettingzoo.PettingZooAdapter(TrafficJunction())`` is a PettingZoo
``ParallelEnv``: all ``N`` car slots stay agents for the whole episode (an empty slot gets a
zero observation and only action 0 legal; the mask is ``infos[agent]["action_mask"]``).
``hybridmarl.envs.video.write_video`` turns rendered frames into a GIF.

Version history
---------------
- v0: initial.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hybridmarl.envs.base import MultiAgentEnv

__all__ = [
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
    "Demonstrator",
    "TJParams",
    "TJState",
    "TrafficJunction",
    "always_gas",
    "car_cells",
    "epsilon_demonstrator",
    "p_arrive_curriculum",
    "route_id",
    "yield_before_junction",
]

# --------------------------------------------------------------------------------------------
# Geometry (reference §1.1). Built from the lane description, stored as plain numpy data.
# --------------------------------------------------------------------------------------------

GRID_SIZE = 14
DIRECTIONS = ("N", "E", "W", "S")  # CommNet source order, also the spawn order (§1.1, §1.2 A.3)
TURNS = ("straight", "right", "left")
NUM_DIRECTIONS = len(DIRECTIONS)
NUM_ROUTES = NUM_DIRECTIONS * len(TURNS)
MAX_ROUTE_LEN = 15
BRAKE, GAS = 0, 1
NUM_ACTIONS = 2
JUNCTION_CELLS = ((6, 6), (6, 7), (7, 6), (7, 7))
# Every route reaches its first junction cell at index 6 (6 approach cells from the edge).
JUNCTION_START = 6


def _build_routes() -> list[list[tuple[int, int]]]:
    down = [(r, 6) for r in range(14)]  # southbound lane, col 6
    up = [(r, 7) for r in range(13, -1, -1)]  # northbound lane, col 7
    east = [(7, c) for c in range(14)]  # eastbound lane, row 7
    west = [(6, c) for c in range(13, -1, -1)]  # westbound lane, row 6
    return [
        # North entry (0,6), heading south.
        down,
        down[:7] + [(6, c) for c in range(5, -1, -1)],
        down[:8] + [(7, c) for c in range(7, 14)],
        # East entry (6,13), heading west.
        west,
        west[:7] + [(r, 7) for r in range(5, -1, -1)],
        west[:8] + [(r, 6) for r in range(7, 14)],
        # West entry (7,0), heading east.
        east,
        east[:7] + [(r, 6) for r in range(8, 14)],
        east[:8] + [(r, 7) for r in range(6, -1, -1)],
        # South entry (13,7), heading north.
        up,
        up[:7] + [(7, c) for c in range(8, 14)],
        up[:8] + [(6, c) for c in range(6, -1, -1)],
    ]


def _as_tables() -> tuple[np.ndarray, np.ndarray]:
    routes = _build_routes()
    cells = np.full((NUM_ROUTES, MAX_ROUTE_LEN, 2), -1, dtype=np.int32)
    lengths = np.zeros((NUM_ROUTES,), dtype=np.int32)
    for i, route in enumerate(routes):
        cells[i, : len(route)] = route
        lengths[i] = len(route)
    return cells, lengths


ROUTE_CELLS, ROUTE_LENGTHS = _as_tables()
"""``[12, 15, 2]`` route cells (row, col), padded with -1; ``[12]`` route lengths."""
ROUTE_CELLS.setflags(write=False)
ROUTE_LENGTHS.setflags(write=False)
ROUTE_NAMES = tuple(f"{d}-{t}" for d in DIRECTIONS for t in TURNS)

ROAD_MASK = np.zeros((GRID_SIZE, GRID_SIZE), dtype=bool)
ROAD_MASK[6:8, :] = True
ROAD_MASK[:, 6:8] = True
ROAD_MASK.setflags(write=False)
NUM_ROAD_CELLS = int(ROAD_MASK.sum())  # 52
ROAD_INDEX = np.full((GRID_SIZE, GRID_SIZE), -1, dtype=np.int32)
ROAD_INDEX[ROAD_MASK] = np.arange(NUM_ROAD_CELLS, dtype=np.int32)
ROAD_INDEX.setflags(write=False)
"""Road-cell index (row-major over road cells) of each grid cell, -1 off-road."""

_JUNCTION_FLAT = np.array([r * GRID_SIZE + c for r, c in JUNCTION_CELLS], dtype=np.int32)
ROUTE_JUNCTION_MASK = np.array(
    [
        [
            cell in set(map(tuple, ROUTE_CELLS[i, : ROUTE_LENGTHS[i]].tolist()))
            for cell in JUNCTION_CELLS
        ]
        for i in range(NUM_ROUTES)
    ],
    dtype=bool,
)
"""``[12, 4]``: which of :data:`JUNCTION_CELLS` each route crosses (1 right, 2 straight, 3 left)."""
ROUTE_JUNCTION_MASK.setflags(write=False)


def route_id(direction: str, turn: str) -> int:
    """CommNet route id: ``3 * DIRECTIONS.index(direction) + TURNS.index(turn)``."""
    return 3 * DIRECTIONS.index(direction) + TURNS.index(turn)


# --------------------------------------------------------------------------------------------
# State and parameters.
# --------------------------------------------------------------------------------------------


class TJParams(struct.PyTreeNode):
    """Traffic Junction parameters. Every field is a pytree leaf: changing a value (e.g. the
    curriculum's ``p_arrive``) does not trigger recompilation."""

    p_arrive: float = 0.2  # evaluation value, CommNet medium (reference §1.4)
    max_steps: int = 40  # paper Section 5.3
    collision_reward: float = -5.0  # per colliding car per step, paper Section 5.3
    arrival_reward: float = 1.0  # per arriving car, paper Section 5.3
    time_penalty: bool = False  # CommNet's -0.01*tau; off: paper uses sparse rewards (ref §1.0)
    time_penalty_coef: float = 0.01  # CommNet / IC3Net value (reference §1.2)


class TJState(struct.PyTreeNode):
    """One Traffic Junction state. ``N`` = number of car slots (agents).

    ``route``/``pos``/``tau`` of inactive slots are meaningless (kept from the last car).
    """

    route: jax.Array  # int32 [N] route id of the car in each slot
    pos: jax.Array  # int32 [N] index of the car's cell along its route
    active: jax.Array  # bool [N] slot currently holds a car
    tau: jax.Array  # int32 [N] steps since the car entered
    t: jax.Array  # int32 [] steps taken this episode
    failed: jax.Array  # bool [] a collision happened at some step of this episode
    total_collisions: jax.Array  # int32 [] sum over steps of colliding cars (N_c)
    total_arrivals: jax.Array  # int32 [] cars that reached their destination


def _flat_cells(route: jax.Array, pos: jax.Array) -> jax.Array:
    """Flat grid index ``row * 14 + col`` of position ``pos`` along ``route``."""
    cells = jnp.asarray(ROUTE_CELLS)[route, jnp.minimum(pos, jnp.asarray(ROUTE_LENGTHS)[route] - 1)]
    return cells[..., 0] * GRID_SIZE + cells[..., 1]


def car_cells(state: TJState) -> jax.Array:
    """int32 ``[N, 2]`` (row, col) of every slot's car (meaningless where inactive)."""
    lengths = jnp.asarray(ROUTE_LENGTHS)[state.route]
    return jnp.asarray(ROUTE_CELLS)[state.route, jnp.minimum(state.pos, lengths - 1)]


def _empty_state(num_agents: int) -> TJState:
    zeros = jnp.zeros((num_agents,), jnp.int32)
    return TJState(
        route=zeros,
        pos=zeros,
        active=jnp.zeros((num_agents,), bool),
        tau=zeros,
        t=jnp.zeros((), jnp.int32),
        failed=jnp.zeros((), bool),
        total_collisions=jnp.zeros((), jnp.int32),
        total_arrivals=jnp.zeros((), jnp.int32),
    )


def _spawn(
    key: jax.Array, state: TJState, p_arrive: jax.Array | float
) -> tuple[TJState, jax.Array]:
    """Arrivals (reference §1.2 A.3): entries in order N, E, W, S; a random free slot each."""
    n = state.active.shape[0]
    # One draw for everything: each separate jax.random call costs ~0.5 s of XLA compile on CPU.
    u = jax.random.uniform(key, (NUM_DIRECTIONS, 2 + n))
    arrive_u, slot_u = u[:, 0], u[:, 2:]
    turns = jnp.minimum(jnp.floor(u[:, 1] * len(TURNS)).astype(jnp.int32), len(TURNS) - 1)
    slots = jnp.arange(n)
    spawned = jnp.zeros((n,), bool)
    # A static 4-iteration loop: the order matters once the slots run out.
    for d in range(NUM_DIRECTIONS):
        free = ~state.active
        go = jnp.any(free) & (arrive_u[d] < p_arrive)
        slot = jnp.argmax(jnp.where(free, slot_u[d], -1.0))
        new = go & (slots == slot)
        state = state.replace(
            active=state.active | new,
            route=jnp.where(new, 3 * d + turns[d], state.route),
            pos=jnp.where(new, 0, state.pos),
            tau=jnp.where(new, 0, state.tau),
        )
        spawned = spawned | new
    return state, spawned


# --------------------------------------------------------------------------------------------
# The environment.
# --------------------------------------------------------------------------------------------

# 12 route colours for rendering: one hue family per entry, three shades for the turns.
# fmt: off
_ROUTE_COLOURS = np.array(
    [
        (31, 119, 180), (100, 170, 230), (10, 60, 120),  # N: blues
        (44, 160, 44), (120, 210, 110), (20, 95, 20),  # E: greens
        (255, 127, 14), (255, 190, 110), (170, 80, 0),  # W: oranges
        (148, 103, 189), (200, 170, 230), (90, 50, 130),  # S: purples
    ],
    dtype=np.uint8,
)
# fmt: on


class TrafficJunction(MultiAgentEnv[TJState, TJParams]):
    """CommNet "medium" Traffic Junction with the paper's rewards; see the module docstring."""

    def __init__(self, num_agents: int = 10) -> None:
        if num_agents < 1:
            raise ValueError(f"num_agents must be >= 1, got {num_agents}")
        self.name = "traffic_junction_v0"
        self.num_agents = num_agents  # "at most 10 cars" (paper Section 5.3)
        self.agents = tuple(f"car_{i}" for i in range(num_agents))
        self.num_actions = NUM_ACTIONS
        self.cell_feature_size = 1 + num_agents + NUM_ROUTES
        self.observation_shape = (9 * self.cell_feature_size + NUM_ROAD_CELLS,)
        self.critic_feature_size = (
            NUM_DIRECTIONS * num_agents * (self.observation_shape[0] + NUM_ACTIONS)
        )
        self.default_params = TJParams()
        # Used by the PettingZoo adapter for the Box bounds.
        self.observation_bounds = (0.0, float(num_agents))

    # -- core API -----------------------------------------------------------------------------

    def reset(self, key: jax.Array, params: TJParams | None = None) -> tuple[jax.Array, TJState]:
        del key, params  # no cars at t = 0 (reference §1.2 A.6)
        state = _empty_state(self.num_agents)
        return self.observe(state), state

    def step(
        self,
        key: jax.Array,
        state: TJState,
        actions: jax.Array,
        params: TJParams | None = None,
    ) -> tuple[jax.Array, TJState, jax.Array, jax.Array, dict[str, jax.Array]]:
        params = self.default_params if params is None else params
        actions = jnp.asarray(actions)
        active0 = state.active
        lengths = jnp.asarray(ROUTE_LENGTHS)[state.route]
        gas = (actions == GAS) & active0
        pos = jnp.where(gas, jnp.minimum(state.pos + 1, lengths - 1), state.pos)
        tau = state.tau + active0.astype(jnp.int32)

        flat = _flat_cells(state.route, pos)
        counts = (
            jnp.zeros((GRID_SIZE * GRID_SIZE,), jnp.int32).at[flat].add(active0.astype(jnp.int32))
        )
        collided = active0 & (counts[flat] > 1)
        arrived = active0 & (pos == lengths - 1)

        penalty = jnp.where(params.time_penalty, params.time_penalty_coef * tau, 0.0)
        car_rewards = (
            params.collision_reward * collided + params.arrival_reward * arrived - penalty * active0
        ).astype(jnp.float32)
        reward = jnp.sum(car_rewards)

        moved = state.replace(pos=pos, tau=tau, active=active0 & ~arrived)
        new_state, spawned = _spawn(key, moved, params.p_arrive)
        n_collisions = jnp.sum(collided, dtype=jnp.int32)
        n_arrivals = jnp.sum(arrived, dtype=jnp.int32)
        t = state.t + 1
        failed = state.failed | (n_collisions > 0)
        new_state = new_state.replace(
            t=t,
            failed=failed,
            total_collisions=state.total_collisions + n_collisions,
            total_arrivals=state.total_arrivals + n_arrivals,
        )
        done = t >= params.max_steps
        info = {
            "collisions": n_collisions,
            "arrivals": n_arrivals,
            "spawned": jnp.sum(spawned, dtype=jnp.int32),
            "failed": failed,
            "success": done & ~failed,
            "num_active": jnp.sum(new_state.active, dtype=jnp.int32),
            "t": t,
            "collided": collided,
            "arrived": arrived,
            "car_rewards": car_rewards,
        }
        return self.observe(new_state), new_state, reward, done, info

    def get_avail_actions(self, state: TJState, params: TJParams | None = None) -> jax.Array:
        del params
        return jnp.stack([jnp.ones_like(state.active), state.active], axis=-1)

    def agent_active(self, state: TJState) -> jax.Array:
        return state.active

    def observe(self, state: TJState) -> jax.Array:
        """float32 ``[N, 259]`` observations (layout in the module docstring)."""
        n = self.num_agents
        active = state.active
        cells = car_cells(state)
        per_car = (
            jnp.concatenate(
                [
                    jnp.ones((n, 1), jnp.float32),
                    jnp.eye(n, dtype=jnp.float32),
                    jax.nn.one_hot(state.route, NUM_ROUTES, dtype=jnp.float32),
                ],
                axis=-1,
            )
            * active[:, None]
        )
        # Pad by one cell on every side so every 3x3 window is in bounds.
        grid = jnp.zeros((GRID_SIZE + 2, GRID_SIZE + 2, self.cell_feature_size), jnp.float32)
        grid = grid.at[cells[:, 0] + 1, cells[:, 1] + 1].add(per_car)

        def window(row: jax.Array, col: jax.Array) -> jax.Array:
            return jax.lax.dynamic_slice(grid, (row, col, 0), (3, 3, self.cell_feature_size))

        vision = jax.vmap(window)(cells[:, 0], cells[:, 1]).reshape(n, -1)
        location = jax.nn.one_hot(
            jnp.asarray(ROAD_INDEX)[cells[:, 0], cells[:, 1]], NUM_ROAD_CELLS, dtype=jnp.float32
        )
        return jnp.concatenate([vision, location], axis=-1) * active[:, None]

    def critic_features(self, state: TJState, actions: jax.Array) -> jax.Array:
        n = self.num_agents
        active = state.active
        per_car = jnp.concatenate(
            [
                self.observe(state),
                jax.nn.one_hot(actions, NUM_ACTIONS, dtype=jnp.float32) * active[:, None],
            ],
            axis=-1,
        )
        direction = state.route // len(TURNS)
        ids = jnp.arange(n)

        def group(d: jax.Array) -> jax.Array:
            member = active & (direction == d)
            score = jnp.where(member, state.pos * n + (n - 1 - ids), -1)
            order = jnp.argsort(-score, stable=True)
            return per_car[order] * member[order][:, None]

        return jax.vmap(group)(jnp.arange(NUM_DIRECTIONS)).reshape(-1)

    # -- helpers ------------------------------------------------------------------------------

    def make_state(
        self,
        cars: Sequence[tuple[int, int, int]] = (),
        *,
        t: int = 0,
        taus: Sequence[int] | None = None,
        failed: bool = False,
    ) -> TJState:
        """Build a state by hand from ``(slot, route_id, pos)`` triples (tests, debugging)."""
        n = self.num_agents
        route = np.zeros((n,), np.int32)
        pos = np.zeros((n,), np.int32)
        active = np.zeros((n,), bool)
        tau = np.zeros((n,), np.int32)
        for i, (slot, rid, p) in enumerate(cars):
            if not 0 <= slot < n or active[slot]:
                raise ValueError(f"bad or duplicate slot {slot}")
            if not 0 <= rid < NUM_ROUTES or not 0 <= p < ROUTE_LENGTHS[rid] - 1:
                raise ValueError(f"bad route/pos {(rid, p)}: a car never rests on its exit cell")
            route[slot], pos[slot], active[slot] = rid, p, True
            tau[slot] = p if taus is None else taus[i]
        return TJState(
            route=jnp.asarray(route),
            pos=jnp.asarray(pos),
            active=jnp.asarray(active),
            tau=jnp.asarray(tau),
            t=jnp.asarray(t, jnp.int32),
            failed=jnp.asarray(failed),
            total_collisions=jnp.zeros((), jnp.int32),
            total_arrivals=jnp.zeros((), jnp.int32),
        )

    def render(
        self, state: TJState, params: TJParams | None = None, cell_px: int = 24
    ) -> np.ndarray:
        """uint8 ``[14*cell_px, 14*cell_px, 3]``: dark off-road, grey road (lighter junction),
        a square per car coloured by route, a red frame on cells holding 2+ cars."""
        del params
        from PIL import Image, ImageDraw

        g, c = GRID_SIZE, cell_px
        img = np.full((g * c, g * c, 3), 40, dtype=np.uint8)
        for r in range(g):
            for col in range(g):
                if ROAD_MASK[r, col]:
                    shade = 170 if (r, col) in JUNCTION_CELLS else 135
                    img[r * c + 1 : (r + 1) * c - 1, col * c + 1 : (col + 1) * c - 1] = shade
        active = np.asarray(state.active)
        cells = np.asarray(car_cells(state))
        routes = np.asarray(state.route)
        occupants: dict[tuple[int, int], list[int]] = {}
        for i in np.flatnonzero(active):
            occupants.setdefault((int(cells[i, 0]), int(cells[i, 1])), []).append(int(routes[i]))
        m = max(c // 6, 1)
        red = np.array((220, 20, 20), np.uint8)
        for (r, col), rids in occupants.items():
            y0, y1, x0, x1 = r * c, (r + 1) * c, col * c, (col + 1) * c
            # Overlapping cars share the square as vertical stripes, so each stays visible.
            edges = np.linspace(x0 + m, x1 - m, len(rids) + 1).round().astype(int)
            for k, rid in enumerate(rids):
                img[y0 + m : y1 - m, edges[k] : edges[k + 1]] = _ROUTE_COLOURS[rid]
            if len(rids) > 1:
                f = max(c // 12, 1)
                img[y0 : y0 + f, x0:x1] = red
                img[y1 - f : y1, x0:x1] = red
                img[y0:y1, x0 : x0 + f] = red
                img[y0:y1, x1 - f : x1] = red
        pil = Image.fromarray(img)
        ImageDraw.Draw(pil).text((3, 2), f"t={int(state.t)}", fill=(230, 230, 230))
        return np.asarray(pil, dtype=np.uint8).copy()


# --------------------------------------------------------------------------------------------
# Curriculum (reference §1.4).
# --------------------------------------------------------------------------------------------


def p_arrive_curriculum(
    epoch: int | jax.Array,
    *,
    start: float = 0.05,
    end: float = 0.2,
    start_epoch: int = 100,
    end_epoch: int = 200,
    quantum: float = 0.01,
) -> jax.Array:
    """Linearly anneal ``p_arrive`` from ``start`` to ``end`` between ``start_epoch`` and
    ``end_epoch`` (constant outside), rounded towards ``start`` to multiples of ``quantum``.

    Defaults are CommNet's medium curriculum (add_rate 0.05 -> 0.2, epochs 100 -> 200 of 300;
    IC3Net uses the same rule with 0.01 quantisation), reference §1.4. "Epoch" is whatever unit
    the caller counts (epochs, updates or episodes). ``quantum=0`` disables rounding. Jittable;
    use as ``params.replace(p_arrive=p_arrive_curriculum(epoch))``.
    """
    span = max(end_epoch - start_epoch, 1)
    frac = jnp.clip((jnp.asarray(epoch, jnp.float32) - start_epoch) / span, 0.0, 1.0)
    delta = (end - start) * frac
    if quantum > 0:
        # The epsilon keeps exact multiples (e.g. 0.15) from flooring one quantum too low.
        delta = jnp.sign(delta) * jnp.floor(jnp.abs(delta) / quantum + 1e-4) * quantum
    return jnp.asarray(start + delta, jnp.float32)


# --------------------------------------------------------------------------------------------
# Demonstrators: pure, jittable (state, key) -> int32 actions [N].
# --------------------------------------------------------------------------------------------

Demonstrator = Callable[[TJState, jax.Array], jax.Array]


def always_gas(state: TJState, key: jax.Array) -> jax.Array:
    """Gas for every active car (brake for inactive slots, the only legal action there).

    Probably the paper's demonstrator: Section 5.3 notes that "the network needs to learn
    'forward' at any time" to imitate it.
    """
    del key
    return state.active.astype(jnp.int32)


def yield_before_junction(state: TJState, key: jax.Array) -> jax.Array:
    """A myopic "first come, first served stop line" rule (reference §1.5 suggestion 2, ours).

    For an active car at route index ``p`` (every route's junction starts at index 6, so
    ``p == 5`` is the stop line):

    - **Stop line**: brake iff a junction cell on its route holds another car now, or is the
      next cell of a car now inside the junction ("about to be occupied": cars in the junction
      are assumed to go), or another car waiting at its own stop line has priority and their
      junction paths share a cell. Priority: the car that entered the grid earlier (larger
      ``tau``), then entry direction N > E > W > S, then lower id.
    - **Elsewhere** (approach lanes, junction, exit lanes): brake iff a car in the next cell of
      its route brakes (resolved front to back, so a queue moves as a platoon); cars inside
      the junction are thus never held by the stop-line rule.
    - **Shared cell** (e.g. a car spawned onto a queued car): only the oldest car of the cell
      (larger ``tau``, then lower id) may go; the others brake.

    It is safe but slow, i.e. sub-optimal in the other direction from :func:`always_gas`: a
    stop-line car waits until every junction cell of its path is clear, so junction crossings
    are serialised. It cannot stop a new car from spawning onto a queue that has backed up to
    the entry cell (both then brake and collide every step), which is its only failure mode in
    practice. Measured with ``bench/tj_demonstrators.py`` (1000 episodes, p_arrive 0.2): about
    0-0.3% failures and 13.0 arrivals per episode, against about 97.5% failures and 18.0
    arrivals for :func:`always_gas` (2.4% failures at p_arrive 0.5). Not tuned; mix it with
    :func:`epsilon_demonstrator` for a demonstrator of intermediate quality.
    """
    del key
    n = state.active.shape[0]
    active = state.active
    pos, route, tau = state.pos, state.route, state.tau
    lengths = jnp.asarray(ROUTE_LENGTHS)[route]
    flat = _flat_cells(route, pos)
    nxt = _flat_cells(route, jnp.minimum(pos + 1, lengths - 1))
    ids = jnp.arange(n)
    other = active[None, :] & (ids[None, :] != ids[:, None])  # [i, j]: j is another live car

    junction = jnp.asarray(_JUNCTION_FLAT)
    in_junction = active & jnp.any(flat[:, None] == junction[None, :], axis=1)
    # [i, k]: junction cell k holds a car other than i, or is the next cell of one in the junction.
    held = jnp.any(other[:, :, None] & (flat[None, :, None] == junction[None, None, :]), axis=1)
    claimed = jnp.any(
        (other & in_junction[None, :])[:, :, None]
        & (nxt[None, :, None] == junction[None, None, :]),
        axis=1,
    )
    path = jnp.asarray(ROUTE_JUNCTION_MASK)[route]  # [N, 4]
    path_blocked = jnp.any(path & (held | claimed), axis=1)

    at_stop = active & (pos == JUNCTION_START - 1)
    direction = route // len(TURNS)
    conflict = jnp.any(path[:, None, :] & path[None, :, :], axis=-1)
    # [i, j]: j has priority over i.
    first = (tau[None, :] > tau[:, None]) | (
        (tau[None, :] == tau[:, None])
        & (
            (direction[None, :] < direction[:, None])
            | ((direction[None, :] == direction[:, None]) & (ids[None, :] < ids[:, None]))
        )
    )
    rival = jnp.any(other & at_stop[None, :] & conflict & first, axis=1)

    older = (tau[None, :] > tau[:, None]) | (
        (tau[None, :] == tau[:, None]) & (ids[None, :] < ids[:, None])
    )
    not_oldest = jnp.any(other & (flat[None, :] == flat[:, None]) & older, axis=1)

    base = not_oldest | (at_stop & (path_blocked | rival))
    ahead = other & (nxt[:, None] == flat[None, :])  # [i, j]: j stands in i's next cell
    follows = active & ~at_stop

    def propagate(_: int, brake: jax.Array) -> jax.Array:
        return base | (follows & jnp.any(ahead & brake[None, :], axis=1))

    # A chain of followers has at most n cars, so n rounds reach the fixed point.
    brake = jax.lax.fori_loop(0, n, propagate, base)
    return (active & ~brake).astype(jnp.int32)


def epsilon_demonstrator(policy: Demonstrator, epsilon: float) -> Demonstrator:
    """``policy`` with each active car's action replaced by a uniform one with prob ``epsilon``
    (reference §1.5 suggestion 3: controlled sub-optimality). Still pure and jittable."""

    def noisy(state: TJState, key: jax.Array) -> jax.Array:
        k_policy, k_flip, k_act = jax.random.split(key, 3)
        actions = policy(state, k_policy)
        n = actions.shape[0]
        flip = jax.random.uniform(k_flip, (n,)) < epsilon
        random_actions = jax.random.randint(k_act, (n,), 0, NUM_ACTIONS)
        return jnp.where(flip & state.active, random_actions, actions).astype(jnp.int32)

    return noisy
