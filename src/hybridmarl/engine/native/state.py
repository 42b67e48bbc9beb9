"""The native engine's state: a ``GameState``'s arrays as NumPy, always with a batch axis.

``NativeStates`` has exactly the ``GameState`` fields, with the same dtypes (int32, LTD totals
float32) and shapes plus a leading batch axis ``B``; conversion both ways is lossless.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from hybridmarl.engine import units as U
from hybridmarl.engine.native.kernels import FIELDS
from hybridmarl.engine.scenarios import MAX_UNITS_PER_SIDE, InputError
from hybridmarl.engine.state import GameState, UnitSpec, build_batch_arrays


class NativeStates(NamedTuple):
    """A batch of game states as NumPy arrays (field meanings: ``engine.state.GameState``)."""

    utype: np.ndarray  # int32 [B, 2, U]
    uid: np.ndarray
    x: np.ndarray
    y: np.ndarray
    px: np.ndarray
    py: np.ndarray
    t_act: np.ndarray
    last: np.ndarray
    hp: np.ndarray
    t_move: np.ndarray
    t_attack: np.ndarray
    time: np.ndarray  # int32 [B]
    turn: np.ndarray  # int32 [B]
    stale: np.ndarray  # int32 [B]
    prev_hp_sum: np.ndarray  # int32 [B, 2]
    ltd_total: np.ndarray  # float32 [B, 2]
    ltd2_total: np.ndarray  # float32 [B, 2]

    @property
    def batch_size(self) -> int:
        return int(self.hp.shape[0])

    @property
    def num_slots(self) -> int:
        return int(self.hp.shape[2])

    def unit_fields(self) -> tuple[np.ndarray, ...]:
        """The eleven per-unit arrays in kernel order (``kernels.FIELDS``)."""
        return tuple(getattr(self, f) for f in FIELDS)

    def copy(self) -> NativeStates:
        return NativeStates(*(a.copy() for a in self))

    def take(self, index) -> NativeStates:
        """A sub-batch (``index``: int, slice or index array); always keeps the batch axis."""
        if isinstance(index, int | np.integer):
            index = slice(int(index), int(index) + 1)
        return NativeStates(*(np.ascontiguousarray(a[index]) for a in self))


_DTYPES = {
    f: np.float32 if f in ("ltd_total", "ltd2_total") else np.int32 for f in NativeStates._fields
}


def check_representable(states: NativeStates) -> None:
    """Raise ``InputError`` (the messages of ``scenarios.validate_units``) for states the engine
    cannot play: a side over ``MAX_UNITS_PER_SIDE`` units, or an unknown unit type."""
    n = states.num_slots
    alive = states.hp > 0
    if n > MAX_UNITS_PER_SIDE:
        counts = alive.sum(axis=2)
        b, p = np.unravel_index(int(np.argmax(counts)), counts.shape)
        raise InputError(
            f"state {b}: player {p} has {int(counts[b, p])} units (at most {MAX_UNITS_PER_SIDE})"
        )
    bad = alive & ((states.utype < 0) | (states.utype >= U.NUM_TYPES))
    if bad.any():
        b, p, s = (int(i) for i in np.argwhere(bad)[0])
        raise InputError(
            f"state {b} unit {int(states.uid[b, p, s])}: unknown unit type {int(states.utype[b, p, s])!r} "
            f"(known: {', '.join(U.TYPE_NAMES)})"
        )


def _native(arrays: dict[str, np.ndarray]) -> NativeStates:
    # Always a writable copy: kernels update states in place, and NumPy views of JAX arrays are
    # read-only (a distinct Numba type, too).
    return NativeStates(
        **{
            f: np.array(arrays[f], dtype=_DTYPES[f], order="C", copy=True)
            for f in NativeStates._fields
        }
    )


def from_arrays(arrays: dict[str, np.ndarray]) -> NativeStates:
    """Native states from batch arrays such as ``state.build_batch_arrays`` or
    ``Scenario.generate_arrays`` return (checked like ``from_jax``)."""
    out = _native(arrays)
    check_representable(out)
    return out


def from_jax(state: GameState) -> NativeStates:
    """NumPy copy of a ``GameState`` (single, ``hp`` [2, U], or batched, [B, 2, U])."""
    batched = np.ndim(state.hp) == 3
    arrays = {}
    for f in NativeStates._fields:
        a = np.asarray(getattr(state, f))
        arrays[f] = a if batched else a[None]
    out = _native(arrays)
    check_representable(out)
    return out


def to_jax(states: NativeStates, batched: bool = True) -> GameState:
    """The ``GameState`` of a native batch; ``batched=False`` drops the axis of a batch of one."""
    if not batched and states.batch_size != 1:
        raise ValueError(f"batched=False needs a batch of one state, got {states.batch_size}")
    pick = (lambda a: a) if batched else (lambda a: a[0])
    return GameState(**{f: jnp.asarray(pick(getattr(states, f))) for f in NativeStates._fields})


def _check_unit_lists(states: Sequence[Sequence[UnitSpec]]) -> None:
    """``scenarios.validate_units``' errors for what the native engine cannot represent."""
    for i, units in enumerate(states):
        for k, u in enumerate(units):
            if u.type not in U.TYPE_INDEX:
                raise InputError(
                    f"state {i} unit {k}: unknown unit type {u.type!r} (known: {', '.join(U.TYPE_NAMES)})"
                )
        for p in (0, 1):
            n = sum(1 for u in units if u.player == p)
            if n > MAX_UNITS_PER_SIDE:
                raise InputError(
                    f"state {i}: player {p} has {n} units (at most {MAX_UNITS_PER_SIDE})"
                )


def build_native_states(
    states: Sequence[Sequence[UnitSpec]], num_slots: int | None = None
) -> NativeStates:
    """Start states from unit lists (ids = list positions), padded to ``num_slots`` (default: the
    largest side of any state); equal to ``from_jax(build_batch(states, num_slots))``."""
    _check_unit_lists(states)
    return _native(build_batch_arrays(states, num_slots))
