"""Parallel games and the data they produce.

- :class:`Pool`: ``B`` games played side by side (a pytree: env states, observations, a key).
  :func:`pool_steps` advances every game by ``K`` steps inside one ``lax.scan`` under ``jit``;
  a game that ends is reset at once (a new random start state), so every slot stays busy.
  What it returns per step: the state each game was in (``s_t``), the reward, ``done`` and
  the episode metrics (valid where ``done``).
- :class:`EpisodeAssembler` (host): collects the per-slot steps until a slot's episode ends,
  then labels every visited state with its discounted return ``V(s_t) = sum_i λ^(i-t) r_i``
  (Alg. 2) and hands out finished episodes. Its partial episodes are part of a checkpoint.
- :class:`ReplayBuffer` (host): Alg. 2's data buffer ``B`` of ``(s, V(s))`` pairs, a FIFO ring of
  fixed capacity. States are stored (small integer pytrees), not critic features; the critic's
  input is computed from them when the critic is fitted.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hybridmarl.training.losses import discounted_returns
from hybridmarl.training.task import Task, flatten_named, unflatten_named


class Pool(struct.PyTreeNode):
    states: Any  # [B] env states
    obs: jax.Array  # float32 [B, N, D]
    key: jax.Array  # uint32 [2] (raw key data, so checkpoints stay plain arrays)


def new_pool(task: Task, key: jax.Array, num_envs: int) -> Pool:
    """B fresh games (one compiled call; resetting eagerly would be very slow)."""
    return _new_pool_fn(task, num_envs)(key)


@functools.lru_cache(maxsize=16)
def _new_pool_fn(task: Task, num_envs: int):
    def make(key: jax.Array) -> Pool:
        k_reset, k_pool = jax.random.split(key)
        obs, states = jax.vmap(task.reset)(jax.random.split(k_reset, num_envs))
        return Pool(states=states, obs=obs, key=jax.random.key_data(k_pool))

    return jax.jit(make)


def select_tree(mask: jax.Array, new: Any, old: Any) -> Any:
    """Per-slot ``where`` over pytrees with a leading batch axis."""

    def sel(a: jax.Array, b: jax.Array) -> jax.Array:
        return jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)

    return jax.tree.map(sel, new, old)


#: ``act(carry, key, states [B], obs [B, N, D], legal [B, N, A]) -> (actions [B, N], carry, aux)``.
ActFn = Callable[[Any, jax.Array, Any, jax.Array, jax.Array], tuple[jax.Array, Any, Any]]
#: ``on_step(states [B], actions [B, N], next_states [B], reward [B], done [B], info) -> pytree [B, ...]``.
OnStepFn = Callable[[Any, jax.Array, Any, jax.Array, jax.Array, dict], Any]


def pool_steps(
    task: Task, act: ActFn, pool: Pool, carry: Any, num_steps: int, on_step: OnStepFn | None = None
) -> tuple[Pool, Any, dict]:
    """Advance every game of ``pool`` by ``num_steps`` steps (jittable; ``act`` decides).

    Returns ``(pool, carry, out)`` with ``out`` time-major ``[K, B]``: ``state`` (s_t), ``reward``,
    ``done``, ``stats`` (episode metrics, valid where done) and ``aux`` (whatever ``act`` returned);
    with ``on_step`` also ``step``: what it returned for the step (it sees ``s_{t+1}`` before a
    finished game is reset, e.g. for per-agent rewards and next states).
    """
    b = pool.obs.shape[0]

    def body(c: tuple, _: Any) -> tuple:
        pool, carry = c
        key = jax.random.wrap_key_data(pool.key)
        key, k_act, k_step, k_reset = jax.random.split(key, 4)
        legal = jax.vmap(task.avail)(pool.states)
        actions, carry, aux = act(carry, k_act, pool.states, pool.obs, legal)
        obs2, s2, r, d, info = jax.vmap(task.step)(
            jax.random.split(k_step, b), pool.states, actions
        )
        stats = jax.vmap(task.episode_stats)(s2, info)

        def reset_done(args: tuple) -> tuple:
            obs2, s2 = args
            obs_r, s_r = jax.vmap(task.reset)(jax.random.split(k_reset, b))
            return select_tree(d, obs_r, obs2), select_tree(d, s_r, s2)

        obs_n, s_n = jax.lax.cond(jnp.any(d), reset_done, lambda a: a, (obs2, s2))
        out = {"state": pool.states, "reward": r, "done": d, "stats": stats, "aux": aux}
        if on_step is not None:
            out["step"] = on_step(pool.states, actions, s2, r, d, info)
        return (Pool(states=s_n, obs=obs_n, key=jax.random.key_data(key)), carry), out

    (pool, carry), out = jax.lax.scan(body, (pool, carry), None, length=num_steps)
    return pool, carry, out


class EpisodeAssembler:
    """Host-side per-slot episode collection (see the module docstring).

    Rows are dicts of named per-step arrays (``state.<path>``, and for demonstrations ``obs``,
    ``legal``, ``actions``, ...). A finished episode gets ``t`` (step in the episode) and
    ``episode_key`` (a running count of finished episodes) added to its rows.

    A slot's unfinished episode is kept as a list of time-slices of the blocks it spans, so
    the work per block grows with the number of finished episodes, not with ``K x B`` rows.
    """

    def __init__(self, num_envs: int, gamma: float) -> None:
        self.num_envs = num_envs
        self.gamma = gamma
        # Per slot: the pieces of its unfinished episode ({name: [n_i, ...]}) and their rewards.
        self.pieces: list[list[dict[str, np.ndarray]]] = [[] for _ in range(num_envs)]
        self.piece_rewards: list[list[np.ndarray]] = [[] for _ in range(num_envs)]
        self.finished = 0

    def add(self, out: dict) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray]]:
        """Add a ``pool_steps`` output block ``[K, B]`` (states only)."""
        fields = {"state." + k: v for k, v in flatten_named(jax.device_get(out["state"])).items()}
        return self.add_fields(fields, out["reward"], out["done"], out["stats"])

    def add_fields(
        self, fields: dict[str, np.ndarray], reward: Any, done: Any, stats: dict[str, Any]
    ) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray]]:
        """Add named per-step arrays ``[K, B, ...]``; returns the rows of the episodes that
        finished (``{name: [M, ...]}``, grouped by episode in order of completion: by step, then
        by slot), their discounted returns ``[M]`` and the finished episodes' metrics
        ``{name: [E]}``."""
        reward = np.asarray(reward, np.float32)
        done = np.asarray(done, bool)
        stats_np = {k: np.asarray(v) for k, v in stats.items()}
        fields = {k: np.asarray(v) for k, v in fields.items()}
        names = list(fields)
        start = np.zeros(self.num_envs, np.int64)  # first step of the block not yet handed out
        episodes: list[dict[str, np.ndarray]] = []
        fin_returns: list[np.ndarray] = []
        fin_stats: dict[str, list] = {k: [] for k in stats_np}
        fin_stats["return"] = []  # the undiscounted sum of rewards
        for t, s in zip(*np.nonzero(done), strict=True):  # row-major: by step, then by slot
            a = start[s]
            pieces = self.pieces[s] + [{k: fields[k][a : t + 1, s] for k in names}]
            rewards = np.concatenate(self.piece_rewards[s] + [reward[a : t + 1, s]]).astype(
                np.float64
            )
            episode = {k: np.concatenate([p[k] for p in pieces]) for k in names}
            episode["t"] = np.arange(rewards.shape[0], dtype=np.int32)
            episode["episode_key"] = np.full(rewards.shape[0], self.finished, np.int64)
            episodes.append(episode)
            fin_returns.append(discounted_returns(rewards, self.gamma))
            for k in stats_np:
                fin_stats[k].append(stats_np[k][t, s])
            fin_stats["return"].append(float(np.sum(rewards)))
            self.finished += 1
            self.pieces[s], self.piece_rewards[s] = [], []
            start[s] = t + 1
        k_steps = reward.shape[0]
        for s in range(self.num_envs):
            a = start[s]
            if a < k_steps:  # copies, so that a caller may reuse its arrays
                self.pieces[s].append({k: np.array(fields[k][a:, s]) for k in names})
                self.piece_rewards[s].append(np.array(reward[a:, s]))
        if episodes:
            out = {
                k: np.concatenate([e[k] for e in episodes]) for k in names + ["t", "episode_key"]
            }
        else:
            out = {k: np.zeros((0,) + fields[k].shape[2:], fields[k].dtype) for k in fields}
            out["t"] = np.zeros((0,), np.int32)
            out["episode_key"] = np.zeros((0,), np.int64)
        ret = np.concatenate(fin_returns) if fin_returns else np.zeros((0,), np.float32)
        return out, ret, {k: np.asarray(v, np.float32) for k, v in fin_stats.items()}

    # -- checkpointing -----------------------------------------------------------------------------

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The unfinished episodes as flat arrays: ``slot``, ``reward`` and ``row.<name>`` per
        stored step, slot by slot in step order, and the ``finished`` count."""
        slots, rewards, rows = [], [], []
        for s in range(self.num_envs):
            for piece, r in zip(self.pieces[s], self.piece_rewards[s], strict=True):
                slots.append(np.full(r.shape[0], s, np.int32))
                rewards.append(r)
                rows.append(piece)
        out = {
            "slot": np.concatenate(slots) if slots else np.zeros((0,), np.int32),
            "reward": np.concatenate(rewards).astype(np.float32)
            if rewards
            else np.zeros((0,), np.float32),
            "finished": np.asarray(self.finished, np.int64),
        }
        if rows:
            for k in rows[0]:
                out["row." + k] = np.concatenate([p[k] for p in rows])
        return out

    def load_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        self.pieces = [[] for _ in range(self.num_envs)]
        self.piece_rewards = [[] for _ in range(self.num_envs)]
        self.finished = int(arrays["finished"])
        names = [k[len("row.") :] for k in arrays if k.startswith("row.")]
        slot = np.asarray(arrays["slot"])
        for s in np.unique(slot).tolist():
            idx = np.flatnonzero(slot == s)
            self.pieces[int(s)].append({k: np.array(arrays["row." + k][idx]) for k in names})
            self.piece_rewards[int(s)].append(np.asarray(arrays["reward"][idx], np.float32))


class ReplayBuffer:
    """Alg. 2's buffer ``B``: a FIFO ring of ``(state, return)`` pairs (host numpy arrays)."""

    def __init__(self, capacity: int, state_template: Any) -> None:
        self.capacity = int(capacity)
        self.template = state_template  # one unbatched env state (pytree)
        proto = flatten_named(state_template)
        self.states = {k: np.zeros((self.capacity,) + v.shape, v.dtype) for k, v in proto.items()}
        self.returns = np.zeros((self.capacity,), np.float32)
        self.ptr = 0
        self.size = 0

    def add(self, states: dict[str, np.ndarray], returns: np.ndarray) -> None:
        """Append rows (``states``: flattened names, with or without a ``state.`` prefix)."""
        states = {
            (k[len("state.") :] if k.startswith("state.") else k): v for k, v in states.items()
        }
        m = int(returns.shape[0])
        if m == 0:
            return
        if m > self.capacity:  # keep the newest
            states = {k: v[-self.capacity :] for k, v in states.items()}
            returns = returns[-self.capacity :]
            m = self.capacity
        idx = (self.ptr + np.arange(m)) % self.capacity
        for k, v in self.states.items():
            v[idx] = states[k]
        self.returns[idx] = returns
        self.ptr = int((self.ptr + m) % self.capacity)
        self.size = int(min(self.size + m, self.capacity))

    def device_arrays(self) -> tuple[Any, jax.Array, jax.Array]:
        """(states pytree [cap], returns [cap], size) for the jitted critic fit."""
        tree = unflatten_named(self.template, self.states, batch_dims=1)
        return tree, jnp.asarray(self.returns), jnp.asarray(self.size, jnp.int32)

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"state." + k: v for k, v in self.states.items()}
        out["returns"] = self.returns
        out["ptr"] = np.asarray(self.ptr, np.int64)
        out["size"] = np.asarray(self.size, np.int64)
        return out

    def load_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        for k in self.states:
            a = arrays["state." + k]
            if a.shape != self.states[k].shape:
                raise ValueError(
                    f"buffer array {k!r} has shape {a.shape}, expected {self.states[k].shape}"
                )
            self.states[k] = np.array(a)
        self.returns = np.array(arrays["returns"], np.float32)
        self.ptr = int(arrays["ptr"])
        self.size = int(arrays["size"])
