"""Where the tasks of a grid run: on this machine (:class:`LocalExecutor`) or on a Ray cluster
(:class:`RayExecutor`). Both run each task as a fresh Python process
(``python -m hybridmarl.reproduce.worker TASK_DIR``, output to ``TASK_DIR/log.txt``): a crash, an
out-of-memory kill or a diverged run ends that task only, and no process inherits JAX state
from another (the driver never imports JAX; workers are started, not forked from it).

An executor takes the tasks to run and two callbacks, ``started(key)`` and
``finished(key, exit_code, error)``; ``error`` is None when the process exited by itself.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hybridmarl.errors import UserError
from hybridmarl.reproduce.grid import GridTask

LOG_FILE = "log.txt"

Started = Callable[[str], None]
Finished = Callable[[str, int, "str | None"], None]


class ClusterError(UserError):
    """The Ray cluster named by --address cannot be reached, or Ray is not installed."""


def compile_cache_dir() -> Path:
    """JAX's persistent compilation cache shared by the task processes: the seeds of one row,
    and a rerun, compile the same programs, so all but the first load them
    (``$JAX_COMPILATION_CACHE_DIR``, else ``$XDG_CACHE_HOME/hybridmarl/jax``, else
    ``~/.cache/hybridmarl/jax``)."""
    given = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if given:
        return Path(given)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "hybridmarl" / "jax"


def worker_env(use_gpu: bool) -> dict[str, str]:
    """What a task process changes in its environment: JAX must not grab the whole GPU (several
    tasks may share one), and a task without a GPU runs JAX on the CPU (the search players
    then use the native engine). The rest of the environment is the one of the machine the task
    runs on (:func:`start_worker_process`)."""
    env = {"XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
    if not use_gpu:
        env["JAX_PLATFORMS"] = "cpu"
    return env


def start_worker_process(
    task_dir: str | Path, changes: dict[str, str]
) -> tuple[subprocess.Popen[bytes], Any]:
    """Start the process of one task with this process's environment plus ``changes``
    (:func:`worker_env`) and the compilation cache; its output is appended to the task's log.
    Returns the process and the open log (close it when the process has ended)."""
    env = {**os.environ, **changes}
    env["JAX_COMPILATION_CACHE_DIR"] = str(compile_cache_dir())
    # Most of a small task's programs compile in well under JAX's default threshold of 1 s.
    env.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")
    log = open(Path(task_dir) / LOG_FILE, "a")  # noqa: SIM115 (the caller closes it)
    log.write(
        f"\n=== {time.strftime('%Y-%m-%d %H:%M:%S')} {sys.executable} -m hybridmarl.reproduce.worker {task_dir}\n"
    )
    log.flush()
    proc = subprocess.Popen(
        [sys.executable, "-m", "hybridmarl.reproduce.worker", str(task_dir)],
        stdout=log,
        stderr=subprocess.STDOUT,
        env=env,
    )
    return proc, log


def run_worker_process(task_dir: str, changes: dict[str, str]) -> int:
    """Run one task to its end in a new process (on a Ray node: with that node's Python and
    environment). Returns the exit code (negative: killed by that signal)."""
    proc, log = start_worker_process(task_dir, changes)
    try:
        return proc.wait()
    finally:
        log.close()


class LocalExecutor:
    """Tasks as child processes of this command, at most ``workers`` at a time (default 1: one
    task after another)."""

    name = "local"

    def __init__(self, workers: int = 1) -> None:
        self.workers = max(1, workers)

    def run(
        self,
        tasks: list[GridTask],
        task_dir: Callable[[GridTask], Path],
        started: Started,
        finished: Finished,
        tick: Callable[[], None],
    ) -> None:
        queue = list(tasks)
        running: dict[str, tuple[subprocess.Popen[bytes], Any]] = {}
        try:
            while queue or running:
                while queue and len(running) < self.workers:
                    t = queue.pop(0)
                    running[t.key] = start_worker_process(task_dir(t), worker_env(False))
                    started(t.key)
                for key, (proc, log) in list(running.items()):
                    rc = proc.poll()
                    if rc is not None:
                        log.close()
                        del running[key]
                        finished(key, rc, None)
                tick()
                time.sleep(0.2)
        finally:
            # Interrupted: stop our own children (their checkpoints stay; a rerun resumes them).
            for proc, log in running.values():
                proc.terminate()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                log.close()


def _check_reachable(address: str) -> None:
    """A one-line error, quickly, when ``host:port`` does not answer (Ray itself retries for a
    long time)."""
    if address == "auto" or address.startswith("ray://"):
        target = address.removeprefix("ray://")
        if address == "auto":
            return
    else:
        target = address
    host, _, port = target.rpartition(":")
    if not host or not port.isdigit():
        raise ClusterError(
            f"--address {address!r} is not HOST:PORT (or 'auto', or ray://HOST:PORT)"
        )
    try:
        with socket.create_connection((host, int(port)), timeout=5):
            pass
    except OSError as e:
        raise ClusterError(
            f"cannot reach the Ray cluster at --address {address}: {e.strerror or e}"
        ) from None


class RayExecutor:
    """Tasks as Ray tasks, each running the task process on whichever node Ray picks, with
    ``num_cpus=1`` per task and ``num_gpus=gpus_per_train_task`` for training tasks. With no
    ``address`` a local cluster is started (``ray.init()``); otherwise the one at ``address``
    is joined, and ``--out`` must be a folder every node sees. At most ``workers`` tasks are in
    flight (default: the cluster's CPUs)."""

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        workers: int | None = None,
        gpus_per_train_task: float = 0.0,
    ) -> None:
        import importlib.util

        # Checked here, before anything is written: a bad --address is one line and no output.
        if importlib.util.find_spec("ray") is None:
            raise ClusterError(
                "ray is not installed; install the 'scale' extra: pip install 'hybridmarl[scale]' (or use --executor local)"
            )
        if address:
            _check_reachable(address)
        self.address, self.workers, self.gpus = address, workers, gpus_per_train_task

    def _init(self) -> Any:
        import ray  # pyright: ignore[reportMissingImports]  # the optional 'scale' extra

        kwargs: dict[str, Any] = {
            "include_dashboard": False,
            "log_to_driver": False,
            "logging_level": "ERROR",
        }
        if not self.address and self.workers:
            kwargs["num_cpus"] = self.workers
        try:
            ray.init(address=self.address, **kwargs)
        except (ConnectionError, RuntimeError, ValueError) as e:
            where = f"--address {self.address}" if self.address else "a local cluster"
            raise ClusterError(f"cannot start Ray on {where}: {' '.join(str(e).split())}") from None
        return ray

    def run(
        self,
        tasks: list[GridTask],
        task_dir: Callable[[GridTask], Path],
        started: Started,
        finished: Finished,
        tick: Callable[[], None],
    ) -> None:
        ray = self._init()
        try:
            limit = self.workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
            remote = ray.remote(max_retries=0)(run_worker_process)
            queue = list(tasks)
            in_flight: dict[Any, str] = {}
            while queue or in_flight:
                while queue and len(in_flight) < limit:
                    t = queue.pop(0)
                    use_gpu = t.kind == "train" and self.gpus > 0
                    ref = remote.options(num_cpus=1, num_gpus=self.gpus if use_gpu else 0).remote(
                        str(task_dir(t)), worker_env(use_gpu)
                    )
                    in_flight[ref] = t.key
                    started(t.key)
                done, _ = ray.wait(list(in_flight), num_returns=1, timeout=0.5)
                for ref in done:
                    key = in_flight.pop(ref)
                    try:
                        finished(key, int(ray.get(ref)), None)
                    except Exception as e:  # a crashed or killed Ray worker
                        finished(key, -1, f"{type(e).__name__}: {' '.join(str(e).split())[:300]}")
                tick()
        finally:
            ray.shutdown()


def make_executor(
    kind: str, *, address: str | None, workers: int | None, gpus_per_train_task: float
) -> LocalExecutor | RayExecutor:
    """``auto``: Ray when it is installed (or when ``address`` is given), else local."""
    if kind == "auto":
        import importlib.util

        kind = "ray" if address or importlib.util.find_spec("ray") is not None else "local"
    if kind == "ray":
        return RayExecutor(address, workers, gpus_per_train_task)
    if kind == "local":
        if address:
            raise UserError("--address needs --executor ray (or auto)")
        return LocalExecutor(workers or 1)
    raise UserError(f"unknown --executor {kind!r} (known: auto, ray, local)")


__all__ = [
    "LOG_FILE",
    "ClusterError",
    "compile_cache_dir",
    "LocalExecutor",
    "RayExecutor",
    "make_executor",
    "run_worker_process",
    "worker_env",
]
