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

import contextlib
import json
import sys
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
import tyro

from hybridmarl.engine.backend import resolve_engine
from hybridmarl.io import atomic_write
from hybridmarl.options import DEFAULT_IN_DOCSTRING


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
    stalemate_limit: Annotated[int | None, DEFAULT_IN_DOCSTRING] = None
    """End the game after more than this many turns without an HP change. Default: the
    setting's (sparcraft: 50, DC-HEAD; paper: 200)."""
    max_turns: int = 20000
    """Turn cap (SparCraft SearchExperiment: 20,000 decision turns)."""
    map_file: str | None = None
    """Optional SparCraft ASCII walkability map (width, height in 8-px walk tiles, rows of 0/1)."""
    progress: bool = True
    """Show a progress bar."""
    yes: bool = False
    """Play a series above the size guard (more than 20,000,000 battles x units per battle, e.g.
    2,000,000 m5v5 battles) without asking; it is played and written in chunks (100,000 m5v5
    battles), so memory stays bounded (docs/engine.md#large-battle-series)."""
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
    """Which state to trace (a named scenario: at most MAX_TRACE_INDEX, its states are drawn in
    sequence)."""
    seed: int = 0
    """Seed for state generation."""


#: ``battle`` asks for --yes above this many battles x units (2,000,000 m5v5 battles), after
#: printing its time and output-size estimate and before allocating anything.
CONFIRM_UNIT_BATTLES = 20_000_000
#: Units (battles x units per battle) generated, played and written at once: a longer series is
#: played chunk by chunk, so its memory does not grow with --n (100,000 m5v5 battles a chunk;
#: chunk k > 0 draws its start states from seed (seed, k)).
CHUNK_UNITS = 1_000_000
#: Unit-battles per CPU-second of state generation plus native play: 200,000 (m5v5, 400,000
#: battles in 17.5-18.1 CPU-s, start-up included, 2026-12-02, 2-core x86-64 CPU VM, load 5;
#: docs/engine.md). Used only for the estimate.
UNIT_BATTLES_PER_S = 200_000
#: Bytes of --out JSON per battle and per unit (its final HP): 90 per m5v5 battle, measured.
OUT_BYTES_PER_BATTLE, OUT_BYTES_PER_UNIT = 60, 3
#: Highest --index of ``trace`` on a named scenario: its states are drawn in sequence, so
#: tracing state i draws the i before it.
MAX_TRACE_INDEX = 10_000


def check_series_size(n: int, units: int, *, swap: bool, out: bool, yes: bool) -> None:
    """Refuse (one line: the estimate and the way on) a series of ``n`` battles of ``units``
    units each that is above :data:`CONFIRM_UNIT_BATTLES` unless ``yes``."""
    from hybridmarl.cli.sizes import SizeError, duration

    work = n * units * (2 if swap else 1)
    if work <= CONFIRM_UNIT_BATTLES or yes:
        return
    size = n * (2 if swap else 1) * (OUT_BYTES_PER_BATTLE + OUT_BYTES_PER_UNIT * units)
    out_part = f", --out about {size / 1e9:.1f} GB" if out else ""
    raise SizeError(
        f"--n {n} battles of {units} units{' (twice, --swap)' if swap else ''} would take about "
        f"{duration(work / UNIT_BATTLES_PER_S)} of CPU time{out_part} (memory stays bounded: they are "
        f"played in chunks of {chunk_battles(units)}): pass --yes to play them, or a smaller --n"
    )


def chunk_battles(units: int) -> int:
    """Battles per chunk of a series of battles of ``units`` units (:data:`CHUNK_UNITS`)."""
    return max(1, CHUNK_UNITS // max(units, 1))


def _load_map(path: str | None):
    if path is None:
        return None
    from hybridmarl.engine.scenarios import InputError
    from hybridmarl.engine.state import parse_ascii_map
    from hybridmarl.io import read_user_text

    text = read_user_text(path, "map file", InputError)
    try:
        return parse_ascii_map(text)
    except ValueError as e:
        raise InputError(f"map file {path!r}: {str(e).removeprefix('map file: ')}") from None


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
        if spec.split(":")[0].strip().lower() not in (
            "uct",
            "uct-cd",
            "uctcd",
            "abcd",
            "ab",
            "alphabeta",
            "alpha-beta",
            "pgs",
            "portfolio",
        ):
            msg = f"unknown script {spec!r} (scripts: {', '.join(SCRIPTS)}; search players: uct, abcd, pgs)"
        raise InputError(msg) from None


def run_battle(cfg: BattleConfig) -> int:
    """Play the battle series ``cfg`` describes and print its table; raises
    :class:`~hybridmarl.engine.scenarios.InputError` (a ``UserError``) on bad input, before any
    output is written. A series longer than a chunk (:data:`CHUNK_UNITS`) is generated, played
    and written chunk by chunk."""
    # (engine.scenarios' InputError is a UserError; importing it loads JAX, after the size guard)
    from hybridmarl.errors import UserError as InputError
    from hybridmarl.io import check_output_path
    from hybridmarl.validate import COUNT, COUNT_OR_ZERO, SEED, check_values, optional

    check_values(
        {
            "n": cfg.n,
            "seed": cfg.seed,
            "batch_size": cfg.batch_size,
            "stalemate_limit": cfg.stalemate_limit,
            "max_turns": cfg.max_turns,
        },
        {
            "n": COUNT,
            "seed": SEED,
            "batch_size": COUNT,
            "stalemate_limit": optional(COUNT_OR_ZERO),
            "max_turns": COUNT,
        },
        error=InputError,
    )
    if cfg.out:
        check_output_path(cfg.out, error=InputError)
    quick = None if cfg.states else _units_before_loading(cfg)
    if quick is not None:  # the size guard before the engine (and JAX) is even imported
        check_series_size(cfg.n, quick, swap=cfg.swap, out=bool(cfg.out), yes=cfg.yes)

    from hybridmarl.engine.scenarios import load_states_file, resolve_scenario
    from hybridmarl.settings import resolve as resolve_setting

    setting, overkill, stalemate_limit = resolve_setting(
        cfg.setting, overkill=cfg.overkill, stalemate_limit=cfg.stalemate_limit
    )
    walkable = _load_map(cfg.map_file)
    loaded: list | None = None
    if cfg.states:
        loaded = load_states_file(cfg.states, walkable=walkable)
        n, label = len(loaded), cfg.states
        units = max(len(st) for st in loaded)
        sc = None
    else:
        sc = resolve_scenario(cfg.scenario, cfg.scenario_file, setting)
        n, units = cfg.n, sc.n0 + sc.n1
        label = f"{sc.name} (n={cfg.n}, seed={cfg.seed})"
    check_series_size(n, units, swap=cfg.swap, out=bool(cfg.out), yes=cfg.yes)

    from hybridmarl.engine.state import make_rules

    search = [not _is_script(s) for s in (cfg.p0, cfg.p1)]
    for s, is_search in zip((cfg.p0, cfg.p1), search, strict=True):
        if is_search:
            _check_player_spec(s)
    try:
        rules = make_rules(
            walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=cfg.max_turns
        )
    except ValueError as e:
        raise InputError(str(e)) from None
    engine = resolve_engine(cfg.engine)

    chunk = chunk_battles(units)

    def chunk_states(k: int) -> tuple[Any, int]:
        """The start states of chunk ``k`` and the seed its battles play under."""
        first, m = k * chunk, min(chunk, n - k * chunk)
        if loaded is not None:
            return loaded[first : first + m], cfg.seed
        assert sc is not None
        seed = (
            cfg.seed if k == 0 else int(np.random.SeedSequence([cfg.seed, k]).generate_state(1)[0])
        )
        if engine == "native" and walkable is None and not any(search):
            # The same states as sc.generate, drawn straight into arrays: no per-unit objects.
            from hybridmarl.engine.native import from_arrays

            return from_arrays(sc.generate_arrays(m, seed)), seed
        states = sc.generate(m, seed)
        if walkable is not None:
            from hybridmarl.engine.scenarios import parse_states_document, states_to_document

            states = parse_states_document(states_to_document(states), walkable=walkable)
        return states, seed

    def play(a: str, b: str, states: Any, seed: int):
        if any(search):
            # Search players decide on the host, turn by turn (hybridmarl.search.runner).
            from hybridmarl.search import run_player_battles

            return run_player_battles(states, a, b, seed=seed, rules=rules, progress=cfg.progress)
        if engine == "native":
            from hybridmarl.engine import native

            return native.run_battles(states, a, b, seed=seed, rules=rules, progress=cfg.progress)
        from hybridmarl.engine.battle import run_battles

        return run_battles(
            states, a, b, seed=seed, rules=rules, batch_size=cfg.batch_size, progress=cfg.progress
        )

    if setting.name != "sparcraft":
        label += f", {setting.name} setting"
    directions = [(cfg.p0, cfg.p1)] + ([(cfg.p1, cfg.p0)] if cfg.swap else [])
    chunks = (n + chunk - 1) // chunk
    with contextlib.ExitStack() as stack:
        out = stack.enter_context(atomic_write(cfg.out)) if cfg.out else None
        tallies = []
        for i, (a, b) in enumerate(directions):
            tally = _Tally()
            if out is not None:
                out.write(', "swapped": {"results": [' if i == 1 else '{"results": [')
            for k in range(chunks):
                states, seed = chunk_states(k)
                res = play(a, b, states, seed)
                tally.add(res)
                if out is not None:
                    rows = res.to_document()["results"]
                    out.write(
                        ("," if k else "") + ",".join(json.dumps(r, sort_keys=True) for r in rows)
                    )
            if out is not None:
                out.write(
                    '], "summary": '
                    + json.dumps(tally.summary(), sort_keys=True)
                    + ("}" if i == 1 else "")
                )
            tallies.append(tally)
        if out is not None:
            out.write(', "setting": ' + json.dumps(setting.name) + "}\n")
        _print_table(label, tallies)
    if cfg.out:
        print(f"results written to {cfg.out}")
    return 0


def _units_before_loading(cfg: BattleConfig) -> int | None:
    """Units per battle of a named scenario (m<A>v<B>) or a scenario file, read without the
    engine; None where that takes the full loader (which checks everything again)."""
    import re

    if cfg.scenario_file:
        from hybridmarl.io import read_user_json

        try:
            doc = read_user_json(cfg.scenario_file, "scenario file")
            sides = [doc["player0"]] + (
                [] if doc.get("kind") in ("separated", "symmetric") else [doc["player1"]]
            )
            counts = [sum(int(e["count"]) for e in side) for side in sides]
        except Exception:
            return None
        if max(counts) > 512:  # more than engine.scenarios.MAX_UNITS_PER_SIDE: the loader says so
            return None
        return sum(counts) * (2 if len(sides) == 1 else 1)
    m = re.fullmatch(r"m(\d+)v(\d+)(-apart)?", (cfg.scenario or "").strip().lower())
    return int(m.group(1)) + int(m.group(2)) if m else None


class _Tally:
    """The summary of a battle series, summed chunk by chunk (``BattleResults.summary``'s keys)."""

    def __init__(self) -> None:
        self.p0 = self.p1 = ""
        self.battles = self.p0_wins = self.p1_wins = self.draws = 0
        self.time_sum = self.turns_sum = 0

    def add(self, res: Any) -> None:
        self.p0, self.p1 = res.p0, res.p1
        w = np.asarray(res.winner)
        self.battles += len(w)
        self.p0_wins += int((w == 0).sum())
        self.p1_wins += int((w == 1).sum())
        self.draws += int((w == -1).sum())
        self.time_sum += int(np.asarray(res.final_time, np.int64).sum())
        self.turns_sum += int(np.asarray(res.turns, np.int64).sum())

    def summary(self) -> dict[str, Any]:
        n = max(self.battles, 1)
        return {
            "battles": self.battles,
            "p0": self.p0,
            "p1": self.p1,
            "p0_wins": self.p0_wins,
            "p1_wins": self.p1_wins,
            "draws": self.draws,
            "p0_win_rate": self.p0_wins / n,
            "p1_win_rate": self.p1_wins / n,
            "draw_rate": self.draws / n,
            "mean_final_time": self.time_sum / n if self.battles else 0.0,
            "mean_turns": self.turns_sum / n if self.battles else 0.0,
        }


def _print_table(label: str, results) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"Battles: {label}")
    for col in (
        "P0 (left)",
        "P1 (right)",
        "battles",
        "P0 wins",
        "P1 wins",
        "draws",
        "mean turns",
        "mean frames",
    ):
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
    from hybridmarl.errors import UserError
    from hybridmarl.validate import COUNT_OR_ZERO, SEED, check_values

    check_values({"index": cfg.index, "seed": cfg.seed}, {"index": COUNT_OR_ZERO, "seed": SEED})
    if not cfg.states and cfg.index > MAX_TRACE_INDEX:
        raise UserError(
            f"--index {cfg.index}: a named scenario's states are drawn in sequence, so --index is at most "
            f"{MAX_TRACE_INDEX}; use another --seed, or write the state to a --states file"
        )

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
    states = (
        load_states_file(cfg.states)
        if cfg.states
        else named_scenario(cfg.scenario, setting).generate(cfg.index + 1, cfg.seed)
    )
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
