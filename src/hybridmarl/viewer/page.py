"""The replay viewer page: one self-contained HTML file (inline CSS and JavaScript, the episode
as embedded JSON; no server, no network, no external scripts).

The page's DOM is a small, stable contract that tests and users' scripts can read:

- ``#viewer[data-kind]``: ``combat`` or ``traffic_junction``.
- Controls: ``#btn-first``, ``#btn-prev``, ``#btn-play`` (``data-playing``), ``#btn-next``,
  ``#btn-last``, the timeline slider ``#frame-slider`` (one position per frame: per engine turn
  in combat, per step in Traffic Junction) and ``#frame-label``.
- ``#status`` with ``data-frame`` and, in combat, ``data-turn``, ``data-time``, ``data-step``,
  ``data-alive-ours``, ``data-alive-enemy``; in Traffic Junction ``data-t``.
- The side panel's rows ``tr.unit-row[data-unit-id]``; combat rows carry ``data-player``,
  ``data-type``, ``data-hp``, ``data-max-hp``, ``data-alive``, ``data-cooldown`` (frames until
  the unit can attack), ``data-move-cooldown``, ``data-action`` (the engine action it issued this
  turn) and, during a step, ``data-policy-action``, ``data-probs`` (JSON) and
  ``data-alg1-action`` (Alg. 1's action for the unit, hybrid runs); Traffic Junction rows (one
  per car slot) carry ``data-active``, ``data-action`` (gas/brake), ``data-collided`` and
  ``data-alg1-action``.
- The map ``svg#map``: combat units ``g.unit[data-unit-id][data-player][data-hp][data-alive]``
  and attack lines ``line.attack[data-from][data-to]``; Traffic Junction cars
  ``g.car[data-car-id][data-route][data-row][data-col][data-action]`` and collision markers
  ``rect.collision[data-row][data-col]``.
- ``window.hybridmarlViewer``: ``frameCount``, ``seek(i)``, ``frameOfTurn(t)``, ``current()``.
"""

from __future__ import annotations

import html
import json
from importlib import resources
from pathlib import Path
from typing import Any

from hybridmarl.io import atomic_write

__all__ = ["render_page", "write_page"]


def _template() -> str:
    return (
        resources.files("hybridmarl.viewer").joinpath("template.html").read_text(encoding="utf-8")
    )


def render_page(timeline: dict[str, Any], *, title: str, subtitle: str = "", fps: int = 8) -> str:
    """The page's HTML text for a recorded ``timeline`` (``hybridmarl.viewer.combat`` or
    ``hybridmarl.viewer.traffic_junction``); ``fps`` is the playback speed at 1x."""
    doc = {"timeline": timeline, "meta": {"title": title, "subtitle": subtitle, "fps": int(fps)}}
    # Inside <script>, "</script>" or "<!--" in a string would end the block: escape every "<"
    # (JSON.parse reads \u003c back as "<").
    payload = json.dumps(doc, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")
    return _template().replace("__TITLE__", html.escape(title)).replace("__DATA__", payload)


def write_page(
    path: str | Path, timeline: dict[str, Any], *, title: str, subtitle: str = "", fps: int = 8
) -> str:
    """Write the page atomically to ``path`` (parent folders created), UTF-8 whatever the
    locale; returns the path."""
    text = render_page(timeline, title=title, subtitle=subtitle, fps=fps)
    with atomic_write(path, "wb") as f:
        f.write(text.encode("utf-8"))
    return str(path)
