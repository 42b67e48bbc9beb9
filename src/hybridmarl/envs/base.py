"""The functional multi-agent environment interface shared by every hybridmarl environment.

An environment is a stateless object holding only *static* configuration (number of agents,
shapes); everything that changes during an episode lives in an immutable ``state`` pytree
(a ``flax.struct`` dataclass with fixed shapes), and everything a user may want to tune
without recompiling lives in a ``params`` pytree. This is the gymnax / JaxMARL style: it lets
the training code ``jax.jit`` and ``jax.vmap`` whole rollouts, and it is what the paper's
Alg. 1 needs (Section 4.2: "one-step forward simulation" from an arbitrary state, i.e. the
simulator must be callable on a stored state, side-effect free).

Conventions every implementation follows:

- ``reset``/``step``/``get_avail_actions``/``agent_active``/``critic_features`` are pure and
  jit-/vmap-able. ``render`` is plain numpy and is called outside ``jit``.
- Observations are float32 ``[num_agents, *observation_shape]``. Agents that are not currently
  in play (e.g. a Traffic Junction car slot with no car) get all-zero observations,
  ``agent_active == False`` and only action 0 legal, so that every array keeps a fixed shape.
- ``reward`` is the global team reward of the step (a float32 scalar): the paper's setting is a
  shared, sparse, global reward (Section 1 and Section 5.3).
- ``done`` is a bool scalar. There is no auto-reset: callers decide what to do at episode end.
- ``info`` is a dict of fixed-shape arrays with the same keys at every step, so it can be
  carried through ``jax.lax.scan`` and ``jax.vmap``.

``hybridmarl.envs.pettingzoo.PettingZooAdapter`` turns any ``MultiAgentEnv`` into a
PettingZoo ``ParallelEnv``.
"""

from __future__ import annotations

from typing import Any, Protocol, TypeVar, runtime_checkable

import jax
import numpy as np

__all__ = ["MultiAgentEnv", "StepResult"]

StateT = TypeVar("StateT")
ParamsT = TypeVar("ParamsT")

# (obs, state, reward, done, info); kept a plain tuple so it unpacks the same under jit and vmap.
StepResult = tuple[jax.Array, Any, jax.Array, jax.Array, dict[str, jax.Array]]


@runtime_checkable
class MultiAgentEnv(Protocol[StateT, ParamsT]):
    """A pure-functional, fixed-shape, cooperative multi-agent environment.

    Attributes:
        name: short identifier, e.g. ``"traffic_junction_v0"``.
        num_agents: number of agent slots (fixed for the life of the object).
        agents: the agent names, one per slot, in slot order (e.g. ``"car_0"`` .. ``"car_9"``).
        num_actions: size of every agent's discrete action space.
        observation_shape: shape of one agent's observation.
        critic_feature_size: length of the centralised critic's input vector.
        default_params: the environment parameters used when ``params`` is ``None``.
    """

    name: str
    num_agents: int
    agents: tuple[str, ...]
    num_actions: int
    observation_shape: tuple[int, ...]
    critic_feature_size: int
    default_params: ParamsT

    def reset(self, key: jax.Array, params: ParamsT | None = None) -> tuple[jax.Array, StateT]:
        """Start an episode. Returns ``(obs [num_agents, *observation_shape] f32, state)``."""
        ...

    def step(
        self,
        key: jax.Array,
        state: StateT,
        actions: jax.Array,
        params: ParamsT | None = None,
    ) -> tuple[jax.Array, StateT, jax.Array, jax.Array, dict[str, jax.Array]]:
        """Advance one step with int ``actions [num_agents]``.

        Returns ``(obs, new_state, reward f32[], done bool[], info)``. No auto-reset.
        """
        ...

    def get_avail_actions(self, state: StateT, params: ParamsT | None = None) -> jax.Array:
        """Legal-action mask, bool ``[num_agents, num_actions]``; inactive agents: only 0."""
        ...

    def agent_active(self, state: StateT) -> jax.Array:
        """bool ``[num_agents]``: which agent slots are currently in play."""
        ...

    def critic_features(self, state: StateT, actions: jax.Array) -> jax.Array:
        """Centralised critic input for ``(state, joint action)``, f32 ``[critic_feature_size]``."""
        ...

    def render(self, state: StateT, params: ParamsT | None = None) -> np.ndarray:
        """An RGB picture of ``state``, uint8 ``[H, W, 3]`` (numpy; call outside jit)."""
        ...
