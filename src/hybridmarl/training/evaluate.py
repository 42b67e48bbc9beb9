"""The evaluation protocol (paper Section 5.1) and loading trained policies.

- ``n`` battles (default 100) from random start states of the scenario, every agent playing
  the **legal action with the largest probability** under the actor (eval-mode batch norm);
- metrics: **W**, the win rate (a battle is won when the enemy has no unit left that can deal
  damage and we do), with a 95% **Wilson** score interval; **R**, the terminal hit-points reward
  (allied HP - enemy HP at the end, / initial allied HP; Table 1 footnote 1), mean with a 95%
  Student-t interval;
- the enemy is a script (default: the paper's cross-validation, a model learned from c fights
  w and vice versa) or another trained policy (``--enemy-run-dir``: its actor plays the enemy
  side, mirrored so that it sees the battle as it did in training);
- Traffic Junction: ``failure_rate`` (an episode fails when any collision happens; p_arrive
  0.2) with its Wilson interval; ``W`` is then the success rate and ``R`` the mean return.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.envs.stats import Z95 as Z95
from hybridmarl.envs.stats import t_interval as t_interval
from hybridmarl.envs.stats import wilson_interval as wilson_interval
from hybridmarl.training import networks as nets
from hybridmarl.training.checkpoint import (
    AVERAGE_PREFIX,
    BEST,
    CheckpointError,
    find_checkpoint,
    load_checkpoint,
    subtree,
)
from hybridmarl.training.task import Task, TaskSpec, make_task, unflatten_named

# -- playing episodes --------------------------------------------------------------------------------


#: ``policy(params, key, states [B], obs [B, N, D], legal [B, N, A]) -> actions [B, N]``.
def actor_policy(module: nets.MLP):
    def policy(variables, key, states, obs, legal):
        del key, states
        return nets.actor_actions(module, variables, obs, legal)

    return policy


def script_policy(task: Task, name: str):
    fn = task.demonstrator(name)

    def policy(variables, key, states, obs, legal):
        del variables, obs, legal
        return jax.vmap(fn)(jax.random.split(key, states_batch(states)), states)

    return policy


def states_batch(states: Any) -> int:
    return int(jax.tree.leaves(states)[0].shape[0])


def run_episodes(
    task: Task, policy, variables: Any, key: jax.Array, n: int
) -> dict[str, np.ndarray]:
    """Play ``n`` episodes in parallel to their ends; per-episode metrics (``task.metric_names``
    plus ``return``, the undiscounted sum of rewards, and ``steps``)."""
    fn = _episodes_fn(task, policy, n)
    out = fn(variables, key)
    return {k: np.asarray(v) for k, v in jax.device_get(out).items()}


@functools.lru_cache(maxsize=32)
def _episodes_fn(task: Task, policy, n: int):
    def run(variables, key):
        k_reset, k_run = jax.random.split(key)
        obs, states = jax.vmap(task.reset)(jax.random.split(k_reset, n))
        zeros = {k: jnp.zeros((n,), jnp.float32) for k in task.metric_names}

        def cond(c):
            return ~jnp.all(c[3])

        def body(c):
            states, obs, key, finished, stats, ret, steps = c
            key, k_act, k_step = jax.random.split(key, 3)
            legal = jax.vmap(task.avail)(states)
            actions = policy(variables, k_act, states, obs, legal)
            obs2, s2, r, d, info = jax.vmap(task.step)(jax.random.split(k_step, n), states, actions)
            new_stats = jax.vmap(task.episode_stats)(s2, info)
            live = ~finished
            ret = ret + jnp.where(live, r, 0.0)
            steps = steps + live.astype(jnp.int32)
            ending = live & d
            stats = {k: jnp.where(ending, new_stats[k], stats[k]) for k in stats}
            sel = lambda a, b: jnp.where(live.reshape(live.shape + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
            states = jax.tree.map(sel, s2, states)
            obs = sel(obs2, obs)
            return states, obs, key, finished | d, stats, ret, steps

        init = (
            states,
            obs,
            k_run,
            jnp.zeros((n,), bool),
            zeros,
            jnp.zeros((n,), jnp.float32),
            jnp.zeros((n,), jnp.int32),
        )
        _, _, _, _, stats, ret, steps = jax.lax.while_loop(cond, body, init)
        return {**stats, "return": ret, "steps": steps}

    return jax.jit(run)


def best_line(task: Task, result: dict[str, Any], best: dict[str, Any]) -> str:
    """The final evaluation's line for the ``best`` checkpoint (``--eval-every``)."""
    line = task.result_line({**result, **best}).removeprefix("eval ")
    return f"best checkpoint (episode {best['episodes']}, chosen on the selection states): {line}"


def _native_script_eval(task: Task, script: str, engine: str) -> bool:
    from hybridmarl.engine.backend import resolve_engine
    from hybridmarl.engine.native.kernels import SCRIPT_CODES

    if task.kind != "combat" or resolve_engine(engine) != "native":
        return False
    names = (script, getattr(task.env, "enemy_name", None))
    return all(name in SCRIPT_CODES and name != "random" for name in names)


def run_scripted_episodes_native(
    task: Task, script: str, key: jax.Array, n: int
) -> dict[str, np.ndarray]:
    """``run_episodes`` of a combat script on the native engine: the same start states (the
    env's own reset, with the same keys), the episodes played by
    ``envs.combat.native.play_scripted_episodes``."""
    import numba

    from hybridmarl.engine.native.kernels import SCRIPT_CODES
    from hybridmarl.envs.combat.native import play_scripted_episodes, state_arrays

    k_reset, _ = jax.random.split(key)
    _, states = _reset_fn(task, n)(k_reset)
    batch = state_arrays(jax.device_get(states))
    env, rules = task.env, task.env.rules
    won, lost = np.zeros(n, np.bool_), np.zeros(n, np.bool_)
    steps, ret, terminal = np.zeros(n, np.int32), np.zeros(n, np.float32), np.zeros(n, np.float32)
    play_scripted_episodes(
        batch["fields"],
        batch["time"],
        batch["turn"],
        batch["stale"],
        batch["prev_hp_sum"],
        batch["init_hp0"],
        np.array(rules.walkable, np.bool_, order="C", copy=True),
        SCRIPT_CODES[script],
        SCRIPT_CODES[env.enemy_name],
        env.num_agents,
        env.num_actions,
        rules.overkill == "pass",
        rules.stalemate_limit,
        rules.max_turns,
        0,
        max(1, min(n, numba.get_num_threads() * 16)),
        won,
        lost,
        steps,
        ret,
        terminal,
    )
    return {
        "won": won.astype(np.float32),
        "lost": lost.astype(np.float32),
        "draw": (~won & ~lost).astype(np.float32),
        "terminal_hp_reward": terminal,
        "return": ret,
        "steps": steps,
    }


@functools.lru_cache(maxsize=16)
def _reset_fn(task: Task, n: int):
    return jax.jit(lambda k: jax.vmap(task.reset)(jax.random.split(k, n)))


def summarize(task: Task, ep: dict[str, np.ndarray]) -> dict[str, Any]:
    """W/R (or failure rate) with 95% intervals from per-episode metrics (:meth:`Task.summarize`)."""
    return task.summarize(ep)


# -- trained policies ------------------------------------------------------------------------------------


class Policy:
    """A trained policy loaded from a run directory ('load_policy'): 'predict(obs, legal)' plays
    it (the legal argmax of Section 5.1), and the attributes say where it comes from.

    Attributes: 'run_dir'; 'config' (the run's config.json); 'spec' (its 'TaskSpec'); 'module'
    and 'variables' (the network and its parameters and batch-norm statistics); 'meta' (the
    checkpoint's metadata); 'weights' ('last': the actor, or 'average': its weight average).
    """

    def __init__(
        self,
        run_dir: Path,
        config: dict[str, Any],
        spec: TaskSpec,
        module: nets.MLP,
        variables: dict,
        meta: dict,
        weights: str = "last",
    ):
        self.run_dir = run_dir
        self.config = config
        self.spec = spec
        self.module = module
        self.variables = variables
        self.meta = meta
        self.weights = weights

    @property
    def demonstrator(self) -> str:
        return str(
            self.config.get("config", {}).get(
                "demonstrator_name", self.config.get("config", {}).get("demonstrator", "")
            )
        )

    def predict(self, obs: Any, legal: Any) -> np.ndarray:
        """Actions for observations 'obs' [..., obs_dim] and legal-action masks 'legal'
        [..., num_actions] (any leading axes, e.g. [agents] or [games, agents]): the legal action
        with the largest probability under the policy (eval-mode batch norm). NumPy in and out
        (int32 [...])."""
        obs = np.asarray(obs, np.float32)
        legal = np.asarray(legal, bool)
        if obs.shape[:-1] != legal.shape[:-1]:
            raise ValueError(
                f"obs {obs.shape} and legal {legal.shape} differ in their leading axes"
            )
        lead = obs.shape[:-1]
        flat = _predict_fn(nets.module_spec(self.module))(
            self.variables, obs.reshape((-1, obs.shape[-1])), legal.reshape((-1, legal.shape[-1]))
        )
        return np.asarray(flat).reshape(lead)


@functools.lru_cache(maxsize=16)
def _predict_fn(spec: tuple[tuple[int, ...], int]):
    module = nets.from_spec(spec)
    return jax.jit(lambda variables, obs, legal: nets.actor_actions(module, variables, obs, legal))


#: Which weights of a checkpoint 'load_policy' reads: the run's policy ('auto': the weight
#: average where the run keeps one, else the actor), the 'average' (an error without one) or
#: the 'last' actor.
POLICY_CHOICES = ("auto", "average", "last")


def load_policy(
    run_dir: str | Path, checkpoint: str | int | None = None, weights: str = "auto"
) -> Policy:
    """The policy of one checkpoint of a run (config.json says how it was built): the newest,
    or 'checkpoint', given as its episode count (700), its directory name (ckpt_000000700)
    under run_dir/checkpoints, or 'best'. 'weights' (see 'POLICY_CHOICES') picks the actor or
    its weight average (hybrid actor_average_from); by default the average where the run keeps
    one. Raises 'CheckpointError' (a 'UserError') for a missing or unreadable run."""
    if weights not in POLICY_CHOICES:
        raise CheckpointError(
            f"weights must be one of {', '.join(POLICY_CHOICES)}, not {weights!r}"
        )
    from hybridmarl.training.rundir import non_finite_array, read_run_config

    run_dir = Path(run_dir)
    doc = read_run_config(run_dir)
    ck = find_checkpoint(run_dir, checkpoint)
    arrays, meta = load_checkpoint(ck, prefixes=("actor", AVERAGE_PREFIX))
    spec = TaskSpec.from_dict(doc["task"])
    task = make_task(spec)
    hidden = tuple(doc["config"].get("actor_hidden", nets.ACTOR_HIDDEN))
    module = nets.actor_module(task.num_actions, hidden)
    template = jax.eval_shape(
        lambda: module.init(jax.random.key(0), jnp.zeros((2, task.obs_dim)), train=False)
    )
    # A run with weight averaging (hybrid actor_average_from) exports the average.
    has_average = any(k.startswith(AVERAGE_PREFIX + ".") for k in arrays)
    if weights == "average" and not has_average:
        raise CheckpointError(
            f"{ck}: holds no weight average (the run was trained without --actor-average-from, or before its first average)"
        )
    prefix = AVERAGE_PREFIX if has_average and weights != "last" else "actor"
    bad = non_finite_array(arrays, (prefix,))
    if bad is not None:
        raise CheckpointError(
            f"{ck}: array {bad!r} holds NaN/inf (the run diverged); evaluate an earlier --checkpoint"
        )
    try:
        variables = {
            "params": unflatten_named(template["params"], subtree(arrays, f"{prefix}.params")),
            "batch_stats": unflatten_named(
                template["batch_stats"], subtree(arrays, f"{prefix}.batch_stats")
            ),
        }
    except (KeyError, ValueError) as e:
        raise CheckpointError(f"{ck}: actor does not fit the run's config ({e})") from None
    return Policy(
        run_dir,
        doc,
        spec,
        module,
        variables,
        meta,
        "average" if prefix == AVERAGE_PREFIX else "last",
    )


def evaluate_best(run_dir: str | Path, evaluate: Any) -> dict[str, Any] | None:
    """The final evaluation of a run's ``best`` checkpoint (``--keep-best``), if it has one:
    ``evaluate(variables) -> result`` plus the checkpoint's ``episodes`` and its ``selection``
    result. None without a best checkpoint."""
    try:
        best = load_policy(run_dir, BEST)
    except CheckpointError:
        return None
    res = evaluate(best.variables)
    res.update(episodes=best.meta.get("episodes"), selection=best.meta.get("selection"))
    return res


def mirrored_enemy(bundle: Policy, spec: TaskSpec):
    """A trained combat actor as an enemy *script* for player 1 of ``spec``'s scenario.

    The battle is mirrored for it (players swapped, x flipped around the map centre) so it sees
    itself as player 0 on the left, as in training; its left/right moves are flipped back.
    Needs a policy trained with as many agents as the enemy has units, and vice versa.
    """
    from hybridmarl.envs.combat import learned_enemy
    from hybridmarl.envs.combat.opponents import mirror_env

    me = make_task(spec)
    if me.kind != "combat" or bundle.spec.env != "combat":
        raise CheckpointError("--enemy-run-dir needs combat runs")
    mirror = mirror_env(me.env)
    src = make_task(bundle.spec)
    if (src.num_agents, src.num_actions) != (mirror.num_agents, mirror.num_actions):
        raise CheckpointError(
            f"the enemy policy was trained with {src.num_agents} agents and {src.num_actions} actions; "
            f"as the enemy of {spec.scenario} it needs {mirror.num_agents} and {mirror.num_actions}"
        )
    return learned_enemy(
        me.env, functools.partial(nets.actor_actions, bundle.module), bundle.variables
    )


def evaluate_task(
    task: Task,
    module: nets.MLP | None,
    variables: Any,
    *,
    n: int = 100,
    seed: int = 0,
    script: str | None = None,
    engine: str = "auto",
) -> dict[str, Any]:
    """Run the protocol for an actor (``module``/``variables``) or a ``script``; summary dict.

    A combat ``script`` against a scripted enemy plays on the native engine when ``engine``
    resolves to it (``auto``: on a CPU), from the same start states, with the same results; the
    ``random`` script always plays on the JAX engine, whose draws the native one does not
    reproduce."""
    key = jax.random.key(seed)
    if script is not None and _native_script_eval(task, script, engine):
        ep = run_scripted_episodes_native(task, script, key, n)
    elif script is not None:
        ep = run_episodes(task, _script_policy_cached(task, script), None, key, n)
    else:
        assert module is not None
        ep = run_episodes(task, _actor_policy_cached(nets.module_spec(module)), variables, key, n)
    return summarize(task, ep)


def is_search_spec(spec: str) -> bool:
    """True when ``spec`` names a search player (``uct``, ``abcd:time_ms=0,nodes=500``, ``pgs``,
    ...), whether or not its options are valid (``search.make_player`` checks those)."""
    from hybridmarl.search.base import _NAME_ALIASES

    return spec.split(":", 1)[0].strip().lower().replace("_", "-") in _NAME_ALIASES


def evaluate_player(
    task: Task, player: str, *, n: int = 100, seed: int = 0, progress: bool = False
) -> dict[str, Any]:
    """The protocol for any engine player as our side of a combat task, above all the search
    players of Table 1 (``uct:script=attack-closest,playout1=attack-weakest`` is UCT_c as
    ``hybridmarl reproduce`` plays it, ``abcd:...`` A-B_c, ``pgs:portfolio=...`` "Profile"). The start states are exactly those of ``evaluate_task`` with
    the same ``n`` and ``seed``; each battle is played by the host loop of ``search.runner``
    (the player decides between compiled engine turns, with the global state, as in the
    paper) against the task's enemy script, under the env's own rules. W, R and the draws are
    computed from the final states as the env computes them. Battle ``i`` seeds the players
    with ``seed + i``."""
    bar = None
    if progress:
        from hybridmarl.training.logger import Progress

        bar = Progress(n, f"{player} vs {task.spec.enemy}", every_s=30.0)

    def on_battle(done: int, ep: dict[str, list[float]], decisions: list[Any]) -> None:
        if bar is not None:
            bar.update(done, f"W {np.mean(ep['won']):.2f}")

    ep, decisions = play_search_battles(task, player, n=n, seed=seed, on_battle=on_battle)
    if bar is not None:
        bar.close()
    out = summarize(task, ep)
    out["ms_per_decision"] = float(np.mean([d.ms for d in decisions])) if decisions else None
    return out


def play_search_battles(
    task: Task,
    player: str,
    *,
    n: int,
    seed: int,
    first: int = 0,
    on_battle: Callable[[int, dict[str, list[float]], list[Any]], None] | None = None,
) -> tuple[dict[str, np.ndarray], list[Any]]:
    """The battles of :func:`evaluate_player`: per-battle ``won``, ``lost``, ``draw``,
    ``terminal_hp_reward`` and ``steps`` arrays, and the search statistics of every decision of
    our side (``search.base.SearchStats``). Battle ``i`` depends only on start state ``i`` and
    seed ``seed + i``, so ``first`` skips battles ``0 .. first-1`` (those of an interrupted
    series) and the arrays hold battles ``first .. n-1``. ``on_battle(i, so_far, decisions)``
    is called after battle ``i`` (1-based) with the lists of this call so far."""
    from hybridmarl.engine.rules import hp_sums
    from hybridmarl.search import make_player
    from hybridmarl.search.runner import play_game_with_players

    if task.kind != "combat":
        raise ValueError("search players play combat only")
    env = task.env
    k_reset, _ = jax.random.split(jax.random.key(seed))
    _, states = jax.jit(jax.vmap(task.reset))(jax.random.split(k_reset, n))
    ours, enemy = make_player(player), make_player(task.spec.enemy)
    ep: dict[str, list[float]] = {
        k: [] for k in ("won", "lost", "draw", "terminal_hp_reward", "steps")
    }
    decisions: list[Any] = []
    for i in range(first, n):
        start = jax.tree.map(lambda a, i=i: a[i], states)
        g = play_game_with_players(start.game, env.rules, ours, enemy, seed=seed + i)
        hp = np.asarray(hp_sums(g.final_state))
        norm = max(int(start.init_hp[0]), 1)
        ep["won"].append(float(g.winner == 0))
        ep["lost"].append(float(g.winner == 1))
        ep["draw"].append(float(g.winner not in (0, 1)))
        ep["terminal_hp_reward"].append(float(np.float32(hp[0] - hp[1]) / np.float32(norm)))
        ep["steps"].append(float(len(g.decisions[0])))
        decisions += list(g.decisions[0])
        if on_battle is not None:
            on_battle(i + 1, ep, decisions)
    return {k: np.asarray(v) for k, v in ep.items()}, decisions


@functools.lru_cache(maxsize=16)
def _actor_policy_cached(spec: tuple[tuple[int, ...], int]):
    return actor_policy(nets.from_spec(spec))


@functools.lru_cache(maxsize=16)
def _script_policy_cached(task: Task, name: str):
    return script_policy(task, name)
