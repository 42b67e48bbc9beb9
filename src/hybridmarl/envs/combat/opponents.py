"""The enemy side of the combat environment: engine scripts by name, and a trained actor
playing player 1 through a mirrored view of the battle.

An enemy is an engine *script*, ``(key, game, ctx, p) -> int32 engine actions [U]`` for player
``p`` (``hybridmarl.engine.scripts``), played inside :class:`~hybridmarl.envs.combat.Combat`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.engine import rules as R
from hybridmarl.engine.scripts import SCRIPTS, Script, canonical_name, get_script
from hybridmarl.engine.state import GameState
from hybridmarl.envs.combat.state import CombatState

if TYPE_CHECKING:
    from hybridmarl.envs.combat.env import Combat

__all__ = ["CROSS_ENEMY", "cross_enemy", "learned_enemy", "mirror_game", "resolve_enemy"]

#: The paper's cross-validation (Section 5.1): a model learned from c fights w and vice versa.
CROSS_ENEMY = {"attack-closest": "attack-weakest", "attack-weakest": "attack-closest"}

#: GameState fields holding x coordinates (reflected when the battle is mirrored).
_X_FIELDS = ("x", "px")

#: ``actor(variables, obs [N, D], legal [N, A]) -> int32 actions [N]``: a trained policy's
#: greedy legal action (e.g. ``functools.partial(training.networks.actor_actions, module)``).
ActorApply = Callable[[Any, jax.Array, jax.Array], jax.Array]


def resolve_enemy(enemy: str | Script) -> tuple[str, Script]:
    """``(name, script)`` of an enemy given by script name or as a script function."""
    if isinstance(enemy, str):
        try:
            name = canonical_name(enemy)
        except KeyError:
            raise ValueError(
                f"unknown enemy script {enemy!r} (known: {', '.join(SCRIPTS)})"
            ) from None
        return name, get_script(name)
    if callable(enemy):
        return getattr(enemy, "__name__", "custom"), enemy
    raise ValueError(f"enemy must be a script name or a policy function, got {enemy!r}")


def cross_enemy(demonstrator: str) -> str:
    """The cross-validation enemy of a demonstrator (c <-> w), else attack-weakest."""
    base = str(demonstrator).partition(":")[0].strip()
    return CROSS_ENEMY.get(base, "attack-weakest")


def mirror_game(game: GameState, map_width: int) -> GameState:
    """``game`` seen from the other side: the players swapped (every per-player field of
    ``GameState``, i.e. every field with a leading player axis) and x reflected around the
    centre of a ``map_width``-px map, so player 1 becomes player 0 on the left."""
    changes: dict[str, jax.Array] = {}
    for f in dataclasses.fields(game):
        v = getattr(game, f.name)
        if jnp.ndim(v) == 0:
            continue  # shared by both players (frame, turn, stalemate counter)
        if f.name in _X_FIELDS:
            v = map_width - 1 - v
        changes[f.name] = v[::-1]
    return dataclasses.replace(game, **changes)


def learned_enemy(env: Combat, actor: ActorApply, variables: Any) -> Script:
    """A trained actor as the enemy *script* (player 1) of ``env``'s battles.

    The battle is mirrored for it (:func:`mirror_game`) so it sees itself as player 0 on the
    left, as in training; its left/right moves are flipped back. The actor must have been
    trained with as many agents as ``env`` has enemies and with ``5 + n0`` actions (``n0``:
    ``env``'s agents); :func:`mirror_env` builds the environment it sees.
    """
    mirror = mirror_env(env)
    width = env.map_px[0]
    u = env.num_slots
    left, right = R.MOVE_ACTIONS[0], R.MOVE_ACTIONS[1]

    def script(key: jax.Array, game: GameState, ctx: R.TurnContext, p: int) -> jax.Array:
        del key, ctx, p
        g = mirror_game(game, width)
        st = CombatState(
            game=g,
            last_actions=jnp.full((2, u), -1, jnp.int32),
            init_hp=g.prev_hp_sum,
            steps=jnp.zeros((), jnp.int32),
        )
        a = actor(variables, mirror.observe(st), mirror.get_avail_actions(st))
        codes = mirror.env_to_engine_actions(st, a)
        codes = jnp.where(codes == left, right, jnp.where(codes == right, left, codes))
        out = jnp.zeros((u,), jnp.int32).at[: codes.shape[0]].set(codes)
        return out.astype(jnp.int32)

    return script


def mirror_env(env: Combat) -> Combat:
    """A combat env with ``env``'s sides swapped: what a policy playing ``env``'s enemy sees."""
    from hybridmarl.envs.combat.env import Combat
    from hybridmarl.settings import DEFAULT_SETTING

    default = env.setting.name == DEFAULT_SETTING
    return Combat(
        scenario=f"m{env.num_enemies}v{env.num_agents}",
        enemy="attack-weakest",
        max_turns=env.max_turns,
        walkable=np.asarray(env.rules.walkable),
        # The default setting may carry overrides; any other setting has exactly its own rules.
        setting=None if default else env.setting.name,
        stalemate_limit=env.rules.stalemate_limit if default else None,
        overkill=env.rules.overkill if default else None,
    )
