"""The HTML replay viewer (``hybridmarl replay --html OUT.html``): an episode recorded turn by
turn (combat) or step by step (Traffic Junction) and written as one self-contained page.

- :func:`~hybridmarl.viewer.combat.record_combat_timeline`: a combat episode, every engine turn.
- :func:`~hybridmarl.viewer.traffic_junction.record_tj_timeline`: a Traffic Junction episode.
- :func:`~hybridmarl.viewer.page.write_page`: the page (see :mod:`hybridmarl.viewer.page` for
  its DOM contract).
"""

from hybridmarl.viewer.combat import record_combat_timeline
from hybridmarl.viewer.page import render_page, write_page
from hybridmarl.viewer.traffic_junction import record_tj_timeline

__all__ = ["record_combat_timeline", "record_tj_timeline", "render_page", "write_page"]
