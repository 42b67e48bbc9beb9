"""``hybridmarl battle`` and ``hybridmarl trace``: the SparCraft combat engine from the command
line.

- ``battle``: a scripted (or search-player) battle series, start states from a file or a
  scenario, with a win-rate table and optional JSON results.
- ``trace``: a turn-by-turn trace of one battle, in the trace format of SparCraft's reference
  implementation (github.com/davechurchill/ualbertabot, directory SparCraft).

Bad input (an unknown unit type or script, a unit off the map, an empty side, malformed JSON, a
missing file) raises :class:`~hybridmarl.errors.UserError` before any output file is written.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import tyro


@dataclass(frozen=True)
class BattleConfig:
    """Play a series of scripted battles and print a win-rate table."""

    p0: str = "attack-closest"
    """Player 0 (ours, the left army): a script (attack-closest, attack-weakest, attack-dps, nokdps,
    kiter, kiter-dps, kiter-nokdps, cluster, random, attack-weakest-global) or a search player
    spec: uct, abcd or pgs with options, e.g. 'uct:time_ms=40,c=1.6' or 'uct:script=attack-closest'
    (the paper's UCT_c); see hybridmarl.search.base for every option."""
    p1: str = "attack-weakest"
    """Player 1 (the enemy, the right army): a script or a search player spec."""
    scenario: str | None = "m5v5"
    """Named scenario: m<A>v<B> (Marines, armies in contact) or m<A>v<B>-apart (disks 400 px
    apart; docs/engine.md). Ignored when --states or --scenario-file is given."""
    scenario_file: str | None = None
    """JSON scenario file for other unit types, mixes and geometries (see README)."""
    states: str | None = None
    """JSON file of explicit start states: {"states": [{"units": [{"type", "player", "x", "y"}]}]}."""
    n: int = 1000
    """Number of start states to generate (with --scenario / --scenario-file)."""
    seed: int = 0
    """Seed for start-state generation and the random script."""
    out: str | None = None
    """Write per-battle results as JSON here (atomically; nothing is written on bad input)."""
    batch_size: int = 1024
    """Games played at once in one compiled program (jax engine)."""
    setting: Annotated[str, tyro.conf.arg(help_behavior_hint="sparcraft | paper")] = "sparcraft"
    """Named setting (docs/engine.md#settings): the rules and the geometry of named scenarios.
    'sparcraft': SparCraft's current rules (DC-HEAD), disks r=100 px centred 150 px apart.
    'paper': the paper's (classic overkill, stalemate limit 200, a contact geometry calibrated
    to the paper's demonstrator win rates, Table 1); --overkill and --stalemate-limit may not
    contradict it."""
    overkill: Annotated[str | None, tyro.conf.arg(help_behavior_hint="pass | classic")] = None
    """An attack on a target killed earlier in the same turn: 'pass' (SparCraft DC-HEAD: the
    attacker PASSes) or 'classic' (DC-CLASSIC: cooldown spent, no damage). Default: the
    setting's."""
    stalemate_limit: int | None = None
    """End the game after more than this many turns without an HP change. Default: the
    setting's (sparcraft: 50, DC-HEAD; paper: 200)."""
    max_turns: int = 20000
    """Turn cap (SparCraft SearchExperiment: 20,000 decision turns)."""
    map_file: str | None = None
    """Optional SparCraft ASCII walkability map (width, height in 8-px walk tiles, rows of 0/1)."""
    progress: bool = True
    """Show a progress bar."""
    swap: bool = False
    """Also play every state with the scripts swapped and report both directions."""
    engine: Literal["auto", "native", "jax"] = "auto"
    """Engine backend of scripted battles: 'native' (Numba, compiled for the CPU; the first run
    on a machine compiles it once, about a minute), 'jax' (the reference backend, for GPUs), or
    'auto': native when JAX's default device is a CPU, else jax. Both give identical results,
    except the 'random' script's draws (docs/engine-backends.md). Search players decide on the
    host; their engine calls follow the spec's own option (e.g. 'uct:engine=jax'; default auto,
    docs/baselines.md#engine-option)."""


@dataclass(frozen=True)
class TraceConfig:
    """Print a turn-by-turn trace of one battle (SparCraft's reference trace format)."""

    p0: str = "attack-closest"
    """Script of player 0."""
    p1: str = "attack-weakest"
    """Script of player 1."""
    states: str | None = None
    """JSON states file; the state at --index is traced."""
    scenario: str = "m5v5"
    """Named scenario used when --states is not given."""
    setting: Annotated[str, tyro.conf.arg(help_behavior_hint="sparcraft | paper")] = "sparcraft"
    """Named setting (docs/engine.md#settings): the rules, and the geometry of the named
    scenario."""
    index: int = 0
    """Which state to trace."""
    seed: int = 0
    """Seed for state generation."""


def _load_map(path: str | None):
    if path is None:
        return None
    from hybridmarl.engine.scenarios import InputError
    from hybridmarl.engine.state import parse_ascii_map

    try:
        with open(path) as f:
            return parse_ascii_map(f.read())
    except FileNotFoundError:
        raise InputError(f"map file {path!r} not found") from None
    except ValueError as e:
        raise InputError(f"{path}: {e}") from None


def _is_script(spec: str) -> bool:
    from hybridmarl.engine.scripts import canonical_name

    try:
        canonical_name(spec)
    except KeyError:
        return False
    return True


def _check_player_spec(spec: str) -> None:
    """Validate a search-player spec such as ``uct:time_ms=40`` (one-line InputError)."""
    from hybridmarl.engine.scenarios import InputError
    from hybridmarl.engine.scripts import SCRIPTS

    try:
        from hybridmarl.search import make_player

        make_player(spec)
    except ValueError as e:
        msg = str(e).splitlines()[0] if str(e) else f"bad player {spec!r}"
        if spec.split(":")[0].strip().lower() not in ("uct", "uct-cd", "uctcd", "abcd", "ab", "alphabeta", "alpha-beta", "pgs", "portfolio"):
            msg = f"unknown script {spec!r} (scripts: {', '.join(SCRIPTS)}; search players: uct, abcd, pgs)"
        raise InputError(msg) from None


def run_battle(cfg: BattleConfig) -> int:
    """Play the battle series ``cfg`` describes and print its table; raises
    :class:`~hybridmarl.engine.scenarios.InputError` (a ``UserError``) on bad input, before any
    output is written."""
    from hybridmarl.engine.battle import run_battles
    from hybridmarl.engine.scenarios import InputError, load_states_file, resolve_scenario
    from hybridmarl.engine.state import make_rules
    from hybridmarl.io import write_json_atomic
    from hybridmarl.settings import resolve as resolve_setting

    search = [not _is_script(s) for s in (cfg.p0, cfg.p1)]
    for s, is_search in zip((cfg.p0, cfg.p1), search, strict=True):
        if is_search:
            _check_player_spec(s)
    if cfg.n < 1:
        raise InputError("--n must be at least 1")
    if cfg.batch_size < 1:
        raise InputError("--batch-size must be at least 1")
    setting, overkill, stalemate_limit = resolve_setting(
        cfg.setting, overkill=cfg.overkill, stalemate_limit=cfg.stalemate_limit
    )
    walkable = _load_map(cfg.map_file)
    try:
        rules = make_rules(
            walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=cfg.max_turns
        )
    except ValueError as e:
        raise InputError(str(e)) from None
    engine = resolve_engine(cfg.engine)
    states: Any
    if cfg.states:
        states = load_states_file(cfg.states, walkable=walkable)
        label = cfg.states
    else:
        sc = resolve_scenario(cfg.scenario, cfg.scenario_file, setting)
        label = f"{sc.name} (n={cfg.n}, seed={cfg.seed})"
        if engine == "native" and walkable is None and not any(search):
            # The same states as sc.generate, drawn straight into arrays: no per-unit objects.
            from hybridmarl.engine.native import from_arrays

            states = from_arrays(sc.generate_arrays(cfg.n, cfg.seed))
        else:
            states = sc.generate(cfg.n, cfg.seed)
        if walkable is not None:
            from hybridmarl.engine.scenarios import parse_states_document, states_to_document

            states = parse_states_document(states_to_document(states), walkable=walkable)

    if any(search):
        # Search players decide on the host, turn by turn (hybridmarl.search.runner).
        from hybridmarl.search import run_player_battles

        def play(a: str, b: str):
            return run_player_battles(states, a, b, seed=cfg.seed, rules=rules, progress=cfg.progress)
    else:

        def play(a: str, b: str):
            if engine == "native":
                from hybridmarl.engine import native

                return native.run_battles(states, a, b, seed=cfg.seed, rules=rules, progress=cfg.progress)
            return run_battles(states, a, b, seed=cfg.seed, rules=rules, batch_size=cfg.batch_size, progress=cfg.progress)

    if setting.name != "sparcraft":
        label += f", {setting.name} setting"
    results = [play(cfg.p0, cfg.p1)]
    if cfg.swap:
        results.append(play(cfg.p1, cfg.p0))
    _print_table(label, results)
    if cfg.out:
        doc = results[0].to_document()
        if cfg.swap:
            doc["swapped"] = results[1].to_document()
        doc["setting"] = setting.name
        write_json_atomic(cfg.out, doc, indent=None)
        print(f"results written to {cfg.out}")
    return 0


def resolve_engine(name: str) -> str:
    """'native' or 'jax' for a --engine value: 'auto' is native when JAX's default device is a
    CPU (the native backend is the faster one there) and jax otherwise."""
    if name != "auto":
        return name
    import jax

    return "native" if jax.default_backend() == "cpu" else "jax"


def _print_table(label: str, results) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"Battles: {label}")
    for col in ("P0 (left)", "P1 (right)", "battles", "P0 wins", "P1 wins", "draws", "mean turns", "mean frames"):
        table.add_column(col, justify="right")
    for r in results:
        s = r.summary()
        table.add_row(
            s["p0"],
            s["p1"],
            str(s["battles"]),
            f"{s['p0_win_rate']:.1%}",
            f"{s['p1_win_rate']:.1%}",
            f"{s['draw_rate']:.1%}",
            f"{s['mean_turns']:.1f}",
            f"{s['mean_final_time']:.1f}",
        )
    console = Console()
    # Keep the table on one line per row when stdout is not a terminal (logs, pipes, CI).
    Console(width=max(console.width, 120)).print(table)


def run_trace(cfg: TraceConfig) -> int:
    """Print the trace of one battle; raises ``InputError`` (a ``UserError``) on bad input."""
    from hybridmarl.engine.scenarios import InputError, load_states_file, named_scenario
    from hybridmarl.engine.scripts import canonical_name
    from hybridmarl.engine.state import build_state
    from hybridmarl.engine.trace import format_trace, record_trace
    from hybridmarl.settings import get_setting

    for s in (cfg.p0, cfg.p1):
        try:
            canonical_name(s)
        except KeyError as e:
            raise InputError(str(e.args[0])) from None
    setting = get_setting(cfg.setting)
    states = load_states_file(cfg.states) if cfg.states else named_scenario(cfg.scenario, setting).generate(cfg.index + 1, cfg.seed)
    if not 0 <= cfg.index < len(states):
        raise InputError(f"--index {cfg.index} out of range (0..{len(states) - 1})")
    units = states[cfg.index]
    tr = record_trace(units, build_state(units), setting.rules(), cfg.p0, cfg.p1, seed=cfg.seed)
    sys.stdout.write(format_trace(tr))
    return 0


def battle_command(args: list[str]) -> int:
    """``hybridmarl battle [options]``."""
    return run_battle(tyro.cli(BattleConfig, args=args, prog="hybridmarl battle"))


def trace_command(args: list[str]) -> int:
    """``hybridmarl trace [options]``."""
    return run_trace(tyro.cli(TraceConfig, args=args, prog="hybridmarl trace"))
