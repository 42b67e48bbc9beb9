"""Compiled engine calls used by the search players, and the packed state they exchange.

A search keeps many game states on the host (one per tree node). Moving a ``GameState`` pytree of
17 device arrays in and out of a jitted call costs one transfer per leaf, so the search works on a
**packed** state instead: the nine per-unit fields that change during a game plus five scalars,
flattened into one ``int32`` vector (``L = 18 U + 5``). The fields that never change within a game
(unit types, ids, LTD/LTD2 denominators) travel separately as :class:`Consts`. A batch of nodes is
then one ``[K, L]`` array in and one out.

Every function here is compiled once per static configuration (unit slots ``U``, batch ``K``,
script names, static rules) and cached (``functools.lru_cache`` around ``jax.jit``), so a search
never recompiles between decisions or games of the same shape. Callers pad every batch to a
fixed size, and the playout cap and LTD/LTD2 choice are runtime arguments, so UCT and ABCD need
one program per batch size (``K = 1`` and ``K = batch``; ABCD also ``K = max_children``).

The kernels:

- :func:`search_fn`: apply a batch of joint actions to a batch of base states (``makeMoves`` for
  the sides selected by a mask, then ``finishedMoving``), then return each child's *node info*
  (what the host needs to expand it: who moves, which units act, the legal actions, SparCraft's
  unit order, the ordering scripts' moves for both sides, whether it is terminal, ``eval(p,
  LTD2)`` for both sides, a hash key for AB's transposition table) and its leaf evaluation
  (``GameState::eval`` with ``Playout``, ``LTD2`` or ``LTD``; a playout cap of 0 skips the
  playout, which is how node expansion and the root's info use the same program).
- :func:`pgs_fn`: Portfolio Greedy Search playouts where every unit follows its own script
  (``Game::playIndividualScripts``), scored by ``eval(player, LTD2)`` of the final state.

The native engine's counterparts (``engine.native.search``, called through ``search.native``)
return the same arrays; LTD / LTD2 here are :func:`ltd_scores`, summed unit by unit as the
native kernels sum them.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.engine import rules as R
from hybridmarl.engine import units as U
from hybridmarl.engine.scripts import Script, get_script
from hybridmarl.engine.state import GameState, Rules

#: Per-unit fields that change during a game, in packed order ([2, U] each).
DYNAMIC_FIELDS = ("x", "y", "px", "py", "t_act", "last", "hp", "t_move", "t_attack")
NUM_SCALARS = 5  # time, turn, stale, prev_hp_sum[0], prev_hp_sum[1]

#: SparCraft's ``GameState::evalSim`` playout cap (decision turns).
PLAYOUT_TURNS = 200
#: Portfolio Greedy Search playout cap; ``playIndividualScripts`` breaks when rounds > 100.
PGS_PLAYOUT_TURNS = 100

EVAL_METHODS = ("playout", "ltd2", "ltd")


def packed_len(num_slots: int) -> int:
    return len(DYNAMIC_FIELDS) * 2 * num_slots + NUM_SCALARS


@dataclass(frozen=True)
class Consts:
    """The parts of a state that stay fixed during a game (host NumPy arrays)."""

    utype: np.ndarray  # int32 [2, U]
    uid: np.ndarray  # int32 [2, U]
    ltd_total: np.ndarray  # float32 [2]
    ltd2_total: np.ndarray  # float32 [2]

    @property
    def num_slots(self) -> int:
        return int(self.utype.shape[-1])

    def as_args(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return (self.utype, self.uid, self.ltd_total, self.ltd2_total)


def _pack(state: GameState) -> jax.Array:
    parts = [getattr(state, f).reshape(-1) for f in DYNAMIC_FIELDS]
    scalars = jnp.stack(
        [state.time, state.turn, state.stale, state.prev_hp_sum[0], state.prev_hp_sum[1]]
    )
    return jnp.concatenate(parts + [scalars.astype(jnp.int32)]).astype(jnp.int32)


@jax.jit
def _pack_jit(state: GameState) -> jax.Array:
    return _pack(state)


def pack_state(state: GameState) -> tuple[np.ndarray, Consts]:
    """Host packed vector and constants of one (unbatched) state; one device round trip."""
    vec = np.asarray(_pack_jit(state))
    consts = Consts(
        utype=np.asarray(state.utype, np.int32),
        uid=np.asarray(state.uid, np.int32),
        ltd_total=np.asarray(state.ltd_total, np.float32),
        ltd2_total=np.asarray(state.ltd2_total, np.float32),
    )
    return vec, consts


def unpack(
    vec: jax.Array, utype: jax.Array, uid: jax.Array, ltd_total: jax.Array, ltd2_total: jax.Array
) -> GameState:
    """The ``GameState`` of a packed vector (inside jit)."""
    n = utype.shape[-1]
    size = 2 * n
    fields: dict[str, Any] = {}
    for i, f in enumerate(DYNAMIC_FIELDS):
        fields[f] = vec[i * size : (i + 1) * size].reshape(2, n)
    base = len(DYNAMIC_FIELDS) * size
    return GameState(
        utype=utype,
        uid=uid,
        time=vec[base],
        turn=vec[base + 1],
        stale=vec[base + 2],
        prev_hp_sum=vec[base + 3 : base + 5],
        ltd_total=ltd_total,
        ltd2_total=ltd2_total,
        **fields,
    )


def unpack_host(vec: np.ndarray, consts: Consts) -> GameState:
    """A device ``GameState`` from a host packed vector (for callers outside the search)."""
    st = unpack(jnp.asarray(vec), *(jnp.asarray(a) for a in consts.as_args()))
    return st


def _rules(walkable: jax.Array, rules_static: tuple) -> Rules:
    stalemate_limit, overkill, max_turns = rules_static
    return Rules(walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=max_turns)


def rules_static(rules: Rules) -> tuple:
    return (rules.stalemate_limit, rules.overkill, rules.max_turns)


def _scripts(names: tuple[str, ...]) -> tuple[Script, ...]:
    return tuple(get_script(n) for n in names)


def _is_move(codes: jax.Array) -> jax.Array:
    return (codes >= R.MOVE_ACTIONS[0]) & (codes <= R.MOVE_ACTIONS[-1])


# ----------------------------------------------------------------------------- evaluation


def ltd_scores(state: GameState, use_ltd: bool | jax.Array) -> jax.Array:
    """int32 [2]: LTD2 (or, with ``use_ltd``, LTD) of both sides as ``rules.ltd2`` / ``rules.ltd``
    compute them, but with each side's float32 sum taken unit by unit in slot order (SparCraft
    sums unit by unit; XLA's reduction may add the terms in another order, which moves
    ``int(1000 * sum / total)`` by one now and then). The native search kernels
    (``engine.native.search``) sum in the same order, so both engines give equal values."""
    dpf = jnp.asarray(U.TABLES.dpf)[state.utype]
    alive = state.hp > 0
    hpf = jnp.maximum(state.hp, 0).astype(jnp.float32)
    term = jnp.where(use_ltd, hpf, jnp.sqrt(hpf)) * dpf
    term = jnp.where(alive, term, jnp.float32(0.0))
    acc = jnp.zeros(2, jnp.float32)
    for u in range(state.hp.shape[-1]):
        acc = acc + term[:, u]
    totals = jnp.where(use_ltd, state.ltd_total, state.ltd2_total)
    val = (1000.0 * acc / jnp.where(totals > 0, totals, 1.0)).astype(jnp.int32)
    return jnp.where(alive.any(axis=1) & (totals > 0), val, 0)


def evaluate(state: GameState, p: int | jax.Array, use_ltd: bool | jax.Array = False) -> jax.Array:
    """``rules.evaluate(state, p)`` (score difference, +-100000 if exactly one side is dead, 0 if
    both are) with the scores of :func:`ltd_scores`."""
    score = ltd_scores(state, use_ltd)
    dead = R.player_dead(state)
    mine = jnp.where(p == 0, score[0] - score[1], score[1] - score[0])
    me_dead = jnp.where(p == 0, dead[0], dead[1])
    en_dead = jnp.where(p == 0, dead[1], dead[0])
    bonus = jnp.where(en_dead & ~me_dead, 100000, jnp.where(me_dead & ~en_dead, -100000, 0))
    return jnp.where(dead.all(), 0, mine + bonus).astype(jnp.int32)


# ----------------------------------------------------------------------------- node info


def _state_info(
    key: jax.Array, state: GameState, rules: Rules, scripts: tuple[Script, ...]
) -> dict[str, jax.Array]:
    ctx = R.turn_context(state, rules)
    legal = jnp.stack([R.legal_actions(ctx, 0), R.legal_actions(ctx, 1)])
    n = state.hp.shape[-1]
    if scripts:
        k0, k1 = jax.random.split(key)
        smoves = jnp.stack(
            [
                jnp.stack(
                    [
                        s(jax.random.fold_in(k0, i), state, ctx, 0),
                        s(jax.random.fold_in(k1, i), state, ctx, 1),
                    ]
                )
                for i, s in enumerate(scripts)
            ]
        )
    else:
        smoves = jnp.zeros((0, 2, n), jnp.int32)
    ev = jnp.stack([evaluate(state, 0), evaluate(state, 1)])
    # Transposition-table key material (``Unit::calculateHash``): living units in SparCraft's
    # sorted order, each with current position, relative timers, HP and type; dead units zero.
    idx = jnp.argsort(ctx.order, axis=1)
    mat = jnp.stack(
        [
            ctx.cx,
            ctx.cy,
            state.t_attack - state.time,
            state.t_move - state.time,
            state.hp,
            state.utype,
        ],
        axis=-1,
    )
    mat = jnp.where(ctx.alive[..., None], mat, 0)
    mat = jnp.take_along_axis(mat, idx[..., None], axis=1)
    return {
        "movers": ctx.movers,
        "acting": ctx.acting,
        "legal": legal,
        "order": ctx.order,
        "scripts": smoves.astype(jnp.int32),
        "terminal": R.is_terminal(state, rules),
        "ev": ev,
        "hash": mat.astype(jnp.int32),
    }


# ----------------------------------------------------------------------------- playouts


def _script_playout(
    key: jax.Array,
    state: GameState,
    rules: Rules,
    s0: Script,
    s1: Script,
    cap: int | jax.Array,
    player: jax.Array,
    use_key: bool,
) -> tuple[GameState, jax.Array]:
    """``Game(state, s0, s1, cap).play()``: script vs script until terminal or ``cap`` turns.
    Returns the final state and the number of MOVE actions made by ``player``."""

    def cond(c):
        s, k, _, _ = c
        return (~R.is_terminal(s, rules)) & (k < cap)

    def body(c):
        s, k, kk, m = c
        if use_key:
            kk, a, b = jax.random.split(kk, 3)
        else:
            a = b = kk
        ctx = R.turn_context(s, rules)
        acts = jnp.stack([s0(a, s, ctx, 0), s1(b, s, ctx, 1)])
        mine = jnp.where(player == 0, acts[0], acts[1])
        mine_acting = jnp.where(player == 0, ctx.acting[0], ctx.acting[1])
        m = m + jnp.sum(mine_acting & _is_move(mine)).astype(jnp.int32)
        return R.apply_actions(s, ctx, acts, rules), k + 1, kk, m

    final, _, _, moves = jax.lax.while_loop(cond, body, (state, jnp.int32(0), key, jnp.int32(0)))
    return final, moves


def _leaf_value(
    key: jax.Array,
    state: GameState,
    rules: Rules,
    player: jax.Array,
    cap: jax.Array,
    use_ltd: jax.Array,
    playout_scripts: tuple[Script, Script],
    use_key: bool,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``GameState::eval(player, method)``: (value, MOVE count of ``player`` in the playout,
    both sides dead).

    ``Playout`` is a script playout of at most ``cap`` turns scored by evalLTD2 of its final state;
    ``LTD2`` / ``LTD`` are ``cap = 0`` (the state itself) with ``use_ltd`` choosing the score. The
    +-100000 bonus looks at the state being evaluated (docs/engine.md#evaluation-ltd-and-ltd2); 0 when both are dead."""
    dead = R.player_dead(state)
    me_dead = jnp.where(player == 0, dead[0], dead[1])
    en_dead = jnp.where(player == 0, dead[1], dead[0])
    bonus = jnp.where(en_dead & ~me_dead, 100000, jnp.where(me_dead & ~en_dead, -100000, 0))
    final, moves = _script_playout(
        key, state, rules, playout_scripts[0], playout_scripts[1], cap, player, use_key
    )
    score = ltd_scores(final, use_ltd)
    diff = jnp.where(player == 0, score[0] - score[1], score[1] - score[0])
    value = jnp.where(dead.all(), 0, diff + bonus).astype(jnp.int32)
    return value, jnp.where(dead.all(), 0, moves).astype(jnp.int32), dead.all()


# ----------------------------------------------------------------------------- cached kernels


@functools.lru_cache(maxsize=128)
def search_fn(
    num_slots: int,
    batch: int,
    info_scripts: tuple[str, ...],
    playout_scripts: tuple[str, str],
    rules_key: tuple,
) -> Callable:
    """The one compiled program of UCT and ABCD (and PGS's root info), per batch size ``K``.

    Jitted ``(key, base [K, L], actions [K, 2, U], mask [K, 2], do_step [K], player [K], cap [],
    use_ltd [], utype, uid, ltd, ltd2, walkable) -> dict`` of host-bound arrays:

    - ``child`` [K, L]: each base state after the joint ``actions`` (``makeMoves`` for the sides
      selected by ``mask``, then ``finishedMoving``), or the base itself where ``do_step`` is
      False. Masking one side reproduces SparCraft's leaf FirstSim node, which applies only the
      first mover's vector (the other side's acting units do nothing this turn).
    - ``step_moves`` [K, 2]: MOVE actions applied per side;
    - ``info``: :func:`_state_info` of each child (``info_scripts``' moves for both sides);
    - ``value``, ``playout_moves``, ``both_dead`` [K]: ``eval(player, ...)`` of each child by a
      playout of at most ``cap`` turns (``cap`` 0: no playout, i.e. LTD2 / LTD of the child).

    ``cap`` and ``use_ltd`` are runtime values, so node expansion (``cap`` 0) and leaf evaluation
    share one program; only the batch size ``K`` makes a new one.
    """
    del num_slots, batch  # part of the cache key only: one compiled program per shape
    info_fns = _scripts(info_scripts)
    pfns = _scripts(playout_scripts)
    pair = (pfns[0], pfns[1])
    use_key = "random" in playout_scripts

    def one(
        key, vec, actions, mask, do_step, player, cap, use_ltd, utype, uid, ltd, ltd2, walkable
    ):
        rules = _rules(walkable, rules_key)
        state = unpack(vec, utype, uid, ltd, ltd2)
        ctx = R.turn_context(state, rules)
        acting = ctx.acting & mask[:, None] & do_step
        stepped = R.apply_actions(state, dataclasses.replace(ctx, acting=acting), actions, rules)
        child = jax.tree.map(lambda a, b: jnp.where(do_step, a, b), stepped, state)
        k_info, k_eval = jax.random.split(key)
        value, moves, both_dead = _leaf_value(
            k_eval, child, rules, player, cap, use_ltd, pair, use_key
        )
        return {
            "child": _pack(child),
            "step_moves": jnp.sum(acting & _is_move(actions), axis=1).astype(jnp.int32),
            "info": _state_info(k_info, child, rules, info_fns),
            "value": value,
            "playout_moves": moves,
            "both_dead": both_dead,
        }

    def run(
        key, vecs, actions, mask, do_step, player, cap, use_ltd, utype, uid, ltd, ltd2, walkable
    ):
        keys = jax.random.split(key, vecs.shape[0])
        return jax.vmap(one, in_axes=(0, 0, 0, 0, 0, 0, None, None, None, None, None, None, None))(
            keys,
            vecs,
            actions,
            mask,
            do_step,
            player,
            cap,
            use_ltd,
            utype,
            uid,
            ltd,
            ltd2,
            walkable,
        )

    return jax.jit(run)


@functools.lru_cache(maxsize=64)
def pgs_fn(
    num_slots: int, batch: int, scripts: tuple[str, ...], turns: int, rules_key: tuple
) -> Callable:
    """Jitted ``(key, base [L], assign [K, 2, U], player [K], utype, uid, ltd, ltd2, walkable) ->
    value [K]``: per-unit script playouts (``Game::playIndividualScripts``).

    Every turn each script in ``scripts`` is run for the whole side (so NOKDPS's overkill
    bookkeeping sees all of the side's acting units, as in ``UnitScriptData::calculateMoves``) and
    each unit takes the action of its own script ``assign[k, p, u]``. The loop runs while the
    state is not terminal and rounds <= ``turns`` (so up to ``turns + 1`` turns); the value is
    ``eval(player, LTD2)`` of the final state, win bonus included.
    """
    del num_slots, batch
    fns = _scripts(scripts)
    use_key = "random" in scripts

    def one(key, state, assign, player, rules):
        def cond(c):
            s, k, _ = c
            return (~R.is_terminal(s, rules)) & (k <= turns)

        def body(c):
            s, k, kk = c
            if use_key:
                kk, sub = jax.random.split(kk)
            else:
                sub = kk
            ctx = R.turn_context(s, rules)
            keys = jax.random.split(sub, 2 * len(fns)) if use_key else [sub] * (2 * len(fns))
            per_script = jnp.stack(
                [
                    jnp.stack([f(keys[2 * i], s, ctx, 0), f(keys[2 * i + 1], s, ctx, 1)])
                    for i, f in enumerate(fns)
                ]
            )  # [S, 2, U]
            acts = jnp.take_along_axis(per_script, assign[None], axis=0)[0]
            return R.apply_actions(s, ctx, acts, rules), k + 1, kk

        final, _, _ = jax.lax.while_loop(cond, body, (state, jnp.int32(0), key))
        return evaluate(final, player)

    def run(key, vec, assign, player, utype, uid, ltd, ltd2, walkable):
        rules = _rules(walkable, rules_key)
        state = unpack(vec, utype, uid, ltd, ltd2)
        keys = jax.random.split(key, assign.shape[0])
        return jax.vmap(one, in_axes=(0, None, 0, 0, None))(keys, state, assign, player, rules)

    return jax.jit(run)


# ----------------------------------------------------------------------------- game-loop helpers


@functools.lru_cache(maxsize=16)
def turn_fn(rules_key: tuple) -> Callable:
    """Jitted ``(state, walkable) -> (movers [2], acting [2, U], game over)`` for the host loop."""

    def run(state, walkable):
        rules = _rules(walkable, rules_key)
        ctx = R.turn_context(state, rules)
        return ctx.movers, ctx.acting, R.game_over(state, rules)

    return jax.jit(run)


@functools.lru_cache(maxsize=16)
def apply_fn(rules_key: tuple) -> Callable:
    """Jitted ``(state, actions [2, U], walkable) -> (next state, unit actions issued)``."""

    def run(state, actions, walkable):
        rules = _rules(walkable, rules_key)
        ctx = R.turn_context(state, rules)
        return R.apply_actions(state, ctx, actions, rules), jnp.sum(ctx.acting).astype(jnp.int32)

    return jax.jit(run)


@functools.lru_cache(maxsize=64)
def script_fn(name: str, rules_key: tuple) -> Callable:
    """Jitted ``(key, state, walkable) -> int32 [2, U]``: the script's decision for both sides
    (one program per script rather than one per side)."""
    script = get_script(name)

    def run(key, state, walkable):
        rules = _rules(walkable, rules_key)
        ctx = R.turn_context(state, rules)
        k0, k1 = jax.random.split(key)
        return jnp.stack([script(k0, state, ctx, 0), script(k1, state, ctx, 1)])

    return jax.jit(run)


@functools.lru_cache(maxsize=16)
def result_fn() -> Callable:
    """Jitted ``state -> (winner, eval(P0, LTD2))``."""

    def run(state):
        return R.winner(state), R.evaluate(state, 0, "ltd2")

    return jax.jit(run)


__all__ = [
    "EVAL_METHODS",
    "PGS_PLAYOUT_TURNS",
    "PLAYOUT_TURNS",
    "Consts",
    "apply_fn",
    "pack_state",
    "packed_len",
    "pgs_fn",
    "rules_static",
    "result_fn",
    "script_fn",
    "search_fn",
    "turn_fn",
    "unpack",
    "unpack_host",
]
