"""Pictures of combat states (Pillow, outside ``jit``; what they show is described in
:mod:`hybridmarl.envs.combat`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from hybridmarl.engine import rules as R
from hybridmarl.engine import units as UT
from hybridmarl.engine.state import (
    DEFAULT_MAP_HEIGHT_PX,
    DEFAULT_MAP_WIDTH_PX,
    PAD_ID_BASE,
    GameState,
    Rules,
)
from hybridmarl.envs.combat.state import CombatState

__all__ = ["DRAW_RADIUS", "camera_window", "render", "render_facts"]


def camera_window(
    states: GameState | Sequence[GameState],
    margin: int = 96,
    aspect: float = DEFAULT_MAP_WIDTH_PX / DEFAULT_MAP_HEIGHT_PX,
    min_width: int = 480,
) -> tuple[int, int, int, int]:
    """A fixed ``(x0, y0, w, h)`` map window (px) around every real unit of ``states``.

    Pass all states of an episode so the camera stays put; the box is widened to ``aspect``,
    at least ``min_width`` wide and clamped to the map where it fits.
    """
    games = [states] if isinstance(states, GameState) else list(states)
    xs, ys = [], []
    for g in games:
        real = np.asarray(g.uid) < PAD_ID_BASE
        xs.append(np.asarray(g.x)[real])
        ys.append(np.asarray(g.y)[real])
        xs.append(np.asarray(g.px)[real])
        ys.append(np.asarray(g.py)[real])
    x = np.concatenate(xs) if xs else np.zeros(1)
    y = np.concatenate(ys) if ys else np.zeros(1)
    x0, x1 = float(x.min()) - margin, float(x.max()) + margin
    y0, y1 = float(y.min()) - margin, float(y.max()) + margin
    w, h = max(x1 - x0, float(min_width)), y1 - y0
    w, h = max(w, h * aspect), max(h, w / aspect)
    cx, cy = (float(x.min()) + float(x.max())) / 2, (float(y.min()) + float(y.max())) / 2
    x0, y0 = cx - w / 2, cy - h / 2
    if w <= DEFAULT_MAP_WIDTH_PX:
        x0 = min(max(x0, 0.0), DEFAULT_MAP_WIDTH_PX - w)
    if h <= DEFAULT_MAP_HEIGHT_PX:
        y0 = min(max(y0, 0.0), DEFAULT_MAP_HEIGHT_PX - h)
    return round(x0), round(y0), round(w), round(h)


#: Approximate Brood War unit half-sizes in px, for drawing only (the GIF and HTML replays).
DRAW_RADIUS = {
    "Terran_Marine": 8,
    "Terran_Firebat": 9,
    "Terran_Vulture": 12,
    "Protoss_Zealot": 10,
    "Protoss_Dragoon": 15,
    "Zerg_Zergling": 7,
    "Zerg_Hydralisk": 10,
}
_PLAYER_COLOURS = ((214, 48, 49), (46, 170, 70))  # ours red, enemy green (paper Figure 2)
_LINE_COLOURS = ((255, 140, 130), (150, 245, 150))
_HEADER_PX = 24


def render_facts(rules: Rules) -> Callable[[GameState], tuple[jax.Array, ...]]:
    """A jitted ``game -> (cx, cy, acting, over, winner)``, what drawing needs from the engine
    (one compiled call per frame; eager op-by-op dispatch would cost more)."""

    def facts(g: GameState) -> tuple[jax.Array, ...]:
        ctx = R.turn_context(g, rules)
        return ctx.cx, ctx.cy, ctx.acting, R.game_over(g, rules), R.winner(g)

    return jax.jit(facts)


def render(
    state: CombatState,
    facts: Callable[[GameState], tuple[jax.Array, ...]],
    map_px: tuple[int, int],
    *,
    window: tuple[int, int, int, int] | None = None,
    width: int = 640,
) -> np.ndarray:
    """uint8 ``[24 + h, width, 3]`` picture of ``state``: a header, then the map ``window``
    (``(x0, y0, w, h)`` in map px, default the whole ``map_px``) scaled to ``width`` px.
    ``facts`` is :func:`render_facts` of the env's rules."""
    from PIL import Image, ImageDraw, ImageFont

    g = jax.device_get(state.game)
    last = np.asarray(jax.device_get(state.last_actions))
    init_hp = np.asarray(jax.device_get(state.init_hp))
    mw, mh = map_px
    x0, y0, ww, wh = window if window is not None else (0, 0, mw, mh)
    scale = width / ww
    out_h = round(wh * scale)
    img = Image.new("RGB", (width, _HEADER_PX + out_h), (28, 30, 34))
    draw = ImageDraw.Draw(img)

    def to_px(x: float, y: float) -> tuple[float, float]:
        return (x - x0) * scale, _HEADER_PX + (y - y0) * scale

    # Faint 64-px grid so motion is visible, and the map border.
    grid_col = (40, 43, 48)
    for gx in range(0, mw + 1, 64):
        if x0 <= gx <= x0 + ww:
            px_, _ = to_px(gx, 0)
            draw.line([(px_, _HEADER_PX), (px_, _HEADER_PX + out_h)], fill=grid_col)
    for gy in range(0, mh + 1, 64):
        if y0 <= gy <= y0 + wh:
            _, py_ = to_px(0, gy)
            draw.line([(0, py_), (width, py_)], fill=grid_col)

    t = int(g.time)
    cx, cy, acting, over, winner = (np.asarray(v) for v in facts(g))
    over = bool(over)
    hp = np.asarray(g.hp)
    utype = np.asarray(g.utype)
    real = np.asarray(g.uid) < PAD_ID_BASE
    max_hp = UT.TABLES.max_hp[utype]

    # Attack lines of the last step, under the units.
    for p in (0, 1):
        q = 1 - p
        for s in np.flatnonzero(real[p] & (last[p] >= R.ATTACK_BASE)):
            j = int(last[p, s]) - R.ATTACK_BASE
            a = to_px(cx[p, s], cy[p, s])
            b = to_px(cx[q, j], cy[q, j])
            draw.line([a, b], fill=_LINE_COLOURS[p], width=max(1, round(2 * scale)))
    for p in (0, 1):
        for s in np.flatnonzero(real[p]):
            x, y = to_px(cx[p, s], cy[p, s])
            r = max(3.0, DRAW_RADIUS.get(UT.TYPE_NAMES[utype[p, s]], 8) * scale)
            if hp[p, s] <= 0:
                c = (95, 95, 100)
                k = r * 0.6
                draw.line([(x - k, y - k), (x + k, y + k)], fill=c, width=2)
                draw.line([(x - k, y + k), (x + k, y - k)], fill=c, width=2)
                continue
            outline = (255, 255, 255) if (p == 0 and acting[p, s] and not over) else None
            draw.ellipse(
                [x - r, y - r, x + r, y + r],
                fill=_PLAYER_COLOURS[p],
                outline=outline,
                width=max(1, round(scale * 1.5)),
            )
            frac = float(hp[p, s]) / max(float(max_hp[p, s]), 1.0)
            bw, bh = 2 * r + 2, max(2.0, 3 * scale)
            bx, by = x - bw / 2, y - r - bh - 2
            draw.rectangle([bx, by, bx + bw, by + bh], fill=(20, 20, 20))
            colour = (
                (70, 210, 70) if frac > 0.5 else (235, 200, 40) if frac > 0.25 else (230, 60, 50)
            )
            draw.rectangle([bx, by, bx + bw * frac, by + bh], fill=colour)

    # Header.
    draw.rectangle([0, 0, width, _HEADER_PX - 1], fill=(12, 12, 14))
    sums = hp.clip(min=0).sum(axis=1)
    n_alive = (hp > 0).sum(axis=1)
    status = ""
    if over:
        w = int(winner)
        status = "  WON" if w == 0 else "  LOST" if w == 1 else "  DRAW"
    text = (
        f"step {int(state.steps)}  turn {int(g.turn)}  t={t}f  ours {n_alive[0]}u {sums[0]}/{init_hp[0]}hp"
        f"  enemy {n_alive[1]}u {sums[1]}/{init_hp[1]}hp{status}"
    )
    try:
        font: Any = ImageFont.load_default(size=14)
    except TypeError:  # pragma: no cover - Pillow without FreeType
        font = ImageFont.load_default()
    draw.text((6, 4), text, fill=(235, 235, 235), font=font)
    return np.asarray(img, dtype=np.uint8).copy()
