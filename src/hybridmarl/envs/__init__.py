"""Environments: pure-functional multi-agent envs (``base.MultiAgentEnv``) and their PettingZoo view.

>>> from hybridmarl import envs
>>> env = envs.make("combat", scenario="m5v5", enemy="attack-weakest")
>>> pz = envs.make_pettingzoo("traffic_junction")  # dict observations with "action_mask"

Known names: ``combat`` (:class:`hybridmarl.envs.combat.Combat`, the paper's SparCraft combat,
Section 5.1) and ``traffic_junction`` (:class:`hybridmarl.envs.traffic_junction.TrafficJunction`,
Section 5.3). The versioned names ``combat_v0`` and ``traffic_junction_v0`` (and ``tj``) are
accepted too. Submodules are imported on first use, so ``import hybridmarl.envs`` stays cheap.

:func:`env_class` maps a name to its class; every class also says what learning on it needs
(``hybridmarl.envs.base.LearningEnv``), so the training code never branches on the name.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hybridmarl.envs.base import LearningEnv

__all__ = ["ENV_NAMES", "canonical_env_name", "env_class", "make", "make_pettingzoo"]

#: Canonical environment names accepted by :func:`make`.
ENV_NAMES: tuple[str, ...] = ("combat", "traffic_junction")
_ALIASES = {
    "combat_v0": "combat",
    "traffic_junction_v0": "traffic_junction",
    "tj": "traffic_junction",
}


def canonical_env_name(name: str) -> str:
    """The canonical name of an environment (one of :data:`ENV_NAMES`); ``ValueError`` if unknown."""
    key = str(name).strip().lower().replace("-", "_")
    key = _ALIASES.get(key, key)
    if key not in ENV_NAMES:
        raise ValueError(f"unknown environment {name!r} (known: {', '.join(ENV_NAMES)})")
    return key


def env_class(name: str) -> type[LearningEnv]:
    """The class of the environment ``name`` (imported on first use)."""
    if canonical_env_name(name) == "combat":
        from hybridmarl.envs.combat import Combat

        return Combat
    from hybridmarl.envs.traffic_junction import TrafficJunction

    return TrafficJunction


def make(name: str, **kwargs: Any) -> Any:
    """The functional environment ``name`` built with ``kwargs`` (its constructor's arguments)."""
    return env_class(name)(**kwargs)


def make_pettingzoo(
    name: str,
    *,
    params: Any = None,
    render_mode: str | None = None,
    illegal_action: str = "fallback",
    obs_format: str = "dict",
    **kwargs: Any,
) -> Any:
    """A PettingZoo ``ParallelEnv`` (:class:`~hybridmarl.envs.pettingzoo.PettingZooAdapter`)
    over ``make(name, **kwargs)``.

    By default observations are ``{"observation", "action_mask"}`` dicts (``obs_format="array"``
    gives the bare observation arrays) and an illegal action is replaced by the agent's fallback
    action and counted in ``infos`` (``illegal_action="raise"`` raises ``ValueError``)."""
    from hybridmarl.envs.pettingzoo import PettingZooAdapter

    return PettingZooAdapter(
        make(name, **kwargs),
        params=params,
        render_mode=render_mode,
        illegal_action=illegal_action,
        obs_format=obs_format,
    )
