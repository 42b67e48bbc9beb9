"""A PettingZoo ``ParallelEnv`` view of any :class:`hybridmarl.envs.base.MultiAgentEnv`.

One environment, no batching: this is for interoperability (PettingZoo tooling, quick manual
play, recording videos), not for training, which uses the pure functions directly under
``jit``/``vmap``.

Semantics:

- ``possible_agents`` are all agent slots of the wrapped env. What ``agents`` holds depends on
  the env's ``remove_inactive_agents`` attribute (default False):

  - False (Traffic Junction): after ``reset``, ``agents`` is every slot, and slots stay agents
    for the whole episode even while not in play (a TJ slot with no car): such an agent gets an
    all-zero observation, ``infos[agent]["active"] == False`` and an action mask allowing only
    action 0. PettingZoo forbids reviving an agent once removed, and slots come back into play
    (TJ recycles car ids), so removing them early is not an option.
  - True (combat: a dead unit never comes back): ``agents`` after ``reset`` is the slots in
    play; an agent whose slot leaves play (its unit died) gets ``terminations[agent] = True``
    on that step (with its last, all-zero observation) and is removed from ``agents``.

  At episode end every remaining agent gets ``terminations[agent] = True`` (the wrapped env's
  episode end is the task's definition of an episode, e.g. paper Section 5.3's fixed horizon)
  and ``agents`` empties. ``truncations`` are always False.
- Rewards: the wrapped env's global team reward, given to every agent.
- Observations (``obs_format``):

  - ``"dict"`` (the default): ``obs[agent]`` is ``{"observation": float32 [obs_dim],
    "action_mask": int8 [num_actions]}`` and ``observation_space(agent)`` is a
    ``gymnasium.spaces.Dict`` of a ``Box`` and a ``Box(0, 1, (num_actions,), int8)``, the form
    of PettingZoo's classic environments. PettingZoo's tools (``parallel_api_test``'s action
    sampling, masked ``action_space(agent).sample(mask=obs[agent]["action_mask"])``) read the
    mask from there.
  - ``"array"``: ``obs[agent]`` is the bare float32 observation and ``observation_space(agent)``
    the ``Box`` (the format before the dict form became the default); the mask is then only in
    ``infos``.

- ``infos[agent]`` holds ``"action_mask"`` (int8 ``[num_actions]``, in both formats),
  ``"active"``, ``"illegal_action"`` (whether this agent's action of the step was illegal and
  replaced), ``"illegal_action_count"`` (the agent's replaced actions so far this episode; the
  adapter's ``illegal_action_count`` attribute is the episode total over all agents), and the
  wrapped env's ``info``: 0-d entries are shared by every agent, entries whose leading axis is
  ``num_agents`` are sliced per agent, anything else is shared as is. (Combat's own
  ``"illegal_actions"`` counts what reached the env: with the adapter replacing illegal actions
  first, it stays 0.)
- Actions: an agent missing from the action dict plays its *fallback action*: the env's
  ``fallback_actions(state)`` if it defines one (combat: noop where legal, else SparCraft's first
  legal action), else action 0 (the no-op, legal for every Traffic Junction agent). An integer
  action in ``0..num_actions-1`` outside the agent's mask is, by default
  (``illegal_action="fallback"``), replaced by that same fallback action and counted in
  ``infos`` (see above), so tools that sample from the unmasked ``Discrete`` space (such as
  ``pettingzoo.test.parallel_seed_test``) run as is. ``illegal_action="raise"`` raises
  ``ValueError`` naming the agent, the action and its legal actions instead, for debugging a
  policy. ``"noop"`` is accepted as an older name of ``"fallback"``. A non-integer action, one
  outside ``0..num_actions-1`` or an unknown agent always raises ``ValueError``.
- Seeding: ``reset(seed=s)`` re-seeds the adapter's JAX key, so episodes are reproducible;
  ``reset()`` without a seed continues the current key stream (seeded from OS entropy at first
  use). The key is split inside the jitted step (the same stream as splitting outside).
- ``state()`` returns the wrapped env's critic features with every agent's action set to 0.

The wrapped env's ``reset``/``step``/masks are jitted once per env object and shared by every
adapter built on that object (changing ``params`` values does not recompile). Each ``reset`` and
``step`` is one jitted call and one device-to-host transfer, which keeps the adapter's overhead
over the bare jitted step small (``bench/envs.py`` measures it).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from pettingzoo import ParallelEnv

from hybridmarl.envs.base import MultiAgentEnv

__all__ = ["PettingZooAdapter"]


@dataclass(frozen=True)
class _Compiled:
    reset: Any
    step: Any
    avail: Any
    active: Any
    critic: Any
    layouts: dict[str, _Layout]


class _Layout:
    """How a pytree of small arrays was packed into one int32 vector.

    Returning every per-step output (observations, reward, done, info, masks) as one flat
    vector makes the device-to-host copy one transfer instead of about twenty, which was most
    of the adapter's overhead at B = 1. Floats travel as float32 bit patterns, integers and
    bools as int32 (exact for every value an env reports: counters, frames and flags)."""

    def __init__(self, tree: Any) -> None:
        leaves, self.treedef = jax.tree.flatten(tree)
        # (float?, start, stop, shape, dtype) per leaf, so unpacking is slicing only.
        self.entries: list[tuple[bool, int, int, tuple[int, ...], np.dtype]] = []
        offset = 0
        for leaf in leaves:
            is_float = bool(jnp.issubdtype(leaf.dtype, jnp.floating))
            size = int(np.prod(leaf.shape, dtype=np.int64))
            shape = tuple(int(d) for d in leaf.shape)
            self.entries.append((is_float, offset, offset + size, shape, np.dtype(leaf.dtype)))
            offset += size

    @staticmethod
    def pack(tree: Any) -> jax.Array:
        parts = [
            lax.bitcast_convert_type(jnp.ravel(x).astype(jnp.float32), jnp.int32)
            if jnp.issubdtype(x.dtype, jnp.floating)
            else jnp.ravel(x).astype(jnp.int32)
            for x in jax.tree.leaves(tree)
        ]
        return jnp.concatenate(parts) if parts else jnp.zeros((0,), jnp.int32)

    def unpack(self, buf: np.ndarray) -> Any:
        as_float = buf.view(np.float32)
        leaves = [
            (as_float if is_float else buf)[start:stop].reshape(shape).astype(dtype, copy=False)
            for is_float, start, stop, shape, dtype in self.entries
        ]
        return jax.tree.unflatten(self.treedef, leaves)


_CACHE: weakref.WeakKeyDictionary[Any, _Compiled] = weakref.WeakKeyDictionary()


def _compiled(env: MultiAgentEnv[Any, Any]) -> _Compiled:
    """Jitted entry points for ``env``, built once per env object.

    ``reset`` and ``step`` return the new key, the env state (kept on the device) and the
    host-bound outputs packed into two vectors (see ``_Layout``; the layout is recorded while
    tracing). The jitted closures hold the env only weakly, so the cache entry dies with the env.
    """
    try:
        return _CACHE[env]
    except KeyError:
        pass
    ref = weakref.ref(env)
    layouts: dict[str, _Layout] = {}

    def _env() -> MultiAgentEnv[Any, Any]:
        e = ref()
        if e is None:  # pragma: no cover - only reachable if a jitted fn outlives its env
            raise RuntimeError("the wrapped environment was garbage-collected")
        return e

    def extras(state: Any, params: Any) -> tuple[Any, Any, Any]:
        e = _env()
        mask = e.get_avail_actions(state, params)
        fallback_fn = getattr(e, "fallback_actions", None)
        if fallback_fn is None:
            fallback = jnp.zeros((e.num_agents,), jnp.int32)
        else:
            fallback = fallback_fn(state)
        return mask, e.agent_active(state), fallback

    def packed(name: str, tree: Any) -> jax.Array:
        layouts[name] = _Layout(tree)  # runs at trace time: the layout of this compilation
        return _Layout.pack(tree)

    def reset(key: jax.Array, params: Any) -> Any:
        key, sub = jax.random.split(key)
        obs, state = _env().reset(sub, params)
        return key, state, packed("reset", (obs, *extras(state, params)))

    def step(key: jax.Array, state: Any, actions: jax.Array, params: Any) -> Any:
        key, sub = jax.random.split(key)
        obs, new_state, reward, done, info = _env().step(sub, state, actions, params)
        host = (obs, reward, done, info, *extras(new_state, params))
        return key, new_state, packed("step", host)

    compiled = _Compiled(
        reset=jax.jit(reset),
        step=jax.jit(step),
        avail=jax.jit(lambda state, params: _env().get_avail_actions(state, params)),
        active=jax.jit(lambda state: _env().agent_active(state)),
        critic=jax.jit(lambda state, actions: _env().critic_features(state, actions)),
        layouts=layouts,
    )
    _CACHE[env] = compiled
    return compiled


class PettingZooAdapter(ParallelEnv):
    """PettingZoo ``ParallelEnv`` over one instance of a :class:`MultiAgentEnv` (see module doc).

    Args:
        env: the functional environment to wrap.
        params: its parameters (default: ``env.default_params``).
        render_mode: ``None`` or ``"rgb_array"``.
        illegal_action: ``"fallback"`` (default: replace an illegal action by the agent's
            fallback action and count it in ``infos``) or ``"raise"`` (``ValueError``);
            ``"noop"`` is an older name of ``"fallback"``.
        obs_format: ``"dict"`` (default: ``{"observation", "action_mask"}`` per agent with a
            ``Dict`` observation space) or ``"array"`` (the bare observation with a ``Box``).
    """

    metadata = {"render_modes": ["rgb_array"], "name": "hybridmarl", "is_parallelizable": True}

    def __init__(
        self,
        env: MultiAgentEnv[Any, Any],
        params: Any = None,
        render_mode: str | None = None,
        illegal_action: str = "fallback",
        obs_format: str = "dict",
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if illegal_action == "noop":
            illegal_action = "fallback"
        if illegal_action not in ("fallback", "raise"):
            raise ValueError(
                f"illegal_action must be 'fallback' or 'raise', got {illegal_action!r}"
            )
        if obs_format not in ("dict", "array"):
            raise ValueError(f"obs_format must be 'dict' or 'array', got {obs_format!r}")
        self.env = env
        self.params = env.default_params if params is None else params
        self.render_mode = render_mode
        self.illegal_action = illegal_action
        self.obs_format = obs_format
        self.metadata = {**type(self).metadata, "name": env.name}
        self.possible_agents = list(env.agents)
        self.agents = []
        self._index = {agent: i for i, agent in enumerate(self.possible_agents)}
        self._fns = _compiled(env)
        low, high = getattr(env, "observation_bounds", (-np.inf, np.inf))
        self._observation_spaces: dict[str, gymnasium.spaces.Space[Any]] = {}
        for a in self.possible_agents:
            box = gymnasium.spaces.Box(low, high, env.observation_shape, np.float32)
            if obs_format == "dict":
                mask = gymnasium.spaces.Box(0, 1, (env.num_actions,), np.int8)
                self._observation_spaces[a] = gymnasium.spaces.Dict(
                    {"observation": box, "action_mask": mask}
                )
            else:
                self._observation_spaces[a] = box
        self._action_spaces = {
            a: gymnasium.spaces.Discrete(env.num_actions) for a in self.possible_agents
        }
        self.state_space = gymnasium.spaces.Box(
            -np.inf, np.inf, (env.critic_feature_size,), np.float32
        )
        self._key: jax.Array | None = None
        self._state: Any = None
        self._mask: np.ndarray | None = None
        self._active: np.ndarray | None = None
        self._fallback: np.ndarray | None = None
        self._remove_inactive = bool(getattr(env, "remove_inactive_agents", False))
        n = len(self.possible_agents)
        self._illegal_step = np.zeros((n,), bool)
        self._illegal_counts = np.zeros((n,), np.int64)

    # -- spaces ----------------------------------------------------------------------------------

    def observation_space(self, agent: str) -> gymnasium.spaces.Space[Any]:
        return self._observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        return self._action_spaces[agent]

    # -- episode ---------------------------------------------------------------------------------

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        del options
        if seed is not None:
            self._key = jax.random.key(seed)
        elif self._key is None:
            self._key = jax.random.key(int(np.random.SeedSequence().generate_state(1)[0]))
        key, state, buf = self._fns.reset(self._key, self.params)
        self._key, self._state = key, state
        obs, self._mask, self._active, self._fallback = self._fns.layouts["reset"].unpack(
            np.asarray(buf)
        )
        assert self._active is not None
        if self._remove_inactive:
            self.agents = [a for a in self.possible_agents if self._active[self._index[a]]]
        else:
            self.agents = list(self.possible_agents)
        self._illegal_step[:] = False
        self._illegal_counts[:] = 0
        return self._split_obs(obs), self._infos({})

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        dict[str, Any],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        if not self.agents or self._key is None or self._mask is None or self._fallback is None:
            raise RuntimeError("the episode is over (or never started): call reset() first")
        joint = self._fallback.astype(np.int32).copy()
        illegal = np.zeros_like(self._illegal_step)
        for agent, action in actions.items():
            if agent not in self._index:
                raise ValueError(f"unknown agent {agent!r}; agents are {self.possible_agents}")
            i = self._index[agent]
            a = self._as_action(agent, action)
            if not self._mask[i, a]:
                if self.illegal_action == "raise":
                    legal = np.flatnonzero(self._mask[i]).tolist()
                    raise ValueError(
                        f"illegal action {a} for agent {agent!r} (legal actions: {legal}; "
                        f"active={bool(self._active[i]) if self._active is not None else '?'})"
                    )
                a = int(self._fallback[i])
                illegal[i] = True
            joint[i] = a
        self._key, self._state, buf = self._fns.step(self._key, self._state, joint, self.params)
        self._illegal_step = illegal
        self._illegal_counts += illegal
        host = self._fns.layouts["step"].unpack(np.asarray(buf))
        obs, reward, done, info, self._mask, self._active, self._fallback = host
        assert self._active is not None
        agents = list(self.agents)
        done = bool(done)
        rewards = dict.fromkeys(agents, float(reward))
        if self._remove_inactive:
            terminations = {a: done or not bool(self._active[self._index[a]]) for a in agents}
        else:
            terminations = dict.fromkeys(agents, done)
        truncations = dict.fromkeys(agents, False)
        out_obs = self._split_obs(obs)
        infos = self._infos(info)
        self.agents = [] if done else [a for a in agents if not terminations[a]]
        return out_obs, rewards, terminations, truncations, infos

    # -- extras ----------------------------------------------------------------------------------

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gymnasium.logger.warn("render() called with render_mode=None; nothing to draw")
            return None
        if self._state is None:
            raise RuntimeError("call reset() before render()")
        return self.env.render(self._state, self.params)

    def state(self) -> np.ndarray:
        if self._state is None:
            raise RuntimeError("call reset() before state()")
        zeros = jnp.zeros((len(self.possible_agents),), jnp.int32)
        return np.asarray(self._fns.critic(self._state, zeros))

    def close(self) -> None:
        self._state = None

    @property
    def illegal_action_count(self) -> int:
        """Illegal actions replaced by the fallback action so far this episode, all agents."""
        return int(self._illegal_counts.sum())

    @property
    def env_state(self) -> Any:
        """The wrapped env's current state pytree (e.g. to run a demonstrator on it)."""
        return self._state

    # -- helpers ---------------------------------------------------------------------------------

    def _as_action(self, agent: str, action: Any) -> int:
        arr = np.asarray(action)
        if arr.shape != () or not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"action for agent {agent!r} must be an integer, got {action!r}")
        a = int(arr)
        if not 0 <= a < self.env.num_actions:
            raise ValueError(
                f"illegal action {a} for agent {agent!r}: outside 0..{self.env.num_actions - 1}"
            )
        return a

    def _split_obs(self, obs: np.ndarray) -> dict[str, Any]:
        if self.obs_format == "array":
            return {a: np.array(obs[self._index[a]], np.float32) for a in self.agents}
        assert self._mask is not None
        masks = self._mask.astype(np.int8)
        return {
            a: {
                "observation": np.array(obs[self._index[a]], np.float32),
                "action_mask": masks[self._index[a]].copy(),
            }
            for a in self.agents
        }

    def _infos(self, info: dict[str, Any]) -> dict[str, dict[str, Any]]:
        assert self._mask is not None and self._active is not None
        n = len(self.possible_agents)
        shared: dict[str, Any] = {}
        per_agent: dict[str, np.ndarray] = {}
        for k, v in info.items():
            v = np.asarray(v)
            if v.ndim == 0:
                shared[k] = v.item()
            elif v.shape[0] == n:
                per_agent[k] = v
            else:
                shared[k] = v
        masks = self._mask.astype(np.int8)
        infos: dict[str, dict[str, Any]] = {}
        for agent in self.agents:
            i = self._index[agent]
            entry: dict[str, Any] = {
                "action_mask": masks[i],
                "active": bool(self._active[i]),
                "illegal_action": bool(self._illegal_step[i]),
                "illegal_action_count": int(self._illegal_counts[i]),
            }
            entry.update(shared)
            for k, v in per_agent.items():
                entry[k] = v[i].item() if v.ndim == 1 else v[i].copy()
            for k, v in shared.items():
                if isinstance(v, np.ndarray):
                    entry[k] = v.copy()
            infos[agent] = entry
        return infos
