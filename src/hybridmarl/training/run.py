"""The run skeleton every learner shares, written once: a learner's 'train' reads top to bottom
as its method, and calls 'Run' for everything around it.

    run = Run(ALGO, cfg)                  # the task, the run directory (a directory holding
    with run:                             #   checkpoints is refused unless --resume), the
        ...build the state...             #   logger, the clock
        run.start(state, module, ...)     # config.json, periodic evaluation, resume
        ...pre-training phases...; run.save()
        with run.loop():                  # the progress display; the last checkpoint after it
            while run.running():          # the episode budget (and the time limit)
                ...one chunk of the method...
                run.count(stats, env_steps)            # episodes, history
                ...updates...
                run.log_chunk(head, status)            # train.csv, episodes.csv, TensorBoard,
                                                       # progress, periodic evaluation,
                                                       # checkpoint cadence, time limit
        return run.finish(counters)       # the final evaluation (Section 5.1), 'best',
                                          # eval.json, the curve, the result lines

A loss or parameter that becomes NaN/inf raises 'TrainingDiverged' (from 'check_finite'); the
run then closes its logs and the exception propagates, its message saying whether a checkpoint
from before the divergence exists to --resume from.

Before any work, 'Run' checks every number of the config ('hybridmarl.validate'), takes the
run directory's lock ('training.rundir.RunLock'), removes what killed writes left behind, and
on --resume refuses a directory that is not a run, a checkpoint that does not fit, and a config
that changes how the run trains ('rundir.check_resume_config').
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.errors import Interrupted, TrainingDiverged
from hybridmarl.io import write_json_atomic
from hybridmarl.settings import DEFAULT_SETTING
from hybridmarl.training.checkpoint import (
    CheckpointError,
    latest_checkpoint,
    load_checkpoint,
    pause_point,
    prefixed,
    save_checkpoint,
    subtree,
)
from hybridmarl.training.config import (
    FINAL_EVAL_SEED,
    PeriodicEval,
    RunClock,
    TrainConfig,
    config_to_dict,
    key_data,
    key_of,
    resolve_run_dir,
)
from hybridmarl.training.logger import Progress, RunLogger, recent_status
from hybridmarl.training.rundir import (
    RunLock,
    check_resume_config,
    non_finite_array,
    remove_partial_writes,
)
from hybridmarl.training.task import TaskError, TaskSpec, flatten_named, make_task, unflatten_named


@dataclass
class TrainResult:
    """What 'train(config)' returns: the run directory and its final evaluation ('eval.json')."""

    run_dir: Path
    evaluation: dict[str, Any]

    @functools.cached_property
    def policy(self) -> Any:
        """The run's policy ('hybridmarl.load_policy(run_dir)': 'predict(obs, legal)')."""
        from hybridmarl.training.evaluate import load_policy

        return load_policy(self.run_dir)


@dataclass(kw_only=True)
class RunState:
    """The part of a learner's checkpointed state that every learner has: the pool of games,
    the PRNG key, the episode assembler, the counters and the per-episode history. A learner
    subclasses it with its networks ('TREES': array prefix -> attribute), its host buffers
    ('BUFFERS': prefix -> attribute, objects with 'to_arrays'/'load_arrays') and counters
    ('COUNTERS', saved in checkpoint metadata)."""

    pool: Any
    key: jax.Array  # raw uint32 key data
    assembler: Any
    phase: str = "pretrain"
    episodes: int = 0
    env_steps: int = 0
    demo_stats: dict[str, float] = dataclasses.field(default_factory=dict)
    history: dict[str, list[float]] = dataclasses.field(default_factory=dict)

    TREES: ClassVar[dict[str, str]] = {}
    BUFFERS: ClassVar[dict[str, str]] = {}
    COUNTERS: ClassVar[tuple[str, ...]] = ("phase", "episodes", "env_steps", "demo_stats")

    def next_key(self) -> jax.Array:
        k, sub = jax.random.split(key_of(self.key))
        self.key = key_data(k)
        return sub

    def arrays(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for prefix, attr in self.TREES.items():
            tree = getattr(self, attr)
            if tree is not None:
                out.update(prefixed(flatten_named(tree), prefix))
        out.update(prefixed(flatten_named(self.pool), "pool"))
        out["key"] = np.asarray(self.key)
        for prefix, attr in {**self.BUFFERS, "asm": "assembler"}.items():
            out.update(prefixed(getattr(self, attr).to_arrays(), prefix))
        for k, v in self.history.items():
            out[f"history.{k}"] = np.asarray(v, np.float32)
        return out

    def meta(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.COUNTERS}

    def restore(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        for prefix, attr in self.TREES.items():
            tree = getattr(self, attr)
            if tree is not None:
                setattr(self, attr, unflatten_named(tree, subtree(arrays, prefix)))
        self.pool = unflatten_named(self.pool, subtree(arrays, "pool"))
        self.key = jnp.asarray(arrays["key"])
        for prefix, attr in {**self.BUFFERS, "asm": "assembler"}.items():
            getattr(self, attr).load_arrays(subtree(arrays, prefix))
        self.history = {k: np.asarray(v).tolist() for k, v in subtree(arrays, "history").items()}
        self.restore_counters(meta)

    def restore_counters(self, meta: dict[str, Any]) -> None:
        """The counters of checkpoint metadata ``meta`` (those it lacks keep their values)."""
        for k in self.COUNTERS:
            default = getattr(self, k)
            value = meta.get(k, default)
            # A float saved while NaN is written as null (checkpoint._json_safe).
            if value is None and isinstance(default, float):
                value = float("nan")
            elif isinstance(value, dict):
                value = {name: float("nan") if v is None else v for name, v in value.items()}
            setattr(self, k, value)


def check_same_setting(checkpoint: Path, spec: TaskSpec) -> None:
    """Refuse to resume a run under another setting than the one it was trained under (a
    checkpoint without one was trained under the default, ``sparcraft``)."""
    try:
        with open(checkpoint / "meta.json") as f:
            task = json.load(f).get("task", {})
    except (OSError, json.JSONDecodeError):
        return  # load_checkpoint reports an unreadable checkpoint
    saved = task.get("setting", DEFAULT_SETTING) if isinstance(task, dict) else DEFAULT_SETTING
    if saved != spec.setting:
        raise TaskError(
            f"{checkpoint.parent.parent} was trained under setting {saved!r}; cannot resume it under "
            f"setting {spec.setting!r} (pass --setting {saved}, or choose another --run-dir)"
        )


class Run:
    """Set-up, loop bookkeeping and the final evaluation of one training run (module docstring)."""

    def __init__(self, algo: str, cfg: TrainConfig, *, resumable: bool = True) -> None:
        from hybridmarl.validate import check_config

        self.algo, self.cfg, self.resumable = algo, cfg, resumable
        check_config(cfg)  # every number, before any work
        self.clock = RunClock()
        self.spec = cfg.task_spec()
        self.task = make_task(self.spec)
        self.run_dir = resolve_run_dir(algo, cfg)
        if (
            cfg.resume
            and not (self.run_dir / "config.json").is_file()
            and latest_checkpoint(self.run_dir) is None
        ):
            what = (
                "no such run directory"
                if not self.run_dir.exists()
                else "not a run directory (no config.json)"
            )
            raise CheckpointError(
                f"--resume: {self.run_dir}: {what}; drop --resume to start a new run there"
            )
        self.lock = RunLock(self.run_dir)
        self.lock.acquire()
        try:
            self._open(cfg)
        except BaseException:
            self.lock.release()
            raise

    def _open(self, cfg: TrainConfig) -> None:
        freed = remove_partial_writes(self.run_dir)
        if freed:
            print(
                f"{self.run_dir}: removed {freed / 2**20:.1f} MiB of partial writes left by an interrupted run"
            )
        self.checkpoint = latest_checkpoint(self.run_dir)
        if self.checkpoint is not None and not cfg.resume:
            how = (
                "pass --resume to continue it"
                if self.resumable
                else f"pass --resume ({self.algo} restarts from scratch)"
            )
            raise TaskError(
                f"{self.run_dir} already holds checkpoints: {how}, or choose another --run-dir"
            )
        self._meta: dict[str, Any] = {}
        if self.checkpoint is not None and self.resumable:
            check_same_setting(self.checkpoint, self.spec)
            self._arrays, self._meta = load_checkpoint(self.checkpoint)
            check_resume_config(self.checkpoint, self._meta.get("config"), config_to_dict(cfg))
        elif self.checkpoint is not None:
            self.checkpoint = None  # a learner that restarts from scratch
        elif cfg.resume and self.resumable:
            print(f"{self.run_dir} holds no checkpoint yet: starting the run from the beginning")
        self.log = RunLogger(self.run_dir, tensorboard=cfg.tensorboard)
        if self.checkpoint is None:
            self.log.reset()  # a fresh start: no rows of an earlier attempt
        self.eval_task = self.task.against(cfg.eval_enemy_name())
        self.module: Any = None
        self.state: Any = None
        self.config_doc: dict[str, Any] = {}
        self.periodic = PeriodicEval(cfg, self.run_dir, self.log, 0)
        self.time_limited = False
        self._progress: Progress | None = None
        self._policy: Callable[[], Any] = lambda: None
        self._policy_arrays: Callable[[], dict[str, np.ndarray]] = dict
        self._t_chunk = 0.0
        self._next_ckpt = 0
        self._new: tuple[int, int, dict[str, np.ndarray]] = (0, 0, {})
        self._interrupted = False

    # -- set-up -------------------------------------------------------------------------------------

    def __enter__(self) -> Run:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        try:
            self._close_progress()
            self.log.close()
            if isinstance(exc, TrainingDiverged):
                raise TrainingDiverged(f"{exc} {self._after_divergence()}") from None
            if isinstance(exc, KeyboardInterrupt) and self.resumable:
                ck = latest_checkpoint(self.run_dir)
                where = f"{ck.name} ({self.run_dir})" if ck else "no checkpoint yet"
                print(
                    f"\ninterrupted; last checkpoint: {where}; continue with: hybridmarl train --run-dir {self.run_dir} --resume",
                    file=sys.stderr,
                )
        finally:
            self.lock.release()

    def _after_divergence(self) -> str:
        """What is left to continue from, for the message of a diverged run."""
        ck = latest_checkpoint(self.run_dir) if self.resumable else None
        if ck is None:
            return "(no checkpoint was saved before it: fix the cause and start the run again)"
        return (
            f"(checkpoint {ck.name}, saved before it, is still valid: fix the cause and --resume)"
        )

    def config_document(self, networks: dict[str, int] | None = None) -> dict[str, Any]:
        """config.json: the algo, the full config (flat), the task, network sizes, versions."""
        from hybridmarl import __version__

        doc: dict[str, Any] = {
            "algo": self.algo,
            "config": {
                **config_to_dict(self.cfg),
                "demonstrator_name": self.cfg.demonstrator_name(),
                "eval_enemy_name": self.cfg.eval_enemy_name(),
            },
            "task": self.spec.to_dict(),
        }
        if networks is not None:
            doc["networks"] = networks
        doc["versions"] = {"jax": jax.__version__, "hybridmarl": __version__}
        return doc

    def start(
        self,
        state: RunState,
        module: Any,
        policy: Callable[[], Any],
        policy_arrays: Callable[[], dict[str, np.ndarray]],
        networks: dict[str, int],
    ) -> None:
        """Adopt the learner's state, resume it from the newest checkpoint (with --resume) and
        write config.json. 'policy()' gives the variables of the run's policy ('module'),
        'policy_arrays()' the arrays the 'best' checkpoint keeps of it."""
        self.state, self.module, self._policy, self._policy_arrays = (
            state,
            module,
            policy,
            policy_arrays,
        )
        self.config_doc = self.config_document(networks)
        self.periodic = PeriodicEval(self.cfg, self.run_dir, self.log, state.episodes)
        if self.checkpoint is not None:
            arrays, meta = self._arrays, self._meta
            bad = non_finite_array(arrays, tuple(state.TREES))
            if bad is not None:
                raise CheckpointError(
                    f"checkpoint {self.checkpoint}: array {bad!r} holds NaN/inf (the run diverged); resume from an earlier checkpoint"
                )
            try:
                state.restore(arrays, meta)
            except (KeyError, ValueError, TypeError) as e:
                msg = str(e.args[0]) if e.args else type(e).__name__
                raise CheckpointError(
                    f"checkpoint {self.checkpoint} does not fit the run's config ({msg})"
                ) from None
            self.clock.resume(meta)
            self.periodic.resume(meta, state.episodes)
            self.log.resume_at(state.episodes, meta.get("log_rows"))
            del self._arrays
            print(
                f"resumed {self.run_dir} from {self.checkpoint.name} (phase {state.phase}, {state.episodes} episodes)"
            )
        self.log.write_config(self.config_doc)

    def checkpoint_meta(self) -> dict[str, Any]:
        return {
            **self.state.meta(),
            **self.clock.elapsed(),
            **self.periodic.meta(),
            "algo": self.algo,
            "config": self.config_doc["config"],
            "task": self.spec.to_dict(),
            "log_rows": self.log.row_counts(),
        }

    def save(self) -> None:
        save_checkpoint(
            self.run_dir,
            self.state.episodes,
            self.state.arrays(),
            self.checkpoint_meta(),
            keep=self.cfg.keep_checkpoints,
        )

    def evaluate(self, variables: Any, seed_offset: int = FINAL_EVAL_SEED) -> dict[str, Any]:
        """The evaluation protocol (Section 5.1) of the policy 'variables' against the
        evaluation enemy, on the start states of seed + 'seed_offset'."""
        from hybridmarl.training import evaluate as E

        return E.evaluate_task(
            self.eval_task,
            self.module,
            variables,
            n=self.cfg.eval_episodes,
            seed=self.cfg.seed + seed_offset,
        )

    # -- the training loop --------------------------------------------------------------------------

    @contextlib.contextmanager
    def loop(self) -> Iterator[None]:
        """The interaction phase: the progress display while it runs; the last checkpoint after."""
        self._progress = Progress(
            self.cfg.total_episodes,
            f"{self.algo} {self.spec.label()}",
            enabled=self.cfg.progress,
            start=self.state.episodes,
        )
        self._next_ckpt = self._after(self.state.episodes)
        # Ctrl-C stops the loop at the end of the chunk (a consistent state), which is then saved.
        handled = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, self._on_interrupt) if handled else None
        try:
            yield
        finally:
            if handled:
                signal.signal(signal.SIGINT, previous)
        self._close_progress()
        self.save()
        if self._interrupted:
            raise Interrupted(
                f"interrupted at {self.state.episodes} episodes, checkpoint saved; "
                f"continue with: hybridmarl train --run-dir {self.run_dir} --resume"
            )

    def _on_interrupt(self, signum: int, frame: Any) -> None:
        if self._interrupted:  # a second Ctrl-C: stop at once (the last checkpoint stays valid)
            raise KeyboardInterrupt
        self._interrupted = True
        print(
            "\nstopping at the end of this chunk to save a checkpoint (Ctrl-C again to stop at once)",
            file=sys.stderr,
            flush=True,
        )

    def running(self) -> bool:
        """True while the episode budget lasts and the clock has not stopped the run; starts
        the timing of the next chunk."""
        self._t_chunk = time.time()
        return (
            not self.time_limited
            and not self._interrupted
            and self.state.episodes < self.cfg.total_episodes
        )

    def count(self, stats: dict[str, np.ndarray], env_steps: int) -> None:
        """Count a chunk: its finished episodes (per-episode metrics 'stats') and env steps."""
        pause_point("chunk", lambda: self._interrupted)
        st = self.state
        n_new = int(next(iter(stats.values())).shape[0]) if stats else 0
        self._new = (st.episodes, n_new, stats)
        st.episodes += n_new
        st.env_steps += env_steps
        for k, v in stats.items():
            st.history.setdefault(k, []).extend(v.tolist())

    def recent(self) -> dict[str, float]:
        """Means over the last 100 episodes (NaN until there is history)."""
        h = self.state.history
        return {
            k: float(np.mean(h[k][-100:])) if h.get(k) else float("nan")
            for k in (*self.task.metric_names, "return")
        }

    def train_row(
        self,
        head: dict[str, Any],
        chunk_s: float,
        per_second: dict[str, float] | None = None,
        episodes: int | None = None,
    ) -> dict[str, Any]:
        """One train.csv row. Every row has the same keys (the CSV header is the first row's,
        often written before any episode has finished)."""
        return {
            "episodes": self.state.episodes if episodes is None else episodes,
            "env_steps": self.state.env_steps,
            **head,
            **{f"{k}_100": v for k, v in self.recent().items()},
            "chunk_s": chunk_s,
            **{k: n / max(chunk_s, 1e-9) for k, n in (per_second or {}).items()},
            **self.clock.elapsed(),
        }

    def log_chunk(
        self, head: dict[str, Any], status: str, per_second: dict[str, float] | None = None
    ) -> None:
        """After a chunk: its train.csv row ('head': the method's columns), its episodes.csv
        rows, TensorBoard, the progress line ('status': the method's part), the periodic
        evaluation, the checkpoint cadence and the time limit."""
        st, cfg = self.state, self.cfg
        row = self.train_row(head, time.time() - self._t_chunk, per_second)
        self.log.train.write([row])
        self.log.scalars(st.episodes, row)
        first, n_new, stats = self._new
        self.log.episodes.write(
            [
                {
                    "episode": first + i + 1,
                    "env_steps": st.env_steps,
                    **{k: float(v[i]) for k, v in stats.items()},
                }
                for i in range(n_new)
            ]
        )
        if self._progress is not None:
            primary, secondary = self.task.progress_metrics
            self._progress.update(
                st.episodes, f"{recent_status(self.recent(), primary, secondary)}  {status}"
            )
        self.periodic.maybe_run(
            st.episodes,
            lambda off: self.evaluate(self._policy(), off),
            self._policy_arrays,
            self.checkpoint_meta(),
        )
        if st.episodes >= self._next_ckpt:
            self.save()
            self._next_ckpt = self._after(st.episodes)
        limit = float(getattr(cfg, "time_limit_min", 0.0))
        if limit > 0 and self.clock.elapsed()["wall_s"] >= 60.0 * limit:
            self.time_limited = True

    def _after(self, episodes: int) -> int:
        every = self.cfg.checkpoint_every
        return (episodes // every + 1) * every

    def _close_progress(self) -> None:
        if self._progress is not None:
            self._progress.close()
            self._progress = None

    # -- the end ------------------------------------------------------------------------------------

    def finish(
        self,
        counters: dict[str, Any],
        *,
        before: dict[str, Any] | None = None,
        baseline: float | None = None,
        note: str = "",
        lines: Callable[[dict[str, Any]], list[str]] | None = None,
    ) -> TrainResult:
        """The final evaluation (Section 5.1) of the run's policy and of its 'best' checkpoint
        (--eval-every), eval.json, the training curve and the result lines. 'before': results
        reported next to the policy's (e.g. the last actor); 'counters': the run's counters."""
        from hybridmarl.training import evaluate as E
        from hybridmarl.training import plots

        st = self.state
        pause_point("evaluation")
        result = self.evaluate(self._policy())
        result.update(before or {})
        result.update(
            enemy=self.eval_task.enemy, episodes=st.episodes, **counters, **self.clock.elapsed()
        )
        best = E.evaluate_best(self.run_dir, self.evaluate)
        if best is not None:
            result["best"] = best
        write_json_atomic(self.run_dir / "eval.json", result)
        self.log.scalars(
            st.episodes, {k: v for k, v in result.items() if isinstance(v, float)}, prefix="eval"
        )
        secondary = self.task.progress_metrics[1]
        title = f"{self.algo}: {self.spec.label()}, A^D = {self.cfg.demonstrator_name()}"
        plots.training_curve(
            st.history.get(secondary, []),
            self.run_dir / "curve.png",
            metric=secondary,
            title=title,
            baseline=baseline,
        )
        return self._close(
            result,
            note,
            [
                *(lines(result) if lines else []),
                *([E.best_line(self.task, result, best)] if best else []),
            ],
        )

    def report(self, result: dict[str, Any]) -> TrainResult:
        """For a learner without a training loop (BC): write eval.json, close the logs, print
        the result line."""
        write_json_atomic(self.run_dir / "eval.json", result)
        return self._close(result, "", [])

    def _close(self, result: dict[str, Any], note: str, lines: list[str]) -> TrainResult:
        self.log.close()
        print(self.task.result_line(result) + note)
        for line in lines:
            print(line)
        return TrainResult(self.run_dir, result)


__all__ = ["Run", "RunState", "TrainResult"]
