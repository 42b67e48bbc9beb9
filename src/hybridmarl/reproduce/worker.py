"""One task of the grid, in its own process: ``python -m hybridmarl.reproduce.worker TASK_DIR``.

``TASK_DIR/task.json`` says what to do (:class:`hybridmarl.reproduce.grid.GridTask`); the
result goes to ``TASK_DIR/result.json`` (atomically), with the per-episode outcomes of the
evaluation so that rows can be compared battle by battle. A ``train`` task trains in
``TASK_DIR/run``, resuming the run an earlier attempt started, so a killed task continues from
its newest checkpoint; a run that already wrote its ``eval.json`` is not trained again.

Exit codes as the ``hybridmarl`` command: 0 done, 2 bad input, 3 training diverged (NaN), 1
anything else (the traceback is in the task's log).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

#: The task description and the result of a task directory.
TASK_FILE = "task.json"
RESULT_FILE = "result.json"


def _spec(c: dict[str, Any]) -> Any:
    """The evaluation ``TaskSpec`` of a task config (the cross-validation enemy in combat)."""
    from hybridmarl.settings import get_setting
    from hybridmarl.training.task import TaskSpec

    setting = get_setting(c["setting"])
    if c["env"] == "combat":
        return TaskSpec(
            env="combat", scenario=c["scenario"], enemy=c["enemy"], setting=setting.name
        )
    return TaskSpec(env="traffic_junction", p_arrive=setting.p_arrive, setting=setting.name)


def _per_episode(ep: dict[str, Any]) -> dict[str, list[float]]:
    """The per-episode outcomes a table needs (combat: won, R; Traffic Junction: failed,
    arrivals), as plain lists."""
    keys = ("won", "terminal_hp_reward") if "won" in ep else ("failed", "arrivals")
    return {k: [float(x) for x in ep[k]] for k in keys}


def evaluate_policy(
    task: Any, module: Any, variables: Any, script: str | None, n: int, seed: int
) -> tuple[dict[str, Any], dict[str, list[float]]]:
    """The protocol's evaluation (``training.evaluate``) of an actor or a script on the start
    states of ``seed``: its summary and the per-episode outcomes."""
    import jax

    from hybridmarl.training import evaluate as E

    key = jax.random.key(seed)
    policy = E.script_policy(task, script) if script is not None else E.actor_policy(module)
    ep = E.run_episodes(task, policy, variables, key, n)
    return task.summarize(ep), _per_episode(ep)


#: Battles a search task has finished so far, so that a killed task resumes (search tasks take
#: up to hours; battles are independent, so resuming gives the uninterrupted task's numbers).
PARTIAL_FILE = "partial.json"
#: Seconds between two saves of :data:`PARTIAL_FILE`.
PARTIAL_EVERY_S = 60.0
_STAT_NAMES = ("ms", "traversals", "nodes", "playouts")


def _load_partial(path: Path | None, ident: dict[str, Any]) -> dict[str, Any]:
    """The finished battles an earlier attempt of this task saved, or none. A file of another
    task, or one that cannot be read, counts as none (it is only a cache)."""
    empty = {
        **ident,
        "episodes": None,
        "stats": {name: [0.0, 0] for name in _STAT_NAMES},
        "wall_s": 0.0,
        "cpu_s": 0.0,
    }
    if path is None:
        return empty
    try:
        saved = json.loads(path.read_text())
        if not isinstance(saved, dict) or any(saved.get(k) != v for k, v in ident.items()):
            return empty
        lengths = {len(v) for v in saved["episodes"].values()}
        if (
            len(lengths) != 1
            or lengths.pop() > ident["n"]
            or set(saved["stats"]) != set(_STAT_NAMES)
        ):
            return empty
        return saved
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return empty


def evaluate_search(
    task: Any, player: str, n: int, seed: int, task_dir: Path | None = None
) -> tuple[dict[str, Any], dict[str, list[float]], tuple[float, float]]:
    """A search player on the start states of ``seed`` (those of :func:`evaluate_policy`), as
    ``training.evaluate.evaluate_player`` plays it, keeping each battle's outcome. With a
    ``task_dir`` the finished battles are saved to :data:`PARTIAL_FILE` about every minute and a
    later call continues after them. Returns the summary, the per-battle outcomes, and the wall
    and CPU seconds earlier attempts spent."""
    import numpy as np

    from hybridmarl.io import write_json_atomic
    from hybridmarl.training.evaluate import play_search_battles

    ident = {"player": player, "n": n, "seed": seed}
    path = task_dir / PARTIAL_FILE if task_dir is not None else None
    saved = _load_partial(path, ident)
    before: dict[str, list[float]] = saved["episodes"] or {}
    first = len(next(iter(before.values()))) if before else 0
    if first:
        print(
            f"{path}: {first} battles finished earlier, continuing from battle {first + 1}",
            flush=True,
        )
    t0, c0, last_save = time.time(), time.process_time(), time.time()

    def merged(ep: dict[str, list[float]], decisions: list[Any]) -> dict[str, Any]:
        stats = {name: list(saved["stats"][name]) for name in _STAT_NAMES}
        for d in decisions:
            for name in _STAT_NAMES:
                stats[name][0] += float(getattr(d, name))
                stats[name][1] += 1
        return {
            **ident,
            "episodes": {k: [*before.get(k, []), *map(float, v)] for k, v in ep.items()},
            "stats": stats,
            "wall_s": saved["wall_s"] + time.time() - t0,
            "cpu_s": saved["cpu_s"] + time.process_time() - c0,
        }

    def on_battle(done: int, ep: dict[str, list[float]], decisions: list[Any]) -> None:
        nonlocal last_save
        won = [*before.get("won", []), *ep["won"]]
        print(
            f"battle {done}/{n}: W so far {np.mean(won):.3f} ({time.time() - t0:.0f} s)", flush=True
        )
        if path is not None and done < n and time.time() - last_save >= PARTIAL_EVERY_S:
            write_json_atomic(path, merged(ep, decisions))
            last_save = time.time()

    ep, decisions = play_search_battles(
        task, player, n=n, seed=seed, first=first, on_battle=on_battle
    )
    total = merged({k: v.tolist() for k, v in ep.items()}, decisions)
    summary = task.summarize({k: np.asarray(v) for k, v in total["episodes"].items()})
    for name in _STAT_NAMES:
        value, count = total["stats"][name]
        summary[f"{name}_per_decision"] = value / count if count else None
    return summary, _per_episode(total["episodes"]), (saved["wall_s"], saved["cpu_s"])


def train_then_evaluate(
    c: dict[str, Any], task_dir: Path
) -> tuple[dict[str, Any], dict[str, list[float]], dict[str, Any]]:
    """Train the learner of ``c`` with its seed in ``task_dir/run`` (resuming a killed run),
    then evaluate its policy on the protocol's start states against the cross-validation enemy."""
    import hybridmarl
    from hybridmarl import algos
    from hybridmarl.training.checkpoint import latest_checkpoint

    run_dir = task_dir / "run"
    mod = algos.algo_module(c["algo"])
    env = c["env"]
    cfg = mod.PRESETS[c["preset"]](env)
    # Continue a run an earlier attempt started (it wrote its config or a checkpoint).
    resume = (run_dir / "config.json").is_file() or latest_checkpoint(run_dir) is not None
    fields = {
        "demonstrator": c["demonstrator"],
        "setting": c["setting"],
        "seed": c["seed"],
        "run_dir": str(run_dir),
        "resume": resume,
        "progress": False,
        "tensorboard": False,
        **c["overrides"],
    }
    if env == "combat":
        fields.update(scenario=c["scenario"], enemy=c["enemy"])
    cfg = cfg.replace(**fields)
    if (run_dir / "eval.json").is_file():
        print(f"{run_dir}: training finished earlier (eval.json), evaluating it", flush=True)
    else:
        hybridmarl.train(cfg)
    ev = evaluate_run(run_dir, c)
    own = json.loads((run_dir / "eval.json").read_text())
    training = {k: own.get(k) for k in ("episodes", "wall_s", "cpu_s") if k in own}
    training["weights"] = ev["weights"]
    training["eval_wall_s"], training["eval_cpu_s"] = ev["wall_s"], ev["cpu_s"]
    return ev["summary"], ev["per_episode"], training


def evaluate_run(
    run_dir: Path, c: dict[str, Any], checkpoint: str | int | None = None
) -> dict[str, Any]:
    """The protocol evaluation of a training run's policy (or of its ``checkpoint``) as the
    task config ``c`` prescribes: the run's own task (scenario, setting) against the task's
    cross-validation enemy, on the start states of its ``eval_seed``. Returns ``summary``,
    ``per_episode``, ``weights``, ``meta`` (the checkpoint's) and the evaluation's ``wall_s``
    and ``cpu_s``."""
    from hybridmarl.training.evaluate import load_policy
    from hybridmarl.training.task import make_task

    policy = load_policy(run_dir, checkpoint)
    spec = (
        dataclasses.replace(policy.spec, enemy=c["enemy"]) if c["env"] == "combat" else policy.spec
    )
    wall0, cpu0 = time.time(), time.process_time()
    summary, per_episode = evaluate_policy(
        make_task(spec), policy.module, policy.variables, None, c["n"], c["eval_seed"]
    )
    return {
        "summary": summary,
        "per_episode": per_episode,
        "weights": policy.weights,
        "meta": policy.meta,
        "wall_s": time.time() - wall0,
        "cpu_s": time.process_time() - cpu0,
    }


def run_task(task_dir: Path) -> dict[str, Any]:
    """Do the task described in ``task_dir/task.json`` and write its ``result.json``."""
    from hybridmarl import __version__
    from hybridmarl.io import write_json_atomic
    from hybridmarl.training.task import make_task

    task = json.loads((task_dir / TASK_FILE).read_text())
    kind, c = task["kind"], task["config"]
    wall0, cpu0 = time.time(), time.process_time()
    training: dict[str, Any] | None = None
    if kind == "train":
        summary, per_episode, training = train_then_evaluate(c, task_dir)
    elif kind == "search":
        summary, per_episode, (wall_before, cpu_before) = evaluate_search(
            make_task(_spec(c)), c["player"], c["n"], c["eval_seed"], task_dir
        )
        wall0, cpu0 = wall0 - wall_before, cpu0 - cpu_before
    elif kind == "script":
        summary, per_episode = evaluate_policy(
            make_task(_spec(c)), None, None, c["player"], c["n"], c["eval_seed"]
        )
    else:
        raise ValueError(f"unknown task kind {kind!r}")
    wall_s, cpu_s = time.time() - wall0, time.process_time() - cpu0
    if training is not None:
        # The run's own clock spans every attempt (RunClock); this attempt's may hold only the
        # evaluation of a run an earlier attempt trained.
        wall_s = max(wall_s, float(training.get("wall_s") or 0.0) + training["eval_wall_s"])
        cpu_s = max(cpu_s, float(training.get("cpu_s") or 0.0) + training["eval_cpu_s"])
    result = {
        "key": task["key"],
        "kind": kind,
        "config": c,
        "summary": summary,
        "per_episode": per_episode,
        "training": training,
        "wall_s": wall_s,
        "cpu_s": cpu_s,
        "finished": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "version": __version__,
    }
    write_json_atomic(task_dir / RESULT_FILE, result)
    (task_dir / PARTIAL_FILE).unlink(missing_ok=True)
    return result


def _exit_with_parent() -> None:
    """End this process when the process that started it is gone (a killed driver or Ray
    worker), so no task keeps running unseen; its checkpoints stay for the next run."""
    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(2.0)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def main(argv: list[str] | None = None) -> int:
    from hybridmarl.errors import EXIT_BAD_INPUT, EXIT_DIVERGED, TrainingDiverged, UserError

    _exit_with_parent()
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m hybridmarl.reproduce.worker TASK_DIR", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        run_task(Path(args[0]))
    except UserError as e:
        print(f"hybridmarl: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except TrainingDiverged as e:
        print(f"hybridmarl: training stopped: {e}", file=sys.stderr)
        return EXIT_DIVERGED
    return 0


if __name__ == "__main__":
    sys.exit(main())
