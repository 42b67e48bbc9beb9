"""Start states: explicit unit lists (JSON), generators, and named scenarios.

Generators (host-side NumPy, seeded, so the same seed gives the same states everywhere):

- ``two_disks``: each side uniformly over the integer pixels of its own disk, player 0 on the left.
  Units are added alternately (P0, P1, P0, ...) like SparCraft's generators, so with equal sides
  P0 gets even ids and P1 odd ids.
- ``separated_state``: SparCraft's SeparatedState: offsets uniform in [-R, R-1]^2, P0 at c1 + r and
  P1 at c2 - r, plus a copy with the two players' positions swapped.
- ``state_symmetric``: SparCraft's StateSymmetric: a point mirror around (640, 360); the armies are
  intermixed in one square.

Named scenarios: ``m<A>v<B>`` is a Marine battle, A Marines of ours (player 0, left) against B
(player 1, right), in the **contact** geometry of a setting (``hybridmarl.settings``,
docs/engine.md#settings). The default setting, ``sparcraft``, centres the disks 150 px apart
around the map centre ((565, 352) and (715, 352)), radius 100 px; the ``paper`` setting uses the
geometry calibrated to the paper's demonstrator rows (Table 1, ``experiments/paper_setting.py``).
``m<A>v<B>-apart`` uses the reference playouts' main setting (docs/engine.md#start-states-and-scenarios):
centres (440, 352) and (840, 352), radius 100 px, under every setting. Any other geometry or unit mix comes from a
scenario file (``load_scenario_file``).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hybridmarl.engine import units as U
from hybridmarl.engine.state import (
    DEFAULT_MAP_HEIGHT_PX,
    DEFAULT_MAP_WIDTH_PX,
    PAD_ID_BASE,
    WALK_TILE,
    UnitSpec,
    batch_arrays_from_layout,
    build_batch_arrays,
    default_walkable,
    is_walkable_np,
)
from hybridmarl.errors import UserError

MAX_UNITS_PER_SIDE = 512


class InputError(UserError):
    """A problem with user input: the message is one line that names the problem."""


# ----------------------------------------------------------------------------- validation


def validate_units(
    raw: Any, *, where: str = "state", walkable: np.ndarray | None = None
) -> list[UnitSpec]:
    """Validate one state's unit list (``[{"type", "player", "x", "y"}, ...]``; extra keys ignored)."""
    grid = default_walkable() if walkable is None else walkable
    if not isinstance(raw, list):
        raise InputError(f"{where}: 'units' must be a list of units")
    out: list[UnitSpec] = []
    for i, u in enumerate(raw):
        w = f"{where} unit {i}"
        if not isinstance(u, dict):
            raise InputError(f"{w}: must be an object with type, player, x, y")
        for k in ("type", "player", "x", "y"):
            if k not in u:
                raise InputError(f"{w}: missing key {k!r}")
        typ = u["type"]
        if not isinstance(typ, str) or typ not in U.TYPE_INDEX:
            raise InputError(f"{w}: unknown unit type {typ!r} (known: {', '.join(U.TYPE_NAMES)})")
        player = u["player"]
        if isinstance(player, bool) or player not in (0, 1):
            raise InputError(f"{w}: player must be 0 or 1, got {player!r}")
        xy = []
        for k in ("x", "y"):
            v = u[k]
            if isinstance(v, bool) or not isinstance(v, int | float) or not float(v).is_integer():
                raise InputError(f"{w}: {k} must be an integer pixel coordinate, got {v!r}")
            xy.append(int(v))
        if not is_walkable_np(grid, xy[0], xy[1]):
            h, wdt = grid.shape
            raise InputError(
                f"{w}: position ({xy[0]}, {xy[1]}) is off the map or not walkable "
                f"(map is {wdt * 8}x{h * 8} px)"
            )
        out.append(UnitSpec(typ, int(player), xy[0], xy[1]))
    for p in (0, 1):
        n = sum(1 for u in out if u.player == p)
        if n == 0:
            raise InputError(f"{where}: player {p} has no units (each side needs at least one)")
        if n > MAX_UNITS_PER_SIDE:
            raise InputError(f"{where}: player {p} has {n} units (at most {MAX_UNITS_PER_SIDE})")
    return out


def parse_states_document(doc: Any, *, walkable: np.ndarray | None = None) -> list[list[UnitSpec]]:
    """Validate ``{"states": [{"units": [...]}, ...]}``."""
    if not isinstance(doc, dict) or "states" not in doc:
        raise InputError("the top level must be an object with a 'states' list")
    states = doc["states"]
    if not isinstance(states, list) or not states:
        raise InputError("'states' must be a non-empty list")
    out = []
    for i, s in enumerate(states):
        if not isinstance(s, dict) or "units" not in s:
            raise InputError(f"state {i}: must be an object with a 'units' list")
        out.append(validate_units(s["units"], where=f"state {i}", walkable=walkable))
    return out


def load_states_file(
    path: str | Path, *, walkable: np.ndarray | None = None
) -> list[list[UnitSpec]]:
    """Read and validate a states JSON file; any problem raises ``InputError`` with one line."""
    from hybridmarl.io import read_user_json

    p = Path(path)
    doc = read_user_json(p, "states file", InputError)
    try:
        return parse_states_document(doc, walkable=walkable)
    except InputError as e:
        raise InputError(f"states file {str(p)!r}: {e}") from None


def states_to_document(states: Sequence[Sequence[UnitSpec]]) -> dict:
    return {
        "states": [
            {"units": [{"type": u.type, "player": u.player, "x": u.x, "y": u.y} for u in s]}
            for s in states
        ]
    }


# ----------------------------------------------------------------------------- generators


def _alternate(
    side0: list[tuple[str, int, int]], side1: list[tuple[str, int, int]]
) -> list[UnitSpec]:
    """Interleave P0, P1, P0, ... as SparCraft's generators add units; leftovers at the end."""
    out: list[UnitSpec] = []
    for i in range(max(len(side0), len(side1))):
        if i < len(side0):
            t, x, y = side0[i]
            out.append(UnitSpec(t, 0, x, y))
        if i < len(side1):
            t, x, y = side1[i]
            out.append(UnitSpec(t, 1, x, y))
    return out


def _expand(types: Sequence[tuple[str, int]]) -> list[str]:
    out: list[str] = []
    for t, c in types:
        U.type_id(t)
        out += [t] * int(c)
    return out


def disk_points(rng: np.random.Generator, n: int, cx: int, cy: int, r: int) -> np.ndarray:
    """``n`` points uniform over the integer pixels (x, y) with (x-cx)^2 + (y-cy)^2 <= r^2."""
    pts = np.empty((0, 2), np.int64)
    while len(pts) < n:
        cand = rng.integers(-r, r + 1, size=(max(2 * n, 16), 2))
        keep = cand[(cand**2).sum(axis=1) <= r * r]
        pts = np.concatenate([pts, keep])
    return pts[:n] + np.array([cx, cy])


def two_disks(
    rng: np.random.Generator,
    types0: Sequence[tuple[str, int]],
    types1: Sequence[tuple[str, int]],
    center0: tuple[int, int],
    center1: tuple[int, int],
    radius0: int,
    radius1: int | None = None,
) -> list[UnitSpec]:
    t0, t1 = _expand(types0), _expand(types1)
    r1 = radius0 if radius1 is None else radius1
    p0 = disk_points(rng, len(t0), center0[0], center0[1], radius0)
    p1 = disk_points(rng, len(t1), center1[0], center1[1], r1)
    return _alternate(
        [(t, int(x), int(y)) for t, (x, y) in zip(t0, p0, strict=True)],
        [(t, int(x), int(y)) for t, (x, y) in zip(t1, p1, strict=True)],
    )


def _offsets(rng: np.random.Generator, n: int, max_x: int, max_y: int) -> np.ndarray:
    # SparCraft: (rand() % (2*Max)) - Max, i.e. uniform in [-Max, Max - 1].
    return np.stack(
        [rng.integers(0, 2 * max_x, n) - max_x, rng.integers(0, 2 * max_y, n) - max_y], axis=1
    )


def separated_state(
    rng: np.random.Generator,
    rand_x: int,
    rand_y: int,
    c1: tuple[int, int],
    c2: tuple[int, int],
    types: Sequence[tuple[str, int]],
) -> list[list[UnitSpec]]:
    """One SeparatedState pair: the state and the copy with the players' positions swapped."""
    ts = _expand(types)
    r = _offsets(rng, len(ts), rand_x, rand_y)
    a = [(t, c1[0] + int(dx), c1[1] + int(dy)) for t, (dx, dy) in zip(ts, r, strict=True)]
    b = [(t, c2[0] - int(dx), c2[1] - int(dy)) for t, (dx, dy) in zip(ts, r, strict=True)]
    return [_alternate(a, b), _alternate(b, a)]


#: The point StateSymmetric mirrors its two armies around.
SYMMETRIC_CENTER = (640, 360)


def state_symmetric(
    rng: np.random.Generator, max_x: int, max_y: int, types: Sequence[tuple[str, int]]
) -> list[UnitSpec]:
    ts = _expand(types)
    r = _offsets(rng, len(ts), max_x, max_y)
    cx, cy = SYMMETRIC_CENTER
    a = [(t, cx + int(dx), cy + int(dy)) for t, (dx, dy) in zip(ts, r, strict=True)]
    b = [(t, cx - int(dx), cy - int(dy)) for t, (dx, dy) in zip(ts, r, strict=True)]
    return _alternate(a, b)


# ----------------------------------------------------------------------------- scenarios


@dataclass(frozen=True)
class Scenario:
    """A family of start states: unit types per side and a generator with its geometry."""

    name: str
    side0: tuple[tuple[str, int], ...]
    side1: tuple[tuple[str, int], ...]
    kind: str = "disks"  # "disks" | "separated" | "symmetric"
    center0: tuple[int, int] = (565, 352)
    center1: tuple[int, int] = (715, 352)
    radius0: int = 100
    radius1: int = 100
    spread: tuple[int, int] = (128, 128)  # separated / symmetric offsets
    description: str = ""
    extra: dict = field(default_factory=dict, compare=False, hash=False)

    @property
    def n0(self) -> int:
        return sum(c for _, c in self.side0)

    @property
    def n1(self) -> int:
        return sum(c for _, c in self.side1)

    def generate(self, n: int, seed: int) -> list[list[UnitSpec]]:
        """``n`` start states; the same (scenario, n, seed) always gives the same states."""
        rng = np.random.default_rng(np.random.SeedSequence([seed, _stable_hash(self.name)]))
        out: list[list[UnitSpec]] = []
        while len(out) < n:
            if self.kind == "disks":
                out.append(
                    two_disks(
                        rng,
                        self.side0,
                        self.side1,
                        self.center0,
                        self.center1,
                        self.radius0,
                        self.radius1,
                    )
                )
            elif self.kind == "separated":
                out += separated_state(
                    rng, self.spread[0], self.spread[1], self.center0, self.center1, self.side0
                )
            elif self.kind == "symmetric":
                out.append(state_symmetric(rng, self.spread[0], self.spread[1], self.side0))
            else:
                raise InputError(f"scenario {self.name!r}: unknown kind {self.kind!r}")
        return out[:n]

    def generate_arrays(self, n: int, seed: int) -> dict[str, np.ndarray]:
        """The batch arrays of ``generate(n, seed)`` (``state.build_batch_arrays``), drawn from the
        same random stream without building per-unit objects (much faster for large ``n``)."""
        if self.kind != "disks":
            return build_batch_arrays(self.generate(n, seed))
        rng = np.random.default_rng(np.random.SeedSequence([seed, _stable_hash(self.name)]))
        types0 = [U.type_id(t) for t in _expand(self.side0)]
        types1 = [U.type_id(t) for t in _expand(self.side1)]
        n0, n1 = len(types0), len(types1)
        slots = max(n0, n1, 1)
        pos = np.zeros((n, 2, slots, 2), np.int64)
        for k in range(n):
            pos[k, 0, :n0] = disk_points(rng, n0, self.center0[0], self.center0[1], self.radius0)
            pos[k, 1, :n1] = disk_points(rng, n1, self.center1[0], self.center1[1], self.radius1)
        # Ids of the interleaved unit list (P0, P1, P0, ...; leftovers at the end), as _alternate.
        ids = np.tile(PAD_ID_BASE + np.arange(slots, dtype=np.int32), (2, 1))
        utype_row = np.zeros((2, slots), np.int32)
        next_id = 0
        for i in range(max(n0, n1)):
            for p, types in ((0, types0), (1, types1)):
                if i < len(types):
                    ids[p, i] = next_id
                    utype_row[p, i] = types[i]
                    next_id += 1
        present = np.zeros((2, slots), bool)
        present[0, :n0] = True
        present[1, :n1] = True
        hp_row = np.where(present, U.TABLES.max_hp[utype_row], 0).astype(np.int32)
        return batch_arrays_from_layout(
            np.broadcast_to(utype_row, (n, 2, slots)).copy(),
            np.broadcast_to(ids, (n, 2, slots)).copy(),
            pos[..., 0].astype(np.int32),
            pos[..., 1].astype(np.int32),
            np.broadcast_to(hp_row, (n, 2, slots)).copy(),
        )


# ----------------------------------------------------------------------------- geometry rules
# What a scenario's generator fixes, for samplers that draw the same distribution elsewhere
# (``hybridmarl.envs.combat`` draws start states inside JAX).


def side_types(sc: Scenario) -> tuple[list[str], list[str]]:
    """The unit types of each side, one entry per unit, in generator order."""
    t0 = _expand(sc.side0)
    # SparCraft's separated and symmetric generators give both players player 0's units.
    t1 = t0 if sc.kind in ("separated", "symmetric") else _expand(sc.side1)
    return t0, t1


def generator_units(types0: Sequence[str], types1: Sequence[str]) -> list[UnitSpec]:
    """Units in the generators' id order (P0, P1, P0, ...), all at the origin."""
    return _alternate([(t, 0, 0) for t in types0], [(t, 0, 0) for t in types1])


def disk_offsets(radius: int) -> np.ndarray:
    """int32 ``[P, 2]``: every integer offset ``(dx, dy)`` with ``dx^2 + dy^2 <= radius^2``, the
    support of :func:`disk_points` (uniform over these offsets)."""
    r = int(radius)
    d = np.arange(-r, r + 1)
    dx, dy = np.meshgrid(d, d, indexing="xy")
    keep = dx * dx + dy * dy <= r * r
    return np.stack([dx[keep], dy[keep]], axis=1).astype(np.int32)


def spread_anchors(sc: Scenario) -> tuple[tuple[int, int], tuple[int, int]]:
    """Where a separated or symmetric scenario's offsets are added to (player 0, player 1):
    player 0 at ``anchor0 + offset``, player 1 at ``anchor1 - offset``."""
    if sc.kind == "symmetric":
        return SYMMETRIC_CENTER, SYMMETRIC_CENTER
    return sc.center0, sc.center1


def _walkable_all(grid: np.ndarray, x: np.ndarray, y: np.ndarray) -> bool:
    """Vectorised ``is_walkable_np`` over all points (C truncating division)."""
    tx = np.fix(np.asarray(x) / WALK_TILE).astype(np.int64)
    ty = np.fix(np.asarray(y) / WALK_TILE).astype(np.int64)
    h, w = grid.shape
    inside = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
    return bool((inside & grid[np.clip(ty, 0, h - 1), np.clip(tx, 0, w - 1)]).all())


def check_on_walkable(sc: Scenario, walkable: np.ndarray) -> None:
    """Raise ``InputError`` unless every position ``sc`` can generate is on a walkable tile."""
    grid = np.asarray(walkable)
    if sc.kind == "disks":
        for p, (c, r) in enumerate(((sc.center0, sc.radius0), (sc.center1, sc.radius1))):
            pts = disk_offsets(r) + np.array(c, np.int32)
            if not _walkable_all(grid, pts[:, 0], pts[:, 1]):
                raise InputError(
                    f"scenario {sc.name!r}: player {p}'s disk (centre {tuple(c)}, radius {r}) "
                    "is not entirely on walkable map tiles"
                )
    elif sc.kind in ("separated", "symmetric"):
        mx, my = sc.spread
        dx, dy = np.meshgrid(np.arange(-mx, mx), np.arange(-my, my))
        for ax, ay in spread_anchors(sc):
            for sgn in (1, -1):
                if not _walkable_all(grid, ax + sgn * dx, ay + sgn * dy):
                    raise InputError(
                        f"scenario {sc.name!r}: spread {sc.spread} around {(ax, ay)} leaves "
                        "the walkable map"
                    )
    else:
        raise InputError(f"scenario {sc.name!r}: unknown kind {sc.kind!r}")


def _stable_hash(s: str) -> int:
    h = 2166136261
    for ch in s.encode():
        h = ((h ^ ch) * 16777619) & 0xFFFFFFFF
    return h


APART_CENTERS = ((440, 352), (840, 352))
APART_RADIUS = 100

_MARINE_RE = re.compile(r"^m(\d+)v(\d+)(-apart|-contact)?$")

#: The paper's combat scenarios (Table 1).
PAPER_SCENARIOS = ("m5v5", "m30v30", "m18v20", "m24v30")


def named_scenario(name: str, setting: Any = None) -> Scenario:
    """``m<A>v<B>`` (contact geometry of ``setting``, ``hybridmarl.settings``; default
    ``sparcraft``: disks r=100 px centred 150 px apart) or ``m<A>v<B>-apart``
    (docs/engine.md#start-states-and-scenarios main setting, the same under every setting)."""
    from hybridmarl.settings import get_setting

    geom = get_setting(setting).geometry
    m = _MARINE_RE.match(name.strip().lower())
    if not m:
        raise InputError(
            f"unknown scenario {name!r}: use m<A>v<B> (e.g. m5v5, m18v20), m<A>v<B>-apart, or --scenario-file"
        )
    a, b = int(m[1]), int(m[2])
    if not (1 <= a <= MAX_UNITS_PER_SIDE and 1 <= b <= MAX_UNITS_PER_SIDE):
        raise InputError(f"scenario {name!r}: each side needs 1..{MAX_UNITS_PER_SIDE} units")
    marine = "Terran_Marine"
    if m[3] == "-apart":
        return Scenario(
            name=name,
            side0=((marine, a),),
            side1=((marine, b),),
            center0=APART_CENTERS[0],
            center1=APART_CENTERS[1],
            radius0=APART_RADIUS,
            radius1=APART_RADIUS,
            description=f"{a} vs {b} Marines, disks r={APART_RADIUS} px centred 400 px apart (docs/engine.md#start-states-and-scenarios)",
        )
    cx, cy = DEFAULT_MAP_WIDTH_PX // 2, DEFAULT_MAP_HEIGHT_PX // 2
    sep, r = geom.separation_for(a, b), geom.radius
    if cx - sep // 2 - r < 0 or cx - sep // 2 + sep + r >= DEFAULT_MAP_WIDTH_PX or cy - r < 0:
        raise InputError(
            f"scenario {name!r}: its disks (radius {r} px, centres {sep} px apart) leave the "
            f"{DEFAULT_MAP_WIDTH_PX}x{DEFAULT_MAP_HEIGHT_PX} map"
        )
    return Scenario(
        name=name,
        side0=((marine, a),),
        side1=((marine, b),),
        center0=(cx - sep // 2, cy),
        center1=(cx - sep // 2 + sep, cy),
        radius0=r,
        radius1=r,
        description=f"{a} vs {b} Marines, disks r={r} px centred {sep} px apart (contact)",
    )


def _pair(v: Any, what: str, *, low: int | None = None) -> tuple[int, int]:
    if not (
        isinstance(v, list)
        and len(v) == 2
        and all(isinstance(c, int) and not isinstance(c, bool) for c in v)
    ):
        raise InputError(f"scenario file: {what} must be [x, y] integers, got {v!r}")
    if low is not None and min(v) < low:
        raise InputError(f"scenario file: {what} must be at least {low} in x and y, got {v!r}")
    return (int(v[0]), int(v[1]))


def _radius(v: Any, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise InputError(
            f"scenario file: {what} must be an integer number of pixels, at least 0, got {v!r}"
        )
    return v


def _side(v: Any, what: str) -> tuple[tuple[str, int], ...]:
    if not isinstance(v, list) or not v:
        raise InputError(f"scenario file: {what} must be a non-empty list of {{type, count}}")
    out = []
    for i, e in enumerate(v):
        if not isinstance(e, dict) or "type" not in e or "count" not in e:
            raise InputError(f'scenario file: {what}[{i}] must be {{"type": ..., "count": ...}}')
        if not isinstance(e["type"], str) or e["type"] not in U.TYPE_INDEX:
            raise InputError(
                f"scenario file: {what}[{i}]: unknown unit type {e['type']!r} (known: {', '.join(U.TYPE_NAMES)})"
            )
        c = e["count"]
        if isinstance(c, bool) or not isinstance(c, int) or c < 1:
            raise InputError(f"scenario file: {what}[{i}]: count must be a positive integer")
        out.append((e["type"], c))
    if sum(c for _, c in out) > MAX_UNITS_PER_SIDE:
        raise InputError(f"scenario file: {what} has more than {MAX_UNITS_PER_SIDE} units")
    return tuple(out)


def load_scenario_file(path: str | Path) -> Scenario:
    """A scenario from JSON::

    {"name": "zealots-vs-dragoons",
     "kind": "disks",                       # or "separated", "symmetric"
     "player0": [{"type": "Protoss_Zealot", "count": 8}],
     "player1": [{"type": "Protoss_Dragoon", "count": 6}],
     "center0": [565, 352], "center1": [715, 352],   # disks / separated
     "radius0": 100, "radius1": 100,                  # disks
     "spread": [128, 128]}                            # separated / symmetric
    """
    from hybridmarl.io import read_user_json

    p = Path(path)
    doc = read_user_json(p, "scenario file", InputError)
    try:
        return _scenario_from_document(doc, p.stem)
    except InputError as e:
        raise InputError(
            f"scenario file {str(p)!r}: {str(e).removeprefix('scenario file: ')}"
        ) from None


#: The keys of a scenario file (any other is a typo, refused rather than ignored).
SCENARIO_KEYS = (
    "name",
    "description",
    "kind",
    "player0",
    "player1",
    "center0",
    "center1",
    "radius0",
    "radius1",
    "spread",
)


def _scenario_from_document(doc: dict[str, Any], stem: str) -> Scenario:
    unknown = sorted(set(doc) - set(SCENARIO_KEYS))
    if unknown:
        raise InputError(f"unknown key {unknown[0]!r} (known: {', '.join(SCENARIO_KEYS)})")
    if not isinstance(doc.get("name", ""), str):
        raise InputError(f"name must be a string, got {doc['name']!r}")
    kind = doc.get("kind", "disks")
    if kind not in ("disks", "separated", "symmetric"):
        raise InputError(f"scenario file: kind must be disks, separated or symmetric, got {kind!r}")
    side0 = _side(doc.get("player0"), "player0")
    side1 = side0 if kind in ("separated", "symmetric") else _side(doc.get("player1"), "player1")
    base = named_scenario("m1v1")
    sc = Scenario(
        name=str(doc.get("name", stem)),
        side0=side0,
        side1=side1,
        kind=kind,
        center0=_pair(doc["center0"], "center0") if "center0" in doc else base.center0,
        center1=_pair(doc["center1"], "center1") if "center1" in doc else base.center1,
        radius0=_radius(doc.get("radius0", base.radius0), "radius0"),
        radius1=_radius(doc.get("radius1", doc.get("radius0", base.radius1)), "radius1"),
        spread=_pair(doc["spread"], "spread", low=1) if "spread" in doc else (128, 128),
    )
    _check_fits(sc)
    return sc


def _check_fits(sc: Scenario) -> None:
    grid = default_walkable()
    h, w = grid.shape[0] * 8, grid.shape[1] * 8
    if sc.kind == "disks":
        for c, r, who in ((sc.center0, sc.radius0, "player0"), (sc.center1, sc.radius1, "player1")):
            if r < 0 or c[0] - r < 0 or c[1] - r < 0 or c[0] + r >= w or c[1] + r >= h:
                raise InputError(
                    f"scenario file: {who}'s disk (centre {c}, radius {r}) leaves the {w}x{h} map"
                )
    else:
        # Offsets are uniform in [-spread, spread - 1], and mirrored: units land within
        # [c - spread, c + spread] of their centre.
        centres = (sc.center0, sc.center1) if sc.kind == "separated" else (SYMMETRIC_CENTER,)
        for c in centres:
            if (
                c[0] - sc.spread[0] < 0
                or c[1] - sc.spread[1] < 0
                or c[0] + sc.spread[0] >= w
                or c[1] + sc.spread[1] >= h
            ):
                raise InputError(
                    f"scenario file: spread {sc.spread} around {c} leaves the {w}x{h} map"
                )


def resolve_scenario(
    name: str | None = None, path: str | None = None, setting: Any = None
) -> Scenario:
    """A scenario file (``path``) or the named scenario ``name`` under ``setting``."""
    if path:
        return load_scenario_file(path)
    if not name:
        raise InputError("give a scenario name (e.g. m5v5) or a scenario file")
    return named_scenario(name, setting)
