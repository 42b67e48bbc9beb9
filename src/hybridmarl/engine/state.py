"""Game state: an immutable pytree of per-unit arrays, and the static rules it is played under.

Layout: every per-unit array has shape ``[2, U]``: row ``p`` holds player ``p``'s units in
ascending SparCraft unit id, padded to ``U = max(n0, n1)`` with units that are dead from the start
(``hp == 0``). Padding keeps shapes fixed per scenario, so a batch of games is one array program.

Unit ids follow SparCraft: a unit's id is its position in the unit list it was built from
(``GameState::addUnit``). Ids break ties in SparCraft's unit ordering and scripts.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
from flax import struct

from hybridmarl.engine import units as U

# Previous-action kinds (decide the timing of the next ATTACK and whether a unit is mid-move).
NONE, ATTACK, RELOAD, MOVE, PASS = 0, 1, 2, 3, 4

#: Map size used by SparCraft's SearchExperiment: Map(40, 22) build tiles = 160 x 88 walk tiles.
DEFAULT_MAP_WIDTH_PX = 1280
DEFAULT_MAP_HEIGHT_PX = 704
WALK_TILE = 8

#: Padding units get ids from here up, so they sort after every real unit.
PAD_ID_BASE = 1 << 12


@struct.dataclass
class GameState:
    """One SparCraft game state (or a batch of them, with a leading batch axis on every leaf)."""

    utype: jnp.ndarray  # int32 [2, U] unit type index (see units.UNIT_TYPES)
    uid: jnp.ndarray  # int32 [2, U] SparCraft unit id
    x: jnp.ndarray  # int32 [2, U] stored position = destination of the last move
    y: jnp.ndarray  # int32 [2, U]
    px: jnp.ndarray  # int32 [2, U] position before the last move (for interpolation)
    py: jnp.ndarray  # int32 [2, U]
    t_act: jnp.ndarray  # int32 [2, U] frame of the unit's previous action
    last: jnp.ndarray  # int32 [2, U] kind of the previous action (NONE/ATTACK/RELOAD/MOVE/PASS)
    hp: jnp.ndarray  # int32 [2, U] current HP+shields, 0 = dead
    t_move: jnp.ndarray  # int32 [2, U] timeCanMove (absolute frame)
    t_attack: jnp.ndarray  # int32 [2, U] timeCanAttack (absolute frame)
    time: jnp.ndarray  # int32 [] current frame
    turn: jnp.ndarray  # int32 [] decision turns played
    stale: jnp.ndarray  # int32 [] consecutive turns with no HP change
    prev_hp_sum: jnp.ndarray  # int32 [2]
    ltd_total: jnp.ndarray  # float32 [2]  sum maxHP*dpf   (LTD denominators)
    ltd2_total: jnp.ndarray  # float32 [2] sum sqrt(maxHP)*dpf (LTD2 denominators)

    @property
    def num_slots(self) -> int:
        return int(self.hp.shape[-1])


@struct.dataclass
class Rules:
    """How a game is played: the map (a pytree leaf) and static settings (part of the jit key)."""

    walkable: jnp.ndarray  # bool [H_tiles, W_tiles], True = walkable
    stalemate_limit: int = struct.field(pytree_node=False, default=50)
    overkill: str = struct.field(pytree_node=False, default="pass")  # "pass" (HEAD) | "classic"
    max_turns: int = struct.field(pytree_node=False, default=20000)


def default_walkable(
    width_px: int = DEFAULT_MAP_WIDTH_PX, height_px: int = DEFAULT_MAP_HEIGHT_PX
) -> np.ndarray:
    return np.ones((height_px // WALK_TILE, width_px // WALK_TILE), dtype=bool)


def make_rules(
    walkable: np.ndarray | None = None,
    *,
    stalemate_limit: int = 50,
    overkill: str = "pass",
    max_turns: int = 20000,
) -> Rules:
    """Rules with SparCraft DC-HEAD defaults: 1280x704 all-walkable map, stalemate after >50 turns
    with no HP change, an attack on a target killed earlier in the turn becomes a PASS, and the
    SearchExperiment turn cap of 20,000 (docs/engine.md#game-end)."""
    if overkill not in ("pass", "classic"):
        raise ValueError(f"overkill must be 'pass' or 'classic', got {overkill!r}")
    grid = default_walkable() if walkable is None else np.asarray(walkable, dtype=bool)
    if grid.ndim != 2 or grid.size == 0:
        raise ValueError("walkable map must be a non-empty 2-D grid of walk tiles")
    return Rules(
        walkable=jnp.asarray(grid),
        stalemate_limit=int(stalemate_limit),
        overkill=overkill,
        max_turns=int(max_turns),
    )


def parse_ascii_map(text: str) -> np.ndarray:
    """Parse SparCraft's ASCII walkability map: width, height (walk tiles), then rows of 0/1."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if len(lines) < 2:
        raise ValueError("map file needs a width line, a height line and rows of 0/1")
    try:
        width, height = int(lines[0]), int(lines[1])
    except ValueError:
        raise ValueError(
            "map file: the first two lines must be the width and height in walk tiles"
        ) from None
    rows = lines[2:]
    if width <= 0 or height <= 0:
        raise ValueError(f"map file: width and height must be positive, got {width}x{height}")
    if len(rows) != height:
        raise ValueError(f"map file: expected {height} rows of tiles, found {len(rows)}")
    for r, row in enumerate(rows):  # before allocating: a mistyped width must not allocate it
        if len(row) < width or any(c not in "01" for c in row[:width]):
            raise ValueError(f"map file: row {r} must have {width} characters of 0/1")
    grid = np.zeros((height, width), dtype=bool)
    for r, row in enumerate(rows):
        grid[r] = [c == "1" for c in row[:width]]
    return grid


def is_walkable_np(walkable: np.ndarray, x: int, y: int) -> bool:
    """Host-side walkability of a pixel, with C's truncating division: x in [-7, -1] maps to
    tile 0 and is walkable; a negative tile index is off the map (SparCraft ``Map::isWalkable``)."""
    tx, ty = math.trunc(x / WALK_TILE), math.trunc(y / WALK_TILE)
    h, w = walkable.shape
    return 0 <= tx < w and 0 <= ty < h and bool(walkable[ty, tx])


@dataclass(frozen=True)
class UnitSpec:
    """A unit of a start state: SparCraft type name, owner and integer pixel position."""

    type: str
    player: int
    x: int
    y: int


def num_slots_for(units: Sequence[UnitSpec]) -> int:
    n0 = sum(1 for u in units if u.player == 0)
    n1 = sum(1 for u in units if u.player == 1)
    return max(n0, n1, 1)


def build_state(units: Sequence[UnitSpec], num_slots: int | None = None) -> GameState:
    """Build a start state from a unit list (ids = list positions), padded to ``num_slots``.

    The caller validates the list (see ``hybridmarl.engine.scenarios.validate_units``); this only
    lays it out. All units start with full HP, no previous action and both timers at frame 0.
    """
    n = num_slots_for(units) if num_slots is None else num_slots
    arrays = build_batch_arrays([units], n)
    return GameState(**{k: jnp.asarray(v[0]) for k, v in arrays.items()})


def stack_states(states: Sequence[GameState]) -> GameState:
    """Stack equally-shaped states along a new leading batch axis."""
    import jax

    return jax.tree.map(lambda *xs: jnp.stack(xs), *states)


def build_batch_arrays(
    states: Sequence[Sequence[UnitSpec]], num_slots: int | None = None
) -> dict[str, np.ndarray]:
    """The arrays of ``stack_states([build_state(s, num_slots) for s in states])``, built in NumPy
    in one pass (no per-state device arrays): per-unit fields int32 ``[B, 2, U]``, ``time``,
    ``turn``, ``stale`` int32 ``[B]``, ``prev_hp_sum`` int32 ``[B, 2]``, LTD totals float32
    ``[B, 2]``. ``num_slots`` defaults to the largest side of any state. Same errors as
    ``build_state``."""
    n = max((num_slots_for(s) for s in states), default=1) if num_slots is None else num_slots
    b = len(states)
    utype = np.zeros((b, 2, n), np.int32)
    uid = np.broadcast_to(PAD_ID_BASE + np.arange(n, dtype=np.int32), (b, 2, n)).copy()
    x = np.zeros((b, 2, n), np.int32)
    y = np.zeros((b, 2, n), np.int32)
    hp = np.zeros((b, 2, n), np.int32)
    max_hp_table = U.TABLES.max_hp
    type_ids: dict[str, int] = {}
    for k, units in enumerate(states):
        count = [0, 0]
        for i, u in enumerate(units):
            p = u.player
            s = count[p]
            if s >= n:
                raise ValueError(f"player {p} has more than {n} units")
            t = type_ids.get(u.type)
            if t is None:
                t = type_ids[u.type] = U.type_id(u.type)
            utype[k, p, s], uid[k, p, s], x[k, p, s], y[k, p, s] = t, i, u.x, u.y
            hp[k, p, s] = max_hp_table[t]
            count[p] += 1
    return batch_arrays_from_layout(utype, uid, x, y, hp)


def batch_arrays_from_layout(
    utype: np.ndarray, uid: np.ndarray, x: np.ndarray, y: np.ndarray, hp: np.ndarray
) -> dict[str, np.ndarray]:
    """Start-state arrays (``build_batch_arrays``' result) from the laid-out unit slots: int32
    ``[B, 2, U]`` types, ids (padding ids from ``PAD_ID_BASE``), positions and full HP (0 for
    padding)."""
    b, _, n = hp.shape
    present = hp > 0
    max_hp = U.TABLES.max_hp[utype].astype(np.float32)
    dpf = U.TABLES.dpf[utype]
    # SparCraft accumulates these in float, unit by unit in slot order within each player:
    # the same float32 sums, vectorised over states and players.
    ltd = np.zeros((b, 2), np.float32)
    ltd2 = np.zeros((b, 2), np.float32)
    for s in range(n):
        term = (max_hp[:, :, s] * dpf[:, :, s]).astype(np.float32)
        term2 = (np.sqrt(max_hp[:, :, s]) * dpf[:, :, s]).astype(np.float32)
        ltd = np.where(present[:, :, s], (ltd + term).astype(np.float32), ltd)
        ltd2 = np.where(present[:, :, s], (ltd2 + term2).astype(np.float32), ltd2)
    zeros = np.zeros((b, 2, n), np.int32)
    return {
        "utype": utype,
        "uid": uid,
        "x": x,
        "y": y,
        "px": x.copy(),
        "py": y.copy(),
        "t_act": zeros,
        "last": zeros.copy(),
        "hp": hp,
        "t_move": zeros.copy(),
        "t_attack": zeros.copy(),
        "time": np.zeros(b, np.int32),
        "turn": np.zeros(b, np.int32),
        "stale": np.zeros(b, np.int32),
        "prev_hp_sum": hp.sum(axis=2, dtype=np.int32),
        "ltd_total": ltd,
        "ltd2_total": ltd2,
    }


def build_batch(states: Sequence[Sequence[UnitSpec]], num_slots: int | None = None) -> GameState:
    """A batched ``GameState`` equal to ``stack_states([build_state(s, n) for s in states])``,
    built from NumPy arrays in one pass (linear in the number of states)."""
    arrays = build_batch_arrays(states, num_slots)
    return GameState(**{k: jnp.asarray(v) for k, v in arrays.items()})


def unit_hp_by_id(state: GameState, num_units: int) -> np.ndarray:
    """Final HP per SparCraft unit id (0 if dead), for one unbatched state."""
    uid = np.asarray(state.uid).ravel()
    hp = np.asarray(state.hp).ravel()
    out = np.zeros(num_units, np.int64)
    keep = uid < num_units
    out[uid[keep]] = np.maximum(hp[keep], 0)
    return out
