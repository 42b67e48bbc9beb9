"""Observations and critic features of the combat environment (layouts in
:mod:`hybridmarl.envs.combat`)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jax import lax

from hybridmarl.engine import rules as R
from hybridmarl.engine import units as UT
from hybridmarl.engine.state import MOVE, GameState
from hybridmarl.envs.combat.state import INT32_MAX
from hybridmarl.envs.combat.view import View

__all__ = [
    "CRITIC_SIDE_FIELDS",
    "HP_SCALE",
    "K_ALLIES",
    "K_ENEMIES",
    "POS_SCALE",
    "SELF_FIELDS",
    "TIME_SCALE",
    "UNIT_FIELDS",
    "critic_features",
    "obs_slice",
    "observe",
]

#: Section 5.1: "the ten closest allied units and ten closest enemy units".
K_ALLIES = 10
K_ENEMIES = 10
POS_SCALE = 256.0
HP_SCALE = 100.0
TIME_SCALE = 32.0
_MAX_WAIT = 64  # frames; remaining times are clipped here before scaling

SELF_FIELDS: tuple[str, ...] = (
    "alive",
    "x",
    "y",
    "hp_frac",
    "hp",
    "move_wait",
    "attack_wait",
    "moving",
    "can_fire",
    "acting",
    "range",
    "move_len",
    "allies_alive",
    "enemies_alive",
) + tuple(f"type_{name}" for name in UT.TYPE_NAMES)

UNIT_FIELDS: tuple[str, ...] = (
    "alive",
    "hp_frac",
    "hp",
    "move_wait",
    "attack_wait",
    "moving",
    "range",
    "hp_rank",
    "dx",
    "dy",
    "dist",
    "in_my_range",
    "in_its_range",
    "ready",
)

CRITIC_SIDE_FIELDS: tuple[str, ...] = (
    "alive_frac",
    "hp_mean",
    "hp_var",
    "hp_min",
    "hp_max",
    "cooldown_mean",
    "cooldown_var",
    "cooldown_min",
    "cooldown_max",
    "x_mean",
    "x_var",
    "x_min",
    "x_max",
    "y_mean",
    "y_var",
    "y_min",
    "y_max",
)


_D2_CAP = (1 << (31 - R.SLOT_BITS)) - 1  # squared distances packed with a slot must fit int32


def _materialise(tree: Any, guard: jax.Array) -> Any:
    """Identity on ``tree`` that XLA cannot fuse through.

    XLA:CPU fuses cheap producers into their consumers and recomputes them per consumer
    element; for a reduction that reads each input element U times (the rank counts below) that
    turns O(U^2) work into O(U^3). ``lax.optimization_barrier`` would stop it but is removed on
    CPU before fusion, so the values go through a while loop whose condition (``guard < 0``,
    false for a frame counter) is false at run time but unknown at compile time: zero
    iterations, and its result is a materialised buffer. (The never-run body changes every
    value, so XLA cannot forward the loop's input to its output either.)"""

    def bump(x: jax.Array) -> jax.Array:
        return ~x if x.dtype == jnp.bool_ else x + jnp.ones((), x.dtype)

    def body(c: tuple[jax.Array, Any]) -> tuple[jax.Array, Any]:
        return c[0] + 1, jax.tree.map(bump, c[1])

    return lax.while_loop(lambda c: jnp.any(c[0] < 0), body, (guard, tree))[1]


def _unit_table(game: GameState, ctx: R.TurnContext, view: View, num_enemies: int) -> jax.Array:
    """float32 [2, U, 8]: the per-unit fields ``UNIT_FIELDS[:8]`` of every slot."""
    t = game.time
    f32 = jnp.float32
    max_hp = jnp.asarray(UT.TABLES.max_hp)[game.utype].astype(f32)
    hp = jnp.maximum(game.hp, 0).astype(f32)
    range_px = jnp.sqrt(jnp.asarray(UT.TABLES.range_sq)[game.utype].astype(f32))
    rank = jnp.stack(
        [
            jnp.zeros((game.hp.shape[-1],), f32),
            (view.rank_of_slot + 1).astype(f32) / num_enemies,
        ]
    )
    cols = [
        ctx.alive.astype(f32),
        hp / jnp.maximum(max_hp, 1.0),
        hp / HP_SCALE,
        jnp.clip(game.t_move - t, 0, _MAX_WAIT).astype(f32) / TIME_SCALE,
        jnp.clip(game.t_attack - t, 0, _MAX_WAIT).astype(f32) / TIME_SCALE,
        ((game.last == MOVE) & (t < game.t_move)).astype(f32),
        range_px / POS_SCALE,
        rank,
    ]
    return jnp.stack(cols, axis=-1)


def observe(
    game: GameState,
    view: View,
    *,
    num_agents: int,
    num_enemies: int,
    k_allies: int = K_ALLIES,
    k_enemies: int = K_ENEMIES,
    map_px: tuple[int, int],
) -> jax.Array:
    """float32 ``[n0, 21 + 14 * (k_allies + k_enemies)]``: every agent's observation of ``game``
    (``view`` is ``make_view(game, rules)``); ``map_px`` is the map's (width, height)."""
    # Materialise the turn context first: XLA would otherwise fuse (recompute) pieces of it,
    # such as the interpolated positions, into every consumer below, including the
    # O(U^3) rank reductions.
    game, view = _materialise((game, view), game.time)
    ctx = view.ctx
    n0, u, m = num_agents, game.hp.shape[-1], num_enemies
    f32 = jnp.float32
    table = _unit_table(game, ctx, view, m)  # [2, U, 8]
    range_sq = jnp.asarray(UT.TABLES.range_sq)[game.utype]
    alive = ctx.alive
    me = jnp.arange(n0)
    slot = jnp.arange(u, dtype=jnp.int32)
    cx, cy = ctx.cx, ctx.cy

    # Own block: the shared per-unit fields, then the rest in SELF_FIELDS order.
    width, height = map_px
    mine = table[0, :n0]
    n_allies = jnp.sum(alive[0]) - alive[0, :n0]
    n_enemies = jnp.sum(alive[1])
    own_arr = jnp.concatenate(
        [
            jnp.stack(
                [
                    mine[:, 0],
                    cx[0, :n0].astype(f32) / width,
                    cy[0, :n0].astype(f32) / height,
                    mine[:, 1],
                    mine[:, 2],
                    mine[:, 3],
                    mine[:, 4],
                    mine[:, 5],
                    ctx.can_attack_now[0, :n0].astype(f32),
                    ctx.acting[0, :n0].astype(f32),
                    mine[:, 6],
                    ctx.move_dist[0, :n0].astype(f32) / UT.MOVE_DISTANCE,
                    n_allies.astype(f32) / max(n0 - 1, 1),
                    jnp.broadcast_to(n_enemies.astype(f32) / m, (n0,)),
                ],
                axis=-1,
            ),
            jax.nn.one_hot(game.utype[0, :n0], UT.NUM_TYPES, dtype=f32),
        ],
        axis=-1,
    )

    can_fire = (ctx.can_attack_now[0, :n0] & ctx.acting[0, :n0]).astype(f32)
    # Per-unit columns gathered once per selected unit: the 8 shared fields, then the
    # position and squared weapon range the pair fields need.
    ext = jnp.concatenate(
        [
            table,
            jnp.stack([cx, cy, range_sq], axis=-1).astype(f32),  # exact: all < 2^24
            ctx.acting[..., None].astype(f32),
        ],
        axis=-1,
    )  # [2, U, 12]

    # Packed (squared distance, slot) keys of the candidates; materialised, so the rank
    # reductions below read them instead of recomputing distances per comparison.
    ax = cx[0, :n0, None] - cx[0][None, :]
    ay = cy[0, :n0, None] - cy[0][None, :]
    d2_allies = ax * ax + ay * ay
    cand = (
        alive[0][None, :] & (slot[None, :] != me[:, None]),
        jnp.broadcast_to(alive[1][None, :], (n0, u)),
    )
    keys = tuple(
        jnp.where(c, (jnp.minimum(d2, _D2_CAP) << R.SLOT_BITS) | slot[None, :], INT32_MAX)
        for c, d2 in zip(cand, (d2_allies, ctx.d2[:n0]), strict=True)
    )
    keys = _materialise(keys, game.time)

    def select(key: jax.Array, c: jax.Array, k: int) -> tuple[jax.Array, jax.Array]:
        """Slots [n0, k] of the k closest candidates, nearest first, and their validity.

        No sort (XLA's CPU sort of many short rows is slow): a candidate's rank is the
        number of candidates with a smaller key, and the k-th closest slot is read off the
        rank == k one-hot."""
        rank = jnp.sum(key[:, :, None] < key[:, None, :], axis=1)  # [n0, U]
        ks = jnp.arange(k, dtype=jnp.int32)
        hit = (rank[:, None, :] == ks[None, :, None]) & c[:, None, :]  # [n0, k, U]
        j = jnp.sum(jnp.where(hit, slot[None, None, :], 0), axis=-1)
        valid = ks[None, :] < jnp.sum(c, axis=-1, keepdims=True)
        return j, valid

    sel = _materialise(
        (select(keys[0], cand[0], k_allies), select(keys[1], cand[1], k_enemies)),
        game.time,
    )
    gathered = _materialise(
        tuple(ext[q][sel[q][0]] for q in (0, 1)), game.time
    )  # [n0, k, 12] per side

    my_x = cx[0, :n0, None].astype(f32)
    my_y = cy[0, :n0, None].astype(f32)
    my_r2 = range_sq[0, :n0, None].astype(f32)
    outs = []
    for q in (0, 1):
        g_ = gathered[q]
        valid = sel[q][1] & alive[0, :n0, None]  # a dead agent's observation is all zero
        dx = g_[..., 8] - my_x
        dy = g_[..., 9] - my_y
        d2 = dx * dx + dy * dy  # exact in float32: integers < 2^24
        in_mine = (d2 <= my_r2).astype(f32)
        ready = in_mine * can_fire[:, None] if q == 1 else g_[..., 11]
        block = jnp.concatenate(
            [
                g_[..., :8],
                jnp.stack(
                    [
                        dx / POS_SCALE,
                        dy / POS_SCALE,
                        jnp.sqrt(d2) / POS_SCALE,
                        in_mine,
                        (d2 <= g_[..., 10]).astype(f32),
                        ready,
                    ],
                    axis=-1,
                ),
            ],
            axis=-1,
        )
        outs.append((block * valid[..., None]).reshape(n0, -1))
    own_arr = own_arr * alive[0, :n0, None]
    return jnp.concatenate([own_arr, *outs], axis=-1)


def obs_slice(
    part: str,
    index: int = 0,
    field: str | None = None,
    *,
    k_allies: int = K_ALLIES,
    k_enemies: int = K_ENEMIES,
) -> slice | int:
    """Where ``field`` of the ``index``-th ``part`` ("self", "ally", "enemy") block sits in an
    observation (a slice over the whole block if ``field`` is None)."""
    self_size, unit_size = len(SELF_FIELDS), len(UNIT_FIELDS)
    if part == "self":
        names, start = SELF_FIELDS, 0
    elif part in ("ally", "enemy"):
        names = UNIT_FIELDS
        k = k_allies if part == "ally" else k_enemies
        if not 0 <= index < k:
            raise IndexError(f"{part} block {index} out of range 0..{k - 1}")
        base = self_size + (0 if part == "ally" else unit_size * k_allies)
        start = base + unit_size * index
    else:
        raise ValueError(f"part must be 'self', 'ally' or 'enemy', got {part!r}")
    if field is None:
        return slice(start, start + len(names))
    return start + names.index(field)


def critic_features(g: GameState, num_agents: int, num_enemies: int) -> jax.Array:
    """float32 ``[35]`` statistics of both sides of ``g`` (layout in :mod:`hybridmarl.envs.combat`)."""
    cx, cy = R.current_positions(g, g.time)
    alive = g.hp > 0
    sizes = (num_agents, num_enemies)
    values = {
        "hp": jnp.maximum(g.hp, 0).astype(jnp.float32) / HP_SCALE,
        "cooldown": jnp.clip(g.t_attack - g.time, 0, None).astype(jnp.float32) / TIME_SCALE,
        "x": cx.astype(jnp.float32) / POS_SCALE,
        "y": cy.astype(jnp.float32) / POS_SCALE,
    }
    feats = []
    centroids = []
    for p in (0, 1):
        mask = alive[p]
        n = jnp.sum(mask)
        nf = jnp.maximum(n, 1).astype(jnp.float32)
        any_ = n > 0
        feats.append((n.astype(jnp.float32) / sizes[p])[None])
        for name in ("hp", "cooldown", "x", "y"):
            v = values[name][p]
            mean = jnp.sum(jnp.where(mask, v, 0.0)) / nf
            var = jnp.sum(jnp.where(mask, (v - mean) ** 2, 0.0)) / nf
            vmin = jnp.where(any_, jnp.min(jnp.where(mask, v, jnp.inf)), 0.0)
            vmax = jnp.where(any_, jnp.max(jnp.where(mask, v, -jnp.inf)), 0.0)
            feats.append(jnp.stack([mean, var, vmin, vmax]))
            if name in ("x", "y"):
                centroids.append(mean)
    both = (jnp.sum(alive[0]) > 0) & (jnp.sum(alive[1]) > 0)
    dist = jnp.sqrt((centroids[0] - centroids[2]) ** 2 + (centroids[1] - centroids[3]) ** 2)
    feats.append(jnp.where(both, dist, 0.0)[None])
    return jnp.concatenate(feats).astype(jnp.float32)
