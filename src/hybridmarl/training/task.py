"""A task = an environment plus what the learners need around it, behind one small interface.

The learners (``algos.hybrid``, ``algos.bc``, ...) never branch on the environment; they use a
:class:`Task`, and the Task does not branch either: everything environment-specific comes from
the environment's class (``hybridmarl.envs.env_class``, protocol ``hybridmarl.envs.base.LearningEnv``).

- ``env``: the functional environment (``hybridmarl.envs``), with its ``reset``/``step``/masks;
- ``demonstrator(name)``: a scripted demonstrator as a pure env policy ``(key, state) -> [N]``:
  for combat any engine script (``attack-closest`` = the paper's c, ``attack-weakest`` = w,
  converted to env actions by ``Combat.script_policy``: attack slot -> HP rank, moves 2..5 ->
  1..4, RELOAD/PASS -> noop); for Traffic Junction ``always-gas`` / ``yield-before-junction``.
  ``name:eps`` adds ε-random legal actions (controlled sub-optimality, e.g. ``always-gas:0.1``);
- ``lookahead(key, state, candidates [A, N])``: Alg. 1's one-step forward simulation
  ``(reward [A], next_state [A], done [A])`` of A joint actions, one vmapped call (combat's own
  ``Combat.lookahead``; for other envs ``vmap(step)`` with one shared key, so every candidate
  sees the same random arrivals: common random numbers);
- ``value_features(state)``: the critic's input for ``V(s)`` (``env.critic_features`` with
  all-zero actions: combat ignores actions, and for Traffic Junction the paper's
  per-car "action one-hot" part then only marks which cars are present);
- ``episode_stats(state, info)``: the per-episode metrics at the end of an episode;
- ``summarize(episodes)`` / ``result_line(summary)``: the evaluation summary of per-episode
  metrics and its one-line form.

``TaskSpec`` is the hashable, JSON-able description stored in run metadata and datasets.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl import envs
from hybridmarl.envs.base import Policy, canonical_policy_name, split_noise
from hybridmarl.errors import UserError
from hybridmarl.io import flatten_named, unflatten_named

ENV_CHOICES = envs.ENV_NAMES


class TaskError(UserError):
    """Bad task settings (unknown env, scenario, script, ...): a one-line message."""


def canonical_env(name: str) -> str:
    """The canonical environment name (``hybridmarl.envs.ENV_NAMES``); ``TaskError`` if unknown."""
    try:
        return envs.canonical_env_name(name)
    except ValueError:
        raise TaskError(f"unknown env {name!r} (known: {', '.join(ENV_CHOICES)})") from None


def split_demonstrator(name: str) -> tuple[str, float]:
    """``"attack-closest:0.1"`` -> (``"attack-closest"``, 0.1)."""
    try:
        return split_noise(name)
    except ValueError as e:
        raise TaskError(str(e.args[0])) from None


def canonical_script(env: str, name: str) -> str:
    """Canonical demonstrator / enemy script name for ``env`` (keeps a ``:eps`` suffix)."""
    cls = envs.env_class(canonical_env(env))
    try:
        return canonical_policy_name(cls, name)
    except ValueError as e:
        raise TaskError(str(e.args[0])) from None


def default_enemy(demonstrator: str) -> str:
    """The cross-validation enemy of a demonstrator (c <-> w), else attack-weakest (combat)."""
    from hybridmarl.envs.combat.opponents import cross_enemy

    return cross_enemy(demonstrator)


@dataclass(frozen=True)
class TaskSpec:
    """Which environment, built how. Hashable (cache key) and JSON-able (run metadata)."""

    env: str = "combat"
    scenario: str = "m5v5"
    enemy: str = "attack-weakest"
    max_turns: int = 1000
    p_arrive: float = 0.2
    num_cars: int = 10
    time_penalty: bool = False
    #: The named setting (``hybridmarl.settings``): combat rules and scenario geometry; for
    #: traffic_junction, ``paper`` fixes ``p_arrive``. Run metadata without it reads as the default.
    setting: str = "sparcraft"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> TaskSpec:
        fields = TaskSpec.__dataclass_fields__
        return TaskSpec(**{k: v for k, v in d.items() if k in fields})

    def label(self) -> str:
        return envs.env_class(self.env).spec_label(self)


class Task:
    """See the module docstring.

    ``enemy_script``: an engine script (``(key, game, ctx, p) -> int32 [U]``, e.g.
    ``hybridmarl.envs.combat.learned_enemy``) that plays the enemy instead of ``spec.enemy``.
    """

    def __init__(
        self, spec: TaskSpec, enemy_script: Callable[..., jax.Array] | None = None
    ) -> None:
        self.spec = spec
        self.kind = canonical_env(spec.env)
        self.env_class = envs.env_class(self.kind)
        try:
            self.env, self.params = self.env_class.from_spec(spec, enemy_script=enemy_script)
        except TaskError:
            raise
        except (ValueError, KeyError) as e:
            msg = str(e.args[0]) if e.args else str(e)
            raise TaskError(msg) from None
        self.num_agents = int(self.env.num_agents)
        self.num_actions = int(self.env.num_actions)
        self.obs_dim = int(np.prod(self.env.observation_shape))
        self.critic_dim = int(self.env.critic_feature_size)
        self.metric_names: tuple[str, ...] = tuple(self.env_class.metric_names)
        #: (primary, secondary) metric of progress lines and curves.
        self.progress_metrics: tuple[str, str] = self.env_class.progress_metrics

    # -- environment ------------------------------------------------------------------------------

    def state_template(self) -> Any:
        """Shapes and dtypes of one env state (``jax.ShapeDtypeStruct`` leaves; nothing runs)."""
        if not hasattr(self, "_template"):
            self._template = jax.eval_shape(self.reset, jax.random.key(0))[1]
        return self._template

    def reset(self, key: jax.Array) -> tuple[jax.Array, Any]:
        obs, state = self.env.reset(key, self.params)
        return obs.reshape((self.num_agents, -1)), state

    def step(self, key: jax.Array, state: Any, actions: jax.Array):
        obs, s2, r, d, info = self.env.step(key, state, actions, self.params)
        return obs.reshape((self.num_agents, -1)), s2, r, d, info

    def batch_step(self, keys: jax.Array, states: Any, actions: jax.Array):
        """``jax.vmap(step)`` over a batch (same results). Combat uses ``Combat.batch_step``,
        which advances only the games that owe enemy-only turns instead of the whole batch in
        lockstep with its slowest game."""
        if hasattr(self.env, "batch_step"):
            obs, s2, r, d, info = self.env.batch_step(keys, states, actions, self.params)
            return obs.reshape((obs.shape[0], self.num_agents, -1)), s2, r, d, info
        return jax.vmap(self.step)(keys, states, actions)

    def observe(self, state: Any) -> jax.Array:
        return self.env.observe(state).reshape((self.num_agents, -1))

    def avail(self, state: Any) -> jax.Array:
        return self.env.get_avail_actions(state, self.params)

    def value_features(self, state: Any) -> jax.Array:
        """Critic input for ``V(s)`` (actions all zero; see the module docstring)."""
        return self.env.critic_features(state, jnp.zeros((self.num_agents,), jnp.int32))

    def lookahead(self, key: jax.Array, state: Any, cand: jax.Array):
        """Alg. 1's one-step simulation of A candidate joint actions ``[A, N]`` from ``state``."""
        if hasattr(self.env, "lookahead"):
            return self.env.lookahead(key, state, cand)

        def one(a: jax.Array):
            _, s2, r, d, _ = self.env.step(key, state, a, self.params)
            return r, s2, d

        return jax.vmap(one)(cand)

    def episode_stats(self, state: Any, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """float32 metrics of an episode whose last step returned ``(state, info)``."""
        return self.env.episode_metrics(state, info)

    def agent_rewards(
        self, state: Any, next_state: Any, done: jax.Array, info: dict[str, jax.Array]
    ) -> jax.Array:
        """Per-agent rewards ``[N]`` of one step (the independent learners DQfD and OGTL)."""
        return self.env.agent_rewards(state, next_state, done, info)

    # -- evaluation -------------------------------------------------------------------------------

    @property
    def enemy(self) -> str | None:
        """The scripted opponent's name (combat), else None."""
        return self.spec.enemy if self.env_class.has_enemy else None

    def against(self, enemy: str | None) -> Task:
        """This task with another scripted opponent (combat); tasks without one return themselves."""
        if not self.env_class.has_enemy or not enemy:
            return self
        return make_task(dataclasses.replace(self.spec, enemy=enemy))

    def summarize(self, ep: dict[str, np.ndarray]) -> dict[str, Any]:
        """The evaluation summary of per-episode metrics (``metric_names`` plus ``return`` and
        ``steps``): ``n``, the environment's own measures with 95% intervals, ``mean_steps``."""
        n = int(next(iter(ep.values())).shape[0])
        return {"n": n, **self.env_class.summarize(ep), "mean_steps": float(np.mean(ep["steps"]))}

    def result_line(self, r: dict[str, Any]) -> str:
        """One line of an evaluation result (:meth:`summarize`'s dict)."""
        return self.env_class.result_line(r)

    # -- demonstrators ------------------------------------------------------------------------------

    def demonstrator(self, name: str) -> Policy:
        """A scripted demonstrator as a pure env policy ``(key, state) -> int32 [N]``."""
        full = canonical_script(self.kind, name)
        base, eps = split_demonstrator(full)
        policy = self.env.demonstrator(base)
        if eps <= 0:
            return policy
        return epsilon_policy(policy, self.avail, eps)


def epsilon_policy(policy: Policy, avail_fn: Callable[[Any], jax.Array], eps: float) -> Policy:
    """``policy`` with each agent's action replaced, with probability ``eps``, by a uniformly
    random legal action."""

    def noisy(key: jax.Array, state: Any) -> jax.Array:
        k0, k1, k2 = jax.random.split(key, 3)
        a = policy(k0, state)
        legal = avail_fn(state)
        rnd = jax.random.categorical(k2, jnp.where(legal, 0.0, -jnp.inf), axis=-1).astype(jnp.int32)
        flip = jax.random.uniform(k1, a.shape) < eps
        return jnp.where(flip, rnd, a).astype(jnp.int32)

    return noisy


@functools.lru_cache(maxsize=16)
def make_task(spec: TaskSpec) -> Task:
    """A cached :class:`Task` (one per spec, so jitted functions keyed on it are reused)."""
    return Task(spec)


__all__ = [
    "Policy",
    "Task",
    "TaskError",
    "TaskSpec",
    "canonical_env",
    "canonical_script",
    "default_enemy",
    "flatten_named",
    "make_task",
    "split_demonstrator",
    "unflatten_named",
]
