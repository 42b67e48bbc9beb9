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
    uct:script=attack-closest,playout1=attack-weakest   # UCT_c as the reproduction grid plays it
    abcd:time_ms=0,nodes=500             # deterministic budget
    pgs:time_ms=0,portfolio=nokdps+kiter-dps,iterations=1,responses=0

Options (defaults from SparCraft; docs/baselines.md describes each player)::

    common to uct and abcd
      max_children=20          children per node (sample config); alias children=
      ordering=nokdps+kiter-dps ScriptFirst ordering scripts ('none': plain odometer)
      playout0=nokdps          player 0's playout script (P0Script, sample config)
      playout1=nokdps          player 1's playout script (P1Script); playout=X sets both
      eval=playout             leaf evaluation: playout | ltd2 | ltd
      player_to_move=alternate first mover below the root: alternate | not-alternate | random
      opponent_model=none      script the opponent is assumed to play (one child at its nodes)
    uct
      time_ms=40               wall-clock budget per decision, 0 = none (CIG 2013)
      traversals=5000          traversal cap (sample config)
      c=1.6                    UCB exploration constant (sample config)
      root_select=most-visited most-visited | highest-value (SparCraft's default: most visited)
      batch=auto               leaves per engine call (leaf parallelism; 1 = serial UCT)
    abcd
      time_ms=40               wall-clock budget per decision, 0 = none (sample config)
      nodes=0                  node budget (deterministic), 0 = none; needs time_ms or nodes
      max_depth=50             iterative deepening limit (SearchExperiment)
      tt=true, tt_size=100000  transposition table (Constants::Transposition_Table_Size)
      fallback=nokdps          move when depth 1 does not finish
      batch=auto               leaf playouts per engine call after the eldest (1 = serial)
    pgs
      time_ms=40               budget per decision, checked before each unit, 0 = none
      playouts=0               playout budget (deterministic), 0 = none
      portfolio=nokdps+kiter-dps  script portfolio (hard-coded in SparCraft)
      enemy_seed=nokdps        enemy script while seeding
      iterations=1, responses=0, playout_turns=100   I, R and the playout cap
      lookahead=1              1: one unit per engine call; 2: speculative unit pairs (same result)
    any search
      engine=auto              native | jax | auto (native when JAX runs on the CPU); both
                               engines give the same decisions (docs/engine-backends.md)
      script=NAME              shorthand: ordering and playouts (and abcd's fallback; pgs's
                               portfolio and enemy seed) all set to NAME

``UCT_OPTIONS``, ``ABCD_OPTIONS`` and ``PGS_OPTIONS`` hold the same table with the source of
every default; :func:`describe_options` prints it.
"""

from __future__ import annotations

import abc
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import jax
import numpy as np

from hybridmarl.engine.backend import resolve_engine
from hybridmarl.engine.scripts import canonical_name
from hybridmarl.engine.state import GameState, Rules
from hybridmarl.search import kernels as K


@dataclass
class SearchStats:
    """What the last decision cost. Counters a search does not use stay 0."""

    algorithm: str = ""
    ms: float = 0.0  # wall-clock time of the decision
    cpu_ms: float = 0.0  # CPU time of this process during the decision (all threads)
    traversals: int = 0  # UCT: completed traversals
    nodes: int = 0  # ABCD: nodes expanded (SparCraft's count); UCT: tree nodes created
    playouts: int = 0  # playouts actually run (batching may run more than a serial search)
    depth: int = 0  # ABCD: deepest completed iteration; UCT: deepest node reached
    calls: int = 0  # compiled engine calls made
    fallback: bool = False  # the decision came from the fallback script
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        d = {
            k: getattr(self, k)
            for k in (
                "algorithm",
                "ms",
                "cpu_ms",
                "traversals",
                "nodes",
                "playouts",
                "depth",
                "calls",
                "fallback",
            )
        }
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
    kind: str  # int | float | bool | script | scripts | script? | choice | batch
    default: Any
    help: str
    choices: tuple[str, ...] = ()
    minimum: float | None = None


def _opt(
    name: str,
    kind: str,
    default: Any,
    help: str,
    choices: tuple[str, ...] = (),
    minimum: float | None = None,
) -> Option:
    return Option(name, kind, default, help, choices, minimum)


_COMMON_SEARCH = (
    _opt(
        "max_children",
        "int",
        20,
        "children per node; 20 in SparCraft's sample config (docs/baselines.md#abcd; docs/baselines.md#uct-cd)",
        minimum=1,
    ),
    _opt(
        "ordering",
        "scripts",
        ("nokdps", "kiter-dps"),
        "ScriptFirst move ordering scripts, first children of every node; 'none' = plain odometer",
    ),
    _opt(
        "playout0",
        "script",
        "nokdps",
        "player 0's playout script (SparCraft's P0Script; sample config NOKDPS)",
    ),
    _opt(
        "playout1", "script", "nokdps", "player 1's playout script (P1Script; sample config NOKDPS)"
    ),
    _opt(
        "eval",
        "choice",
        "playout",
        "leaf evaluation: playout (200-turn script playout + LTD2), ltd2 or ltd",
        choices=K.EVAL_METHODS,
    ),
    _opt(
        "player_to_move",
        "choice",
        "alternate",
        "first mover at simultaneous nodes below the root (sample config Alternate)",
        choices=("alternate", "not-alternate", "random"),
    ),
    _opt(
        "opponent_model",
        "script?",
        None,
        "script the opponent is assumed to play (one child at its nodes); sample config None",
    ),
)

ENGINES = ("auto", "native", "jax")
_ENGINE_OPTION = _opt(
    "engine",
    "choice",
    "auto",
    "engine for every call the search makes: native (Numba, CPU), jax, or auto = native when JAX runs on the CPU (docs/engine-backends.md)",
    choices=ENGINES,
)

UCT_OPTIONS: tuple[Option, ...] = (
    _opt(
        "time_ms",
        "float",
        40.0,
        "wall-clock budget per decision in ms, 0 = none (sample config / CIG 2013: 40 ms)",
        minimum=0,
    ),
    _opt(
        "traversals", "int", 5000, "maximum traversals per decision (sample config 5000)", minimum=1
    ),
    _opt("c", "float", 1.6, "UCB exploration constant (sample config 1.6)", minimum=0),
    *_COMMON_SEARCH,
    _opt(
        "root_select",
        "choice",
        "most-visited",
        "root move: most visited child (SparCraft default) or highest UCB value",
        choices=("most-visited", "highest-value"),
    ),
    _opt(
        "batch",
        "batch",
        "auto",
        "leaf-parallel batch: leaves evaluated per engine call (virtual loss); 1 = SparCraft's serial UCT; auto = by army size, see auto_batch (our deviation)",
    ),
    _ENGINE_OPTION,
)

ABCD_OPTIONS: tuple[Option, ...] = (
    _opt(
        "time_ms",
        "float",
        40.0,
        "wall-clock budget per decision in ms, 0 = none (sample config 40 ms)",
        minimum=0,
    ),
    _opt(
        "nodes",
        "int",
        0,
        "deterministic budget: stop after this many nodes (SparCraft's nodesExpanded), 0 = none",
        minimum=0,
    ),
    _opt(
        "max_depth",
        "int",
        50,
        "iterative deepening limit (SearchExperiment's IDAlphaBeta: 50)",
        minimum=1,
    ),
    *_COMMON_SEARCH,
    _opt(
        "tt",
        "bool",
        True,
        "transposition table (100,000 entries, scan 10, kept across decisions of a game)",
    ),
    _opt(
        "tt_size",
        "int",
        100_000,
        "transposition table entries (Constants::Transposition_Table_Size)",
        minimum=16,
    ),
    _opt("fallback", "script", "nokdps", "move when depth 1 does not complete (SparCraft: NOKDPS)"),
    _opt(
        "batch",
        "batch",
        "auto",
        "leaf playouts per engine call after the eldest child (young-brothers-wait batching); 1 = serial; auto = by army size, at most max_children (our deviation)",
    ),
    _ENGINE_OPTION,
)

PGS_OPTIONS: tuple[Option, ...] = (
    _opt(
        "time_ms",
        "float",
        40.0,
        "wall-clock budget per decision in ms, checked before each unit, 0 = none (CIG 2013: 40 ms; sample config 0)",
        minimum=0,
    ),
    _opt(
        "playouts",
        "int",
        0,
        "deterministic budget: stop improving once this many playouts ran, 0 = none",
        minimum=0,
    ),
    _opt(
        "portfolio",
        "scripts",
        ("nokdps", "kiter-dps"),
        "script portfolio, in order (hard-coded {NOKDPS, KiterDPS} in SparCraft)",
    ),
    _opt(
        "enemy_seed",
        "script",
        "nokdps",
        "enemy script while seeding (Player_PortfolioGreedySearch default NOKDPS)",
    ),
    _opt("iterations", "int", 1, "improvement passes I (default 1)", minimum=1),
    _opt("responses", "int", 0, "response rounds R (default 0)", minimum=0),
    _opt(
        "playout_turns",
        "int",
        K.PGS_PLAYOUT_TURNS,
        "playout cap; the loop runs while rounds <= cap, i.e. up to cap+1 turns",
        minimum=1,
    ),
    _opt(
        "lookahead",
        "lookahead",
        1,
        "1: one unit's candidates per engine call (SparCraft's order); 2: a pair of units per call, speculatively, same result (measured: at most ~10% faster)",
    ),
    _ENGINE_OPTION,
)

ALGORITHMS: dict[str, tuple[Option, ...]] = {
    "uct": UCT_OPTIONS,
    "abcd": ABCD_OPTIONS,
    "pgs": PGS_OPTIONS,
}
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
        lines.append(
            f"  script=NAME  -- shorthand: sets {', '.join(_SCRIPT_SHORTHAND[alg])} to NAME"
        )
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
        v = (
            None
            if value is None or (isinstance(value, str) and value.lower() == "none")
            else _script_name(value, what)
        )
    elif kind == "scripts":
        if isinstance(value, str):
            items = (
                []
                if value.lower() == "none"
                else [s for s in value.replace("/", "+").split("+") if s]
            )
        elif isinstance(value, Sequence):
            items = list(value)
        else:
            raise ValueError(f"{what}: expected script names joined by '+', got {value!r}")
        v = tuple(_script_name(s, what) for s in items)
    elif kind == "lookahead":
        v = _convert(Option(opt.name, "int", None, "", minimum=1), value, where)
        if v > 2:
            raise ValueError(f"{what}: must be 1 or 2, got {value!r}")
    elif kind == "batch":
        if isinstance(value, str) and value.strip().lower() == "auto":
            return "auto"
        v = _convert(Option(opt.name, "int", None, "", minimum=1), value, where)
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
        raise ValueError(
            "player spec must be a non-empty string such as 'uct:time_ms=40' or 'nokdps'"
        )
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
        raise ValueError(
            f"{where}: unknown option(s) {', '.join(map(repr, unknown))} (known: {known})"
        )
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
        out = np.asarray(fn(sub, state, rules.walkable)[p], np.int32)
        self._stats = SearchStats(algorithm="script", ms=(time.perf_counter() - t0) * 1e3, calls=1)
        return out


class DeviceArgs:
    """Per-decision constants, shared by every engine call of a decision: in device form for the
    JAX engine, as NumPy arrays (``native``) for the native engine."""

    def __init__(self, consts: K.Consts, rules: Rules, engine: str = "jax"):
        self.consts = consts
        self.rules = rules
        self.rules_key = K.rules_static(rules)
        self.num_slots = consts.num_slots
        self.engine = engine
        self.native: Any = None
        if engine == "native":
            from hybridmarl.search.native import NativeArgs

            self.native = NativeArgs(consts, rules)
            self.args: tuple = ()
        else:
            self.args = tuple(jax.device_put(a) for a in consts.as_args()) + (rules.walkable,)


class SearchPlayer(abc.ABC):
    """Shared plumbing of the search players: seeding, root packing, statistics, timing."""

    algorithm = ""

    def __init__(self, options: dict[str, Any], name: str):
        self.options = options
        self.name = name
        self.engine = resolve_engine(options.get("engine", "jax"))
        self.reset(0)
        self._stats: SearchStats | None = None

    @property
    def stats(self) -> SearchStats | None:
        return self._stats

    def reset(self, seed: int) -> None:
        # Two streams: move shuffles / random first movers, and keys for the compiled calls (only
        # the ``random`` script uses them), so batching choices never shift the shuffles.
        self.rng = np.random.default_rng([int(seed), 0])
        self._key_rng = np.random.default_rng([int(seed), 1])

    def key(self) -> np.ndarray:
        """A fresh raw PRNG key (uint32 [2]) for a compiled call."""
        return self._key_rng.integers(0, 2**32, size=2, dtype=np.uint32)

    def decide(self, state: GameState, rules: Rules, p: int) -> np.ndarray:
        if p not in (0, 1):
            raise ValueError(f"player index must be 0 or 1, got {p!r}")
        t0 = time.perf_counter()
        c0 = time.process_time()
        root, consts = self._pack(state)
        dev = DeviceArgs(consts, rules, self.engine)
        stats = SearchStats(algorithm=self.algorithm)
        move = self._search(root, dev, p, stats, t0)
        stats.ms = (time.perf_counter() - t0) * 1e3
        stats.cpu_ms = (time.process_time() - c0) * 1e3
        self._stats = stats
        return np.asarray(move, np.int32)

    @abc.abstractmethod
    def _search(
        self, root: np.ndarray, dev: DeviceArgs, p: int, stats: SearchStats, t0: float
    ) -> np.ndarray:
        """The algorithm's search from the packed root: the move of player ``p``."""

    def warmup(self, state: GameState, rules: Rules) -> float:
        """Compile every program this player uses for ``state``'s shape; returns seconds spent."""
        t0 = time.perf_counter()
        root, consts = self._pack(state)
        if self.engine == "native":
            from hybridmarl.search.native import compile_search_kernels

            compile_search_kernels()
        self._warmup(root, DeviceArgs(consts, rules, self.engine))
        return time.perf_counter() - t0

    def _pack(self, state: GameState) -> tuple[np.ndarray, K.Consts]:
        if self.engine == "native":
            from hybridmarl.search.native import pack_state_host

            return pack_state_host(state)
        return K.pack_state(state)

    @abc.abstractmethod
    def _warmup(self, root: np.ndarray, dev: DeviceArgs) -> None:
        """Compile the algorithm's programs for this root's shapes."""


def auto_batch(num_slots: int) -> int:
    """Playouts per engine call for ``batch=auto``, by unit slots per side. A batched playout
    costs about as much as one serial playout for small armies (call overhead dominates) but
    grows with the batch for large ones, where a big batch would overrun a 40 ms budget by
    several times. Measured on the 2-core CI machine (``bench/search.py``)."""
    if num_slots <= 12:
        return 32
    if num_slots <= 24:
        return 16
    if num_slots <= 40:
        return 8
    return 4


def resolve_batch(value: int | str, num_slots: int, cap: int | None = None) -> int:
    b = auto_batch(num_slots) if value == "auto" else int(value)
    return max(1, min(b, cap)) if cap is not None else b


def deadline_from(t0: float, time_ms: float) -> float:
    """Absolute perf_counter deadline (inf when there is no time budget)."""
    return t0 + time_ms / 1e3 if time_ms > 0 else float("inf")


def eval_params(method: str) -> tuple[int, bool]:
    """(playout cap, use LTD) of an evaluation method: a 200-turn playout scored by LTD2, or the
    state's own LTD2 / LTD (docs/engine.md#evaluation-ltd-and-ltd2)."""
    if method == "playout":
        return K.PLAYOUT_TURNS, False
    return 0, method == "ltd"


class Engine:
    """The search program of one decision, on the player's engine: ``kernels.search_fn`` (JAX;
    every call padded to a fixed batch size, so each size compiles once) or
    ``native.search_call`` (the native engine; same results, no padding); counts the calls."""

    def __init__(
        self,
        player: SearchPlayer,
        dev: DeviceArgs,
        info_scripts: tuple[str, ...],
        playout_scripts: tuple[str, str],
        stats: SearchStats,
    ):
        self.player = player
        self.dev = dev
        self.info_scripts = info_scripts
        self.playout_scripts = playout_scripts
        self.stats = stats

    def fn(self, k: int) -> Callable:
        return K.search_fn(
            self.dev.num_slots, k, self.info_scripts, self.playout_scripts, self.dev.rules_key
        )

    def run(
        self,
        k: int,
        base: np.ndarray,
        actions: np.ndarray,
        mask: np.ndarray,
        do_step: np.ndarray,
        player: int,
        cap: int,
        use_ltd: bool = False,
    ) -> dict[str, Any]:
        """Run ``m <= k`` entries (leading axis of ``actions``; ``base`` [m, L] or one [L] state
        for all) padded to ``k``; returns host arrays with ``k`` rows (the first ``m`` are real).
        The native engine runs the ``m`` entries only (no padding: nothing compiles per shape)."""
        m = actions.shape[0]
        if self.dev.native is not None:
            from hybridmarl.search.native import search_call

            out = search_call(
                self.dev.native,
                base,
                actions,
                mask,
                do_step,
                player,
                cap,
                use_ltd,
                self.info_scripts,
                self.playout_scripts,
                int(self.player.key()[0]),
            )
            self.stats.calls += 1
            return out
        if base.ndim == 1:
            base = np.broadcast_to(base, (k, base.shape[0]))
        elif m < k:
            base = np.concatenate([base, np.broadcast_to(base[:1], (k - m, base.shape[1]))])
        if m < k:
            pad = k - m
            actions = np.concatenate(
                [actions, np.broadcast_to(actions[:1], (pad, *actions.shape[1:]))]
            )
            mask = np.concatenate([mask, np.broadcast_to(mask[:1], (pad, 2))])
            do_step = np.concatenate([do_step, np.broadcast_to(do_step[:1], (pad,))])
        out = self.fn(k)(
            self.player.key(),
            base,
            actions.astype(np.int32),
            mask.astype(bool),
            do_step.astype(bool),
            np.full(k, player, np.int32),
            np.int32(cap),
            np.bool_(use_ltd),
            *self.dev.args,
        )
        self.stats.calls += 1
        return jax.device_get(out)

    def info(self, vec: np.ndarray) -> dict[str, np.ndarray]:
        """Node info of one state (no turn played, no playout), without the batch axis."""
        n = self.dev.num_slots
        out = self.run(
            1,
            vec[None],
            np.zeros((1, 2, n), np.int32),
            np.zeros((1, 2), bool),
            np.zeros(1, bool),
            0,
            0,
        )
        return {k: v[0] for k, v in out["info"].items()}

    def warmup(self, vec: np.ndarray, sizes: Sequence[int]) -> None:
        n = self.dev.num_slots
        if self.dev.native is not None:  # one compiled program for every batch size
            self.run(
                1,
                vec[None],
                np.zeros((1, 2, n), np.int32),
                np.zeros((1, 2), bool),
                np.zeros(1, bool),
                0,
                0,
            )
            return
        for k in sorted(set(sizes)):
            jax.block_until_ready(
                self.fn(k)(
                    self.player.key(),
                    np.repeat(vec[None], k, 0),
                    np.zeros((k, 2, n), np.int32),
                    np.zeros((k, 2), bool),
                    np.zeros(k, bool),
                    np.zeros(k, np.int32),
                    np.int32(0),
                    np.bool_(False),
                    *self.dev.args,
                )
            )


def unique(names: Sequence[str]) -> tuple[str, ...]:
    out: list[str] = []
    for n in names:
        if n not in out:
            out.append(n)
    return tuple(out)
