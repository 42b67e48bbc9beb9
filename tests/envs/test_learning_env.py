"""The training Task takes everything environment-specific from the environment's class
(``hybridmarl.envs.base.LearningEnv``): a made-up environment goes through it unchanged."""

from __future__ import annotations

import inspect
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hybridmarl import envs
from hybridmarl.engine.state import UnitSpec
from hybridmarl.envs.base import LearningEnv, canonical_policy_name, split_noise
from hybridmarl.envs.combat import Combat
from hybridmarl.envs.traffic_junction import TrafficJunction
from hybridmarl.training import task as task_module
from hybridmarl.training.task import Task, TaskSpec


class CounterState(struct.PyTreeNode):
    t: jax.Array
    hits: jax.Array


class Counter(LearningEnv[CounterState, None]):
    """Two agents count to three; metric ``hits``; no enemy."""

    name = "counter_v0"
    num_agents = 2
    agents = ("a", "b")
    num_actions = 3
    observation_shape = (1,)
    critic_feature_size = 1
    default_params = None

    metric_names: ClassVar[tuple[str, ...]] = ("hits",)
    progress_metrics: ClassVar[tuple[str, str]] = ("hits", "return")
    demonstrator_names: ClassVar[tuple[str, ...]] = ("ones",)
    has_enemy: ClassVar[bool] = False

    @classmethod
    def from_spec(cls, spec: Any, enemy_script: Any = None) -> tuple[Counter, None]:
        return cls(), None

    @classmethod
    def spec_label(cls, spec: Any) -> str:
        return "counter"

    @classmethod
    def canonical_demonstrator(cls, name: str) -> str:
        if name.lower() not in cls.demonstrator_names:
            raise ValueError(f"unknown counter demonstrator {name!r}")
        return name.lower()

    def demonstrator(self, name: str):
        return lambda key, state: jnp.ones((2,), jnp.int32)

    def reset(self, key, params=None):
        s = CounterState(t=jnp.zeros((), jnp.int32), hits=jnp.zeros((), jnp.int32))
        return self.observe(s), s

    def step(self, key, state, actions, params=None):
        s = CounterState(t=state.t + 1, hits=state.hits + jnp.sum(actions == 1))
        return self.observe(s), s, jnp.float32(1.0), s.t >= 3, {"t": s.t}

    def observe(self, state):
        return jnp.broadcast_to(state.t.astype(jnp.float32), (2, 1))

    def get_avail_actions(self, state, params=None):
        return jnp.ones((2, 3), bool)

    def agent_active(self, state):
        return jnp.ones((2,), bool)

    def critic_features(self, state, actions):
        return state.t.astype(jnp.float32)[None]

    def episode_metrics(self, state, info):
        return {"hits": state.hits.astype(jnp.float32)}

    def agent_rewards(self, state, next_state, done, info):
        return jnp.full((2,), 0.5, jnp.float32)

    @classmethod
    def summarize(cls, episodes):
        return {"mean_hits": float(np.mean(episodes["hits"]))}

    @classmethod
    def result_line(cls, result):
        return f"counter: {result['mean_hits']:.1f} hits in {result['n']} episodes"


def test_task_takes_everything_from_the_env_class(monkeypatch):
    monkeypatch.setattr(envs, "env_class", lambda name: Counter)
    task = Task(TaskSpec(env="traffic_junction"))
    assert isinstance(task.env, Counter) and task.env_class is Counter
    assert task.metric_names == ("hits",) and task.progress_metrics == ("hits", "return")
    assert task.enemy is None and task.against("attack-closest") is task
    assert task.spec.label() == "counter"
    _, s = task.reset(jax.random.key(0))
    a = task.demonstrator("ones")(jax.random.key(1), s)
    assert np.asarray(a).tolist() == [1, 1]
    noisy = task.demonstrator("ONES:0.5")(jax.random.key(1), s)  # epsilon noise stays generic
    assert noisy.shape == (2,)
    _, s2, _, _, info = task.step(jax.random.key(2), s, a)
    assert float(task.episode_stats(s2, info)["hits"]) == 2.0
    assert np.asarray(task.agent_rewards(s, s2, jnp.asarray(False), info)).tolist() == [0.5, 0.5]
    res = task.summarize(
        {"hits": np.array([1.0, 3.0]), "return": np.zeros(2), "steps": np.array([3, 5])}
    )
    assert res == {"n": 2, "mean_hits": 2.0, "mean_steps": 4.0}
    assert task.result_line(res) == "counter: 2.0 hits in 2 episodes"


def test_task_module_never_branches_on_the_environment():
    src = inspect.getsource(task_module)
    for name in envs.ENV_NAMES:
        assert f'"{name}"' not in src.replace('env: str = "combat"', "")


def test_env_classes_implement_the_protocol():
    for cls in (Combat, TrafficJunction):
        assert envs.env_class(cls.__name__ == "Combat" and "combat" or "tj") is cls
        for attr in ("metric_names", "progress_metrics", "demonstrator_names", "has_enemy"):
            assert getattr(cls, attr) is not None
        for name in cls.demonstrator_names:
            assert cls.canonical_demonstrator(name) == name
    assert canonical_policy_name(Combat, "Attack-Closest:0.10") == "attack-closest:0.1"
    assert canonical_policy_name(TrafficJunction, "gas") == "always-gas"
    assert split_noise("yield:0") == ("yield", 0.0)


def test_task_with_an_enemy_script_and_mirroring():
    from hybridmarl.engine.scripts import get_script
    from hybridmarl.envs.combat import mirror_game
    from hybridmarl.envs.combat.opponents import mirror_env

    script = get_script("attack-closest")
    task = Task(
        TaskSpec(env="combat", scenario="m3v4", enemy="attack-weakest"), enemy_script=script
    )
    assert task.env.enemy is script and task.enemy == "attack-weakest"
    mirror = mirror_env(task.env)
    assert (mirror.num_agents, mirror.num_enemies) == (4, 3)
    g = task.env.game_state(
        [UnitSpec("Terran_Marine", 0, 100, 50), UnitSpec("Terran_Marine", 1, 300, 60)]
    )
    m = mirror_game(g, task.env.map_px[0])
    assert int(m.x[0, 0]) == 1279 - 300 and int(m.x[1, 0]) == 1279 - 100 and int(m.y[0, 0]) == 60
    assert (np.asarray(mirror_game(m, task.env.map_px[0]).x) == np.asarray(g.x)).all()
