"""Named settings: which rules and start geometry a scenario is played under.

A setting is data, :class:`Setting`: the combat rules (overkill, stalemate limit), the contact
geometry of the named Marine scenarios ``m<A>v<B>``, and Traffic Junction's arrival
probability. Two settings exist (``SETTINGS``):

- ``sparcraft`` (the default): SparCraft's current rules (DC-HEAD: an attack on a target killed
  earlier in the same turn makes the attacker PASS; the game ends after more than 50 turns without
  an HP change), disks of radius 100 px centred 150 px apart, and Traffic Junction's
  ``p_arrive`` 0.2 (CommNet's evaluation value).
- ``paper``: the setting of Peng, Xing & Cao (IJCAI 2020), which predates SparCraft's rule
  change: classic overkill (the attack spends its cooldown and deals no damage), a stalemate limit
  of 200 turns, a contact geometry calibrated so that both scripted demonstrators' win rates
  (Table 1, D_c and D_w) match the paper's, and the Traffic Junction arrival probability at which
  the always-gas demonstrator fails as often as the paper's D (Table 2). The calibration is
  ``experiments/paper_setting.py``; its table is in docs/engine.md#settings.

Settings never change what an explicit start-state file or a scenario file holds; they set the
geometry of the named scenarios ``m<A>v<B>`` and the rules. The ``-apart`` scenarios keep their
geometry (docs/engine.md#start-states-and-scenarios) and take the setting's rules.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hybridmarl.errors import UserError


class SettingError(UserError):
    """An unknown setting name, or options that contradict the chosen setting (one line)."""


@dataclass(frozen=True)
class ContactGeometry:
    """Start geometry of the named scenarios ``m<A>v<B>``: player 0's disk left of player 1's,
    both of radius ``radius`` px, centred on the map's middle row and
    ``separation + separation_per_unit * (A + B)`` px apart (rounded to whole pixels)."""

    separation: int = 150
    radius: int = 100
    separation_per_unit: float = 0.0

    def separation_for(self, a: int, b: int) -> int:
        """Distance between the disk centres for ``a`` units against ``b``."""
        return int(round(self.separation + self.separation_per_unit * (int(a) + int(b))))

    def describe(self) -> str:
        if self.separation_per_unit:
            k = "" if self.separation_per_unit == 1 else f"{self.separation_per_unit:g} x "
            return (
                f"disks of radius {self.radius} px, centres {self.separation} + {k}(A + B) px apart "
                "for A vs B units"
            )
        return f"disks of radius {self.radius} px centred {self.separation} px apart"


@dataclass(frozen=True)
class Setting:
    """Rules and start geometry of one named setting (module docstring)."""

    name: str
    overkill: str  # "pass" (SparCraft DC-HEAD) | "classic"
    stalemate_limit: int
    geometry: ContactGeometry
    p_arrive: float  # Traffic Junction arrival probability
    description: str

    def rules(self, walkable: Any = None, *, max_turns: int = 20000):
        """The engine ``Rules`` of this setting (``engine.state.make_rules``)."""
        from hybridmarl.engine.state import make_rules

        return make_rules(
            walkable,
            stalemate_limit=self.stalemate_limit,
            overkill=self.overkill,
            max_turns=max_turns,
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "overkill": self.overkill,
            "stalemate_limit": self.stalemate_limit,
            "geometry": self.geometry.describe(),
            "p_arrive": self.p_arrive,
        }


DEFAULT_SETTING = "sparcraft"

#: Traffic Junction arrival probability of the paper setting: always-gas fails in 0.72 of the
#: episodes there (0.719 over 8,000 episodes), the paper's D (Table 2); measured with
#: experiments/paper_setting.py --mode tj (docs/environments.md#settings).
PAPER_P_ARRIVE = 0.105

#: Contact geometry of the paper setting: disks of radius 110 px whose centres are 112 + A + B px
#: apart (m5v5: 122, m18v20: 150, m24v30: 166, m30v30: 172). Calibrated on the four scenarios of
#: Table 1 with experiments/paper_setting.py (docs/engine.md#settings).
PAPER_GEOMETRY = ContactGeometry(separation=112, radius=110, separation_per_unit=1.0)

SETTINGS: dict[str, Setting] = {
    "sparcraft": Setting(
        name="sparcraft",
        overkill="pass",
        stalemate_limit=50,
        geometry=ContactGeometry(separation=150, radius=100),
        p_arrive=0.2,
        description="SparCraft's current rules (DC-HEAD overkill PASS, stalemate after 50 turns)",
    ),
    "paper": Setting(
        name="paper",
        overkill="classic",
        stalemate_limit=200,
        geometry=PAPER_GEOMETRY,
        p_arrive=PAPER_P_ARRIVE,
        description="the paper's setting (classic overkill, stalemate after 200 turns, calibrated geometry)",
    ),
}


def get_setting(name: str | Setting | None) -> Setting:
    """The setting called ``name`` (None: the default); ``SettingError`` if unknown."""
    if isinstance(name, Setting):
        return name
    key = DEFAULT_SETTING if name is None else str(name).strip().lower()
    try:
        return SETTINGS[key]
    except KeyError:
        raise SettingError(f"unknown setting {name!r} (known: {', '.join(SETTINGS)})") from None


def check_options(
    setting: str | None,
    *,
    overkill: str | None = None,
    stalemate_limit: int | None = None,
    p_arrive: float | None = None,
) -> Setting:
    """The setting ``setting`` names, after checking that options given beside it agree with it.

    The default setting (``sparcraft``, also ``setting`` None) is the base of custom runs: any
    option may change it. Every other setting is fixed: an option given beside it that differs
    from the setting's own value raises ``SettingError`` (``--setting paper --overkill pass`` is
    a contradiction, not an override).
    """
    s = get_setting(setting)
    if s.name == DEFAULT_SETTING:
        return s
    given = (
        ("overkill", overkill, s.overkill),
        ("stalemate-limit", stalemate_limit, s.stalemate_limit),
        ("p-arrive", p_arrive, s.p_arrive),
    )
    for flag, value, own in given:
        if value is not None and value != own:
            raise SettingError(
                f"--{flag} {value} contradicts --setting {s.name} ({flag} {own}); drop one of them"
            )
    return s


def resolve(
    setting: str | None,
    *,
    overkill: str | None = None,
    stalemate_limit: int | None = None,
) -> tuple[Setting, str, int]:
    """(setting, overkill, stalemate limit): the options where given, else the setting's
    (after :func:`check_options`)."""
    s = check_options(setting, overkill=overkill, stalemate_limit=stalemate_limit)
    return (
        s,
        s.overkill if overkill is None else overkill,
        s.stalemate_limit if stalemate_limit is None else int(stalemate_limit),
    )


__all__ = [
    "DEFAULT_SETTING",
    "PAPER_GEOMETRY",
    "PAPER_P_ARRIVE",
    "SETTINGS",
    "ContactGeometry",
    "Setting",
    "SettingError",
    "check_options",
    "get_setting",
    "resolve",
]
