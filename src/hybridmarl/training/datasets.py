"""Graded demonstration datasets: scripted demonstrators of different strengths, each recorded
clean and with ε-random actions, ranked by their measured win rate W against the enemy script
(in the spirit of OG-MARL's dataset tiers).

Every dataset is an ordinary ``hybridmarl-demos`` file (:mod:`hybridmarl.training.demos`;
docs/datasets.md): ``hybridmarl train --demonstrator DIR/<name>.safetensors`` and
:func:`~hybridmarl.training.demos.load_dataset` read it as they read ``hybridmarl demos
collect``'s output. Its metadata adds a ``graded`` entry (script, noise, rank, W). The folder
also gets ``manifest.json``: the datasets from the strongest demonstrator to the weakest, each
with its W and R (95 % intervals) on a fixed set of evaluation battles.

All demonstrators of one generation share one compiled collector and one compiled evaluator:
the script is picked by ``lax.switch`` on a traced index and the noise level is a traced
number, so a set of eight datasets costs one compilation, not eight.

    from hybridmarl.training.datasets import generate_graded
    generate_graded("data/m5v5-graded", scenario="m5v5", enemy="attack-weakest")
"""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.errors import UserError
from hybridmarl.io import write_json_atomic
from hybridmarl.training.demos import (
    FORMAT,
    VERSION,
    Dataset,
    _renumber,
    _step_fields,
    save_dataset,
)
from hybridmarl.training.evaluate import run_episodes, summarize
from hybridmarl.training.rollout import EpisodeAssembler, new_pool, pool_steps
from hybridmarl.training.task import Task, TaskSpec, canonical_script, make_task

__all__ = [
    "DEFAULT_NOISE",
    "DEFAULT_SCRIPTS",
    "MANIFEST",
    "GradedError",
    "GradedSpec",
    "generate_graded",
    "load_manifest",
    "scripts_arg",
    "tier_table",
]

#: Candidate demonstrators for combat, from SparCraft's scripts (docs/engine.md#scripts).
DEFAULT_SCRIPTS = ("nokdps", "kiter-dps", "attack-closest", "attack-weakest")
#: The probability that each agent's action is replaced by a uniformly random legal one.
DEFAULT_NOISE = 0.2
MANIFEST = "manifest.json"
MANIFEST_FORMAT = "hybridmarl-graded-demos"


class GradedError(UserError):
    """Bad settings for a graded dataset set (one-line message)."""


@dataclass(frozen=True)
class GradedSpec:
    """What to generate: one clean and (with ``noise > 0``) one noisy dataset per script."""

    scenario: str = "m5v5"
    enemy: str = "attack-weakest"
    setting: str = "sparcraft"
    scripts: tuple[str, ...] = DEFAULT_SCRIPTS
    noise: float = DEFAULT_NOISE
    num_observations: int = 10_000
    """Joint states per dataset (whole episodes; the last one is cut at this count)."""
    eval_battles: int = 200
    """Battles per demonstrator for W and R (the same start states for all of them); 0: W and
    R of the dataset's own episodes (no separate evaluation, one compilation less)."""
    seed: int = 0
    num_envs: int = 64
    gamma: float = 0.995


def _demonstrators(spec: GradedSpec) -> list[tuple[str, str, float]]:
    """``(name, script, eps)`` of every dataset: each script clean, then with ``noise``."""
    out = []
    for script in spec.scripts:
        out.append((script, script, 0.0))
        if spec.noise > 0:
            out.append((f"{script}-eps{spec.noise:g}", script, float(spec.noise)))
    return out


def _check(spec: GradedSpec) -> tuple[str, ...]:
    if not spec.scripts:
        raise GradedError("no scripts given")
    scripts = tuple(
        canonical_script("combat", s) for s in spec.scripts
    )  # TaskError names a bad one
    if any(":" in s for s in scripts):
        raise GradedError(
            "give scripts without a ':eps' suffix; --noise sets the noisy versions' ε"
        )
    if len(set(scripts)) != len(scripts):
        raise GradedError(f"scripts repeat: {', '.join(scripts)}")
    if not 0.0 <= spec.noise <= 1.0:
        raise GradedError(f"noise must be in [0, 1], got {spec.noise!r}")
    for name, value in (("num_observations", spec.num_observations), ("num_envs", spec.num_envs)):
        if value < 1:
            raise GradedError(f"{name} must be >= 1, got {value}")
    if spec.eval_battles < 0:
        raise GradedError(f"eval_battles must be >= 0, got {spec.eval_battles}")
    return scripts


@functools.lru_cache(maxsize=4)
def _switch_policy(task: Task, scripts: tuple[str, ...]):
    """``(key, state, which, eps) -> actions``: script ``which`` (a traced index), each agent's
    action replaced by a uniformly random legal one with probability ``eps`` (traced), as
    ``hybridmarl.training.task.epsilon_policy`` does."""
    fns = [task.env.demonstrator(s) for s in scripts]

    def act(key: jax.Array, state: Any, which: jax.Array, eps: jax.Array) -> jax.Array:
        k0, k1, k2 = jax.random.split(key, 3)
        a = jax.lax.switch(
            which, [lambda k, s, f=f: f(k, s).astype(jnp.int32) for f in fns], k0, state
        )
        legal = task.avail(state)
        rnd = jax.random.categorical(k2, jnp.where(legal, 0.0, -jnp.inf), axis=-1).astype(jnp.int32)
        flip = jax.random.uniform(k1, a.shape) < eps
        return jnp.where(flip, rnd, a).astype(jnp.int32)

    return act


@functools.lru_cache(maxsize=4)
def _collector(task: Task, scripts: tuple[str, ...], num_envs: int, chunk: int):
    """Jitted ``(pool, which, eps) -> (pool, out)``: ``chunk`` steps of every game."""
    policy = _switch_policy(task, scripts)

    def act(carry, key, states, obs, legal):
        which, eps = carry
        a = jax.vmap(policy, in_axes=(0, 0, None, None))(
            jax.random.split(key, num_envs), states, which, eps
        )
        active = jax.vmap(task.env.agent_active)(states)
        return a, carry, {"obs": obs, "legal": legal, "actions": a, "active": active}

    @jax.jit
    def run(pool, which, eps):
        pool, _, out = pool_steps(task, act, pool, (which, eps), chunk)
        return pool, out

    return run


@functools.lru_cache(maxsize=4)
def _evaluator(task: Task, scripts: tuple[str, ...]):
    """A ``run_episodes`` policy whose "variables" are ``(which, eps)``."""
    policy = _switch_policy(task, scripts)

    def play(variables, key, states, obs, legal):
        del obs, legal
        which, eps = variables
        n = int(jax.tree.leaves(states)[0].shape[0])
        return jax.vmap(policy, in_axes=(0, 0, None, None))(
            jax.random.split(key, n), states, which, eps
        )

    return play


def _record(
    task: Task,
    spec: GradedSpec,
    scripts: tuple[str, ...],
    which: int,
    eps: float,
    seed: int,
    chunk: int = 64,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """``demos.collect``'s recording loop for one demonstrator of the switch policy: the
    dataset's arrays and the metrics of its episodes (``won``, ``terminal_hp_reward``, ...,
    ``steps``; the last episode's records may be cut at ``num_observations``)."""
    run = _collector(task, scripts, spec.num_envs, chunk)
    pool = new_pool(task, jax.random.key(seed), spec.num_envs)
    asm = EpisodeAssembler(spec.num_envs, spec.gamma)
    parts: list[dict[str, np.ndarray]] = []
    metrics: list[dict[str, np.ndarray]] = []
    got = 0
    w, e = jnp.int32(which), jnp.float32(eps)
    while got < spec.num_observations:
        pool, out = run(pool, w, e)
        done_fields, returns, stats = asm.add_fields(
            _step_fields(out), out["reward"], out["done"], out["stats"]
        )
        if returns.size:
            done_fields["return"] = returns
            parts.append(done_fields)
            metrics.append(stats)
            got += int(returns.size)
    episode_of_row = _renumber(np.concatenate([p["episode_key"] for p in parts]))
    arrays = {k: np.concatenate([p[k] for p in parts])[: spec.num_observations] for k in parts[0]}
    arrays["episode"] = _renumber(arrays["episode_key"])
    del arrays["episode_key"]
    kept = int(arrays["episode"].max()) + 1
    episodes = {k: np.concatenate([m[k] for m in metrics])[:kept] for k in metrics[0]}
    episodes["steps"] = np.bincount(episode_of_row)[:kept].astype(np.float32)
    return arrays, episodes


def generate_graded(
    out_dir: str | Path, spec: GradedSpec = GradedSpec(), *, log: Any = print
) -> dict[str, Any]:
    """Measure every demonstrator's W against ``spec.enemy``, record its dataset and write the
    datasets and ``manifest.json`` to ``out_dir``; returns the manifest.

    Each dataset records ``spec.num_observations`` joint states of finished episodes from random
    start states (seeded by ``spec.seed`` plus the demonstrator's index, so datasets differ in
    their start states too). W and R come from ``spec.eval_battles`` battles with seed
    ``spec.seed``: the same start states for every demonstrator, as ``hybridmarl eval`` plays
    them (with ``eval_battles=0``: the dataset's own episodes). Every entry also has
    ``dataset_W`` and ``dataset_R``, the same measures over the episodes in the file.
    Raises :class:`GradedError` or ``TaskError`` (one line) on bad settings.
    """
    scripts = _check(spec)
    task_spec = TaskSpec(
        env="combat", scenario=spec.scenario, enemy=spec.enemy, setting=spec.setting
    )
    task = make_task(task_spec)  # TaskError names a bad scenario, enemy or setting
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise GradedError(f"{out}: exists and is not a folder")
    evaluate = _evaluator(task, scripts)
    demonstrators = _demonstrators(GradedSpec(**{**spec.__dict__, "scripts": scripts}))

    def rank_key(e: dict[str, Any]) -> tuple[float, float, str]:
        return (-e["W"], -e["R"], e["name"])  # rank 1: the highest W, then R

    def save(e: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        meta = {
            "format": FORMAT,
            "version": VERSION,
            "task": task_spec.to_dict(),
            "demonstrator": e["demonstrator"],
            "seed": e["seed"],
            "gamma": float(spec.gamma),
            "num_agents": task.num_agents,
            "num_actions": task.num_actions,
            "obs_dim": task.obs_dim,
            "num_observations": e["num_observations"],
            "graded": {
                k: e[k]
                for k in (
                    "name",
                    "script",
                    "noise",
                    "rank",
                    "W",
                    "W_ci95",
                    "R",
                    "R_ci95",
                    "eval_battles",
                )
            },
        }
        save_dataset(Dataset(arrays=arrays, meta=meta), out / e["file"])

    # W and R on the evaluation battles first: with the ranks known, each dataset is written as
    # soon as it is recorded, so only one is held in memory.
    evaluated: dict[str, dict[str, Any]] = {}
    if spec.eval_battles > 0:
        for name, script, eps in demonstrators:
            variables = (jnp.int32(scripts.index(script)), jnp.float32(eps))
            episodes = run_episodes(
                task, evaluate, variables, jax.random.key(spec.seed), spec.eval_battles
            )
            evaluated[name] = {"name": name, **summarize(task, episodes)}
        order = sorted(evaluated.values(), key=rank_key)
        for rank, r in enumerate(order, start=1):
            r["rank"] = rank

    entries: list[dict[str, Any]] = []
    pending: dict[str, dict[str, np.ndarray]] = {}  # ranked by their own episodes: saved at the end
    for i, (name, script, eps) in enumerate(demonstrators):
        t0 = time.perf_counter()
        arrays, episodes = _record(
            task, spec, scripts, scripts.index(script), eps, spec.seed + 1 + i
        )
        own = summarize(task, episodes)
        result = evaluated.get(name, own)
        e = {
            "name": name,
            "file": f"{name}.safetensors",
            "demonstrator": script if eps == 0 else f"{script}:{eps:g}",
            "script": script,
            "noise": eps,
            "rank": result.get("rank"),
            "W": result["W"],
            "W_ci95": result["W_ci95"],
            "R": result["R"],
            "R_ci95": result["R_ci95"],
            "draws": result["draws"],
            "eval_battles": spec.eval_battles,
            "dataset_W": own["W"],
            "dataset_R": own["R"],
            "num_observations": int(arrays["actions"].shape[0]),
            "episodes": int(arrays["episode"].max()) + 1,
            "seed": spec.seed + 1 + i,
        }
        entries.append(e)
        if e["rank"] is not None:
            save(e, arrays)
        else:
            pending[name] = arrays
        log(
            f"{name}: W {e['W']:.2f} [{e['W_ci95'][0]:.2f}, {e['W_ci95'][1]:.2f}]  R {e['R']:+.3f}  "
            f"({e['episodes']} episodes, {time.perf_counter() - t0:.0f} s)"
        )
    entries.sort(key=rank_key)
    for rank, e in enumerate(entries, start=1):
        if e["name"] in pending:
            e["rank"] = rank
            save(e, pending.pop(e["name"]))
    manifest = {
        "format": MANIFEST_FORMAT,
        "version": 1,
        "task": task_spec.to_dict(),
        "eval_seed": spec.seed,
        "gamma": spec.gamma,
        "datasets": entries,
    }
    write_json_atomic(out / MANIFEST, manifest)
    return manifest


def load_manifest(folder: str | Path) -> dict[str, Any]:
    """The ``manifest.json`` of a graded set (``GradedError`` if missing or not one)."""
    path = Path(folder) / MANIFEST
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise GradedError(
            f"{path}: no such file (generate the set with experiments/graded_datasets.py)"
        ) from None
    except json.JSONDecodeError as e:
        raise GradedError(f"{path}: not JSON ({e.msg}, line {e.lineno})") from None
    if not isinstance(doc, dict) or doc.get("format") != MANIFEST_FORMAT:
        raise GradedError(
            f"{path}: not a graded dataset manifest (format {doc.get('format') if isinstance(doc, dict) else None!r})"
        )
    return doc


def tier_table(manifest: dict[str, Any]) -> str:
    """A Markdown table of the datasets, strongest first."""
    rows = [
        "| rank | dataset | demonstrator | W [95 % CI] | R [95 % CI] | W of its episodes | observations | episodes |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for e in manifest["datasets"]:
        rows.append(
            f"| {e['rank']} | `{e['file']}` | `{e['demonstrator']}` | {e['W']:.2f} [{e['W_ci95'][0]:.2f}, {e['W_ci95'][1]:.2f}] "
            f"| {e['R']:+.3f} [{e['R_ci95'][0]:+.3f}, {e['R_ci95'][1]:+.3f}] | {e['dataset_W']:.2f} "
            f"| {e['num_observations']} | {e['episodes']} |"
        )
    return "\n".join(rows)


def scripts_arg(text: str | Sequence[str]) -> tuple[str, ...]:
    """``"a,b"`` or ``["a", "b"]`` -> ``("a", "b")``."""
    items = text.split(",") if isinstance(text, str) else list(text)
    return tuple(s.strip() for s in items if s.strip())
