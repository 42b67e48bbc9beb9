"""The combat environment: :class:`Combat` (reset, step, look-ahead, batches, masks).

The environment's description (actions, observations, rewards, termination) is the package's
docstring, :mod:`hybridmarl.envs.combat`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from hybridmarl.engine import rules as R
from hybridmarl.engine.scenarios import Scenario, load_states_file, named_scenario, side_types
from hybridmarl.engine.scripts import SCRIPTS, Script, canonical_name, get_script
from hybridmarl.engine.state import (
    PAD_ID_BASE,
    WALK_TILE,
    GameState,
    UnitSpec,
    build_state,
    make_rules,
    stack_states,
)
from hybridmarl.envs.base import LearningEnv, Policy, canonical_policy_name
from hybridmarl.envs.combat import observe as O
from hybridmarl.envs.combat import render as draw
from hybridmarl.envs.combat import rewards
from hybridmarl.envs.combat.observe import (
    CRITIC_SIDE_FIELDS,
    K_ALLIES,
    K_ENEMIES,
    SELF_FIELDS,
    UNIT_FIELDS,
)
from hybridmarl.envs.combat.opponents import resolve_enemy
from hybridmarl.envs.combat.state import INT32_MAX, CombatParams, CombatState, ScenarioSampler
from hybridmarl.envs.combat.view import (
    ATTACK_OFFSET,
    NOOP,
    View,
    action_mask,
    engine_to_env,
    env_to_engine,
    make_view,
)
from hybridmarl.envs.stats import t_interval, wilson_interval
from hybridmarl.settings import resolve as resolve_setting

__all__ = ["Combat"]


class Combat(LearningEnv[CombatState, CombatParams]):
    """SparCraft combat, our units as agents against a scripted enemy (see :mod:`hybridmarl.envs.combat`).

    Args:
        scenario: a scenario name (``"m5v5"``, ``"m18v20"``, ``"m30v30-apart"``, ...) or a
            ``Scenario``; default ``"m5v5"`` unless ``start_states`` is given (then ``None``:
            reset draws only from the bank).
        enemy: the enemy's policy: a script name (``hybridmarl.engine.scripts.SCRIPTS``) or a
            function with the script signature ``(key, state, ctx, p) -> int32 [U]``. Default
            ``attack-weakest``, one of the paper's two heuristics (Section 5.1).
        max_turns: cap on *engine* decision turns per episode (default 1000; see Termination).
        debug: raise on illegal actions instead of replacing them (see Action space).
        start_states: a bank of start states: a list of unit lists (``UnitSpec``) or a stacked
            ``GameState``; becomes ``default_params.bank``.
        setting: the named setting (``hybridmarl.settings``: ``"sparcraft"``, the default, or
            ``"paper"``): the geometry of a named scenario and the rules' overkill and stalemate
            limit (docs/engine.md#settings).
        stalemate_limit, overkill: override the setting's (``SettingError`` if they contradict a
            setting that is not the default).
        walkable: the walk-tile map (default SparCraft's 1280x704 all-walkable map).
        num_allies_obs, num_enemies_obs: allies / enemies in the observation (10 / 10).
    """

    #: Dead units never come back, so the PettingZoo adapter terminates and removes their agents.
    remove_inactive_agents = True

    def __init__(
        self,
        scenario: str | Scenario | None = None,
        enemy: str | Script = "attack-weakest",
        max_turns: int = 1000,
        debug: bool = False,
        start_states: Sequence[Sequence[UnitSpec]] | GameState | None = None,
        *,
        setting: str | None = None,
        stalemate_limit: int | None = None,
        overkill: str | None = None,
        walkable: np.ndarray | None = None,
        num_allies_obs: int = K_ALLIES,
        num_enemies_obs: int = K_ENEMIES,
    ) -> None:
        if scenario is None and start_states is None:
            scenario = "m5v5"
        self.setting, overkill, stalemate_limit = resolve_setting(
            setting, overkill=overkill, stalemate_limit=stalemate_limit
        )
        sc = named_scenario(scenario, self.setting) if isinstance(scenario, str) else scenario
        if int(max_turns) < 1:
            raise ValueError(f"max_turns must be >= 1, got {max_turns}")
        self.rules = make_rules(
            walkable, stalemate_limit=stalemate_limit, overkill=overkill, max_turns=int(max_turns)
        )
        self.max_turns = int(max_turns)
        self.debug = bool(debug)
        self.scenario = sc
        self.enemy_name, self.enemy = resolve_enemy(enemy)

        # Shapes: agents = the largest P0 side, M = the largest P1 side of scenario and bank.
        counts: list[tuple[int, int]] = []
        if sc is not None:
            t0, t1 = side_types(sc)
            counts.append((len(t0), len(t1)))
        bank: GameState | None = None
        bank_units: list[list[UnitSpec]] | None = None
        if start_states is not None:
            if isinstance(start_states, GameState):
                bank = start_states if start_states.hp.ndim == 3 else stack_states([start_states])
                real = np.asarray(bank.uid) < PAD_ID_BASE
                counts.append((int(real[:, 0].sum(1).max()), int(real[:, 1].sum(1).max())))
            else:
                bank_units = [list(s) for s in start_states]
                if not bank_units:
                    raise ValueError("start_states is empty")
                for s in bank_units:
                    counts.append((sum(u.player == 0 for u in s), sum(u.player == 1 for u in s)))
        n0 = max(c[0] for c in counts)
        n1 = max(c[1] for c in counts)
        if n0 < 1 or n1 < 1:
            raise ValueError("each side needs at least one unit")
        self.num_slots = max(n0, n1)
        if bank is not None and bank.hp.shape[-1] != self.num_slots:
            raise ValueError(
                f"start-state bank has {bank.hp.shape[-1]} slots per side, expected {self.num_slots}"
            )
        if bank_units is not None:
            bank = stack_states([build_state(s, self.num_slots) for s in bank_units])
        self.num_agents = n0
        self.num_enemies = n1
        self.agents = tuple(f"unit_{i}" for i in range(n0))
        self.num_actions = ATTACK_OFFSET + n1
        self.k_allies = int(num_allies_obs)
        self.k_enemies = int(num_enemies_obs)
        self.self_size = len(SELF_FIELDS)
        self.unit_size = len(UNIT_FIELDS)
        self.observation_shape = (
            self.self_size + self.unit_size * (self.k_allies + self.k_enemies),
        )
        self.critic_feature_size = 2 * len(CRITIC_SIDE_FIELDS) + 1
        self.name = "combat_v0"
        self.default_params = CombatParams(bank=bank)
        walk = np.asarray(self.rules.walkable)
        self._sampler = ScenarioSampler.build(sc, self.num_slots, walk) if sc is not None else None
        #: (width, height) of the map in px.
        self.map_px = (walk.shape[1] * WALK_TILE, walk.shape[0] * WALK_TILE)

    @classmethod
    def from_states_file(cls, path: str | Path, **kwargs: Any) -> Combat:
        """An env whose ``reset`` draws from the start states of a ``{"states": [...]}`` JSON file
        (validated by ``engine.scenarios.load_states_file``; bad input raises ``InputError``)."""
        walkable = kwargs.get("walkable")
        states = load_states_file(path, walkable=walkable)
        return cls(start_states=states, **kwargs)

    # -- start states -----------------------------------------------------------------------------

    def game_state(self, units: Sequence[UnitSpec]) -> GameState:
        """A ``GameState`` padded to this env's slot count (host side; for ``reset_to``)."""
        n0 = sum(u.player == 0 for u in units)
        n1 = sum(u.player == 1 for u in units)
        if n0 > self.num_agents or n1 > self.num_enemies:
            raise ValueError(
                f"state has {n0} vs {n1} units; this env has {self.num_agents} agents and "
                f"{self.num_enemies} enemies"
            )
        return build_state(units, self.num_slots)

    def sample_game(self, key: jax.Array, params: CombatParams | None = None) -> GameState:
        """Draw a start ``GameState`` (bank if ``params.bank`` is set, else the generator)."""
        params = self.default_params if params is None else params
        if params.bank is not None:
            k = params.bank.hp.shape[0]
            i = jax.random.randint(key, (), 0, k)
            return jax.tree.map(lambda a: a[i], params.bank)
        s = self._sampler
        if s is None:
            raise ValueError(
                "this env has no scenario generator: pass params with a start-state bank"
            )
        return s.sample(key)

    # -- core API ---------------------------------------------------------------------------------

    def reset(
        self, key: jax.Array, params: CombatParams | None = None
    ) -> tuple[jax.Array, CombatState]:
        k_sample, k_adv = jax.random.split(key)
        return self.reset_to(self.sample_game(k_sample, params), k_adv)

    def reset_to(
        self, game: GameState, key: jax.Array | None = None
    ) -> tuple[jax.Array, CombatState]:
        """Start an episode from ``game`` (advancing enemy-only turns first). Jittable."""
        if game.hp.shape[-1] != self.num_slots:
            raise ValueError(
                f"state has {game.hp.shape[-1]} slots per side, this env uses {self.num_slots} "
                "(build it with env.game_state(units))"
            )
        key = jax.random.key(0) if key is None else key
        init_hp = R.hp_sums(game).astype(jnp.int32)
        u = self.num_slots
        last = jnp.full((2, u), -1, jnp.int32)
        game, last, _ = self._play(key, game, last, jnp.zeros((u,), jnp.int32), force_first=False)
        state = CombatState(
            game=game, last_actions=last, init_hp=init_hp, steps=jnp.zeros((), jnp.int32)
        )
        return self.observe(state), state

    def step(
        self,
        key: jax.Array,
        state: CombatState,
        actions: jax.Array,
        params: CombatParams | None = None,
    ) -> tuple[jax.Array, CombatState, jax.Array, jax.Array, dict[str, jax.Array]]:
        del params
        new_state, reward, done, info = self._step_core(key, state, actions)
        return self.observe(new_state), new_state, reward, done, info

    def lookahead(
        self, key: jax.Array, state: CombatState, candidate_actions: jax.Array
    ) -> tuple[jax.Array, CombatState, jax.Array]:
        """Alg. 1's one-step forward simulation of A joint actions (int32 ``[A, n0]``) from one
        state, as one vmapped call: ``(reward [A], next_state [A], done [A])``; each entry equals
        ``step(key, state, candidate_actions[a])``. Batch over states with
        ``jax.vmap(env.lookahead, in_axes=(0, 0, 0))``."""

        def one(actions: jax.Array) -> tuple[jax.Array, CombatState, jax.Array]:
            s, r, d, _ = self._step_core(key, state, actions)
            return r, s, d

        return jax.vmap(one)(jnp.asarray(candidate_actions, jnp.int32))

    def get_avail_actions(
        self, state: CombatState, params: CombatParams | None = None
    ) -> jax.Array:
        del params
        return self._mask(self._view(state.game))

    def agent_active(self, state: CombatState) -> jax.Array:
        """bool ``[n0]``: the agent's unit is alive."""
        return state.game.hp[0, : self.num_agents] > 0

    def fallback_actions(self, state: CombatState) -> jax.Array:
        """int32 ``[n0]``: the env action an illegal action is replaced by (noop where legal,
        else the engine's first legal action; noop for units that do not act)."""
        view = self._view(state.game)
        first = R.first_legal_action(view.ctx, 0)
        env_first = self._engine_to_env(view, first)
        acting = view.ctx.acting[0, : self.num_agents] & ~view.over
        return jnp.where(acting, env_first, NOOP).astype(jnp.int32)

    def is_done(self, state: CombatState) -> jax.Array:
        return R.game_over(state.game, self.rules)

    # -- the step ---------------------------------------------------------------------------------

    def _our_turn(self, game: GameState) -> jax.Array:
        pmin = R.player_minimum_free_time(game)
        return (pmin[0] <= pmin[1]) & (pmin[0] < INT32_MAX)

    def _turn(
        self, key: jax.Array, game: GameState, last: jax.Array, ours: jax.Array, n: jax.Array
    ) -> tuple[GameState, jax.Array]:
        """One engine turn, the ``n``-th of a step: our engine actions ``ours`` [U] (ignored for
        units that do not act) and the enemy script's, with key ``fold_in(key, n)``."""
        ctx = R.turn_context(game, self.rules)
        a1 = self.enemy(jax.random.fold_in(key, n), game, ctx, 1).astype(jnp.int32)
        joint = jnp.stack([ours, a1])
        return R.apply_actions(game, ctx, joint, self.rules), jnp.where(ctx.acting, joint, last)

    def _needs_enemy_turn(self, game: GameState) -> jax.Array:
        return ~R.game_over(game, self.rules) & ~self._our_turn(game)

    def _play(
        self,
        key: jax.Array,
        game: GameState,
        last: jax.Array,
        ours: jax.Array,
        force_first: bool,
        n_start: int = 0,
        active: jax.Array | bool = True,
    ) -> tuple[GameState, jax.Array, jax.Array]:
        """Engine turns under one ``lax.while_loop``: the first turn with our engine actions
        ``ours`` [U] if ``force_first`` (on later turns none of our units acts, so their entries
        are ignored), then enemy-only turns until one of our units acts or the game is over
        (none at all if not ``active``). One loop body (one copy of the enemy script and
        ``apply_actions``) keeps compile times down. Turns are numbered from ``n_start`` (the
        enemy's key). Returns the game, the updated ``last_actions`` and the turns played."""
        pass_all = jnp.full_like(ours, R.PASS_ACTION)

        def cond(carry: tuple[GameState, jax.Array, jax.Array]) -> jax.Array:
            g, _, n = carry
            more = active & self._needs_enemy_turn(g)
            return (n == 0) | more if force_first else more

        def body(
            carry: tuple[GameState, jax.Array, jax.Array],
        ) -> tuple[GameState, jax.Array, jax.Array]:
            g, last, n = carry
            a0 = jnp.where(n == 0, ours, pass_all) if force_first else pass_all
            g2, last = self._turn(key, g, last, a0, n + n_start)
            return g2, last, n + 1

        return lax.while_loop(cond, body, (game, last, jnp.zeros((), jnp.int32)))

    def _our_engine_actions(
        self, state: CombatState, actions: jax.Array
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(engine actions [U] for our side with illegal ones replaced, illegal [n0], over)."""
        n0, u = self.num_agents, self.num_slots
        view = self._view(state.game)
        mask = self._mask(view)
        a = jnp.asarray(actions).astype(jnp.int32).reshape((n0,))
        in_bounds = (a >= 0) & (a < self.num_actions)
        ok = (
            in_bounds
            & jnp.take_along_axis(mask, jnp.clip(a, 0, self.num_actions - 1)[:, None], axis=1)[:, 0]
        )
        illegal = ~ok
        if self.debug:
            self._check_legal(a, mask, illegal)
        first = R.first_legal_action(view.ctx, 0)[:n0]
        codes = jnp.where(illegal, first, self._env_to_engine(view, a))
        eng0 = jnp.full((u,), R.PASS_ACTION, jnp.int32).at[:n0].set(codes)
        return eng0, illegal, view.over

    def _step_core(
        self, key: jax.Array, state: CombatState, actions: jax.Array
    ) -> tuple[CombatState, jax.Array, jax.Array, dict[str, jax.Array]]:
        eng0, illegal, over0 = self._our_engine_actions(state, actions)
        last0 = jnp.full_like(state.last_actions, -1)
        # The loop's first turn recomputes this turn's context from the same game: same values.
        g2, last, n_turns = self._play(key, state.game, last0, eng0, force_first=True)
        return self._finish(state, g2, last, n_turns, illegal, over0)

    def _finish(
        self,
        state: CombatState,
        g2: GameState,
        last: jax.Array,
        n_turns: jax.Array,
        illegal: jax.Array,
        over0: jax.Array,
    ) -> tuple[CombatState, jax.Array, jax.Array, dict[str, jax.Array]]:
        g = state.game
        # A finished game stays as it is.
        g_new = jax.tree.map(lambda old, new: jnp.where(over0, old, new), g, g2)
        last = jnp.where(over0, state.last_actions, last)
        new_state = CombatState(
            game=g_new,
            last_actions=last,
            init_hp=state.init_hp,
            steps=state.steps + jnp.where(over0, 0, 1).astype(jnp.int32),
        )
        norm = jnp.maximum(state.init_hp[0], 1).astype(jnp.float32)
        hp_old = R.hp_sums(g)
        hp_new = R.hp_sums(g_new)
        diff_old = (hp_old[0] - hp_old[1]).astype(jnp.float32)
        diff_new = (hp_new[0] - hp_new[1]).astype(jnp.float32)
        reward = (diff_new - diff_old) / norm
        done = R.game_over(g_new, self.rules)
        info = self._info(new_state, done, norm, illegal, jnp.where(over0, 0, n_turns))
        return new_state, reward.astype(jnp.float32), done, info

    def batch_step(
        self,
        keys: jax.Array,
        states: CombatState,
        actions: jax.Array,
        params: CombatParams | None = None,
        *,
        sub_batch: int | None = None,
    ) -> tuple[jax.Array, CombatState, jax.Array, jax.Array, dict[str, jax.Array]]:
        """``jax.vmap(env.step)(keys, states, actions)`` (same results), faster for large batches.

        Under ``vmap`` the enemy-only turns of a step run in lockstep: the whole batch pays for
        as many loop iterations as its slowest game (3-4 at B = 1024 while the mean is ~1.1).
        Here every game plays its decision turn at once, then only the games that still owe
        enemy-only turns are gathered into sub-batches of ``sub_batch`` games (default
        ceil(B / 8)) and advanced there, round after round until none is left.
        """
        del params
        b = keys.shape[0]
        size = max(1, min(b, sub_batch if sub_batch is not None else -(-b // 8)))

        def first_turn(
            k: jax.Array, state: CombatState, a: jax.Array
        ) -> tuple[GameState, jax.Array, jax.Array, jax.Array, jax.Array]:
            eng0, illegal, over0 = self._our_engine_actions(state, a)
            last0 = jnp.full_like(state.last_actions, -1)
            g1, last1 = self._turn(k, state.game, last0, eng0, jnp.int32(0))
            return g1, last1, illegal, over0, self._needs_enemy_turn(g1) & ~over0

        g1, last1, illegal, over0, pending = jax.vmap(first_turn)(keys, states, actions)
        turns = jnp.ones((b,), jnp.int32)

        def more(carry: tuple[Any, ...]) -> jax.Array:
            return jnp.any(carry[3])

        def round_(carry: tuple[Any, ...]) -> tuple[Any, ...]:
            g, last, turns, pending = carry
            idx = jnp.nonzero(pending, size=size, fill_value=b)[0]
            take = jnp.minimum(idx, b - 1)
            sub = jax.tree.map(lambda a: a[take], g)
            g2, last2, n = jax.vmap(
                lambda k, gg, ll, act: self._play(
                    k, gg, ll, jnp.zeros((self.num_slots,), jnp.int32), False, 1, act
                )
            )(keys[take], sub, last[take], idx < b)
            g = jax.tree.map(lambda a, v: a.at[idx].set(v, mode="drop"), g, g2)
            last = last.at[idx].set(last2, mode="drop")
            turns = turns.at[idx].add(n, mode="drop")
            pending = pending.at[idx].set(False, mode="drop")
            return g, last, turns, pending

        g2, last2, turns, _ = lax.while_loop(more, round_, (g1, last1, turns, pending))

        def finish(*args: Any) -> tuple[Any, ...]:
            new, reward, done, info = self._finish(*args)
            return self.observe(new), new, reward, done, info

        return jax.vmap(finish)(states, g2, last2, turns, illegal, over0)

    def _info(
        self,
        state: CombatState,
        done: jax.Array,
        norm: jax.Array,
        illegal: jax.Array,
        engine_turns: jax.Array,
    ) -> dict[str, jax.Array]:
        g = state.game
        hp = R.hp_sums(g)
        w = R.winner(g)
        won = done & (w == 0)
        lost = done & (w == 1)
        alive = g.hp > 0
        return {
            "won": won,
            "lost": lost,
            "draw": done & ~won & ~lost,
            "truncated": done & ~R.is_terminal(g, self.rules),
            "terminal_hp_reward": ((hp[0] - hp[1]).astype(jnp.float32) / norm).astype(jnp.float32),
            "allied_hp": hp[0].astype(jnp.int32),
            "enemy_hp": hp[1].astype(jnp.int32),
            "allied_alive": jnp.sum(alive[0], dtype=jnp.int32),
            "enemy_alive": jnp.sum(alive[1], dtype=jnp.int32),
            "turn": g.turn,
            "time": g.time,
            "steps": state.steps,
            "illegal_actions": jnp.sum(illegal, dtype=jnp.int32),
            "engine_turns": engine_turns.astype(jnp.int32),
        }

    def _check_legal(self, a: jax.Array, mask: jax.Array, illegal: jax.Array) -> None:
        agents = self.agents

        def report(a_np: Any, mask_np: Any, illegal_np: Any) -> None:
            a_np, mask_np, illegal_np = (
                np.asarray(a_np),
                np.asarray(mask_np),
                np.asarray(illegal_np),
            )
            if not illegal_np.any():
                return
            a2 = a_np.reshape(-1, a_np.shape[-1])
            m2 = mask_np.reshape(-1, *mask_np.shape[-2:])
            bad = illegal_np.reshape(-1, illegal_np.shape[-1])
            b, i = (int(v) for v in np.argwhere(bad)[0])
            legal = np.flatnonzero(m2[b, i]).tolist()
            raise ValueError(
                f"combat: illegal action {int(a2[b, i])} for agent {agents[i]!r} "
                f"(legal actions: {legal}; {int(bad.sum())} illegal in all)"
            )

        try:  # concrete values (eager call): check on the host right away
            concrete = (np.asarray(a), np.asarray(mask), np.asarray(illegal))
        except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
            jax.debug.callback(report, a, mask, illegal)  # traced: check when it runs
        else:
            report(*concrete)

    # -- actions ----------------------------------------------------------------------------------

    def _view(self, game: GameState) -> View:
        return make_view(game, self.rules)

    def _mask(self, view: View) -> jax.Array:
        return action_mask(view, self.num_agents, self.num_enemies)

    def _env_to_engine(self, view: View, a: jax.Array) -> jax.Array:
        return env_to_engine(view, a, self.num_agents, self.num_enemies)

    def _engine_to_env(self, view: View, codes: jax.Array) -> jax.Array:
        return engine_to_env(view, codes, self.num_agents)

    def env_to_engine_actions(self, state: CombatState, actions: jax.Array) -> jax.Array:
        """int32 ``[n0]`` engine action codes for env ``actions`` at ``state`` (no legality check)."""
        return self._env_to_engine(self._view(state.game), jnp.asarray(actions, jnp.int32))

    def engine_to_env_actions(self, state: CombatState, codes: jax.Array) -> jax.Array:
        """int32 ``[n0]`` env actions for player 0's engine codes (``[U]`` or ``[n0]``) at
        ``state``; non-acting units get noop. Inverse of :meth:`env_to_engine_actions` on legal
        actions."""
        view = self._view(state.game)
        env = self._engine_to_env(view, jnp.asarray(codes, jnp.int32))
        acting = view.ctx.acting[0, : self.num_agents] & ~view.over
        return jnp.where(acting, env, NOOP).astype(jnp.int32)

    def script_policy(self, script: str | Script) -> Policy:
        """Our side played by an engine script, as a pure env policy ``(key, state) -> [n0]``
        (scripted demonstrations, Section 5.1's heuristics c and w)."""
        fn = get_script(script) if isinstance(script, str) else script

        def policy(key: jax.Array, state: CombatState) -> jax.Array:
            ctx = R.turn_context(state.game, self.rules)
            return self.engine_to_env_actions(state, fn(key, state.game, ctx, 0))

        return policy

    # -- observations -----------------------------------------------------------------------------

    def observe(self, state: CombatState) -> jax.Array:
        """float32 ``[n0, obs]`` (layout in :mod:`hybridmarl.envs.combat`)."""
        return O.observe(
            state.game,
            self._view(state.game),
            num_agents=self.num_agents,
            num_enemies=self.num_enemies,
            k_allies=self.k_allies,
            k_enemies=self.k_enemies,
            map_px=self.map_px,
        )

    def obs_slice(self, part: str, index: int = 0, field: str | None = None) -> slice | int:
        """Where ``field`` of the ``index``-th ``part`` ("self", "ally", "enemy") block sits in an
        observation (a slice over the whole block if ``field`` is None)."""
        return O.obs_slice(part, index, field, k_allies=self.k_allies, k_enemies=self.k_enemies)

    def critic_features(self, state: CombatState, actions: jax.Array | None = None) -> jax.Array:
        """float32 ``[35]`` global statistics (layout in :mod:`hybridmarl.envs.combat`);
        ``actions`` is ignored."""
        del actions
        return O.critic_features(state.game, self.num_agents, self.num_enemies)

    # -- rendering --------------------------------------------------------------------------------

    def render(
        self,
        state: CombatState,
        params: CombatParams | None = None,
        *,
        window: tuple[int, int, int, int] | None = None,
        width: int = 640,
    ) -> np.ndarray:
        """uint8 ``[24 + h, width, 3]`` picture of ``state``: a header, then the map ``window``
        (``(x0, y0, w, h)`` in map px, default the whole map) scaled to ``width`` px."""
        del params
        facts = self.__dict__.get("_render_facts")
        if facts is None:  # compiled once per env, on the first frame
            facts = self.__dict__["_render_facts"] = draw.render_facts(self.rules)
        return draw.render(state, facts, self.map_px, window=window, width=width)

    # -- learning on it (``hybridmarl.envs.base.LearningEnv``) -------------------------------------

    metric_names: ClassVar[tuple[str, ...]] = ("won", "lost", "draw", "terminal_hp_reward")
    #: Progress lines and curves: higher W, then R.
    progress_metrics: ClassVar[tuple[str, str]] = ("won", "terminal_hp_reward")
    #: Any engine script demonstrates (the paper's c = attack-closest, w = attack-weakest).
    demonstrator_names: ClassVar[tuple[str, ...]] = tuple(SCRIPTS)
    has_enemy: ClassVar[bool] = True

    @classmethod
    def from_spec(
        cls, spec: Any, enemy_script: Script | None = None
    ) -> tuple[Combat, CombatParams]:
        """The env of ``spec.scenario`` against ``spec.enemy`` (or ``enemy_script``) with
        ``spec.max_turns`` under ``spec.setting``, and its default parameters."""
        enemy = enemy_script if enemy_script is not None else canonical_policy_name(cls, spec.enemy)
        env = cls(
            scenario=spec.scenario,
            enemy=enemy,
            max_turns=spec.max_turns,
            setting=getattr(spec, "setting", None),
        )
        return env, env.default_params

    @classmethod
    def spec_label(cls, spec: Any) -> str:
        setting = getattr(spec, "setting", "sparcraft")
        return f"{spec.scenario} vs {spec.enemy}" + (
            "" if setting == "sparcraft" else f" ({setting} setting)"
        )

    @classmethod
    def canonical_demonstrator(cls, name: str) -> str:
        try:
            return canonical_name(name)
        except KeyError as e:
            raise ValueError(str(e.args[0])) from None

    def demonstrator(self, name: str) -> Policy:
        """Our side played by the engine script ``name`` (:meth:`script_policy`)."""
        return self.script_policy(name)

    def episode_metrics(
        self, state: CombatState, info: dict[str, jax.Array]
    ) -> dict[str, jax.Array]:
        del state
        return {k: info[k].astype(jnp.float32) for k in self.metric_names}

    def agent_rewards(
        self,
        state: CombatState,
        next_state: CombatState,
        done: jax.Array,
        info: dict[str, jax.Array],
    ) -> jax.Array:
        """Damage dealt minus damage taken, plus the shared terminal reward
        (:mod:`hybridmarl.envs.combat.rewards`)."""
        del info
        return rewards.agent_rewards(state, next_state, done, self.num_agents)

    @classmethod
    def summarize(cls, episodes: Mapping[str, np.ndarray]) -> dict[str, Any]:
        """W (win rate, 95% Wilson interval), R (mean terminal hit-points reward, 95% Student-t
        interval), loss and draw rates (paper Section 5.1)."""
        ep = episodes
        n = int(next(iter(ep.values())).shape[0])
        wins = int(np.sum(ep["won"] > 0.5))
        lo, hi = wilson_interval(wins, n)
        r, rlo, rhi = t_interval(ep["terminal_hp_reward"])
        return dict(
            W=wins / n,
            W_ci95=[lo, hi],
            R=r,
            R_ci95=[rlo, rhi],
            losses=float(np.mean(ep["lost"])),
            draws=float(np.mean(ep["draw"])),
        )

    @classmethod
    def result_line(cls, result: Mapping[str, Any]) -> str:
        r = result
        return (
            f"eval vs {r['enemy']} ({r['n']} battles): W {r['W']:.2f} [{r['W_ci95'][0]:.2f}, {r['W_ci95'][1]:.2f}]  "
            f"R {r['R']:+.3f} [{r['R_ci95'][0]:+.3f}, {r['R_ci95'][1]:+.3f}]"
        )
