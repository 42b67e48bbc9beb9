"""A combat episode recorded engine turn by engine turn, as the JSON the HTML viewer reads.

One env step of ``Combat`` is one of our decision turns followed by the enemy-only turns up to
our next decision point (``hybridmarl.envs.combat``). The viewer wants every engine turn, so
this module plays each step turn by turn on the host with the env's own pieces and keys: the
start state of ``Combat.reset``, our engine actions with illegal ones replaced
(``Combat._our_engine_actions``), then ``Combat._turn`` with ``fold_in(key, n)`` for the n-th
turn of the step, exactly as ``Combat.step``'s loop does. Compiling these small pieces, rather
than ``reset`` and ``step`` as well, keeps a replay's start-up short; the tests check the
result turn by turn against ``hybridmarl.engine.trace.record_trace``.

Timeline frame ``i`` is the game after ``i`` engine turns (frame 0: the start state); its
``turn`` field is the engine's own turn counter (``GameState.turn``), so frame ``T`` matches
turn record ``T - 1`` of ``hybridmarl.engine.trace.record_trace`` on the same start state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.engine import rules as R
from hybridmarl.engine import units as UT
from hybridmarl.engine.state import PAD_ID_BASE, WALK_TILE, GameState
from hybridmarl.engine.units import PASS_DURATION
from hybridmarl.envs.combat.state import CombatState

__all__ = ["COMBAT_ACTION_NAMES", "record_combat_timeline"]

#: Env action names for the moves and noop (``Combat``'s action space, docs/environments.md).
COMBAT_ACTION_NAMES = ("noop", "move left", "move right", "move down", "move up")
#: Allied action probabilities shown per unit (the most likely first).
TOP_ACTIONS = 3

ProbsFn = Callable[[Any], jax.Array]
"""``(CombatState) -> float32 [n0, A]``: the actor's action probabilities at a decision point."""
Alg1Fn = Callable[[jax.Array, Any], dict[str, jax.Array]]
"""``(key, state) -> {"actions" [n0], "start" [n0], "q_start", "q_final"}``: Alg. 1's joint
action Ã at a decision point, the joint action it started from and Q(s, ·) of both."""


def alg1_entry(
    choice: dict[str, Any], labels: list[list[str]], agents: list[int]
) -> dict[str, Any]:
    """The JSON of one Alg. 1 result for the listed agents: their actions in Ã (``actions``) and
    in the start joint action (``start``), in the order given, Q of both joint actions, and how
    many agents Alg. 1 moved away from the start."""
    actions, start = np.asarray(choice["actions"]), np.asarray(choice["start"])
    q0, q1 = float(choice["q_start"]), float(choice["q_final"])
    return {
        "actions": [labels[i][int(actions[i])] for i in agents],
        "start": [labels[i][int(start[i])] for i in agents],
        "q_start": round(q0, 6) if np.isfinite(q0) else None,
        "q_final": round(q1, 6) if np.isfinite(q1) else None,
        "changed": int((actions != start).sum()),
    }


class _Recorder:
    """Turns games into frames: unit layout, positions, HP, cooldowns and per-turn actions."""

    def __init__(self, env: Any, start: GameState) -> None:
        from hybridmarl.envs.combat.render import DRAW_RADIUS, render_facts

        self.env = env
        self.facts = render_facts(env.rules)
        uid = np.asarray(start.uid)
        utype = np.asarray(start.utype)
        self.slots = [
            (p, s) for p in (0, 1) for s in range(uid.shape[1]) if uid[p, s] < PAD_ID_BASE
        ]
        self.units = [
            {
                "id": int(uid[p, s]),
                "player": p,
                "slot": s,
                "agent": f"unit_{s}" if p == 0 and s < env.num_agents else None,
                "type": UT.TYPE_NAMES[utype[p, s]],
                "max_hp": int(UT.TABLES.max_hp[utype[p, s]]),
                "radius": DRAW_RADIUS.get(UT.TYPE_NAMES[utype[p, s]], 8),
            }
            for p, s in self.slots
        ]
        self.frames: list[dict[str, Any]] = []
        self.games: list[GameState] = []  # every frame's game, for the camera window

    def frame(
        self,
        game: GameState,
        step: int,
        before: GameState | None = None,
        actions: np.ndarray | None = None,
        mover: str | None = None,
    ) -> dict[str, Any]:
        """The frame of ``game``; ``before``/``actions`` (engine codes [2, U], -1 where a unit did
        not act) describe the turn that led to it."""
        self.games.append(game)
        g = jax.device_get(game)
        cx, cy, _, over, winner = (np.asarray(v) for v in self.facts(game))
        time = int(g.time)
        hp = np.asarray(g.hp)
        uid = np.asarray(g.uid)
        acts: list[str | None] = []
        attacks: list[list[int]] = []
        for p, s in self.slots:
            code = -1 if actions is None else int(actions[p, s])
            acts.append(None if code < 0 else self._describe(before, g, p, s, code, attacks))
        frame = {
            "turn": int(g.turn),
            "time": time,
            "step": step,
            "mover": mover,
            "decision": False,
            "over": bool(over),
            "winner": int(winner) if bool(over) else None,
            "hp": [max(int(hp[p, s]), 0) for p, s in self.slots],
            "x": [round(float(cx[p, s]), 1) for p, s in self.slots],
            "y": [round(float(cy[p, s]), 1) for p, s in self.slots],
            "cd_attack": [max(int(g.t_attack[p, s]) - time, 0) for p, s in self.slots],
            "cd_move": [max(int(g.t_move[p, s]) - time, 0) for p, s in self.slots],
            "action": acts,
            "attacks": attacks,
            "hp_sum": [int(hp[p].clip(min=0)[uid[p] < PAD_ID_BASE].sum()) for p in (0, 1)],
        }
        self.frames.append(frame)
        return frame

    @staticmethod
    def _describe(
        before: Any, after: Any, p: int, s: int, code: int, attacks: list[list[int]]
    ) -> str:
        """``hybridmarl trace``'s wording of one engine action (ATTACK/MOVE/RELOAD/PASS)."""
        if code >= R.ATTACK_BASE:
            target = int(before.uid[1 - p, code - R.ATTACK_BASE])
            t = int(before.time)
            if (
                int(after.t_move[p, s]) == t + PASS_DURATION
                and int(after.t_attack[p, s]) == t + PASS_DURATION
            ):
                return f"ATTACK {target} [overkill->PASS]"  # the target died earlier in the turn
            attacks.append([int(before.uid[p, s]), target])
            return f"ATTACK {target}"
        if code in R.MOVE_ACTIONS:
            return f"MOVE ({int(after.x[p, s])},{int(after.y[p, s])})"
        return "RELOAD" if code == R.RELOAD_ACTION else "PASS"


def _action_codes_fn(env: Any) -> Callable[[Any], jax.Array]:
    """A jitted ``state -> int32 [A, n0]``: the engine action every env action stands for."""
    n0, na = env.num_agents, env.num_actions

    def codes(state: Any) -> jax.Array:
        every = jnp.arange(na, dtype=jnp.int32)
        return jax.vmap(lambda a: env.env_to_engine_actions(state, jnp.full((n0,), a, jnp.int32)))(
            every
        )

    return jax.jit(codes)


def _action_labels(codes: np.ndarray, uid: np.ndarray) -> list[list[str]]:
    """``[n0][A]`` names of every env action of every agent, from its engine ``codes``
    ``[A, n0]``: attack k names the enemy unit id it targets now (enemies are ranked by HP)."""
    na, n0 = codes.shape
    labels = []
    for i in range(n0):
        row: list[str] = list(COMBAT_ACTION_NAMES)
        for a in range(len(COMBAT_ACTION_NAMES), na):
            j = int(codes[a, i]) - R.ATTACK_BASE
            row.append(
                f"attack {int(uid[1, j])}"
                if 0 <= j < uid.shape[1] and uid[1, j] < PAD_ID_BASE
                else f"attack[{a - len(COMBAT_ACTION_NAMES)}]"
            )
        labels.append(row)
    return labels


def record_combat_timeline(
    env: Any,
    policy: Callable[[jax.Array, Any], jax.Array],
    seed: int = 0,
    max_steps: int = 500,
    *,
    probs_fn: ProbsFn | None = None,
    alg1_fn: Alg1Fn | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Play one episode of ``env`` (a ``Combat``) with the env policy ``policy`` and record every
    engine turn.

    The keys are those of ``hybridmarl.cli.replay.record_combat_episode`` (the GIF replay), so
    the same seed plays the same episode. ``probs_fn``, if given, adds the actor's action
    probabilities (top ``TOP_ACTIONS``) of every acting allied unit at each decision point;
    ``alg1_fn`` Alg. 1's joint action there (called with the step's simulator key).

    Returns ``(timeline, last)``: the viewer's JSON-able document (``kind`` ``combat``) and a
    dict with the final ``CombatState`` (``state``), the summed ``return`` (``Combat.step``'s
    rewards), the ``illegal`` action count (replaced as ``Combat.step`` does), ``done`` and the
    env ``steps`` played.
    """
    from hybridmarl.envs.combat import camera_window

    if max_steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    act = jax.jit(policy)
    # The env's own pieces of a step, called one engine turn at a time (see the module docstring).
    turn = jax.jit(env._turn)
    needs_enemy_turn = jax.jit(env._needs_enemy_turn)
    engine_actions = jax.jit(env._our_engine_actions)
    sample = jax.jit(env.sample_game)
    probs = jax.jit(probs_fn) if probs_fn is not None else None
    action_codes = _action_codes_fn(env)

    u = env.num_slots
    none = jnp.full((2, u), -1, jnp.int32)
    pass_all = jnp.full((u,), R.PASS_ACTION, jnp.int32)

    def play_turn(
        key: jax.Array, game: GameState, ours: jax.Array, n: int, step: int, last: np.ndarray
    ) -> tuple[GameState, dict[str, Any], np.ndarray]:
        """One engine turn; its frame, and ``last`` updated like ``CombatState.last_actions``."""
        new, acts = turn(key, game, none, ours, jnp.int32(n))
        acts = np.asarray(acts)  # engine action of each unit that acted this turn, -1 elsewhere
        p0_moved, p1_moved = bool((acts[0] >= 0).any()), bool((acts[1] >= 0).any())
        mover = "BOTH" if p0_moved and p1_moved else "P0" if p0_moved else "P1"
        return new, rec.frame(new, step, game, acts, mover), np.where(acts >= 0, acts, last)

    # Combat.reset: a start state, then enemy-only turns (none from a scenario generator).
    key = jax.random.key(seed)
    key, k0 = jax.random.split(key)
    k_sample, k_adv = jax.random.split(k0)
    game = sample(k_sample)
    rec = _Recorder(env, game)
    rec.frame(game, 0)
    init_hp = np.asarray(R.hp_sums(game)).astype(np.int32)
    last = np.full((2, u), -1, np.int32)
    n = 0
    while bool(needs_enemy_turn(game)):
        game, _, last = play_turn(k_adv, game, pass_all, n, 0, last)
        n += 1

    def combat_state(game: GameState, last: np.ndarray, steps: int) -> Any:
        return CombatState(
            game=game,
            last_actions=jnp.asarray(last),
            init_hp=jnp.asarray(init_hp),
            steps=jnp.int32(steps),
        )

    norm = np.float32(max(int(init_hp[0]), 1))
    state = combat_state(game, last, 0)
    total, illegal, steps = 0.0, 0, 0
    done = bool(rec.frames[-1]["over"])
    while not done and steps < max_steps:
        key, k_act, k_env = jax.random.split(key, 3)
        actions = act(k_act, state)
        labels = _action_labels(np.asarray(action_codes(state)), np.asarray(state.game.uid))
        acting0 = np.asarray(rec.facts(state.game)[2])[0]
        p = np.asarray(probs(state)) if probs is not None else None
        agents = []
        acting_agents = [i for i in range(env.num_agents) if acting0[i]]
        for i in acting_agents:
            entry: dict[str, Any] = {
                "unit": int(np.asarray(state.game.uid)[0, i]),
                "chosen": labels[i][int(actions[i])],
            }
            if p is not None:
                order = np.argsort(-p[i], kind="stable")[:TOP_ACTIONS]
                entry["probs"] = [
                    [labels[i][a], round(float(p[i, a]), 4)] for a in order if p[i, a] > 0
                ]
            agents.append(entry)

        alg1 = None
        if alg1_fn is not None:
            alg1 = alg1_entry(alg1_fn(k_env, state), labels, acting_agents)
            for entry, action, start in zip(
                agents, alg1.pop("actions"), alg1.pop("start"), strict=True
            ):
                entry["alg1"], entry["alg1_start"] = action, start

        eng0, bad, _ = engine_actions(state, actions)
        illegal += int(np.asarray(bad).sum())
        steps += 1
        hp_before = rec.frames[-1]["hp_sum"]
        last = np.full((2, u), -1, np.int32)
        game, first, last = play_turn(k_env, state.game, eng0, 0, steps, last)
        first["decision"] = True
        first["policy"] = {
            "env_actions": np.asarray(actions).tolist(),
            "agents": agents,
            "illegal": int(np.asarray(bad).sum()),
        }
        if alg1 is not None:
            first["policy"]["alg1"] = alg1
        n = 1
        while bool(needs_enemy_turn(game)):
            game, _, last = play_turn(k_env, game, pass_all, n, steps, last)
            n += 1
        # Combat.step's reward: the change of (our HP - their HP), normalised by our start HP.
        hp_after = rec.frames[-1]["hp_sum"]
        diff = np.float32(hp_after[0] - hp_after[1]) - np.float32(hp_before[0] - hp_before[1])
        reward = float(diff / norm)
        rec.frames[-1]["reward"] = round(reward, 6)
        total += reward
        done = bool(rec.frames[-1]["over"])
        state = combat_state(game, last, steps)

    window = camera_window(rec.games)
    timeline = {
        "kind": "combat",
        "units": rec.units,
        "frames": rec.frames,
        "map": {
            "width": int(env.rules.walkable.shape[1]) * WALK_TILE,
            "height": int(env.rules.walkable.shape[0]) * WALK_TILE,
            "window": list(window),
        },
        "players": ["ours", "enemy"],
    }
    return timeline, {
        "state": state,
        "return": total,
        "illegal": illegal,
        "done": done,
        "steps": steps,
    }
