"""SparCraft's search players: UCT-CD, ABCD and Portfolio Greedy Search, on the native CPU
engine or the JAX engine (player option ``engine=auto|native|jax``; docs/baselines.md#engine-option).

>>> from hybridmarl.search import make_player, run_player_battles
>>> from hybridmarl.engine.scenarios import named_scenario
>>> states = named_scenario("m5v5").generate(10, seed=0)
>>> res = run_player_battles(states, "uct:time_ms=40", "attack-weakest", progress=False)  # doctest: +SKIP

Modules: ``base`` (player interface, options and spec grammar), ``factory`` (``make_player``),
``uct``, ``abcd``, ``pgs`` (the algorithms, each documenting its deviations from SparCraft),
``moves`` (SparCraft's child generation), ``kernels`` (the compiled JAX engine calls), ``native``
(the same calls on the native engine, ``engine.native.search``) and ``runner`` (host-loop games
and battle series).
"""

from hybridmarl.search.abcd import ABCDPlayer
from hybridmarl.search.base import (
    ABCD_OPTIONS,
    PGS_OPTIONS,
    UCT_OPTIONS,
    Player,
    ScriptPlayer,
    SearchPlayer,
    SearchStats,
    describe_options,
    parse_spec,
)
from hybridmarl.search.factory import make_player
from hybridmarl.search.pgs import PGSPlayer
from hybridmarl.search.runner import PlayedGame, play_game_with_players, run_player_battles
from hybridmarl.search.uct import UCTPlayer

__all__ = [
    "ABCD_OPTIONS",
    "ABCDPlayer",
    "PGS_OPTIONS",
    "PGSPlayer",
    "PlayedGame",
    "Player",
    "ScriptPlayer",
    "SearchPlayer",
    "SearchStats",
    "UCT_OPTIONS",
    "UCTPlayer",
    "describe_options",
    "make_player",
    "parse_spec",
    "play_game_with_players",
    "run_player_battles",
]
