"""Traffic Junction demonstrators: pure, jittable env policies ``(key, state) -> int32
actions [N]`` (:data:`hybridmarl.envs.base.Policy`), sub-optimal on purpose (paper Section 5.3)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hybridmarl.envs.base import Policy
from hybridmarl.envs.traffic_junction.env import (
    JUNCTION_FLAT,
    JUNCTION_START,
    NUM_ACTIONS,
    ROUTE_JUNCTION_MASK,
    ROUTE_LENGTHS,
    TURNS,
    TJState,
    flat_cells,
)

__all__ = [
    "DEMONSTRATORS",
    "DEMONSTRATOR_ALIASES",
    "always_gas",
    "canonical_demonstrator",
    "epsilon_demonstrator",
    "yield_before_junction",
]


def always_gas(key: jax.Array, state: TJState) -> jax.Array:
    """Gas for every active car (brake for inactive slots, the only legal action there).

    Probably the paper's demonstrator: Section 5.3 notes that "the network needs to learn
    'forward' at any time" to imitate it.
    """
    del key
    return state.active.astype(jnp.int32)


def yield_before_junction(key: jax.Array, state: TJState) -> jax.Array:
    """A myopic "first come, first served stop line" rule (ours).

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
    flat = flat_cells(route, pos)
    nxt = flat_cells(route, jnp.minimum(pos + 1, lengths - 1))
    ids = jnp.arange(n)
    other = active[None, :] & (ids[None, :] != ids[:, None])  # [i, j]: j is another live car

    junction = jnp.asarray(JUNCTION_FLAT)
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


def epsilon_demonstrator(policy: Policy, epsilon: float) -> Policy:
    """``policy`` with each active car's action replaced by a uniform one with prob ``epsilon``
    (controlled sub-optimality). Still pure and jittable."""

    def noisy(key: jax.Array, state: TJState) -> jax.Array:
        k_policy, k_flip, k_act = jax.random.split(key, 3)
        actions = policy(k_policy, state)
        n = actions.shape[0]
        flip = jax.random.uniform(k_flip, (n,)) < epsilon
        random_actions = jax.random.randint(k_act, (n,), 0, NUM_ACTIONS)
        return jnp.where(flip & state.active, random_actions, actions).astype(jnp.int32)

    return noisy


#: The demonstrators by canonical name.
DEMONSTRATORS: dict[str, Policy] = {
    "always-gas": always_gas,
    "yield-before-junction": yield_before_junction,
}
#: Short names accepted for them.
DEMONSTRATOR_ALIASES = {"gas": "always-gas", "yield": "yield-before-junction"}


def canonical_demonstrator(name: str) -> str:
    """The canonical name of a demonstrator (``_`` for ``-`` and the aliases accepted);
    ``ValueError`` if unknown."""
    key = str(name).strip().lower().replace("_", "-")
    key = DEMONSTRATOR_ALIASES.get(key, key)
    if key not in DEMONSTRATORS:
        raise ValueError(
            f"unknown traffic_junction demonstrator {name!r} (known: {', '.join(DEMONSTRATORS)})"
        )
    return key
