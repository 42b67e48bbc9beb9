"""Host-loop games and battle series between any players (scripts or search players).

``play_game_with_players`` plays one game turn by turn on the host: each turn one compiled call
says who moves, every moving player decides from the same state (``Player.decide``), and one
compiled call applies both sides' actions (P1's, then P0's; ``rules.apply_actions``). This is the
engine's ``play_game`` with the policies outside the compiled program, so a search can run
between turns. ``run_player_battles`` plays a list of start states and returns the engine's
``BattleResults``; when both players are scripts it hands the whole series to the engine's fully
compiled ``run_battles``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import jax
import numpy as np

from hybridmarl.engine.battle import BattleResults, pad_states, run_battles
from hybridmarl.engine.state import GameState, Rules, UnitSpec, make_rules
from hybridmarl.search import kernels as K
from hybridmarl.search.base import Player, ScriptPlayer, SearchStats
from hybridmarl.search.factory import make_player


@dataclass
class PlayedGame:
    """Outcome of one host-loop game (fields as in the engine's ``GameResult``) and the players'
    per-decision statistics."""

    winner: int  # 0, 1, or -1 for a draw / unfinished
    final_time: int
    turns: int
    hp: np.ndarray  # int [2, U] final HP per slot
    ltd2_eval: int  # eval(P0, LTD2) with the +-100000 bonus
    unit_actions: int
    final_state: GameState
    decisions: list[list[SearchStats]] = field(default_factory=lambda: [[], []])
    seconds: float = 0.0


def as_player(p: str | Player) -> Player:
    return make_player(p) if isinstance(p, str) else p


def play_game_with_players(
    state: GameState,
    rules: Rules,
    player0: str | Player,
    player1: str | Player,
    seed: int = 0,
    *,
    max_turns: int | None = None,
) -> PlayedGame:
    """Play ``state`` to the end (terminal, or ``max_turns`` / ``rules.max_turns`` turns).

    Players are player objects or specs for :func:`make_player`; both are ``reset`` with seeds
    derived from ``seed`` (player 0: ``2 seed``, player 1: ``2 seed + 1``).
    """
    t_start = time.perf_counter()
    players = [as_player(player0), as_player(player1)]
    for i, pl in enumerate(players):
        pl.reset(2 * int(seed) + i)
    rk = K.rules_static(rules)
    turn = K.turn_fn(rk)
    apply = K.apply_fn(rk)
    cap = rules.max_turns if max_turns is None else min(int(max_turns), rules.max_turns)
    n = int(state.hp.shape[-1])
    decisions: list[list[SearchStats]] = [[], []]
    unit_actions = 0
    turns = 0
    while True:
        movers, _, over = turn(state, rules.walkable)
        movers = np.asarray(movers)
        if bool(over) or turns >= cap:
            break
        actions = np.zeros((2, n), np.int32)
        for p in (0, 1):
            if movers[p]:
                actions[p] = players[p].decide(state, rules, p)
                st = players[p].stats
                if st is not None:
                    decisions[p].append(st)
        state, issued = apply(state, actions, rules.walkable)
        unit_actions += int(issued)
        turns += 1
    winner, ev = K.result_fn()(state)
    return PlayedGame(
        winner=int(winner),
        final_time=int(state.time),
        turns=int(state.turn),
        hp=np.asarray(state.hp),
        ltd2_eval=int(ev),
        unit_actions=unit_actions,
        final_state=state,
        decisions=decisions,
        seconds=time.perf_counter() - t_start,
    )


def _spec_name(p: str | Player) -> str:
    return p if isinstance(p, str) else p.name


def _script_of(p: str | Player) -> str | None:
    """The script name if ``p`` is a scripted player (object or spec), else None."""
    pl = make_player(p) if isinstance(p, str) else p
    return pl.script if isinstance(pl, ScriptPlayer) else None


def run_player_battles(
    states: Sequence[Sequence[UnitSpec]],
    p0_spec: str | Player,
    p1_spec: str | Player,
    *,
    seed: int = 0,
    rules: Rules | None = None,
    progress: bool = True,
) -> BattleResults:
    """Play every start state once, ``p0_spec`` as player 0 and ``p1_spec`` as player 1.

    Specs are strings for :func:`make_player` (``"uct:time_ms=40"``, ``"nokdps"``, ...) or player
    objects. Game ``i`` is played with ``seed + i`` (see :func:`play_game_with_players`). States
    are padded to the largest side of any of them, so every game reuses one set of compiled
    programs. With ``progress`` a rich progress bar shows the running score and the mean decision
    time of each search player.
    """
    if not states:
        raise ValueError("no start states to play")
    rules = make_rules() if rules is None else rules
    s0, s1 = _script_of(p0_spec), _script_of(p1_spec)
    if s0 is not None and s1 is not None:
        # Script vs script: the engine's fully compiled batched series.
        return run_battles(states, s0, s1, seed=seed, rules=rules, progress=progress)
    players = [as_player(p0_spec), as_player(p1_spec)]
    stacked, _ = pad_states(states)
    n = len(states)
    winner = np.zeros(n, np.int64)
    final_time = np.zeros(n, np.int64)
    turns = np.zeros(n, np.int64)
    ltd2 = np.zeros(n, np.int64)
    actions = np.zeros(n, np.int64)
    unit_hp: list[list[int]] = []
    uid = np.asarray(stacked.uid)
    bar = _Bar(progress, n, f"{_spec_name(p0_spec)} vs {_spec_name(p1_spec)}")
    ms = [[], []]
    try:
        for i in range(n):
            st = jax.tree.map(lambda a, i=i: a[i], stacked)
            g = play_game_with_players(st, rules, players[0], players[1], seed=seed + i)
            winner[i], final_time[i], turns[i], ltd2[i], actions[i] = (
                g.winner,
                g.final_time,
                g.turns,
                g.ltd2_eval,
                g.unit_actions,
            )
            hp = np.zeros(len(states[i]), np.int64)
            u = uid[i].ravel()
            h = np.maximum(g.hp.ravel(), 0)
            keep = u < len(states[i])
            hp[u[keep]] = h[keep]
            unit_hp.append(hp.tolist())
            for p in (0, 1):
                ms[p] += [d.ms for d in g.decisions[p]]
            bar.update(winner[: i + 1], ms)
    finally:
        bar.stop()
    return BattleResults(
        p0=_spec_name(p0_spec),
        p1=_spec_name(p1_spec),
        winner=winner,
        final_time=final_time,
        turns=turns,
        unit_hp=unit_hp,
        ltd2_eval=ltd2,
        unit_actions=actions,
    )


class _Bar:
    """A rich progress bar with the running score and mean decision times."""

    def __init__(self, enabled: bool, total: int, label: str):
        self.prog = None
        if not enabled:
            return
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.prog = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[score]}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
        )
        self.prog.start()
        self.task = self.prog.add_task(label, total=total, score="")

    def update(self, winners: np.ndarray, ms: list[list[float]]) -> None:
        if self.prog is None:
            return
        w0, w1 = int((winners == 0).sum()), int((winners == 1).sum())
        d = len(winners) - w0 - w1
        times = " ".join(f"P{p} {np.mean(m):.1f} ms/dec" for p, m in enumerate(ms) if m)
        self.prog.update(self.task, advance=1, score=f"P0 {w0} / P1 {w1} / draw {d}  {times}")

    def stop(self) -> None:
        if self.prog is not None:
            self.prog.stop()
