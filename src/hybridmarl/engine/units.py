"""Unit data: SparCraft's unit table, and the per-type lookup tables the engine uses.

Every number is SparCraft's (docs/engine.md#unit-types; SparCraft DC-HEAD with its bundled
BWAPI tables, no upgrades). Tables that involve floating point (move length, move duration,
damage-per-frame) are computed here once, in NumPy float64 / float32 exactly as SparCraft computes
them in C++ (double for move lengths, float for dpf), so the jitted engine only does integer
lookups and cannot drift from the reference through a different rounding order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: SparCraft's ``Constants`` (``src/Common.h``).
RANGE_ADDITION = 32  # px added to every weapon range (stand-in for unit sizes)
MOVE_DISTANCE = 16  # px of a default move
MOVE_PENALTY = 4  # extra cooldown frames for an attack right after a move
PASS_DURATION = 20  # frames a PASS takes
MIN_DAMAGE = 2  # SparCraft's minimum damage per hit (BW's would be 0.5)
MIN_UNIT_DPF = 0.1

# Damage types and size classes (BWAPI).
NORMAL, EXPLOSIVE, CONCUSSIVE = 0, 1, 2
SMALL, MEDIUM, LARGE = 0, 1, 2
SIZE_MULTIPLIER = np.array(
    [
        [1.0, 1.0, 1.0],  # Normal
        [0.5, 0.75, 1.0],  # Explosive
        [1.0, 0.5, 0.25],  # Concussive
    ],
    dtype=np.float64,
)


@dataclass(frozen=True)
class UnitType:
    """One row of the unit table (docs/engine.md#unit-types)."""

    name: str
    hp: int
    shields: int
    armor: int
    size: int
    speed: float  # px/frame, BWAPI topSpeed (no upgrades)
    damage: int  # weapon base damage
    damage_type: int
    cooldown: int  # frames
    weapon_range: int  # BWAPI max range in px (SparCraft adds RANGE_ADDITION)
    anim_first: int  # attack animation frames, first shot
    anim_repeat: int  # attack animation frames, repeat shot
    hits: int = 1  # Zealot and Firebat hit twice

    @property
    def max_hp(self) -> int:
        """SparCraft pools HP and shields into one number."""
        return self.hp + self.shields

    @property
    def script_damage(self) -> int:
        """SparCraft's ``Unit::damage()``: raw damage, doubled for the Zealot only (not the Firebat)."""
        return self.damage * (2 if self.name == "Protoss_Zealot" else 1)


UNIT_TYPES: tuple[UnitType, ...] = (
    UnitType("Terran_Marine", 40, 0, 0, SMALL, 4.0, 6, NORMAL, 15, 128, 8, 6),
    UnitType("Terran_Firebat", 50, 0, 1, SMALL, 4.0, 8, CONCUSSIVE, 22, 32, 8, 8, hits=2),
    UnitType("Terran_Vulture", 80, 0, 0, MEDIUM, 6.4, 20, CONCUSSIVE, 30, 160, 1, 1),
    UnitType("Protoss_Zealot", 100, 60, 1, SMALL, 4.0, 8, NORMAL, 22, 15, 8, 7, hits=2),
    UnitType("Protoss_Dragoon", 100, 80, 1, LARGE, 5.0, 20, EXPLOSIVE, 30, 128, 7, 3),
    UnitType("Zerg_Zergling", 35, 0, 0, SMALL, 5.49, 5, NORMAL, 8, 15, 5, 5),
    UnitType("Zerg_Hydralisk", 80, 0, 0, MEDIUM, 3.66, 10, EXPLOSIVE, 15, 128, 3, 2),
)

TYPE_NAMES: tuple[str, ...] = tuple(t.name for t in UNIT_TYPES)
TYPE_INDEX: dict[str, int] = {t.name: i for i, t in enumerate(UNIT_TYPES)}
NUM_TYPES = len(UNIT_TYPES)

#: Longest "time until the unit can attack" a move-length lookup can see: a cooldown plus the
#: move penalty. Indices above this are clamped (they cannot occur with the units above).
MAX_T_ATK = 64


def hit_damage(attacker: UnitType, target: UnitType) -> int:
    """Damage of one ATTACK action (docs/engine.md#action-effects-and-timing), no upgrades."""
    base = attacker.damage - target.armor
    dmg = max(int(base * SIZE_MULTIPLIER[attacker.damage_type, target.size]), MIN_DAMAGE)
    return dmg * attacker.hits


def dpf(unit: UnitType) -> np.float32:
    """SparCraft's ``Unit::dpf()`` in float32: max(0.1, damage() / (cooldown + 1))."""
    value = np.float32(unit.script_damage) / (np.float32(unit.cooldown) + np.float32(1))
    return np.float32(max(np.float32(MIN_UNIT_DPF), value))


def move_distance(unit: UnitType, t_atk: int) -> int:
    """Length in px of a MOVE generated ``t_atk`` frames before the unit can attack.

    SparCraft (``GameState::generateMoves``, in double): if t_atk is 0 the attack cooldown is used;
    the move lasts min(t_atk, 16/speed) frames and covers int(duration * speed) px.
    """
    time_until_attack = float(unit.cooldown if t_atk == 0 else t_atk)
    default = MOVE_DISTANCE / unit.speed
    chosen = min(time_until_attack, default) if time_until_attack != 0 else default
    return int(chosen * unit.speed)


def move_duration(unit: UnitType, distance: int) -> int:
    """Frames a MOVE of ``distance`` px takes: max(1, int(distance / speed)) (``Unit::move``)."""
    return max(int(float(distance) / unit.speed), 1)


@dataclass(frozen=True)
class TypeTables:
    """Per-type constants as NumPy arrays, indexed by type id (closed over by jitted code)."""

    max_hp: np.ndarray  # int32 [T]
    range_sq: np.ndarray  # int32 [T]   (weapon range + 32)^2
    cooldown: np.ndarray  # int32 [T]
    anim_first: np.ndarray  # int32 [T]
    anim_repeat: np.ndarray  # int32 [T]
    script_damage: np.ndarray  # int32 [T]
    dpf: np.ndarray  # float32 [T]
    damage: np.ndarray  # int32 [T, T]   attacker x target
    move_dist: np.ndarray  # int32 [T, MAX_T_ATK + 1]
    move_dur: np.ndarray  # int32 [T, MAX_T_ATK + 1]


def _build_tables() -> TypeTables:
    ts = UNIT_TYPES
    move_dist = np.array(
        [[move_distance(t, k) for k in range(MAX_T_ATK + 1)] for t in ts], dtype=np.int32
    )
    move_dur = np.array(
        [[move_duration(t, int(d)) for d in move_dist[i]] for i, t in enumerate(ts)],
        dtype=np.int32,
    )
    return TypeTables(
        max_hp=np.array([t.max_hp for t in ts], dtype=np.int32),
        range_sq=np.array([(t.weapon_range + RANGE_ADDITION) ** 2 for t in ts], dtype=np.int32),
        cooldown=np.array([t.cooldown for t in ts], dtype=np.int32),
        anim_first=np.array([t.anim_first for t in ts], dtype=np.int32),
        anim_repeat=np.array([t.anim_repeat for t in ts], dtype=np.int32),
        script_damage=np.array([t.script_damage for t in ts], dtype=np.int32),
        dpf=np.array([dpf(t) for t in ts], dtype=np.float32),
        damage=np.array([[hit_damage(a, b) for b in ts] for a in ts], dtype=np.int32),
        move_dist=move_dist,
        move_dur=move_dur,
    )


TABLES = _build_tables()


def type_id(name: str) -> int:
    """Type index of a SparCraft unit name such as ``"Terran_Marine"``; KeyError if unknown."""
    try:
        return TYPE_INDEX[name]
    except KeyError:
        known = ", ".join(TYPE_NAMES)
        raise KeyError(f"unknown unit type {name!r} (known: {known})") from None
