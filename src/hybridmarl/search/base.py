"""The player interface for non-script players, search statistics, and player specs.

Player interface
----------------
A player is an object with

- ``reset(seed)``: start a new game; reseeds the player's NumPy generator (random move shuffles,
  the Random first-mover policy, keys for the ``random`` script);
- ``decide(state, rules, p) -> int32 [U]``: engine action codes for player ``p``'s acting units
  in ``state`` (other entries are 0 and ignored by the engine);
- ``stats``: :class:`SearchStats` of the last decision.

Scripts are players too (:class:`ScriptPlayer`, a jitted script call), so a game runner treats
both alike.

Player specs
------------
``make_player(spec, **options)`` builds a player from a compact string::

    spec    := name [ ":" option ( "," option )* ]
    option  := key "=" value
    value   := number | "true" | "false" | script | script ( "+" script )* | "none" | word

Names: ``uct`` (aliases ``uct-cd``, ``uctcd``), ``abcd`` (``ab``, ``alphabeta``, ``alpha-beta``),
``pgs`` (``portfolio``, ``portfolio-greedy``), or any script name (``nokdps``,
``attack-closest``, ... — SparCraft's own names such as ``NOKDPS`` and ``AttackClosest`` too).
Keyword ``options`` override the string's. Examples::

    uct:time_ms=40,traversals=5000,c=1.6
    uct:script=attack-closest            # the paper's UCT_c: demonstrator ordering and playouts
    abcd:time_ms=0,nodes=500             # deterministic budget
    pgs:time_ms=0,portfolio=nokdps+kiter-dps,iterations=1,responses=0

Every option, its default and where the default comes from is listed in ``UCT_OPTIONS``,
``ABCD_OPTIONS`` and ``PGS_OPTIONS`` (printed by :func:`describe_options`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import jax
import numpy as np

from hybridmarl.engine.scripts import canonical_name
from hybridmarl.engine.state import GameState, Rules
from hybridmarl.search import kernels as K


@dataclass
class SearchStats:
    """What the last decision cost. Counters a search does not use stay 0."""

    algorithm: str = ""
    ms: float = 0.0  # wall-clock time of the decision
    traversals: int = 0  # UCT: completed traversals
    nodes: int = 0  # ABCD: nodes expanded (SparCraft's count); UCT: tree nodes created
    playouts: int = 0  # playouts actually run (batching may run more than a serial search)
    depth: int = 0  # ABCD: deepest completed iteration; UCT: deepest node reached
    calls: int = 0  # compiled engine calls made
    fallback: bool = False  # the decision came from the fallback script
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in ("algorithm", "ms", "traversals", "nodes", "playouts", "depth", "calls", "fallback")}
        d.update(self.extra)
        return d


@runtime_checkable
class Player(Protocol):
    """Anything that can play a side: scripts and search players."""

    name: str

    @property
    def stats(self) -> SearchStats | None: ...

    def reset(self, seed: int) -> None: ...

    def decide(self, state: GameState, rules: Rules, p: int) -> np.ndarray: ...


# ----------------------------------------------------------------------------- options


@dataclass(frozen=True)
class Option:
    """One player option: its name, kind, default, and the source of the default."""

    name: str
    kind: str  # int | float | bool | script | scripts | script? | choice
    default: Any
    help: str
    choices: tuple[str, ...] = ()
    minimum: float | None = None


def _opt(name: str, kind: str, default: Any, help: str, choices: tuple[str, ...] = (), minimum: float | None = None) -> Option:
    return Option(name, kind, default, help, choices, minimum)


_COMMON_SEARCH = (
    _opt("max_children", "int", 20, "children per node; 20 in SparCraft's sample config (sparcraft.md §4.1, §4.2)", minimum=1),
    _opt("ordering", "scripts", ("nokdps", "kiter-dps"), "ScriptFirst move ordering scripts, first children of every node; 'none' = plain odometer (§3, §4.1)"),
    _opt("playout0", "script", "nokdps", "player 0's playout script (SparCraft's P0Script; sample config NOKDPS, §4.1)"),
    _opt("playout1", "script", "nokdps", "player 1's playout script (P1Script; sample config NOKDPS)"),
    _opt("eval", "choice", "playout", "leaf evaluation: playout (200-turn script playout + LTD2), ltd2 or ltd (§2.9)", choices=K.EVAL_METHODS),
    _opt("player_to_move", "choice", "alternate", "first mover at simultaneous nodes below the root (sample config Alternate, §4.1)", choices=("alternate", "not-alternate", "random")),
    _opt("opponent_model", "script?", None, "script the opponent is assumed to play (one child at its nodes); sample config None"),
)

UCT_OPTIONS: tuple[Option, ...] = (
    _opt("time_ms", "float", 40.0, "wall-clock budget per decision in ms, 0 = none (sample config / CIG 2013: 40 ms, §4.2)", minimum=0),
    _opt("traversals", "int", 5000, "maximum traversals per decision (sample config 5000, §4.2)", minimum=1),
    _opt("c", "float", 1.6, "UCB exploration constant (sample config 1.6, §4.2)", minimum=0),
    *_COMMON_SEARCH,
    _opt("root_select", "choice", "most-visited", "root move: most visited child (SparCraft default) or highest UCB value", choices=("most-visited", "highest-value")),
    _opt("batch", "int", 16, "leaf-parallel batch: leaves evaluated per engine call (virtual loss); 1 = SparCraft's serial UCT (our deviation)", minimum=1),
)

ABCD_OPTIONS: tuple[Option, ...] = (
    _opt("time_ms", "float", 40.0, "wall-clock budget per decision in ms, 0 = none (sample config 40 ms, §4.1)", minimum=0),
    _opt("nodes", "int", 0, "deterministic budget: stop after this many nodes (SparCraft's nodesExpanded), 0 = none", minimum=0),
    _opt("max_depth", "int", 50, "iterative deepening limit (SearchExperiment's IDAlphaBeta: 50, §4.1)", minimum=1),
    *_COMMON_SEARCH,
    _opt("tt", "bool", True, "transposition table (100,000 entries, scan 10, kept across decisions of a game, §4.1)"),
    _opt("tt_size", "int", 100_000, "transposition table entries (Constants::Transposition_Table_Size)", minimum=16),
    _opt("fallback", "script", "nokdps", "move when depth 1 does not complete (SparCraft: NOKDPS, §4.1)"),
    _opt("batch", "int", 20, "leaf playouts per engine call after the eldest child (young-brothers-wait batching); 1 = serial", minimum=1),
)

PGS_OPTIONS: tuple[Option, ...] = (
    _opt("time_ms", "float", 40.0, "wall-clock budget per decision in ms, checked before each unit, 0 = none (CIG 2013: 40 ms; sample config 0, §4.3)", minimum=0),
    _opt("playouts", "int", 0, "deterministic budget: stop improving once this many playouts ran, 0 = none", minimum=0),
    _opt("portfolio", "scripts", ("nokdps", "kiter-dps"), "script portfolio, in order (hard-coded {NOKDPS, KiterDPS} in SparCraft, §4.3)"),
    _opt("enemy_seed", "script", "nokdps", "enemy script while seeding (Player_PortfolioGreedySearch default NOKDPS, §4.3)"),
    _opt("iterations", "int", 1, "improvement passes I (default 1, §4.3)", minimum=1),
    _opt("responses", "int", 0, "response rounds R (default 0, §4.3)", minimum=0),
    _opt("playout_turns", "int", K.PGS_PLAYOUT_TURNS, "playout cap; the loop runs while rounds <= cap, i.e. up to cap+1 turns (§2.8)", minimum=1),
)

ALGORITHMS: dict[str, tuple[Option, ...]] = {"uct": UCT_OPTIONS, "abcd": ABCD_OPTIONS, "pgs": PGS_OPTIONS}
_NAME_ALIASES = {
    "uct": "uct",
    "uct-cd": "uct",
    "uctcd": "uct",
    "abcd": "abcd",
    "ab": "abcd",
    "alphabeta": "abcd",
    "alpha-beta": "abcd",
    "pgs": "pgs",
    "portfolio": "pgs",
    "portfolio-greedy": "pgs",
}
#: ``script=NAME`` sets these options at once (applied before the other options), e.g. the
#: paper's UCT_c / A-B_c that search with the demonstrator script.
_SCRIPT_SHORTHAND = {
    "uct": ("ordering", "playout0", "playout1"),
    "abcd": ("ordering", "playout0", "playout1", "fallback"),
    "pgs": ("portfolio", "enemy_seed"),
}


def describe_options(algorithm: str | None = None) -> str:
    """Human-readable list of every option with its default and source."""
    lines = []
    for alg, opts in ALGORITHMS.items():
        if algorithm and alg != algorithm:
            continue
        lines.append(f"{alg}:")
        for o in opts:
            d = "+".join(o.default) if isinstance(o.default, tuple) else o.default
            lines.append(f"  {o.name}={d}  -- {o.help}")
        lines.append(f"  script=NAME  -- shorthand: sets {', '.join(_SCRIPT_SHORTHAND[alg])} to NAME")
    return "\n".join(lines)


def _script_name(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{what}: expected a script name, got {value!r}")
    try:
        return canonical_name(value)
    except KeyError as e:
        raise ValueError(f"{what}: {e.args[0]}") from None


def _convert(opt: Option, value: Any, where: str) -> Any:
    what = f"{where} option {opt.name!r}"
    kind = opt.kind
    if kind == "int":
        if isinstance(value, bool):
            raise ValueError(f"{what}: expected an integer, got {value!r}")
        try:
            v: Any = int(value) if not isinstance(value, float) or value.is_integer() else None
        except (TypeError, ValueError):
            v = None
        if v is None:
            raise ValueError(f"{what}: expected an integer, got {value!r}")
    elif kind == "float":
        if isinstance(value, bool):
            raise ValueError(f"{what}: expected a number, got {value!r}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{what}: expected a number, got {value!r}") from None
        if not np.isfinite(v):
            raise ValueError(f"{what}: expected a finite number, got {value!r}")
    elif kind == "bool":
        if isinstance(value, bool):
            v = value
        elif isinstance(value, str) and value.lower() in ("true", "1", "yes", "on"):
            v = True
        elif isinstance(value, str) and value.lower() in ("false", "0", "no", "off"):
            v = False
        else:
            raise ValueError(f"{what}: expected true or false, got {value!r}")
    elif kind == "script":
        v = _script_name(value, what)
    elif kind == "script?":
        v = None if value is None or (isinstance(value, str) and value.lower() == "none") else _script_name(value, what)
    elif kind == "scripts":
        if isinstance(value, str):
            items = [] if value.lower() == "none" else [s for s in value.replace("/", "+").split("+") if s]
        elif isinstance(value, Sequence):
            items = list(value)
        else:
            raise ValueError(f"{what}: expected script names joined by '+', got {value!r}")
        v = tuple(_script_name(s, what) for s in items)
    elif kind == "choice":
        s = str(value).lower().replace("_", "-")
        if s not in opt.choices:
            raise ValueError(f"{what}: expected one of {', '.join(opt.choices)}, got {value!r}")
        v = s
    else:  # pragma: no cover - table error
        raise AssertionError(kind)
    if opt.minimum is not None and v < opt.minimum:
        raise ValueError(f"{what}: must be >= {opt.minimum:g}, got {value!r}")
    return v


def parse_spec(spec: str) -> tuple[str, dict[str, str]]:
    """Split ``name:key=value,...`` into the name and raw option strings."""
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError("player spec must be a non-empty string such as 'uct:time_ms=40' or 'nokdps'")
    name, _, rest = spec.strip().partition(":")
    opts: dict[str, str] = {}
    if rest.strip():
        for item in rest.split(","):
            item = item.strip()
            if not item:
                continue
            key, eq, val = item.partition("=")
            if not eq or not key.strip() or not val.strip():
                raise ValueError(f"player spec {spec!r}: option {item!r} must be key=value")
            k = key.strip().lower().replace("-", "_")
            if k in opts:
                raise ValueError(f"player spec {spec!r}: option {k!r} given twice")
            opts[k] = val.strip()
    return name.strip(), opts


def resolve_options(algorithm: str, raw: dict[str, Any], where: str) -> dict[str, Any]:
    """Defaults updated with ``raw`` (validated and converted); raises ValueError on anything bad."""
    table = {o.name: o for o in ALGORITHMS[algorithm]}
    values = {o.name: o.default for o in table.values()}
    raw = dict(raw)
    if "children" in raw and "max_children" not in raw:
        raw["max_children"] = raw.pop("children")
    if "script" in raw:
        name = _script_name(raw.pop("script"), f"{where} option 'script'")
        for k in _SCRIPT_SHORTHAND[algorithm]:
            values[k] = (name,) if table[k].kind == "scripts" else name
    if "playout" in raw:
        v = raw.pop("playout")
        raw.setdefault("playout0", v)
        raw.setdefault("playout1", v)
    unknown = sorted(set(raw) - set(table))
    if unknown:
        known = ", ".join(sorted(table) + ["script"] + (["playout"] if "playout0" in table else []))
        raise ValueError(f"{where}: unknown option(s) {', '.join(map(repr, unknown))} (known: {known})")
    for k, v in raw.items():
        values[k] = _convert(table[k], v, where)
    if algorithm == "pgs" and not values["portfolio"]:
        raise ValueError(f"{where}: the portfolio needs at least one script")
    if algorithm == "abcd" and values["time_ms"] == 0 and values["nodes"] == 0:
        raise ValueError(f"{where}: give a time budget (time_ms > 0) or a node budget (nodes > 0)")
    return values


# ----------------------------------------------------------------------------- players


class ScriptPlayer:
    """A scripted player (jitted script call per decision)."""

    def __init__(self, script: str):
        self.script = canonical_name(script)
        self.name = self.script
        self._key = jax.random.PRNGKey(0)
        self._stats = SearchStats(algorithm="script")

    @property
    def stats(self) -> SearchStats:
        return self._stats

    def reset(self, seed: int) -> None:
        self._key = jax.random.PRNGKey(seed)

    def decide(self, state: GameState, rules: Rules, p: int) -> np.ndarray:
        t0 = time.perf_counter()
        self._key, sub = jax.random.split(self._key)
        fn = K.script_fn(self.script, K.rules_static(rules))
        out = np.asarray(fn(sub, state, rules.walkable, p), np.int32)
        self._stats = SearchStats(algorithm="script", ms=(time.perf_counter() - t0) * 1e3, calls=1)
        return out


class DeviceArgs:
    """Per-decision constants in device form, shared by every compiled call of a decision."""

    def __init__(self, consts: K.Consts, rules: Rules):
        self.consts = consts
        self.rules = rules
        self.rules_key = K.rules_static(rules)
        self.args = tuple(jax.device_put(a) for a in consts.as_args()) + (rules.walkable,)
        self.num_slots = consts.num_slots


class SearchPlayer:
    """Shared plumbing of the search players: seeding, root packing, statistics, timing."""

    algorithm = ""

    def __init__(self, options: dict[str, Any], name: str):
        self.options = options
        self.name = name
        self.rng = np.random.default_rng(0)
        self._stats: SearchStats | None = None

    @property
    def stats(self) -> SearchStats | None:
        return self._stats

    def reset(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def key(self) -> np.ndarray:
        """A fresh raw PRNG key (uint32 [2]) from the player's generator."""
        return self.rng.integers(0, 2**32, size=2, dtype=np.uint32)

    def decide(self, state: GameState, rules: Rules, p: int) -> np.ndarray:
        if p not in (0, 1):
            raise ValueError(f"player index must be 0 or 1, got {p!r}")
        t0 = time.perf_counter()
        root, consts = K.pack_state(state)
        dev = DeviceArgs(consts, rules)
        stats = SearchStats(algorithm=self.algorithm)
        move = self._search(root, dev, p, stats, t0)
        stats.ms = (time.perf_counter() - t0) * 1e3
        self._stats = stats
        return np.asarray(move, np.int32)

    def _search(self, root: np.ndarray, dev: DeviceArgs, p: int, stats: SearchStats, t0: float) -> np.ndarray:
        raise NotImplementedError

    def warmup(self, state: GameState, rules: Rules) -> float:
        """Compile every program this player uses for ``state``'s shape; returns seconds spent."""
        t0 = time.perf_counter()
        root, consts = K.pack_state(state)
        self._warmup(root, DeviceArgs(consts, rules))
        return time.perf_counter() - t0

    def _warmup(self, root: np.ndarray, dev: DeviceArgs) -> None:
        raise NotImplementedError


def deadline_from(t0: float, time_ms: float) -> float:
    """Absolute perf_counter deadline (inf when there is no time budget)."""
    return t0 + time_ms / 1e3 if time_ms > 0 else float("inf")


def root_info(player: SearchPlayer, root: np.ndarray, dev: DeviceArgs, scripts: tuple[str, ...], stats: SearchStats) -> dict[str, np.ndarray]:
    """Node info of the root state (batch of one), as host arrays without the batch axis."""
    fn = info_for(dev, scripts)
    out = jax.device_get(fn(player.key(), root[None], *dev.args))
    stats.calls += 1
    return {k: v[0] for k, v in out.items()}


def info_for(dev: DeviceArgs, scripts: tuple[str, ...]) -> Callable:
    return K.info_fn(dev.num_slots, 1, scripts, dev.rules_key)


def unique(names: Sequence[str]) -> tuple[str, ...]:
    out: list[str] = []
    for n in names:
        if n not in out:
            out.append(n)
    return tuple(out)
