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

What the learners need from an environment
------------------------------------------
The training code (``hybridmarl.training.task.Task``) never branches on which environment it
runs; everything environment-specific comes from the environment class, through the
:class:`LearningEnv` protocol:

- ``from_spec(spec, enemy_script=None) -> (env, params)`` builds the env from a task description
  (``TaskSpec``: ``scenario``, ``enemy``, ``max_turns``, ``p_arrive``, ``num_cars``, ...);
  ``spec_label(spec)`` names it in one line;
- ``metric_names`` (the per-episode metrics, float32), ``progress_metrics`` (the (primary,
  secondary) metric of progress lines and learning curves), ``episode_metrics(state, info)``
  (their values for an episode whose last step returned ``(state, info)``);
- ``agent_rewards(state, next_state, done, info)``: per-agent rewards ``[N]`` of one step, for
  the independent learners (DQfD, OGTL; paper Section 5.2);
- ``demonstrator_names``, ``canonical_demonstrator(name)`` (a user-given name, aliases
  accepted, to its canonical form; ``ValueError`` if unknown) and ``demonstrator(name)``: a
  scripted demonstrator as a :data:`Policy`;
- ``has_enemy``: whether the env plays a scripted opponent (``TaskSpec.enemy``);
- ``summarize(episodes)``: the evaluation summary (win rate and terminal reward, or failure
  rate, with 95% intervals) of per-episode metrics, and ``result_line(summary)``: it as one
  line.

Policies
--------
Every env-level policy (scripted demonstrators, a trained actor wrapped for an env) has one
signature, :data:`Policy`: ``(key, state) -> int32 actions [num_agents]``. It is pure and
jittable. A demonstrator name may carry noise, ``NAME:EPSILON`` (:func:`split_noise`): each
agent's action is then replaced by a uniformly random legal one with probability ``EPSILON``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Protocol, TypeVar, runtime_checkable

import jax
import numpy as np

__all__ = [
    "LearningEnv",
    "MultiAgentEnv",
    "Policy",
    "StepResult",
    "canonical_policy_name",
    "split_noise",
]

StateT = TypeVar("StateT")
ParamsT = TypeVar("ParamsT")

# (obs, state, reward, done, info); kept a plain tuple so it unpacks the same under jit and vmap.
StepResult = tuple[jax.Array, Any, jax.Array, jax.Array, dict[str, jax.Array]]

#: An env-level policy: ``(key, state) -> int32 actions [num_agents]`` (pure, jittable).
Policy = Callable[[jax.Array, Any], jax.Array]


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


@runtime_checkable
class LearningEnv(MultiAgentEnv[StateT, ParamsT], Protocol[StateT, ParamsT]):
    """A :class:`MultiAgentEnv` that also says what learning on it needs (module docstring)."""

    metric_names: ClassVar[tuple[str, ...]]
    progress_metrics: ClassVar[tuple[str, str]]
    demonstrator_names: ClassVar[tuple[str, ...]]
    has_enemy: ClassVar[bool]

    @classmethod
    def from_spec(
        cls, spec: Any, enemy_script: Callable[..., jax.Array] | None = None
    ) -> tuple[Any, Any]:
        """``(env, params)`` built from a task description; ``enemy_script`` (an engine script)
        replaces ``spec.enemy`` where the env has an enemy."""
        ...

    @classmethod
    def spec_label(cls, spec: Any) -> str:
        """A one-line name of the task ``spec`` describes."""
        ...

    @classmethod
    def canonical_demonstrator(cls, name: str) -> str:
        """The canonical form of a demonstrator name (no ``:EPSILON``); ``ValueError`` if unknown."""
        ...

    def demonstrator(self, name: str) -> Policy:
        """The demonstrator ``name`` (canonical, no ``:EPSILON``) as a :data:`Policy`."""
        ...

    def episode_metrics(self, state: StateT, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """float32 ``metric_names`` of an episode whose last step returned ``(state, info)``."""
        ...

    def agent_rewards(
        self, state: StateT, next_state: StateT, done: jax.Array, info: dict[str, jax.Array]
    ) -> jax.Array:
        """float32 ``[num_agents]`` per-agent rewards of the step ``state -> next_state``."""
        ...

    @classmethod
    def summarize(cls, episodes: Mapping[str, np.ndarray]) -> dict[str, Any]:
        """Evaluation summary of per-episode metrics (``metric_names`` plus ``return``)."""
        ...

    @classmethod
    def result_line(cls, result: Mapping[str, Any]) -> str:
        """One line of an evaluation result (``summarize``'s dict, plus ``n`` and ``enemy``)."""
        ...


def split_noise(name: str) -> tuple[str, float]:
    """``"attack-closest:0.1"`` -> (``"attack-closest"``, 0.1); no suffix: epsilon 0.
    ``ValueError`` for a malformed suffix or an epsilon outside [0, 1]."""
    base, _, eps = str(name).partition(":")
    if not eps:
        return base.strip(), 0.0
    try:
        e = float(eps)
    except ValueError:
        raise ValueError(f"demonstrator {name!r}: expected NAME or NAME:EPSILON") from None
    if not 0.0 <= e <= 1.0:
        raise ValueError(f"demonstrator {name!r}: epsilon must be in [0, 1]")
    return base.strip(), e


def canonical_policy_name(env_cls: Any, name: str) -> str:
    """``name`` with its base made canonical by ``env_cls.canonical_demonstrator`` (a
    ``:EPSILON`` suffix is kept, as ``:%g``)."""
    base, eps = split_noise(name)
    base = env_cls.canonical_demonstrator(base)
    return f"{base}:{eps:g}" if eps > 0 else base
