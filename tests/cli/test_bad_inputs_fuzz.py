"""Every file a user hands the command line, broken in every way we can think of: each bad
variant must end in exit code 2 and exactly one line on stderr that names the file, with no
traceback. The cases are generated (byte-level damage common to every file, then structural
damage specific to each loader), and run in-process through ``hybridmarl.cli.main.main``.

``python tests/cli/test_bad_inputs_fuzz.py`` prints the table: input class -> exit code ->
message.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hybridmarl.cli.main import main

# -- the valid originals ---------------------------------------------------------------------------

STATES = {
    "states": [
        {
            "units": [
                {"type": "Terran_Marine", "player": 0, "x": 500, "y": 350},
                {"type": "Terran_Marine", "player": 1, "x": 700, "y": 350},
            ]
        }
    ]
}
SCENARIO = {
    "name": "zd",
    "kind": "disks",
    "player0": [{"type": "Protoss_Zealot", "count": 2}],
    "player1": [{"type": "Protoss_Dragoon", "count": 2}],
    "center0": [565, 352],
    "center1": [715, 352],
    "radius0": 100,
    "radius1": 100,
}
MAP = "4\n3\n1111\n1111\n1111\n"


def _toy_config(run_dir: Path) -> Any:
    from hybridmarl.algos.hybrid import PRESETS

    return PRESETS["toy"]("combat").replace(scenario="m3v3", run_dir=str(run_dir), progress=False)


def _config_doc(cfg: Any) -> dict[str, Any]:
    from hybridmarl.training.config import config_to_dict

    return {
        "algo": "hybrid",
        "config": {
            **config_to_dict(cfg),
            "demonstrator_name": "attack-closest",
            "eval_enemy_name": "attack-weakest",
        },
        "task": cfg.task_spec().to_dict(),
    }


def _actor_arrays(cfg: Any) -> dict[str, np.ndarray]:
    """The arrays of a freshly initialised actor of ``cfg``'s task, as a checkpoint holds them."""
    import jax
    import jax.numpy as jnp

    from hybridmarl.io import flatten_named
    from hybridmarl.training import networks as nets
    from hybridmarl.training.checkpoint import prefixed
    from hybridmarl.training.task import make_task

    task = make_task(cfg.task_spec())
    module = nets.actor_module(task.num_actions, cfg.actor_hidden)
    variables = module.init(jax.random.key(0), jnp.zeros((2, task.obs_dim)), train=False)
    return prefixed(flatten_named(variables), "actor")


def _dataset_arrays() -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    k, n, a, d = 3, 2, 4, 5
    legal = np.ones((k, n, a), bool)
    arrays = {
        "obs": np.zeros((k, n, d), np.float32),
        "legal": legal,
        "actions": np.zeros((k, n), np.int32),
        "active": np.ones((k, n), bool),
        "episode": np.zeros(k, np.int32),
        "t": np.arange(k, dtype=np.int32),
        "reward": np.zeros(k, np.float32),
        "return": np.zeros(k, np.float32),
        "state.x": np.zeros((k, 2), np.float32),
    }
    meta = {
        "format": "hybridmarl-demos",
        "version": 1,
        "task": {"env": "combat", "scenario": "m2v2"},
        "num_agents": n,
        "num_actions": a,
        "obs_dim": d,
        "demonstrator": "attack-closest",
        "seed": 0,
    }
    return arrays, meta


def _write_dataset(path: Path, arrays: dict[str, np.ndarray], meta: Any) -> None:
    from safetensors.numpy import save_file

    header = meta if isinstance(meta, str) else json.dumps(meta)
    save_file(
        {k: np.ascontiguousarray(v) for k, v in arrays.items()},
        str(path),
        metadata={"hybridmarl": header},
    )


@dataclass(frozen=True)
class Base:
    """The valid files every case starts from (one copy per case)."""

    root: Path
    config: dict[str, Any]
    actor: dict[str, np.ndarray]
    meta: dict[str, Any]


def make_base(root: Path) -> Base:
    from hybridmarl.training.checkpoint import save_checkpoint
    from hybridmarl.training.evaluate import load_policy

    run = root / "run"
    cfg = _toy_config(run)
    doc = _config_doc(cfg)
    run.mkdir()
    (run / "config.json").write_text(json.dumps(doc))
    actor = _actor_arrays(cfg)
    meta = {
        "episodes": 8,
        "phase": "joint",
        "algo": "hybrid",
        "config": doc["config"],
        "task": doc["task"],
    }
    save_checkpoint(run, 8, actor, meta)
    (run / "train.csv").write_text("episodes,loss\n4,0.5\n8,0.25\n")
    load_policy(run)  # the originals are valid: every failure below comes from the damage
    return Base(root, doc, actor, meta)


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Base:
    return make_base(tmp_path_factory.mktemp("valid"))


# -- damage ----------------------------------------------------------------------------------------

#: Byte-level damage that applies to any file: name -> the bytes that replace it (given the original).
BYTES: dict[str, Callable[[bytes], bytes]] = {
    "empty": lambda b: b"",
    "whitespace only": lambda b: b" \n\t\n",
    "truncated to half": lambda b: b[: len(b) // 2],
    "truncated to one byte": lambda b: b[:1],
    "binary garbage": lambda b: bytes(
        np.random.default_rng(0).integers(0, 256, 512, dtype=np.uint8)
    ),
    "binary with NUL inside": lambda b: b[:10] + b"\0\0" + b[10:],
    "not UTF-8": lambda b: b"\xff\xfe\xfa" + b,
    "JSON list": lambda b: b"[1, 2, 3]",
    "JSON string": lambda b: b'"hello"',
    "JSON number": lambda b: b"42",
    "JSON null": lambda b: b"null",
    "NaN literal": lambda b: b'{"x": NaN}',
    "nested 100000 deep": lambda b: b"[" * 100_000,
}


@dataclass(frozen=True)
class Case:
    loader: str
    damage: str
    write: Callable[[Path, Base], list[str]]  # (case dir, base) -> argv


def _json_cases(
    loader: str,
    name: str,
    original: Any,
    argv: Callable[[Path], list[str]],
    mutations: dict[str, Callable[[Any], Any]],
) -> list[Case]:
    """Byte damage, a directory in place of the file, and structural ``mutations`` of a JSON file."""
    cases = []

    def put(data: bytes | None):
        def write(d: Path, base: Base) -> list[str]:
            p = d / name
            if data is None:
                p.mkdir()
            else:
                p.write_bytes(data)
            return argv(p)

        return write

    raw = json.dumps(original).encode()
    for label, damage in BYTES.items():
        cases.append(Case(loader, label, put(damage(raw))))
    cases.append(Case(loader, "a directory", put(None)))
    for label, mutate in mutations.items():
        doc = json.loads(raw)
        cases.append(Case(loader, label, put(json.dumps(mutate(doc)).encode())))
    return cases


def _set(path: str, value: Any) -> Callable[[Any], Any]:
    """A mutation: set the item at ``a.0.b`` (dict keys, list indexes) to ``value``; the value
    ``DELETE`` removes the key."""

    def mutate(doc: Any) -> Any:
        *head, last = path.split(".")
        node = doc
        for part in head:
            node = node[int(part)] if isinstance(node, list) else node[part]
        key: Any = int(last) if isinstance(node, list) else last
        if value is DELETE:
            del node[key]
        else:
            node[key] = value
        return doc

    return mutate


DELETE = object()
WRONG = {
    "a list": [1, 2],
    "a string": "x",
    "null": None,
    "NaN": float("nan"),
    "a boolean": True,
    "an object": {"a": 1},
}


def _states_cases() -> list[Case]:
    u = "states.0.units.0"
    mutations = {
        "no 'states' key": _set("states", DELETE),
        "empty 'states'": _set("states", []),
        "'states' an object": _set("states", {}),
        "state without 'units'": _set("states.0.units", DELETE),
        "'units' a string": _set("states.0.units", "abc"),
        "a unit a number": _set(u, 7),
        "unknown unit type": _set(f"{u}.type", "Terran_Dragon"),
        "unit off the map": _set(f"{u}.x", 100_000),
        "negative coordinate": _set(f"{u}.y", -500),
        "fractional coordinate": _set(f"{u}.x", 10.5),
        "player 2": _set(f"{u}.player", 2),
        "one side empty": _set("states.0.units", [STATES["states"][0]["units"][0]]),
        **{f"unit {k} missing": _set(f"{u}.{k}", DELETE) for k in ("type", "player", "x", "y")},
        **{f"x is {w}": _set(f"{u}.x", v) for w, v in WRONG.items()},
        **{f"type is {w}": _set(f"{u}.type", v) for w, v in WRONG.items() if w != "a string"},
        **{f"player is {w}": _set(f"{u}.player", v) for w, v in WRONG.items()},
    }
    battle = _json_cases(
        "states file (battle)",
        "states.json",
        STATES,
        lambda p: ["battle", "--states", str(p), "--no-progress"],
        mutations,
    )
    trace = _json_cases(
        "states file (trace)", "states.json", STATES, lambda p: ["trace", "--states", str(p)], {}
    )
    return battle + trace


def _scenario_cases() -> list[Case]:
    mutations = {
        "unknown key": _set("radius_0", 10),
        "no player0": _set("player0", DELETE),
        "no player1": _set("player1", DELETE),
        "unknown kind": _set("kind", "ring"),
        "kind a list": _set("kind", ["disks"]),
        "count 0": _set("player0.0.count", 0),
        "count a string": _set("player0.0.count", "2"),
        "count huge": _set("player0.0.count", 10**9),
        "unknown unit type": _set("player0.0.type", "Zerg_Dragon"),
        "unit type a list": _set("player0.0.type", ["Zerg_Zergling"]),
        "disk off the map": _set("center0", [5, 5]),
        "centre of three numbers": _set("center0", [1, 2, 3]),
        "negative radius": _set("radius0", -3),
        "zero spread": lambda d: {**d, "kind": "separated", "spread": [0, 0]},
        "negative spread": lambda d: {**d, "kind": "separated", "spread": [-5, 10]},
        "symmetric spread off the map": lambda d: {**d, "kind": "symmetric", "spread": [2000, 100]},
        "separated spread off the map": lambda d: {**d, "kind": "separated", "spread": [600, 100]},
        **{f"radius is {w}": _set("radius0", v) for w, v in WRONG.items()},
        **{f"centre is {w}": _set("center1", v) for w, v in WRONG.items()},
        **{f"player0 is {w}": _set("player0", v) for w, v in WRONG.items()},
        "name a list": _set("name", [1]),
    }
    return _json_cases(
        "scenario file",
        "scenario.json",
        SCENARIO,
        lambda p: ["battle", "--scenario-file", str(p), "--n", "2", "--no-progress"],
        mutations,
    )


def _map_cases() -> list[Case]:
    texts = {
        "one line": "4\n",
        "width not a number": "four\n3\n1111\n1111\n1111\n",
        "zero width": "0\n3\n\n",
        "negative height": "4\n-3\n",
        "too few rows": "4\n3\n1111\n1111\n",
        "short row": "4\n3\n1111\n11\n1111\n",
        "row of 2s": "4\n3\n1111\n2222\n1111\n",
        "width of a trillion": "1000000000000\n2\n11\n11\n",
    }
    cases = []

    def put(data: bytes | None):
        def write(d: Path, base: Base) -> list[str]:
            p = d / "walk.map"
            if data is None:
                p.mkdir()
            else:
                p.write_bytes(data)
            return [
                "battle",
                "--map-file",
                str(p),
                "--scenario",
                "m1v1",
                "--n",
                "2",
                "--no-progress",
            ]

        return write

    for label, damage in BYTES.items():
        if label.startswith(("JSON", "NaN", "nested")):
            continue  # not JSON: covered by the text cases
        cases.append(Case("map file", label, put(damage(MAP.encode()))))
    cases.append(Case("map file", "a directory", put(None)))
    cases += [Case("map file", label, put(t.encode())) for label, t in texts.items()]
    return cases


def _run_copy(d: Path, base: Base) -> Path:
    run = d / "run"
    shutil.copytree(base.root / "run", run)
    return run


def _config_cases() -> list[Case]:
    """config.json of a run, through 'eval --run-dir' and 'train --resume'."""
    mutations: dict[str, Callable[[Any], Any]] = {
        **{f"no '{k}' key": _set(k, DELETE) for k in ("algo", "config", "task")},
        "unknown algo": _set("algo", "ppo"),
        "algo a list": _set("algo", ["hybrid"]),
        "config a list": _set("config", [1]),
        "task a string": _set("task", "combat"),
        "NaN learning rate": _set("config.actor_lr", float("nan")),
        "negative learning rate": _set("config.critic_lr", -1.0),
        "num_envs 0": _set("config.num_envs", 0),
        "num_envs a string": _set("config.num_envs", "4"),
        "gamma 2": _set("config.gamma", 2.0),
        "hidden sizes a number": _set("config.actor_hidden", 16),
        "hidden size 0": _set("config.actor_hidden", [16, 0]),
        "seed -1": _set("config.seed", -1),
        "total_episodes a float": _set("config.total_episodes", 8.5),
        "tensorboard a string": _set("config.tensorboard", "yes"),
        "unknown scenario": _set("task.scenario", "m0v0"),
        "unknown env": _set("task.env", "mars"),
        "max_turns 0": _set("task.max_turns", 0),
        "p_arrive 5": _set("task.p_arrive", 5.0),
        "max_turns a list": _set("task.max_turns", [1]),
    }
    cases = []
    for via, argv in (
        ("eval", lambda run: ["eval", "--run-dir", str(run), "--n", "2"]),
        (
            "train --resume",
            lambda run: ["train", "--run-dir", str(run), "--resume", "--no-progress"],
        ),
    ):

        def put(data: bytes | None, argv=argv):
            def write(d: Path, base: Base) -> list[str]:
                run = _run_copy(d, base)
                p = run / "config.json"
                p.unlink()
                if data is None:
                    p.mkdir()
                else:
                    p.write_bytes(data)
                return argv(run)

            return write

        loader = f"run config.json ({via})"

        def original(base: Base) -> bytes:
            return json.dumps(base.config).encode()

        for label, damage in BYTES.items():
            cases.append(
                Case(loader, label, _lazy(put, lambda base, damage=damage: damage(original(base))))
            )
        cases.append(Case(loader, "a directory", put(None)))
        for label, mutate in mutations.items():
            cases.append(
                Case(
                    loader,
                    label,
                    _lazy(
                        put,
                        lambda base, mutate=mutate: json.dumps(
                            mutate(json.loads(original(base)))
                        ).encode(),
                    ),
                )
            )
    return cases


def _lazy(
    put: Callable[[bytes | None], Callable[[Path, Base], list[str]]], data: Callable[[Base], bytes]
) -> Callable[[Path, Base], list[str]]:
    """A writer whose bytes depend on the valid originals (known only once the fixture ran)."""

    def write(d: Path, base: Base) -> list[str]:
        return put(data(base))(d, base)

    return write


def _checkpoint_cases() -> list[Case]:
    """A checkpoint's meta.json and arrays.safetensors, through 'eval --run-dir'."""
    cases = []

    def put_meta(data: Callable[[Base], bytes | None]):
        def write(d: Path, base: Base) -> list[str]:
            run = _run_copy(d, base)
            p = run / "checkpoints" / "ckpt_000000008" / "meta.json"
            p.unlink()
            content = data(base)
            if content is None:
                p.mkdir()
            else:
                p.write_bytes(content)
            return ["eval", "--run-dir", str(run), "--n", "2"]

        return write

    def meta_bytes(base: Base) -> bytes:
        return json.dumps({**base.meta, "format_version": 1, "step": 8}).encode()

    for label, damage in BYTES.items():
        cases.append(
            Case(
                "checkpoint meta.json",
                label,
                put_meta(lambda base, damage=damage: damage(meta_bytes(base))),
            )
        )
    cases.append(Case("checkpoint meta.json", "a directory", put_meta(lambda base: None)))
    for label, version in (
        ("format version 2", 2),
        ("format version missing", DELETE),
        ("format version a string", "1"),
    ):
        cases.append(
            Case(
                "checkpoint meta.json",
                label,
                put_meta(
                    lambda base, version=version: json.dumps(
                        _set("format_version", version)({**base.meta, "format_version": 1})
                    ).encode()
                ),
            )
        )

    def put_arrays(make: Callable[[Base], dict[str, np.ndarray] | bytes | None]):
        def write(d: Path, base: Base) -> list[str]:
            from safetensors.numpy import save_file

            run = _run_copy(d, base)
            p = run / "checkpoints" / "ckpt_000000008" / "arrays.safetensors"
            p.unlink()
            content = make(base)
            if content is None:
                p.mkdir()
            elif isinstance(content, bytes):
                p.write_bytes(content)
            else:
                save_file({k: np.ascontiguousarray(v) for k, v in content.items()}, str(p))
            return ["eval", "--run-dir", str(run), "--n", "2"]

        return write

    def original(base: Base) -> bytes:
        from safetensors.numpy import save

        return save(base.actor)

    for label, damage in BYTES.items():
        cases.append(
            Case(
                "checkpoint arrays",
                label,
                put_arrays(lambda base, damage=damage: damage(original(base))),
            )
        )
    cases.append(Case("checkpoint arrays", "a directory", put_arrays(lambda base: None)))

    def edit(
        fn: Callable[[dict[str, np.ndarray]], None],
    ) -> Callable[[Base], dict[str, np.ndarray]]:
        def make(base: Base) -> dict[str, np.ndarray]:
            arrays = {k: v.copy() for k, v in base.actor.items()}
            fn(arrays)
            return arrays

        return make

    kernel = "actor.params.Dense_0.kernel"
    structural: dict[str, Callable[[dict[str, np.ndarray]], Any]] = {
        "no arrays at all": lambda a: a.clear(),
        "an array missing": lambda a: a.pop(kernel),
        "wrong shape": lambda a: a.__setitem__(kernel, np.zeros((3, 3), np.float32)),
        "wrong dtype": lambda a: a.__setitem__(kernel, a[kernel].astype(np.float64)),
        "int dtype": lambda a: a.__setitem__(kernel, a[kernel].astype(np.int32)),
        "NaN weights": lambda a: a[kernel].__setitem__((0, 0), np.nan),
        "inf weights": lambda a: a[kernel].__setitem__((0, 0), np.inf),
        "weights of another network": lambda a: a.__setitem__(
            kernel, np.zeros((a[kernel].shape[0], 7), np.float32)
        ),
    }
    for label, fn in structural.items():
        cases.append(Case("checkpoint arrays", label, put_arrays(edit(fn))))
    return cases


class Header(str):
    """A dataset's metadata header replaced whole (not JSON of the metadata)."""


def _dataset_cases() -> list[Case]:
    cases = []

    def put(make: Callable[[], bytes | None]):
        def write(d: Path, base: Base) -> list[str]:
            p = d / "demos.safetensors"
            content = make()
            if content is None:
                p.mkdir()
            else:
                p.write_bytes(content)
            return ["demos", "info", str(p)]

        return write

    def put_arrays(fn: Callable[[dict[str, np.ndarray], dict[str, Any]], Any]):
        def write(d: Path, base: Base) -> list[str]:
            p = d / "demos.safetensors"
            arrays, meta = _dataset_arrays()
            replaced = fn(arrays, meta)  # a new metadata header, or anything else (edited in place)
            meta = replaced if isinstance(replaced, Header) else meta
            _write_dataset(p, arrays, meta)
            return ["demos", "info", str(p)]

        return write

    def original() -> bytes:
        from safetensors.numpy import save

        arrays, meta = _dataset_arrays()
        return save(arrays, metadata={"hybridmarl": json.dumps(meta)})

    for label, damage in BYTES.items():
        cases.append(
            Case("demonstration dataset", label, put(lambda damage=damage: damage(original())))
        )
    cases.append(Case("demonstration dataset", "a directory", put(lambda: None)))
    structural: dict[str, Callable[[dict[str, np.ndarray], dict[str, Any]], Any]] = {
        "metadata not JSON": lambda a, m: Header("{not json"),
        "metadata a list": lambda a, m: Header("[1]"),
        "wrong format name": lambda a, m: m.__setitem__("format", "other"),
        "version 9": lambda a, m: m.__setitem__("version", 9),
        "num_agents a string": lambda a, m: m.__setitem__("num_agents", "2"),
        "num_agents 0": lambda a, m: m.__setitem__("num_agents", 0),
        "task a string": lambda a, m: m.__setitem__("task", "combat"),
        "no demonstrator": lambda a, m: m.pop("demonstrator"),
        "no obs": lambda a, m: a.pop("obs"),
        "obs of another shape": lambda a, m: a.__setitem__("obs", np.zeros((3, 2, 9), np.float32)),
        "obs float64": lambda a, m: a.__setitem__("obs", a["obs"].astype(np.float64)),
        "NaN obs": lambda a, m: a["obs"].__setitem__((0, 0, 0), np.nan),
        "inf return": lambda a, m: a["return"].__setitem__(0, np.inf),
        "action out of range": lambda a, m: a["actions"].__setitem__((0, 0), 99),
        "negative action": lambda a, m: a["actions"].__setitem__((0, 0), -1),
        "illegal action": lambda a, m: a["legal"].__setitem__((0, 0, 0), False),
        "no legal action": lambda a, m: a["legal"].__setitem__((1, 1), False),
        "episodes out of order": lambda a, m: a["episode"].__setitem__(0, 5),
        "no state arrays": lambda a, m: a.pop("state.x"),
        "empty dataset": lambda a, m: a.update({k: v[:0] for k, v in a.items()}),
    }
    for label, fn in structural.items():
        cases.append(Case("demonstration dataset", label, put_arrays(fn)))
    return cases


def _csv_cases() -> list[Case]:
    """A run's train.csv, read back by 'train --resume' (before any training work)."""
    cases = []

    def put(data: bytes | None):
        def write(d: Path, base: Base) -> list[str]:
            run = _run_copy(d, base)
            p = run / "train.csv"
            p.unlink()
            if data is None:
                p.mkdir()
            else:
                p.write_bytes(data)
            return ["train", "--run-dir", str(run), "--resume", "--no-progress"]

        return write

    original = b"episodes,loss\n4,0.5\n8,0.25\n"
    for label in ("binary garbage", "binary with NUL inside", "not UTF-8"):
        cases.append(Case("run log train.csv", label, put(BYTES[label](original))))
    cases.append(Case("run log train.csv", "a directory", put(None)))
    return cases


CASES = (
    _states_cases()
    + _scenario_cases()
    + _map_cases()
    + _config_cases()
    + _checkpoint_cases()
    + _dataset_cases()
    + _csv_cases()
)
if os.geteuid() != 0:  # root reads any file: an unreadable file cannot be made for it

    def _unreadable(d: Path, base: Base) -> list[str]:
        p = d / "states.json"
        p.write_text(json.dumps(STATES))
        p.chmod(0)
        return ["battle", "--states", str(p), "--no-progress"]

    CASES.append(Case("states file (battle)", "unreadable (mode 000)", _unreadable))


def run_case(case: Case, d: Path, base: Base, capsys: Any) -> tuple[int, list[str], str]:
    argv = case.write(d, base)
    capsys.readouterr()
    rc = main(argv)
    captured = capsys.readouterr()
    return rc, captured.err.strip().splitlines(), captured.out


def test_at_least_200_cases_over_every_loader():
    loaders = {c.loader for c in CASES}
    assert len(CASES) >= 200, len(CASES)
    assert {
        "states file (battle)",
        "scenario file",
        "map file",
        "run config.json (eval)",
        "run config.json (train --resume)",
        "checkpoint meta.json",
        "checkpoint arrays",
        "demonstration dataset",
        "run log train.csv",
    } <= loaders


@pytest.mark.parametrize("case", CASES, ids=[f"{c.loader}: {c.damage}" for c in CASES])
def test_bad_file_is_one_line_exit_2(case: Case, base: Base, tmp_path: Path, capsys: Any):
    rc, err, out = run_case(case, tmp_path, base, capsys)
    assert rc == 2, (rc, err, out)
    assert len(err) == 1 and err[0].startswith("hybridmarl: error: "), err
    assert "Traceback" not in out + "\n".join(err)
    # The line names the file (or, for a run, its directory or checkpoint).
    named = {
        "states.json",
        "scenario.json",
        "walk.map",
        "config.json",
        "ckpt_000000008",
        "meta.json",
        "arrays.safetensors",
        "demos.safetensors",
        "train.csv",
        str(tmp_path),
    }
    assert any(n in err[0] for n in named), err


def fuzz_table() -> str:
    """The table of every case: input class -> exit code -> message (paths shortened)."""
    import contextlib
    import io
    import tempfile

    @dataclass
    class Captured:
        out: str
        err: str

    class Capture:
        def __init__(self) -> None:
            self.out, self.err = io.StringIO(), io.StringIO()

        def readouterr(self) -> Captured:
            got = Captured(self.out.getvalue(), self.err.getvalue())
            for s in (self.out, self.err):
                s.seek(0)
                s.truncate(0)
            return got

    rows = ["| input | damage | exit | message |", "|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        valid = Path(tmp) / "valid"
        valid.mkdir()
        b = make_base(valid)
        for i, c in enumerate(CASES):
            d = Path(tmp) / f"case{i}"
            d.mkdir()
            cap = Capture()
            with contextlib.redirect_stdout(cap.out), contextlib.redirect_stderr(cap.err):
                rc, err, _ = run_case(c, d, b, cap)
            msg = (err[0] if err else "").replace(tmp, "<tmp>").replace("|", "/")
            rows.append(f"| {c.loader} | {c.damage} | {rc} | {msg} |")
    return "\n".join(rows)


if __name__ == "__main__":
    print(fuzz_table())


# -- unreadable files ------------------------------------------------------------------------------
# Root reads any file, so a mode-000 file cannot be made for it; the permission check itself
# (``hybridmarl.io.check_user_file``, which every loader goes through) is exercised instead by
# having ``os.access`` deny reading the one file.


def _unreadable_cases() -> list[tuple[str, str, Callable[[Path, Base], list[str]]]]:
    def plain(name: str, content: Callable[[], bytes], argv: Callable[[Path], list[str]]):
        def write(d: Path, base: Base) -> list[str]:
            (d / name).write_bytes(content())
            return argv(d / name)

        return write

    def in_run(argv: Callable[[Path], list[str]]):
        def write(d: Path, base: Base) -> list[str]:
            run = _run_copy(d, base)
            return argv(run)

        return write

    def dataset(d: Path, base: Base) -> list[str]:
        arrays, meta = _dataset_arrays()
        _write_dataset(d / "demos.safetensors", arrays, meta)
        return ["demos", "info", str(d / "demos.safetensors")]

    return [
        (
            "states file (battle)",
            "states.json",
            plain(
                "states.json",
                lambda: json.dumps(STATES).encode(),
                lambda p: ["battle", "--states", str(p), "--no-progress"],
            ),
        ),
        (
            "scenario file",
            "scenario.json",
            plain(
                "scenario.json",
                lambda: json.dumps(SCENARIO).encode(),
                lambda p: ["battle", "--scenario-file", str(p), "--n", "2", "--no-progress"],
            ),
        ),
        (
            "map file",
            "walk.map",
            plain(
                "walk.map",
                MAP.encode,
                lambda p: [
                    "battle",
                    "--map-file",
                    str(p),
                    "--scenario",
                    "m1v1",
                    "--n",
                    "2",
                    "--no-progress",
                ],
            ),
        ),
        (
            "run config.json (eval)",
            "config.json",
            in_run(lambda r: ["eval", "--run-dir", str(r), "--n", "2"]),
        ),
        (
            "checkpoint meta.json",
            "meta.json",
            in_run(lambda r: ["eval", "--run-dir", str(r), "--n", "2"]),
        ),
        (
            "checkpoint arrays",
            "arrays.safetensors",
            in_run(lambda r: ["eval", "--run-dir", str(r), "--n", "2"]),
        ),
        ("demonstration dataset", "demos.safetensors", dataset),
        (
            "run log train.csv",
            "train.csv",
            in_run(lambda r: ["train", "--run-dir", str(r), "--resume", "--no-progress"]),
        ),
    ]


@pytest.mark.parametrize(
    "loader,name,write", _unreadable_cases(), ids=[c[0] for c in _unreadable_cases()]
)
def test_unreadable_file_is_one_line_exit_2(
    loader: str,
    name: str,
    write: Callable[[Path, Base], list[str]],
    base: Base,
    tmp_path: Path,
    capsys: Any,
    monkeypatch: pytest.MonkeyPatch,
):
    import hybridmarl.io as hio

    real_access = os.access

    def access(path: Any, mode: int, *args: Any, **kwargs: Any) -> bool:
        if Path(path).name == name and mode & os.R_OK:
            return False
        return real_access(path, mode, *args, **kwargs)

    argv = write(tmp_path, base)
    monkeypatch.setattr(hio.os, "access", access)
    capsys.readouterr()
    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, (loader, rc, err)
    assert len(err) == 1 and err[0].startswith("hybridmarl: error: "), err
    assert "permission denied" in err[0] and name in err[0], err
