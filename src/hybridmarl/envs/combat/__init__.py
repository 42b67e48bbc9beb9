"""The combat Dec-POMDP over the SparCraft engine (paper Section 5.1); see :mod:`hybridmarl.envs.combat.env`."""

from hybridmarl.envs.combat.env import (
    ATTACK_OFFSET,
    HP_SCALE,
    K_ALLIES,
    K_ENEMIES,
    NOOP,
    POS_SCALE,
    SELF_FIELDS,
    TIME_SCALE,
    UNIT_FIELDS,
    Combat,
    CombatParams,
    CombatState,
    EnvPolicy,
    camera_window,
    disk_offsets,
)

__all__ = [
    "ATTACK_OFFSET",
    "HP_SCALE",
    "K_ALLIES",
    "K_ENEMIES",
    "NOOP",
    "POS_SCALE",
    "SELF_FIELDS",
    "TIME_SCALE",
    "UNIT_FIELDS",
    "Combat",
    "CombatParams",
    "CombatState",
    "EnvPolicy",
    "camera_window",
    "disk_offsets",
]
