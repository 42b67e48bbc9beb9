"""Pictures of Traffic Junction states (NumPy and Pillow, outside ``jit``)."""

from __future__ import annotations

import numpy as np

from hybridmarl.envs.traffic_junction.env import (
    GRID_SIZE,
    JUNCTION_CELLS,
    ROAD_MASK,
    TJState,
    car_cells,
)

__all__ = ["ROUTE_COLOURS", "render"]

# 12 route colours for rendering: one hue family per entry, three shades for the turns.
# fmt: off
ROUTE_COLOURS = np.array(
    [
        (31, 119, 180), (100, 170, 230), (10, 60, 120),  # N: blues
        (44, 160, 44), (120, 210, 110), (20, 95, 20),  # E: greens
        (255, 127, 14), (255, 190, 110), (170, 80, 0),  # W: oranges
        (148, 103, 189), (200, 170, 230), (90, 50, 130),  # S: purples
    ],
    dtype=np.uint8,
)
# fmt: on


def render(state: TJState, cell_px: int = 24) -> np.ndarray:
    """uint8 ``[14*cell_px, 14*cell_px, 3]``: dark off-road, grey road (lighter junction),
    a square per car coloured by route (overlapping cars as stripes), a red frame on cells
    holding 2+ cars, and ``t`` in the corner."""
    from PIL import Image, ImageDraw

    g, c = GRID_SIZE, cell_px
    img = np.full((g * c, g * c, 3), 40, dtype=np.uint8)
    for r in range(g):
        for col in range(g):
            if ROAD_MASK[r, col]:
                shade = 170 if (r, col) in JUNCTION_CELLS else 135
                img[r * c + 1 : (r + 1) * c - 1, col * c + 1 : (col + 1) * c - 1] = shade
    active = np.asarray(state.active)
    cells = np.asarray(car_cells(state))
    routes = np.asarray(state.route)
    occupants: dict[tuple[int, int], list[int]] = {}
    for i in np.flatnonzero(active):
        occupants.setdefault((int(cells[i, 0]), int(cells[i, 1])), []).append(int(routes[i]))
    m = max(c // 6, 1)
    red = np.array((220, 20, 20), np.uint8)
    for (r, col), rids in occupants.items():
        y0, y1, x0, x1 = r * c, (r + 1) * c, col * c, (col + 1) * c
        # Overlapping cars share the square as vertical stripes, so each stays visible.
        edges = np.linspace(x0 + m, x1 - m, len(rids) + 1).round().astype(int)
        for k, rid in enumerate(rids):
            img[y0 + m : y1 - m, edges[k] : edges[k + 1]] = ROUTE_COLOURS[rid]
        if len(rids) > 1:
            f = max(c // 12, 1)
            img[y0 : y0 + f, x0:x1] = red
            img[y1 - f : y1, x0:x1] = red
            img[y0:y1, x0 : x0 + f] = red
            img[y0:y1, x1 - f : x1] = red
    pil = Image.fromarray(img)
    ImageDraw.Draw(pil).text((3, 2), f"t={int(state.t)}", fill=(230, 230, 230))
    return np.asarray(pil, dtype=np.uint8).copy()
