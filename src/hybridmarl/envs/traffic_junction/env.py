"""The Traffic Junction environment: geometry, dynamics and :class:`TrafficJunction`.

The environment's description is the package's docstring, :mod:`hybridmarl.envs.traffic_junction`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hybridmarl.envs.base import LearningEnv, Policy
from hybridmarl.envs.stats import t_interval, wilson_interval

__all__ = [
    "BRAKE",
    "DIRECTIONS",
    "GAS",
    "GRID_SIZE",
    "JUNCTION_CELLS",
    "JUNCTION_FLAT",
    "JUNCTION_START",
    "NUM_ACTIONS",
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
    "car_cells",
    "flat_cells",
    "p_arrive_curriculum",
    "route_id",
]

# --------------------------------------------------------------------------------------------
# Geometry. Built from the lane description, stored as plain numpy data.
# --------------------------------------------------------------------------------------------

GRID_SIZE = 14
DIRECTIONS = ("N", "E", "W", "S")  # CommNet source order, also the spawn order
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

#: Flat grid index (``row * 14 + col``) of each of :data:`JUNCTION_CELLS`.
JUNCTION_FLAT = np.array([r * GRID_SIZE + c for r, c in JUNCTION_CELLS], dtype=np.int32)
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

    p_arrive: float = 0.2  # evaluation value, CommNet medium
    max_steps: int = 40  # paper Section 5.3
    collision_reward: float = -5.0  # per colliding car per step, paper Section 5.3
    arrival_reward: float = 1.0  # per arriving car, paper Section 5.3
    time_penalty: bool = False  # CommNet's -0.01*tau; off: the paper's rewards are sparse
    time_penalty_coef: float = 0.01  # CommNet / IC3Net value


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


def flat_cells(route: jax.Array, pos: jax.Array) -> jax.Array:
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
    """Arrivals: entries in order N, E, W, S; a random free slot each."""
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


class TrafficJunction(LearningEnv[TJState, TJParams]):
    """CommNet "medium" Traffic Junction with the paper's rewards; see
    :mod:`hybridmarl.envs.traffic_junction`."""

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
        del key, params  # no cars at t = 0
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

        flat = flat_cells(state.route, pos)
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
        """float32 ``[N, 259]`` observations (layout in :mod:`hybridmarl.envs.traffic_junction`)."""
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
        from hybridmarl.envs.traffic_junction.render import render

        return render(state, cell_px)

    # -- learning on it (``hybridmarl.envs.base.LearningEnv``) -------------------------------------

    metric_names: ClassVar[tuple[str, ...]] = ("failed", "success", "collisions", "arrivals")
    #: Progress lines and curves: lower failure rate, then higher return.
    progress_metrics: ClassVar[tuple[str, str]] = ("failed", "return")
    demonstrator_names: ClassVar[tuple[str, ...]] = ("always-gas", "yield-before-junction")
    has_enemy: ClassVar[bool] = False

    @classmethod
    def from_spec(cls, spec: Any, enemy_script: Any = None) -> tuple[TrafficJunction, TJParams]:
        """``spec.num_cars`` car slots, ``spec.p_arrive`` and ``spec.time_penalty``; a
        ``spec.setting`` other than the default fixes ``p_arrive`` (``hybridmarl.settings``)."""
        if enemy_script is not None:
            raise ValueError("traffic_junction has no enemy to replace")
        from hybridmarl.settings import check_options

        check_options(getattr(spec, "setting", None), p_arrive=float(spec.p_arrive))
        env = cls(num_agents=spec.num_cars)
        params = env.default_params.replace(
            p_arrive=float(spec.p_arrive), time_penalty=bool(spec.time_penalty)
        )
        return env, params

    @classmethod
    def spec_label(cls, spec: Any) -> str:
        setting = getattr(spec, "setting", "sparcraft")
        extra = (", time penalty" if spec.time_penalty else "") + (
            "" if setting == "sparcraft" else f", {setting} setting"
        )
        return f"traffic_junction (p_arrive {spec.p_arrive:g}{extra})"

    @classmethod
    def canonical_demonstrator(cls, name: str) -> str:
        from hybridmarl.envs.traffic_junction.demonstrators import canonical_demonstrator

        return canonical_demonstrator(name)

    def demonstrator(self, name: str) -> Policy:
        """:func:`always_gas` or :func:`yield_before_junction` by name."""
        from hybridmarl.envs.traffic_junction.demonstrators import (
            DEMONSTRATORS,
            canonical_demonstrator,
        )

        return DEMONSTRATORS[canonical_demonstrator(name)]

    def episode_metrics(self, state: TJState, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
        del info
        f = jnp.float32
        return {
            "failed": state.failed.astype(f),
            "success": (~state.failed).astype(f),
            "collisions": state.total_collisions.astype(f),
            "arrivals": state.total_arrivals.astype(f),
        }

    def agent_rewards(
        self, state: TJState, next_state: TJState, done: jax.Array, info: dict[str, jax.Array]
    ) -> jax.Array:
        """The env's own per-car reward terms, ``info["car_rewards"]`` (collision -5 per
        colliding car, arrival +1 per arriving car; they sum to the global reward). The paper
        does not evaluate DQfD/OGTL here ("the reward cannot be decomposed directly", Section
        5.3); this is what the env offers."""
        del state, next_state, done
        return jnp.asarray(info["car_rewards"], jnp.float32)

    @classmethod
    def summarize(cls, episodes: Mapping[str, np.ndarray]) -> dict[str, Any]:
        """The failure rate (an episode fails when any collision happens) with its 95% Wilson
        interval; ``W`` is the success rate and ``R`` the mean return (Section 5.3)."""
        ep = episodes
        n = int(next(iter(ep.values())).shape[0])
        fails = int(np.sum(ep["failed"] > 0.5))
        lo, hi = wilson_interval(fails, n)
        slo, shi = wilson_interval(n - fails, n)
        r, rlo, rhi = t_interval(ep["return"])
        return dict(
            failure_rate=fails / n,
            failure_rate_ci95=[lo, hi],
            W=(n - fails) / n,
            W_ci95=[slo, shi],
            R=r,
            R_ci95=[rlo, rhi],
            mean_arrivals=float(np.mean(ep["arrivals"])),
            mean_collisions=float(np.mean(ep["collisions"])),
        )

    @classmethod
    def result_line(cls, result: Mapping[str, Any]) -> str:
        r = result
        return (
            f"eval ({r['n']} episodes): failure rate {r['failure_rate']:.3f} "
            f"[{r['failure_rate_ci95'][0]:.3f}, {r['failure_rate_ci95'][1]:.3f}]  "
            f"arrivals/episode {r['mean_arrivals']:.1f}  return {r['R']:+.2f}"
        )


# --------------------------------------------------------------------------------------------
# Curriculum.
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
    IC3Net uses the same rule with 0.01 quantisation). "Epoch" is whatever unit
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
