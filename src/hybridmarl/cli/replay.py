"""Record an episode and write it as an animated GIF or an HTML viewer page: a combat battle or
a Traffic Junction episode.

The Python API behind ``hybridmarl replay``::

    from hybridmarl.cli.replay import ReplayConfig, run_replay
    run_replay(ReplayConfig(env="combat", scenario="m5v5", ours="attack-closest",
                            enemy="attack-weakest", out="out/replay_m5v5.gif"))

or, for the frames themselves, :func:`record_combat_episode` / :func:`record_tj_episode`, then
``hybridmarl.envs.video.write_video(frames, path, fps)``. With ``html="OUT.html"`` the episode is
written instead as one self-contained page that steps through it turn by turn
(:mod:`hybridmarl.viewer`; docs/replays.md).

Combat: our side (red) is played by an engine script wrapped as a per-agent env policy
(``Combat.script_policy``: the script's engine actions converted back to env actions) or by any
env policy ``(key, CombatState) -> int32 [n0]``; the enemy (green) is the env's scripted enemy.
The camera is fixed for the whole episode (a window around every unit position of the episode,
:func:`hybridmarl.envs.combat.camera_window`). Traffic Junction: the cars follow a demonstrator
(``always-gas``, ``yield-before-junction``, or any ``(TJState, key) -> int32 [N]``).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.errors import UserError
from hybridmarl.options import DEFAULT_IN_DOCSTRING
from hybridmarl.settings import check_options, get_setting

__all__ = [
    "ReplayConfig",
    "record_combat_episode",
    "record_tj_episode",
    "run_replay",
]

#: Traffic Junction demonstrators by name (``hybridmarl.envs.traffic_junction``).
_FINAL_HOLD_S = 1.0  # the last frame is repeated for about this long, so the ending is readable


@dataclass(frozen=True)
class ReplayConfig:
    """What to replay and where to write it (hybridmarl replay)."""

    env: str = "combat"
    """Environment: combat (SparCraft battle, paper Section 5.1) or traffic_junction
    (Section 5.3)."""
    scenario: str = "m5v5"
    """Combat scenario: a name (m5v5, m30v30, m18v20, m24v30, m<A>v<B>-apart)
    or a scenario JSON file. Ignored for traffic_junction."""
    ours: Annotated[str | None, DEFAULT_IN_DOCSTRING] = None
    """Our side's policy. Combat: an engine script name (default attack-closest, the paper's
    demonstrator c). Traffic Junction: a demonstrator, always-gas or
    yield-before-junction (default)."""
    enemy: str = "attack-weakest"
    """Combat: the scripted enemy (default attack-weakest, the paper's heuristic w).
    Ignored for traffic_junction."""
    seed: int = 0
    """Seed of the episode (start state, random scripts, car arrivals)."""
    out: str = "out/replay.gif"
    """Output path: .gif (or .mp4 if an imageio ffmpeg backend is installed). Not written with
    --html."""
    html: str | None = None
    """Write the episode as one self-contained HTML page to this path (.html or .htm) instead of
    a video: a timeline over engine turns (combat) or steps (Traffic Junction) with play/pause
    and step controls, the map, HP bars, cooldowns, attack lines and a per-unit panel; with
    --run-dir also the actor's action probabilities. Opens in any browser, offline."""
    fps: int = 8
    """Frames per second of the video (one frame per env step)."""
    max_steps: int = 500
    """Stop after this many env steps even if the episode has not ended (Traffic Junction
    episodes end after 40 steps)."""
    setting: str = "sparcraft"
    """Named setting (docs/engine.md#settings): 'sparcraft' or 'paper'. Combat: the rules and
    the geometry of named scenarios; Traffic Junction: the arrival probability. With --run-dir:
    the run's."""
    p_arrive: Annotated[float | None, DEFAULT_IN_DOCSTRING] = None
    """Traffic Junction car arrival probability per entry and step (default: the setting's;
    sparcraft: 0.2, CommNet's evaluation value). Ignored for combat."""
    time_penalty: bool = False
    """Traffic junction: CommNet's -0.01·τ per car per step in the reported return (a run's own
    setting with --run-dir)."""
    run_dir: str | None = None
    """Play our side with the trained actor of this run directory ('hybridmarl train'; its
    newest checkpoint, legal argmax as in the paper's test protocol) instead of --ours. The
    environment and combat scenario are the run's; --enemy still picks the enemy script."""


# --------------------------------------------------------------------------------------------
# Combat.
# --------------------------------------------------------------------------------------------


def _resolve_scenario(scenario: Any, setting: str | None = None) -> Any:
    from hybridmarl.engine.scenarios import Scenario, load_scenario_file, named_scenario

    if isinstance(scenario, Scenario):
        return scenario
    s = str(scenario)
    return load_scenario_file(s) if s.lower().endswith(".json") else named_scenario(s, setting)


def record_combat_episode(
    scenario: Any = "m5v5",
    ours: str | Callable[[jax.Array, Any], jax.Array] = "attack-closest",
    enemy: str = "attack-weakest",
    seed: int = 0,
    max_steps: int = 500,
    *,
    env: Any = None,
    width: int = 640,
    setting: str | None = None,
) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Play one combat episode and render every decision point.

    Args:
        scenario: scenario name, scenario JSON path or ``Scenario`` (ignored if ``env`` is given).
        ours: an engine script name or an env policy ``(key, CombatState) -> int32 [n0]``.
        enemy: the enemy script (ignored if ``env`` is given).
        seed: seeds the start state and the policies' keys.
        max_steps: cap on env steps.
        env: a ready ``Combat`` to use instead of building one.
        width: frame width in px.
        setting: the named setting (``hybridmarl.settings``; ignored if ``env`` is given).

    Returns:
        ``(frames, summary)``: uint8 ``[H, W, 3]`` frames (the start, then one per step) and a
        JSON-able summary of the episode.
    """
    from hybridmarl.envs.combat import Combat, camera_window

    if max_steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    if env is None:
        env = Combat(_resolve_scenario(scenario, setting), enemy=enemy, setting=setting)
    policy = env.script_policy(ours) if isinstance(ours, str) else ours
    reset = jax.jit(env.reset)
    step = jax.jit(env.step)
    act = jax.jit(policy)

    key = jax.random.key(seed)
    key, k0 = jax.random.split(key)
    _, state = reset(k0)
    states = [state]
    total = 0.0
    illegal = 0
    info: dict[str, Any] = {}
    done = False
    while not done and len(states) <= max_steps:
        key, k_act, k_env = jax.random.split(key, 3)
        _, state, reward, d, info = step(k_env, state, act(k_act, state))
        states.append(state)
        total += float(reward)
        illegal += int(info["illegal_actions"])
        done = bool(d)
    window = camera_window([s.game for s in states])
    frames = [env.render(s, window=window, width=width) for s in states]
    info = {k: np.asarray(v).item() for k, v in jax.device_get(info).items()}
    last = states[-1]
    hp = np.asarray(last.game.hp).clip(min=0).sum(axis=1)
    result = "unfinished"
    if done:
        result = "won" if info["won"] else "lost" if info["lost"] else "draw"
    summary = {
        "env": env.name,
        "scenario": env.scenario.name if env.scenario is not None else None,
        "ours": ours if isinstance(ours, str) else getattr(ours, "__name__", "policy"),
        "enemy": env.enemy_name,
        "seed": seed,
        "steps": len(states) - 1,
        "engine_turns": int(last.game.turn),
        "final_frame_time": int(last.game.time),
        "done": done,
        "result": result,
        "allied_hp": int(hp[0]),
        "enemy_hp": int(hp[1]),
        "terminal_hp_reward": float((hp[0] - hp[1]) / max(int(last.init_hp[0]), 1)),
        "return": round(total, 6),
        "illegal_actions": illegal,
    }
    return frames, summary


def _hold_last(frames: list[np.ndarray], fps: int) -> list[np.ndarray]:
    return frames + [frames[-1]] * max(round(_FINAL_HOLD_S * fps) - 1, 0)


# --------------------------------------------------------------------------------------------
# Traffic Junction.
# --------------------------------------------------------------------------------------------


def _tj_demonstrator(name: str) -> Callable[[jax.Array, Any], jax.Array]:
    from hybridmarl.envs.traffic_junction.demonstrators import DEMONSTRATORS, canonical_demonstrator

    try:
        return DEMONSTRATORS[canonical_demonstrator(name)]
    except ValueError as e:
        raise UserError(str(e)) from None


def record_tj_episode(
    demonstrator: str | Callable[[jax.Array, Any], jax.Array] = "yield-before-junction",
    p_arrive: float = 0.2,
    seed: int = 0,
    max_steps: int = 40,
    *,
    cell_px: int = 24,
    time_penalty: bool = False,
) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Play one Traffic Junction episode with a demonstrator and render every step.

    Returns ``(frames, summary)`` like :func:`record_combat_episode`.
    """
    from hybridmarl.envs.traffic_junction import TrafficJunction

    if not 0.0 <= float(p_arrive) <= 1.0:
        raise ValueError(f"p_arrive must be in [0, 1], got {p_arrive}")
    if max_steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    policy = _tj_demonstrator(demonstrator) if isinstance(demonstrator, str) else demonstrator
    env = TrafficJunction()
    params = env.default_params.replace(p_arrive=float(p_arrive), time_penalty=bool(time_penalty))
    step = jax.jit(env.step)
    act = jax.jit(policy)
    key = jax.random.key(seed)
    key, k0 = jax.random.split(key)
    _, state = env.reset(k0, params)
    states = [state]
    total, collisions, arrivals = 0.0, 0, 0
    done = False
    while not done and len(states) <= max_steps:
        key, k_act, k_env = jax.random.split(key, 3)
        _, state, reward, d, info = step(k_env, state, act(k_act, state), params)
        states.append(state)
        total += float(reward)
        collisions += int(info["collisions"])
        arrivals += int(info["arrivals"])
        done = bool(d)
    frames = [env.render(s, cell_px=cell_px) for s in states]
    summary = {
        "env": env.name,
        "demonstrator": demonstrator if isinstance(demonstrator, str) else "policy",
        "p_arrive": float(p_arrive),
        "time_penalty": bool(time_penalty),
        "seed": seed,
        "steps": len(states) - 1,
        "done": done,
        "failed": bool(states[-1].failed),
        "collisions": collisions,
        "arrivals": arrivals,
        "return": round(total, 6),
    }
    return frames, summary


# --------------------------------------------------------------------------------------------
# The CLI entry point.
# --------------------------------------------------------------------------------------------


def _validate(cfg: ReplayConfig) -> str:
    """Canonical env name; raises UserError with a one-line message on bad input."""
    from hybridmarl.engine.scripts import canonical_name

    env = str(cfg.env).strip().lower().replace("-", "_")
    env = {
        "combat_v0": "combat",
        "traffic_junction_v0": "traffic_junction",
        "tj": "traffic_junction",
    }.get(env, env)
    if env not in ("combat", "traffic_junction"):
        raise UserError(f"unknown env {cfg.env!r} (known: combat, traffic_junction)")
    check_options(cfg.setting, p_arrive=cfg.p_arrive if env == "traffic_junction" else None)
    if cfg.html is not None:
        if Path(cfg.html).suffix.lower() not in (".html", ".htm"):
            raise UserError(f"--html {cfg.html!r} must end in .html (or .htm)")
    elif Path(cfg.out).suffix.lower() not in (".gif", ".mp4"):
        raise UserError(f"output {cfg.out!r} must end in .gif (or .mp4)")
    if isinstance(cfg.fps, bool) or not isinstance(cfg.fps, int) or cfg.fps <= 0:
        raise UserError(f"fps must be a positive integer, got {cfg.fps!r}")
    if isinstance(cfg.max_steps, bool) or not isinstance(cfg.max_steps, int) or cfg.max_steps < 1:
        raise UserError(f"max_steps must be a positive integer, got {cfg.max_steps!r}")
    if isinstance(cfg.seed, bool) or not isinstance(cfg.seed, int) or cfg.seed < 0:
        raise UserError(f"seed must be a non-negative integer, got {cfg.seed!r}")
    if env == "combat":
        for who, name in (("ours", cfg.ours or "attack-closest"), ("enemy", cfg.enemy)):
            try:
                canonical_name(name)
            except KeyError as e:
                raise UserError(f"{who}: {e.args[0]}") from None
        _resolve_scenario(
            cfg.scenario, cfg.setting
        )  # InputError (a UserError) with one line if bad
    else:
        _tj_demonstrator(cfg.ours or "yield-before-junction")
        if cfg.p_arrive is not None and not 0.0 <= float(cfg.p_arrive) <= 1.0:
            raise UserError(f"p_arrive must be in [0, 1], got {cfg.p_arrive!r}")
    return env


@dataclass(frozen=True)
class _Trained:
    """A run directory's policy, as the replay plays and shows it."""

    cfg: ReplayConfig  # the replay settings with the run's env, scenario and setting
    act: Callable[[jax.Array, Any], jax.Array]  # the actor's legal argmax, an env policy
    probs: Callable[[Any], jax.Array]  # state -> [n, A] the actor's action probabilities
    alg1: Callable[
        [], Callable[[jax.Array, Any], dict[str, jax.Array]] | None
    ]  # builds _alg1_choice


def _trained_policy(cfg: ReplayConfig) -> _Trained:
    """The policy of ``cfg.run_dir`` (its newest checkpoint) and, for a hybrid run, Alg. 1.
    Raises ValueError (one line) for a missing or broken run directory."""
    import dataclasses

    from hybridmarl.training import networks as nets
    from hybridmarl.training.evaluate import load_policy
    from hybridmarl.training.task import make_task

    bundle = load_policy(str(cfg.run_dir))  # CheckpointError is a ValueError
    spec = bundle.spec
    task = make_task(spec)
    module, variables = bundle.module, bundle.variables

    def act(key: jax.Array, state: Any) -> jax.Array:
        del key
        return nets.actor_actions(
            module, variables, task.observe(state)[None], task.avail(state)[None]
        )[0]

    def probs(state: Any) -> jax.Array:
        logits = nets.apply_eval(module, variables, task.observe(state))
        return jnp.exp(nets.masked_log_softmax(logits, task.avail(state)))

    run_dir = Path(str(cfg.run_dir))

    def alg1() -> Callable[[jax.Array, Any], dict[str, jax.Array]] | None:
        return _alg1_choice(run_dir, bundle.config, task)

    if spec.env == "combat":
        cfg = dataclasses.replace(
            cfg, env="combat", scenario=spec.scenario, ours=None, setting=spec.setting
        )
    else:
        cfg = dataclasses.replace(
            cfg,
            env="traffic_junction",
            p_arrive=spec.p_arrive,
            time_penalty=spec.time_penalty,
            ours=None,
            setting=spec.setting,
        )
    return _Trained(cfg, act, probs, alg1)


def _alg1_choice(
    run_dir: Path, doc: dict[str, Any], task: Any
) -> Callable[[jax.Array, Any], dict[str, jax.Array]] | None:
    """For a hybrid run: ``(key, state) -> {"actions" [n], "start" [n], "q_start", "q_final"}``,
    Alg. 1's joint action Ã at ``state`` as the run's training computes it (its options: start
    policy, iterations, look-ahead; the newest checkpoint's actor, critic and clone), with the
    joint action it started from and Q(s, ·) of both. None for runs of other algorithms."""
    if doc.get("algo") != "hybrid":
        return None
    from hybridmarl.algos.hybrid.brd import best_response_dynamics
    from hybridmarl.algos.hybrid.config import HybridConfig
    from hybridmarl.algos.hybrid.learner import build_learner, continuation_policy, simulated_steps
    from hybridmarl.io import unflatten_named
    from hybridmarl.training import networks as nets
    from hybridmarl.training.checkpoint import find_checkpoint, load_checkpoint, subtree
    from hybridmarl.training.config import config_from_dict

    hcfg = config_from_dict(HybridConfig, doc.get("config", {}))
    arrays, _ = load_checkpoint(find_checkpoint(run_dir))
    demo_script = None if hcfg.demonstrator_is_dataset() else hcfg.demonstrator_name()
    learner = build_learner(task, hcfg, demo_script)

    def net(prefix: str, module: nets.MLP, in_dim: int) -> dict[str, Any] | None:
        if not any(k.startswith(prefix + ".") for k in arrays):
            return None
        template = jax.eval_shape(
            lambda: module.init(jax.random.key(0), jnp.zeros((2, in_dim)), train=False)
        )
        return {
            "params": unflatten_named(template["params"], subtree(arrays, f"{prefix}.params")),
            "batch_stats": unflatten_named(
                template["batch_stats"], subtree(arrays, f"{prefix}.batch_stats")
            ),
        }

    actor = net("actor", learner.actor_mod, task.obs_dim)
    critic = net("critic", learner.critic_mod, task.critic_dim)
    clone = net("clone", learner.actor_mod, task.obs_dim)
    if actor is None or critic is None:
        raise ValueError(f"{run_dir}: the newest checkpoint lacks the actor or the critic")
    demo = learner.demo_script_fn
    if hcfg.brd_start == "demonstrator" and demo is None and clone is None:
        raise ValueError(
            f"{run_dir}: Alg. 1 starts from the demonstrator's clone, which the checkpoint lacks"
        )

    def choose(
        actor: Any, critic: Any, clone: Any, key: jax.Array, state: Any
    ) -> dict[str, jax.Array]:
        q_fn = learner.brd_q_fn(
            actor,
            critic,
            clone,
            gamma=hcfg.gamma,
            lookahead=simulated_steps(hcfg),
            continuation=continuation_policy(hcfg),
        )
        k_demo, k_sim = jax.random.split(key)
        obs, legal = task.observe(state)[None], task.avail(state)[None]
        if hcfg.brd_start == "actor":
            start = nets.actor_actions(learner.actor_mod, actor, obs, legal)
        elif demo is not None:
            start = demo(k_demo, state)[None].astype(jnp.int32)
        else:
            start = nets.actor_actions(learner.actor_mod, clone, obs, legal)
        states = jax.tree.map(lambda x: x[None], state)
        res = best_response_dynamics(
            q_fn,
            k_sim[None],
            states,
            start,
            legal,
            hcfg.brd_iterations,
            work_batch=hcfg.brd_work_batch,
        )
        return {
            "actions": res.actions[0],
            "start": start[0],
            "q_start": res.q_init[0],
            "q_final": res.q_final[0],
        }

    jitted = jax.jit(choose)
    return lambda key, state: jitted(actor, critic, clone, key, state)


def run_replay(cfg: ReplayConfig) -> int:
    """Record the episode ``cfg`` describes and write the video (the last frame held for about
    a second), or with ``cfg.html`` the HTML viewer page; print a one-line JSON summary and
    return 0.

    Raises :class:`~hybridmarl.errors.UserError` (one line) on bad input, a missing or broken
    run directory, or a file that cannot be written; a video needs the ``video`` extra (Pillow,
    imageio), the HTML page nothing beyond the core install.
    """
    trained = None
    try:
        if cfg.run_dir is not None:
            trained = _trained_policy(cfg)
            cfg = trained.cfg
        env = _validate(cfg)
    except UserError:
        raise
    except ValueError as e:
        raise UserError(str(e).splitlines()[0] if str(e) else "bad replay settings") from None
    if cfg.html is not None:
        summary = _write_html(cfg, env, trained)
    else:
        summary = _write_video(cfg, env, trained)
    if trained:
        summary["ours"] = f"policy:{cfg.run_dir}"
    print(json.dumps(summary))
    return 0


def _write_video(cfg: ReplayConfig, env: str, trained: _Trained | None) -> dict[str, Any]:
    from hybridmarl.cli.extras import optional_extras

    with optional_extras():
        from hybridmarl.envs.video import write_video

        if env == "combat":
            ours: Any = trained.act if trained else (cfg.ours or "attack-closest")
            frames, summary = record_combat_episode(
                cfg.scenario, ours, cfg.enemy, cfg.seed, cfg.max_steps, setting=cfg.setting
            )
        else:
            ours = trained.act if trained else (cfg.ours or "yield-before-junction")
            p_arrive = get_setting(cfg.setting).p_arrive if cfg.p_arrive is None else cfg.p_arrive
            frames, summary = record_tj_episode(
                ours, p_arrive, cfg.seed, cfg.max_steps, time_penalty=cfg.time_penalty
            )
        summary["setting"] = cfg.setting
        try:
            path = write_video(_hold_last(frames, cfg.fps), cfg.out, fps=cfg.fps)
        except (OSError, RuntimeError) as e:
            raise UserError(f"cannot write {cfg.out!r}: {e}") from None
    return {**summary, "out": path, "fps": cfg.fps}


def _write_html(cfg: ReplayConfig, env: str, trained: _Trained | None) -> dict[str, Any]:
    """Record the episode turn by turn (:mod:`hybridmarl.viewer`) and write the page."""
    from hybridmarl.viewer import record_combat_timeline, record_tj_timeline, write_page

    probs = trained.probs if trained else None
    alg1 = None
    if trained:
        try:
            alg1 = trained.alg1()
        except (
            ValueError,
            KeyError,
            TypeError,
        ) as e:  # an older or foreign run's config or checkpoint
            print(
                f"hybridmarl: warning: Alg. 1's joint action is not shown: {str(e).splitlines()[0] if str(e) else type(e).__name__}",
                file=sys.stderr,
            )
    who = f"policy {cfg.run_dir}" if trained else None
    if env == "combat":
        from hybridmarl.envs.combat import Combat

        combat = Combat(
            _resolve_scenario(cfg.scenario, cfg.setting), enemy=cfg.enemy, setting=cfg.setting
        )
        ours_name = cfg.ours or "attack-closest"
        policy = trained.act if trained else combat.script_policy(ours_name)
        timeline, last = record_combat_timeline(
            combat, policy, cfg.seed, cfg.max_steps, probs_fn=probs, alg1_fn=alg1
        )
        frames = timeline["frames"]
        end = frames[-1]
        result = "unfinished"
        if last["done"]:
            result = {0: "won", 1: "lost"}.get(end["winner"], "draw")
        who = who or ours_name
        summary: dict[str, Any] = {
            "env": combat.name,
            "scenario": combat.scenario.name if combat.scenario is not None else None,
            "ours": who,
            "enemy": combat.enemy_name,
            "seed": cfg.seed,
            "steps": last["steps"],
            "engine_turns": end["turn"],
            "done": last["done"],
            "result": result,
            "allied_hp": end["hp_sum"][0],
            "enemy_hp": end["hp_sum"][1],
            "return": round(last["return"], 6),
            "illegal_actions": last["illegal"],
        }
        title = f"{summary['scenario']}: {who} (ours, red) vs {combat.enemy_name} (enemy, green)"
        subtitle = (
            f"seed {cfg.seed}, setting {cfg.setting}: {result} after {end['turn']} engine turns "
            f"({last['steps']} decision steps), return {last['return']:.3f}"
        )
    else:
        from hybridmarl.envs.traffic_junction import TrafficJunction

        p_arrive = get_setting(cfg.setting).p_arrive if cfg.p_arrive is None else cfg.p_arrive
        params = TrafficJunction().default_params.replace(
            p_arrive=float(p_arrive), time_penalty=bool(cfg.time_penalty)
        )
        ours_name = cfg.ours or "yield-before-junction"
        policy = trained.act if trained else _tj_demonstrator(ours_name)
        timeline, last = record_tj_timeline(
            policy, params, cfg.seed, cfg.max_steps, probs_fn=probs, alg1_fn=alg1
        )
        frames = timeline["frames"]
        who = who or ours_name
        collisions = sum(f["collisions"] for f in frames)
        summary = {
            "env": "traffic_junction_v0",
            "demonstrator": who,
            "p_arrive": float(p_arrive),
            "time_penalty": bool(cfg.time_penalty),
            "seed": cfg.seed,
            "steps": last["steps"],
            "done": last["done"],
            "failed": bool(frames[-1].get("failed", False)),
            "collisions": collisions,
            "arrivals": sum(f["arrivals"] for f in frames),
            "return": round(last["return"], 6),
        }
        title = f"Traffic Junction: {who}"
        subtitle = (
            f"seed {cfg.seed}, p_arrive {float(p_arrive):g}: {last['steps']} steps, "
            f"{collisions} colliding cars, return {last['return']:.3f}"
        )
    summary["setting"] = cfg.setting
    try:
        path = write_page(cfg.html or "", timeline, title=title, subtitle=subtitle, fps=cfg.fps)
    except OSError as e:
        raise UserError(f"cannot write {cfg.html!r}: {e}") from None
    return {**summary, "html": path, "frames": len(frames)}


def replay_command(args: list[str]) -> int:
    """``hybridmarl replay [options]``."""
    import tyro

    return run_replay(tyro.cli(ReplayConfig, args=args, prog="hybridmarl replay"))
