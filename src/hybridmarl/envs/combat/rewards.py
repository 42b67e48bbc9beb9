"""Per-agent rewards of the combat environment, for the value-based baselines (DQfD, OGTL).

The paper's method learns from the global, shared reward; DQfD and OGTL "need rewards of
single-agent action, which is same to [Hu et al., 2018]" (Section 5.2). Hu et al. (2018) reward a
unit for the damage it deals minus the damage it takes, plus a terminal bonus. Here, for our
agent ``i`` (unit slot ``i`` of player 0) and one env step ``s -> s'``::

    r_i = (dealt_i - taken_i) / H0  +  [done] * R_T

- ``dealt_i``: HP the enemy lost to unit ``i``'s attack during the step. Our units issue actions
  only on the step's first engine turn (the later turns of a step are enemy-only, see
  :mod:`hybridmarl.envs.combat`), so unit ``i`` made at most one attack: ``s'.last_actions[0, i]``
  is its engine action code (``ATTACK(j) = 6 + j``, ``j`` the enemy slot; ``-1`` if it did not
  act). Its damage follows the engine's rule (``hybridmarl.engine.rules.apply_actions``): the
  attacks of our side on one target execute in unit-id order; an attack deals
  ``min(dmg, hp_j - prior)`` where ``dmg`` is the weapon's damage against the target type
  (``units.TABLES.damage``) and ``prior`` the damage of our earlier attacks on ``j`` this turn,
  and nothing once the target is dead (the engine's overkill PASS). So ``sum_i dealt_i`` is
  exactly the enemy's HP loss in the step.
- ``taken_i = hp_i(s) - hp_i(s')``: the HP unit ``i`` lost during the step (all its engine turns).
- ``H0 = s.init_hp[0]``: the sum of all allied units' HP at the start state, **the env's own
  normaliser** (Section 5.1). With it the damage terms sum over agents to exactly the env's
  global reward ``[change of allied HP - change of enemy HP] / H0``.
- ``R_T = (allied HP - enemy HP) / H0`` at ``s'``: the env's terminal hit-points reward
  (``info["terminal_hp_reward"]``, Table 1's R), given to **every** agent (shared) on the step the
  battle ends (``done``). It plays the role of Hu et al.'s terminal win/loss bonus: it is positive
  exactly when we end with more HP than the enemy.

A step from a finished game (the env leaves it unchanged, ``s'.steps == s.steps``) gives 0.
Dead agents get 0 except the shared terminal term; the learners end an agent's own episode when
its unit dies (``hybridmarl.algos.dqfd``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hybridmarl.engine import units as U
from hybridmarl.engine.rules import ATTACK_BASE
from hybridmarl.engine.state import GameState
from hybridmarl.envs.combat.state import CombatState

__all__ = ["agent_rewards", "damage_dealt"]


def damage_dealt(game: GameState, last0: jax.Array) -> jax.Array:
    """float32 ``[U]``: HP dealt by each of player 0's units' attack issued from ``game``.

    ``game``: the engine ``GameState`` the step started from; ``last0``: int32 ``[U]`` the engine
    action each of our units issued on that turn (``-1``: none). Follows the engine's rule
    (attacks on one target in unit-id order; a dead target takes no more damage).
    """
    n = game.hp.shape[-1]
    code = last0.astype(jnp.int32)
    is_attack = code >= ATTACK_BASE
    target = jnp.clip(code - ATTACK_BASE, 0, n - 1)
    dmg = jnp.asarray(U.TABLES.damage)[game.utype[0], game.utype[1][target]]
    uid = game.uid[0]
    earlier = (
        (target[:, None] == target[None, :]) & is_attack[None, :] & (uid[None, :] < uid[:, None])
    )
    prior = jnp.sum(jnp.where(earlier, dmg[None, :], 0), axis=1)
    left = game.hp[1][target] - prior
    dealt = jnp.where(is_attack & (left > 0), jnp.minimum(dmg, left), 0)
    return dealt.astype(jnp.float32)


def agent_rewards(
    state: CombatState, next_state: CombatState, done: jax.Array, num_agents: int
) -> jax.Array:
    """float32 ``[num_agents]``: ``r_i`` of the module docstring for one combat step."""
    g, g2 = state.game, next_state.game
    stepped = next_state.steps > state.steps
    norm = jnp.maximum(state.init_hp[0], 1).astype(jnp.float32)
    dealt = damage_dealt(g, next_state.last_actions[0])[:num_agents]
    taken = (g.hp[0] - g2.hp[0])[:num_agents].astype(jnp.float32)
    hp = jnp.sum(jnp.maximum(g2.hp, 0), axis=1).astype(jnp.float32)
    terminal = (hp[0] - hp[1]) / norm
    r = (dealt - taken) / norm + jnp.where(done, terminal, 0.0)
    return jnp.where(stepped, r, 0.0).astype(jnp.float32)
