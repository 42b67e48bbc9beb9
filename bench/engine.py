"""Engine throughput, both backends side by side (prints JSON).

    python bench/engine.py                                  # native and jax, 1 and 2 cores
    python bench/engine.py --engines native --threads 1 --repeats 5
    python bench/engine.py --out bench-engine.json

For every (engine, cores) pair a fresh worker process is started, pinned to that many CPUs
(``sched_setaffinity``) with ``NUMBA_NUM_THREADS`` / XLA host devices set to match, so one-core
figures are not inflated by a second core. Each worker times full scripted games (``--p0`` vs
``--p1``, default attack-closest vs attack-weakest) per scenario: the minimum and median games/s
over ``--repeats`` runs. Compile time is reported apart (native: loading or compiling the Numba
kernels; ``--cold-compile`` also times a compile from an empty cache; JAX: the first call of the
jitted pool). ``--battles-n`` times ``native.run_battles`` on that many m5v5 states, start-state
generation included, with the worker's peak RSS. System load (``uptime``) is recorded before
and after.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

DEFAULT_GAMES = {"native": {"m5v5": 40000, "m30v30": 6000}, "jax": {"m5v5": 8192, "m30v30": 2048}}


def _uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "load average: " + ", ".join(f"{v:.2f}" for v in os.getloadavg())


def _pin(cores: int) -> None:
    cpus = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, set(cpus[:cores]))


def _rates(n_games: int, seconds: list[float]) -> dict:
    rates = [n_games / s for s in seconds]
    return {"min": round(min(rates), 1), "median": round(statistics.median(rates), 1)}


def worker_native(args) -> dict:
    from hybridmarl.engine import native
    from hybridmarl.engine.scenarios import named_scenario
    from hybridmarl.engine.state import make_rules

    compile_s = native.compile_kernels(quiet=True)
    rules = make_rules()
    rows = []
    for sc_name, n in zip(args.scenarios, args.games, strict=True):
        states = native.from_arrays(named_scenario(sc_name).generate_arrays(n, args.seed))
        times = []
        res = None
        for _ in range(args.repeats):
            t = time.perf_counter()
            _, res = native.play(states, rules, args.p0, args.p1, threads=args.cores)
            times.append(time.perf_counter() - t)
        assert res is not None
        rows.append(
            {
                "scenario": sc_name,
                "games_per_run": n,
                "games_per_s": _rates(n, times),
                "mean_turns": round(float(res.turns.mean()), 2),
                "p0_win_rate": round(float((res.winner == 0).mean()), 4),
            }
        )
    return {
        "compile_or_cache_load_s": round(compile_s, 2),
        "threading_layer": native.threading_layer(),
        "results": rows,
    }


def worker_jax(args) -> dict:
    import jax
    import numpy as np

    from hybridmarl.engine import game
    from hybridmarl.engine.battle import pad_states
    from hybridmarl.engine.scenarios import named_scenario
    from hybridmarl.engine.scripts import canonical_name
    from hybridmarl.engine.state import make_rules

    rules = make_rules()
    devices = jax.local_device_count()
    rows = []
    compile_total = 0.0
    for sc_name, n in zip(args.scenarios, args.games, strict=True):
        pool = args.jax_pool
        n = int(np.ceil(n / (pool * devices)) * pool * devices)
        stacked, _ = pad_states(named_scenario(sc_name).generate(n, args.seed))
        keys = jax.random.split(jax.random.PRNGKey(args.seed), n)
        fn = game.pooled_player(
            canonical_name(args.p0),
            canonical_name(args.p1),
            game.rules_static(rules),
            pool,
            devices,
        )
        t = time.perf_counter()
        jax.block_until_ready(fn(keys, stacked, rules.walkable))  # compiles, and one run
        first = time.perf_counter() - t
        times = []
        res = None
        for _ in range(args.repeats):
            t = time.perf_counter()
            res = fn(keys, stacked, rules.walkable)
            jax.block_until_ready(res)
            times.append(time.perf_counter() - t)
        assert res is not None
        compile_s = max(first - min(times), 0.0)
        compile_total += compile_s
        rows.append(
            {
                "scenario": sc_name,
                "games_per_run": n,
                "pool_per_device": pool,
                "compile_s": round(compile_s, 2),
                "games_per_s": _rates(n, times),
                "mean_turns": round(float(np.asarray(res.turns).mean()), 2),
                "p0_win_rate": round(float((np.asarray(res.winner) == 0).mean()), 4),
            }
        )
    return {"compile_s": round(compile_total, 2), "xla_devices": devices, "results": rows}


def worker_battles(args) -> dict:
    import resource

    from hybridmarl.engine import native
    from hybridmarl.engine.scenarios import named_scenario

    compile_s = native.compile_kernels(quiet=True)
    t0 = time.perf_counter()
    arrays = named_scenario("m5v5").generate_arrays(args.battles_n, args.seed)
    t1 = time.perf_counter()
    res = native.run_battles(
        native.from_arrays(arrays), args.p0, args.p1, progress=False, threads=args.cores
    )
    t2 = time.perf_counter()
    peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {
        "battles": len(res),
        "compile_or_cache_load_s": round(compile_s, 2),
        "generate_s": round(t1 - t0, 2),
        "play_s": round(t2 - t1, 2),
        "total_s": round(t2 - t0, 2),
        "peak_rss_mib": round(peak_kib / 1024, 1),
        "p0_win_rate": res.summary()["p0_win_rate"],
    }


def worker_cold_compile(args) -> dict:
    from hybridmarl.engine import native

    return {"cold_compile_s": round(native.compile_kernels(quiet=True), 2)}


WORKERS = {
    "native": worker_native,
    "jax": worker_jax,
    "battles": worker_battles,
    "cold-compile": worker_cold_compile,
}


def spawn(kind: str, cores: int, args, extra_env: dict | None = None) -> dict:
    env = dict(os.environ)
    env["NUMBA_NUM_THREADS"] = str(cores)
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={cores}"
    env.update(extra_env or {})
    cmd = [
        sys.executable,
        __file__,
        "--worker",
        kind,
        "--cores",
        str(cores),
        "--repeats",
        str(args.repeats),
        "--seed",
        str(args.seed),
        "--p0",
        args.p0,
        "--p1",
        args.p1,
        "--battles-n",
        str(args.battles_n),
        "--jax-pool",
        str(args.jax_pool),
        "--scenarios",
        *args.scenarios,
    ]
    if kind in ("native", "jax"):
        games = args.games or [DEFAULT_GAMES[kind].get(s, 4096) for s in args.scenarios]
        if kind == "jax" and args.jax_games:
            games = args.jax_games
        cmd += ["--games", *map(str, games)]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1:] or ["worker failed"]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--engines", nargs="+", default=["native", "jax"], choices=["native", "jax"])
    ap.add_argument("--threads", nargs="+", type=int, default=[1, 2], help="core counts to time")
    ap.add_argument("--scenarios", nargs="+", default=["m5v5", "m30v30"])
    ap.add_argument("--games", nargs="+", type=int, help="games per timed run, one per scenario")
    ap.add_argument(
        "--jax-games", nargs="+", type=int, help="games per timed run for JAX (default smaller)"
    )
    ap.add_argument("--jax-pool", type=int, default=1024, help="concurrent JAX games per device")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--p0", default="attack-closest")
    ap.add_argument("--p1", default="attack-weakest")
    ap.add_argument(
        "--battles-n", type=int, default=100_000, help="native run_battles size (0: skip)"
    )
    ap.add_argument(
        "--cold-compile", action="store_true", help="also time a native compile from an empty cache"
    )
    ap.add_argument("--out", help="also write the JSON here")
    ap.add_argument("--worker", choices=sorted(WORKERS), help=argparse.SUPPRESS)
    ap.add_argument("--cores", type=int, default=1, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.worker:
        _pin(args.cores)
        print(json.dumps(WORKERS[args.worker](args)))
        return 0

    doc: dict = {
        "benchmark": "engine-backends",
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command": " ".join([os.path.basename(sys.executable), *sys.argv]),
        "p0": args.p0,
        "p1": args.p1,
        "repeats": args.repeats,
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "uptime_before": _uptime(),
        "runs": [],
    }
    for engine in args.engines:
        for cores in args.threads:
            row = {"engine": engine, "cores": cores, **spawn(engine, cores, args)}
            doc["runs"].append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    if "native" in args.engines and args.battles_n > 0:
        cores = max(args.threads)
        doc["native_run_battles_m5v5"] = {"cores": cores, **spawn("battles", cores, args)}
    if args.cold_compile:
        with tempfile.TemporaryDirectory() as cache:
            doc["native_cold_compile"] = spawn(
                "cold-compile", max(args.threads), args, {"NUMBA_CACHE_DIR": cache}
            )
    doc["uptime_after"] = _uptime()
    text = json.dumps(doc, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
