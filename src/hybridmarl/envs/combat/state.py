"""The combat environment's state, parameters and start-state sampler."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hybridmarl.engine.scenarios import (
    Scenario,
    check_on_walkable,
    disk_offsets,
    generator_units,
    side_types,
    spread_anchors,
)
from hybridmarl.engine.state import GameState, build_state

__all__ = ["INT32_MAX", "CombatParams", "CombatState", "ScenarioSampler"]

#: Sorting key of "no candidate" in the packed (value, slot) keys of ranks and observations.
INT32_MAX = jnp.iinfo(jnp.int32).max


class CombatParams(struct.PyTreeNode):
    """Environment parameters (pytree leaves: new values of the same shape do not recompile).

    ``bank``: a stacked ``GameState`` ``[K, 2, U]`` of start states that ``reset`` draws from
    uniformly, or ``None`` to sample the scenario's generator.
    """

    bank: GameState | None = None


class CombatState(struct.PyTreeNode):
    """One environment state: the engine's game plus what the env adds around it."""

    game: GameState
    last_actions: jax.Array  # int32 [2, U] engine action each unit issued during the last step
    #                           (the latest one if it acted more than once), -1 if none
    init_hp: jax.Array  # int32 [2] HP sums at the episode's start state (reward normaliser)
    steps: jax.Array  # int32 [] env steps taken this episode


@dataclass(frozen=True)
class ScenarioSampler:
    """Draws a scenario's start states inside JAX (jittable, vmappable).

    The distribution is the host generator's (``Scenario.generate``), with the geometry taken
    from ``hybridmarl.engine.scenarios``: a disk scenario's units are uniform over the table of
    all integer offsets of their side's disk (:func:`~hybridmarl.engine.scenarios.disk_offsets`,
    chosen among with ``jax.random.randint``); separated and symmetric scenarios draw offsets
    uniform in ``[-spread, spread - 1]`` around their anchors. Built once, in NumPy.
    """

    kind: str
    template: GameState  # unit types, ids, HP, LTD totals; positions are filled in by sample
    present: np.ndarray  # bool [2, U]
    offsets: tuple[np.ndarray, np.ndarray]  # disks: int32 [P_p, 2] integer offsets per side
    anchors: tuple[tuple[int, int], tuple[int, int]]
    spread: tuple[int, int]

    @staticmethod
    def build(sc: Scenario, num_slots: int, walkable: np.ndarray) -> ScenarioSampler:
        """The sampler of ``sc`` with ``num_slots`` slots per side; raises ``ValueError`` if the
        scenario can place a unit off the walkable map."""
        t0, t1 = side_types(sc)
        template = build_state(generator_units(t0, t1), num_slots)
        present = np.zeros((2, num_slots), bool)
        present[0, : len(t0)] = True
        present[1, : len(t1)] = True
        check_on_walkable(sc, walkable)
        if sc.kind == "disks":
            offsets = (disk_offsets(sc.radius0), disk_offsets(sc.radius1))
            anchors = (sc.center0, sc.center1)
        else:
            offsets = (np.zeros((1, 2), np.int32), np.zeros((1, 2), np.int32))
            anchors = spread_anchors(sc)
        return ScenarioSampler(
            kind=sc.kind,
            template=template,
            present=present,
            offsets=offsets,
            anchors=(
                (int(anchors[0][0]), int(anchors[0][1])),
                (int(anchors[1][0]), int(anchors[1][1])),
            ),
            spread=(int(sc.spread[0]), int(sc.spread[1])),
        )

    def sample(self, key: jax.Array) -> GameState:
        """One start ``GameState``."""
        u = self.template.hp.shape[-1]
        k0, k1, k2 = jax.random.split(key, 3)
        if self.kind == "disks":
            xy = []
            for p, kp in ((0, k0), (1, k1)):
                table = jnp.asarray(self.offsets[p])
                idx = jax.random.randint(kp, (u,), 0, table.shape[0])
                xy.append(table[idx] + jnp.asarray(self.anchors[p], jnp.int32))
            pos = jnp.stack(xy)  # [2, U, 2]
        else:
            mx, my = self.spread
            off = jnp.stack(
                [
                    jax.random.randint(k0, (u,), -mx, mx),
                    jax.random.randint(k1, (u,), -my, my),
                ],
                axis=-1,
            ).astype(jnp.int32)
            a = jnp.asarray(self.anchors[0], jnp.int32) + off
            b = jnp.asarray(self.anchors[1], jnp.int32) - off
            if self.kind == "symmetric":
                pos = jnp.stack([a, b])
            else:
                # The host generator yields a pair, (a, b) and its mirror (b, a): pick one.
                swap = jax.random.bernoulli(k2)
                pos = jnp.where(swap, jnp.stack([b, a]), jnp.stack([a, b]))
        present = jnp.asarray(self.present)
        x = jnp.where(present, pos[..., 0], 0).astype(jnp.int32)
        y = jnp.where(present, pos[..., 1], 0).astype(jnp.int32)
        return dataclasses.replace(self.template, x=x, y=y, px=x, py=y)
