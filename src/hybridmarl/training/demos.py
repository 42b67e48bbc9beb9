"""Demonstrations (paper Section 3): recording, the dataset file, validation, behavioural cloning.

Dataset file (safetensors; never pickle), format ``hybridmarl-demos`` version 1. ``K``
observations (joint states), ``N`` agents, ``A`` actions, ``D`` observation size:

==================  ==================  =========================================================
array               dtype / shape       meaning
==================  ==================  =========================================================
``obs``             float32 [K, N, D]   every agent's observation O^g(s_k)
``legal``           bool [K, N, A]      legal-action masks
``actions``         int32 [K, N]        the demonstrator's actions a_g(s_k) (legal under ``legal``)
``active``          bool [K, N]         the agent is in play (a living unit, a car on the road)
``episode``         int32 [K]           episode id (0, 1, ...; non-decreasing)
``t``               int32 [K]           step within the episode
``reward``          float32 [K]         the reward of the step taken in s_k
``return``          float32 [K]         discounted return from s_k (Eq. 1, ``gamma`` below)
``state.<path>``    [K, ...]            the environment state s_k, flattened to named arrays
                                        (restart the simulation from any record with
                                        :func:`state_at`)
==================  ==================  =========================================================

The safetensors header metadata holds ``{"format": "hybridmarl-demos", "version": 1, "task": {...},
"demonstrator": ..., "seed": ..., "gamma": ..., "num_agents", "num_actions", "obs_dim"}`` as JSON.
:func:`load_dataset` checks all of it and raises :class:`DatasetError` with one line saying exactly
what is wrong (the CLI prints it and exits with code 2).

Behavioural cloning (:func:`fit_bc`): the actor architecture (Section 5.1: "the network
architecture of θ^D is the same as the actor network") trained by cross-entropy on the records
where the agent has a choice (two or more legal actions).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.errors import UserError
from hybridmarl.training import networks as nets
from hybridmarl.training.losses import bc_loss
from hybridmarl.training.rollout import EpisodeAssembler, new_pool, pool_steps
from hybridmarl.training.task import Task, TaskSpec, flatten_named, make_task, unflatten_named

FORMAT = "hybridmarl-demos"
VERSION = 1
CORE = {
    "obs": (np.float32, 3),
    "legal": (np.bool_, 3),
    "actions": (np.int32, 2),
    "active": (np.bool_, 2),
    "episode": (np.int32, 1),
    "t": (np.int32, 1),
    "reward": (np.float32, 1),
    "return": (np.float32, 1),
}


class DatasetError(UserError):
    """A demonstration dataset that cannot be used (one-line message)."""


@dataclass
class Dataset:
    arrays: dict[str, np.ndarray]
    meta: dict[str, Any]

    @property
    def size(self) -> int:
        return int(self.arrays["actions"].shape[0])

    @property
    def task_spec(self) -> TaskSpec:
        return TaskSpec.from_dict(self.meta["task"])

    def states(self) -> dict[str, np.ndarray]:
        return {k[len("state.") :]: v for k, v in self.arrays.items() if k.startswith("state.")}


# -- recording ---------------------------------------------------------------------------------------


def collect(
    spec: TaskSpec,
    demonstrator: str,
    num_observations: int = 10_000,
    *,
    seed: int = 0,
    num_envs: int = 64,
    gamma: float = 0.995,
    chunk: int = 64,
    engine: str = "auto",
) -> Dataset:
    """Play the scripted ``demonstrator`` (against the task's scripted enemy) from random start
    states until ``num_observations`` joint states of finished episodes are recorded.

    ``engine`` ('auto': native on a CPU): a combat script against a scripted enemy, neither of
    them ``random``, plays on the native engine (the same dataset, faster; see
    :func:`_native_collector`); everything else on the JAX engine."""
    task = make_task(spec)
    native = _native_collect(task, demonstrator, engine)
    run = (
        _native_collector(task, demonstrator, num_envs, chunk)
        if native
        else _collector(task, demonstrator, num_envs, chunk)
    )
    pool = new_pool(task, jax.random.key(seed), num_envs)
    asm = EpisodeAssembler(num_envs, gamma)
    parts: list[dict[str, np.ndarray]] = []
    got = 0
    while got < num_observations:
        pool, out = run(pool)
        fields = _step_fields(out)
        done_fields, returns, _ = asm.add_fields(fields, out["reward"], out["done"], out["stats"])
        if returns.size:
            done_fields["return"] = returns
            parts.append(done_fields)
            got += int(returns.size)
    arrays = {k: np.concatenate([p[k] for p in parts])[:num_observations] for k in parts[0]}
    # Episode ids in order of completion, renumbered 0, 1, ... (records are grouped by episode).
    arrays["episode"] = _renumber(arrays["episode_key"])
    del arrays["episode_key"]
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "task": spec.to_dict(),
        "demonstrator": demonstrator,
        "seed": int(seed),
        "gamma": float(gamma),
        "num_agents": task.num_agents,
        "num_actions": task.num_actions,
        "obs_dim": task.obs_dim,
        "num_observations": int(num_observations),
    }
    return Dataset(arrays=arrays, meta=meta)


def _renumber(keys: np.ndarray) -> np.ndarray:
    out = np.zeros(keys.shape, np.int32)
    ep = -1
    prev = None
    for i, k in enumerate(keys.tolist()):
        if k != prev:
            ep += 1
            prev = k
        out[i] = ep
    return out


@functools.lru_cache(maxsize=8)
def _collector(task: Task, demonstrator: str, num_envs: int, chunk: int):
    policy = task.demonstrator(demonstrator)

    def act(carry, key, states, obs, legal):
        keys = jax.random.split(key, num_envs)
        a = jax.vmap(policy)(keys, states).astype(jnp.int32)
        active = jax.vmap(task.env.agent_active)(states)
        return a, carry, {"obs": obs, "legal": legal, "actions": a, "active": active}

    @jax.jit
    def run(pool):
        pool, _, out = pool_steps(task, act, pool, None, chunk)
        return pool, out

    return run


def _native_collect(task: Task, demonstrator: str, engine: str) -> bool:
    """Whether ``collect`` plays on the native engine (the ``random`` script draws from another
    generator there, so it stays on JAX: the dataset never depends on the engine)."""
    from hybridmarl.engine.backend import resolve_engine
    from hybridmarl.engine.native.kernels import SCRIPT_CODES

    if task.kind != "combat" or resolve_engine(engine) != "native":
        return False
    names = (demonstrator, getattr(task.env, "enemy_name", None))
    return all(name in SCRIPT_CODES and name != "random" for name in names)


@functools.lru_cache(maxsize=8)
def _native_collector(task: Task, demonstrator: str, num_envs: int, chunk: int):
    """``_collector`` on the native engine: the same chunks (``rollout_native``: the same start
    states and steps as ``pool_steps``), with the observations, legal actions and active agents
    of the recorded states computed in one jitted call per chunk."""
    from hybridmarl.training.rollout_native import NativeScriptRollout

    rollout = NativeScriptRollout(task, demonstrator, num_envs=num_envs, steps=chunk)
    per_state = jax.vmap(
        jax.vmap(lambda s: (task.observe(s), task.avail(s), task.env.agent_active(s)))
    )
    views = jax.jit(per_state)

    def run(pool):
        pool, out = rollout(pool)
        obs, legal, active = jax.device_get(views(out["state"]))
        out["aux"] = {"obs": obs, "legal": legal, "actions": out.pop("actions"), "active": active}
        return pool, out

    return run


def _step_fields(out: dict) -> dict[str, np.ndarray]:
    aux = jax.device_get(out["aux"])
    fields = {k: np.asarray(v) for k, v in aux.items()}
    fields.update({"state." + k: v for k, v in flatten_named(jax.device_get(out["state"])).items()})
    fields["reward"] = np.asarray(out["reward"], np.float32)
    return fields


# -- file I/O ------------------------------------------------------------------------------------------


def save_dataset(ds: Dataset, path: str | Path) -> Path:
    """Write atomically (temporary file + rename)."""
    import os
    import tempfile

    from safetensors.numpy import save_file

    from hybridmarl.io import grant_umask

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        arrays = {k: np.asarray(v).copy(order="C") for k, v in ds.arrays.items()}
        save_file(arrays, tmp, metadata={"hybridmarl": json.dumps(ds.meta, sort_keys=True)})
        grant_umask(tmp)  # safetensors writes it private
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def load_dataset(path: str | Path, *, expect: Task | None = None) -> Dataset:
    """Read and validate a dataset (see the module docstring). ``expect``: the task it must fit."""
    from safetensors import safe_open

    from hybridmarl.io import MAX_ARRAY_FILE_BYTES, check_user_file

    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: no such dataset file")
    check_user_file(path, "dataset file", DatasetError, max_bytes=MAX_ARRAY_FILE_BYTES)
    try:
        with safe_open(str(path), framework="numpy") as f:
            header = f.metadata() or {}
            arrays = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118
    except Exception as e:  # safetensors raises its own error types
        raise DatasetError(
            f"{path}: not a safetensors file ({str(e).splitlines()[0] if str(e) else type(e).__name__})"
        ) from None
    try:
        meta = json.loads(header.get("hybridmarl", ""))
    except json.JSONDecodeError:
        raise DatasetError(
            f"{path}: missing or unreadable 'hybridmarl' metadata (not a hybridmarl demonstration dataset)"
        ) from None
    ds = Dataset(arrays=arrays, meta=meta)
    problem = validate(ds, expect=expect)
    if problem:
        raise DatasetError(f"{path}: {problem}")
    return ds


def validate(ds: Dataset, *, expect: Task | None = None) -> str | None:
    """The first problem found, as one line, or None."""
    meta, a = ds.meta, ds.arrays
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        return f"format is {meta.get('format') if isinstance(meta, dict) else None!r}, expected {FORMAT!r}"
    if meta.get("version") != VERSION:
        return f"dataset version {meta.get('version')!r} is not supported (this hybridmarl reads version {VERSION})"
    for key in ("task", "num_agents", "num_actions", "obs_dim", "demonstrator"):
        if key not in meta:
            return f"metadata lacks {key!r}"
    for key in ("num_agents", "num_actions", "obs_dim"):
        v = meta[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            return f"metadata {key} must be a positive integer, got {v!r}"
    if not isinstance(meta["task"], dict) or not isinstance(meta["demonstrator"], str):
        return "metadata 'task' must be an object and 'demonstrator' a string"
    for name, (dtype, ndim) in CORE.items():
        if name not in a:
            return f"missing array {name!r}"
        if a[name].dtype != dtype:
            return f"array {name!r} has dtype {a[name].dtype}, expected {np.dtype(dtype)}"
        if a[name].ndim != ndim:
            return f"array {name!r} has {a[name].ndim} dimensions, expected {ndim}"
    k = a["actions"].shape[0]
    if k == 0:
        return "the dataset is empty"
    n, na, d = int(meta["num_agents"]), int(meta["num_actions"]), int(meta["obs_dim"])
    shapes = {
        "obs": (k, n, d),
        "legal": (k, n, na),
        "actions": (k, n),
        "active": (k, n),
        "episode": (k,),
        "t": (k,),
        "reward": (k,),
        "return": (k,),
    }
    for name, shape in shapes.items():
        if a[name].shape != shape:
            return f"array {name!r} has shape {a[name].shape}, expected {shape}"
    for name, v in a.items():
        if name.startswith("state.") and (v.ndim < 1 or v.shape[0] != k):
            return f"array {name!r} has {v.shape[0] if v.ndim else 0} records, expected {k}"
    if not any(name.startswith("state.") for name in a):
        return "no 'state.*' arrays: the simulation cannot be restarted from the records"
    acts = a["actions"]
    if acts.min() < 0 or acts.max() >= na:
        bad = np.argwhere((acts < 0) | (acts >= na))[0]
        return f"action {int(acts[tuple(bad)])} out of range 0..{na - 1} at record {bad[0]}, agent {bad[1]}"
    chosen_legal = np.take_along_axis(a["legal"], acts[..., None].astype(np.int64), axis=-1)[..., 0]
    if not chosen_legal.all():
        r, g = (int(x) for x in np.argwhere(~chosen_legal)[0])
        return f"action {int(acts[r, g])} of agent {g} at record {r} is illegal under the record's mask (legal: {np.flatnonzero(a['legal'][r, g]).tolist()})"
    if not a["legal"].any(axis=-1).all():
        r, g = (int(x) for x in np.argwhere(~a["legal"].any(axis=-1))[0])
        return f"agent {g} at record {r} has no legal action"
    if np.any(np.diff(a["episode"]) < 0) or a["episode"].min() < 0:
        return "episode ids must be non-negative and non-decreasing"
    if not (
        np.isfinite(a["obs"]).all()
        and np.isfinite(a["reward"]).all()
        and np.isfinite(a["return"]).all()
    ):
        return "non-finite values in obs, reward or return"
    if expect is not None:
        if (expect.num_agents, expect.num_actions, expect.obs_dim) != (n, na, d):
            return (
                f"recorded for {n} agents, {na} actions, observation size {d}; the task "
                f"({expect.spec.label()}) has {expect.num_agents}, {expect.num_actions}, {expect.obs_dim}"
            )
        try:
            state_at(ds, 0, expect)
        except (KeyError, ValueError) as e:
            return f"state arrays do not fit the task: {e}"
    return None


def state_at(ds: Dataset, index: int | np.ndarray, task: Task) -> Any:
    """The environment state of record(s) ``index`` (restart the simulation from it)."""
    template = task.state_template()
    st = ds.states()
    if np.ndim(index) == 0:
        return unflatten_named(template, {k: v[int(index)] for k, v in st.items()})
    idx = np.asarray(index)
    return unflatten_named(template, {k: v[idx] for k, v in st.items()}, batch_dims=1)


def peek_meta(path: str | Path) -> dict[str, Any]:
    """The metadata of a dataset file without reading or validating the arrays."""
    from safetensors import safe_open

    try:
        with safe_open(str(path), framework="numpy") as f:
            return json.loads((f.metadata() or {}).get("hybridmarl", "{}"))
    except Exception:
        return {}


# -- behavioural cloning (Section 3) --------------------------------------------------------------------


def bc_rows(ds: Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (obs, legal, action) rows where the agent has a choice: [M, D], [M, A], [M]."""
    legal = ds.arrays["legal"]
    choice = legal.sum(-1) >= 2
    return ds.arrays["obs"][choice], legal[choice], ds.arrays["actions"][choice]


def fit_bc(
    actor: nets.NetState,
    module: nets.MLP,
    optimizer: tuple[str, float],
    rows: tuple[np.ndarray, np.ndarray, np.ndarray],
    key: jax.Array,
    steps: int,
    batch_size: int = 256,
) -> tuple[nets.NetState, np.ndarray]:
    """θ^D = argmin sum_k L(a_θ(s_k), a_g(s_k)) by minibatch SGD (``optimizer`` = (name, lr), the
    one ``actor.opt_state`` was made with); returns (actor, losses [steps])."""
    obs, legal, acts = (jnp.asarray(x) for x in rows)
    m = obs.shape[0]
    if m == 0:
        raise DatasetError("no record where an agent has a choice of action: nothing to clone")
    fn = _bc_fit_fn(nets.module_spec(module), optimizer, batch_size)
    actor, losses = fn(actor, obs, legal, acts, key, steps)
    return actor, np.asarray(losses)


@functools.lru_cache(maxsize=8)
def _bc_fit_fn(spec: tuple[tuple[int, ...], int], optimizer: tuple[str, float], batch_size: int):
    module = nets.from_spec(spec)
    tx = nets.make_optimizer(*optimizer)

    def fit(actor, obs, legal, acts, key, steps):
        m = obs.shape[0]

        def one(actor, k):
            idx = jax.random.randint(k, (batch_size,), 0, m)

            def loss_fn(params, batch_stats):
                logits, bs = nets.apply_train(module, params, batch_stats, obs[idx])
                return bc_loss(logits, acts[idx], legal[idx]), (bs, None)

            actor, loss, _ = nets.sgd_step(actor, tx, loss_fn)
            return actor, loss

        return jax.lax.scan(one, actor, jax.random.split(key, steps))

    return jax.jit(fit, static_argnums=(5,))


def bc_accuracy(
    actor: nets.NetState, module: nets.MLP, rows: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> float:
    """Fraction of choice records where the clone's legal argmax equals the demonstrated action."""
    obs, legal, acts = rows
    if obs.shape[0] == 0:
        return float("nan")
    pred = _predict_fn(nets.module_spec(module))(
        {"params": actor.params, "batch_stats": actor.batch_stats},
        jnp.asarray(obs),
        jnp.asarray(legal),
    )
    return float(np.mean(np.asarray(pred) == acts))


@functools.lru_cache(maxsize=8)
def _predict_fn(spec: tuple[tuple[int, ...], int]):
    module = nets.from_spec(spec)
    return jax.jit(lambda v, x, legal: nets.legal_argmax(nets.apply_eval(module, v, x), legal))
