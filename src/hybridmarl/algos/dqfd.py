"""DQfD, Deep Q-learning from Demonstrations (Hester et al., AAAI 2018; the paper's baseline of
Section 5.2; docs/baselines.md), as independent learners sharing one Q network.

    Phase 1  demonstrations: a dataset file, or 'demo_observations' recorded from the script;
             every record is re-simulated once to get its next state and the per-agent rewards
             (per-agent rewards, docs/baselines.md, Section 5.2: "DQfD and OGTL need rewards of single-agent
             action, which is same to [Hu et al., 2018]"). They fill a protected region of the
             replay buffer that is never overwritten;
    Phase 2  pre-training on the demonstrations only ('pretrain_updates' minibatch updates of
             the full loss J(Q) below);
    Phase 3  interaction: 'num_envs' games, every agent plays ε-greedy on the shared Q
             network (legal actions only); finished episodes go into the agent region of the
             buffer (FIFO); one update every 'train_every' env steps on minibatches drawn by
             proportional prioritised replay from demonstrations and agent data together; the
             target network is copied every 'target_update_every' updates;
    Phase 4  evaluation (Section 5.1: legal argmax of Q, W and R with 95% CIs).

The Q network has the actor's architecture (Section 5.1, "re-implemented by the same setting and
network architecture") with |A| outputs, read as Q-values; it is saved as 'actor.*' so
'hybridmarl eval' plays its legal argmax, which is the greedy policy.

Loss (Hester et al. 2018), per sampled agent-transition '(s, i, a, r_i, s')', 'o = O^i(s)'::

    J(Q) = J_DQ + λ1 J_n + λ2 J_E + λ3 J_L2
    J_DQ = huber(r_i + γ' Q_tgt(o', argmax_{a' legal} Q(o', a')) - Q(o, a))      (double DQN)
    J_n  = huber(Σ_{k<n} γ^k r_{i,t+k} + γ^n Q_tgt(o_{t+n}, argmax Q(o_{t+n})) - Q(o, a)), n = 10
    J_E  = max_{a' legal} [Q(o, a') + 0.8·1(a' != a_E)] - Q(o, a_E)   (demonstrations only)
    J_L2 = Σ w^2 over all parameters,  λ1 = λ2 = 1, λ3 = 1e-5

weighted by the importance-sampling weights of prioritised replay. An agent's own episode ends
when its unit dies (or the car leaves) or the game ends: no bootstrap past that. The TD error is
Huber-clipped as in DQN (Hester et al. name no form). Rewards are not log-scaled (the Atari
'sign(r) log(1 + |r|)' of Hester et al.); they are divided by 'reward_unit' (default: the
median |r| of the non-zero per-agent demonstration rewards, one Marine shot at m5v5), so that a
typical reward event is worth 1 as on Atari, the scale the margin 0.8, the Huber threshold and
the λ's were set for (docs/baselines.md#scale; on the raw rewards, where a shot is 0.03, the
margin is 27 shots and DQfD only clones its demonstrator).

train.csv's 'agreement' column: the fraction of deciding agents whose greedy action equals the
demonstrator's on a fixed probe of the first 'PROBE_ROWS' demonstration states.

Prioritised replay (proportional, Schaul et al. 2016 with DQfD's settings): priority
'p = (|δ_1| + ε)^α', 'δ_1' the 1-step TD error (Hester et al. leave open which error sets it;
priorities are also updated during pre-training), 'ε_a = 0.001' for agent data, 'ε_d = 1.0'
for demonstrations, 'α = 0.4', IS exponent 'β' annealed linearly from 0.6 to 1 over the
interaction phase (weights normalised by the largest possible weight). New transitions get the
largest priority seen so far. The buffer is host numpy: each block of 'updates_per_call'
minibatches is drawn with one cumulative sum over all (row, agent) priorities (O(size) per block,
fine at these sizes), trained in one compiled 'lax.scan', and the priorities of the block are
then updated (so within a block they are up to 'updates_per_call - 1' updates stale). Rows hold
the joint state and the next state (small integer pytrees); observations and legal masks are
recomputed from them on the device.

OGTL ('algos.ogtl') reuses all of this with different switches (uniform replay, 1-step TD,
the margin loss's weight annealed during RL).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import jax
import jax.numpy as jnp
import numpy as np
from tyro.conf import OmitArgPrefixes

from hybridmarl.training import networks as nets
from hybridmarl.training.checkpoint import prefixed
from hybridmarl.training.config import Options, TrainConfig, check_finite, key_data
from hybridmarl.training.losses import (
    double_q_bootstrap,
    greedy_agreement,
    huber,
    l2_penalty,
    large_margin_loss,
    linear_decay,
    nstep_returns,
    reward_unit,
)
from hybridmarl.training.rollout import EpisodeAssembler, Pool, new_pool, pool_steps
from hybridmarl.training.run import Run, RunState, TrainResult
from hybridmarl.training.task import Task, TaskError, flatten_named, unflatten_named

ALGO = "dqfd"


@dataclass(frozen=True)
class DQfDBudgetOptions(Options):
    """Budget and parallelism of the interaction phase."""

    RUN_ONLY = frozenset({"total_episodes"})

    total_episodes: int = 20_000
    """Interaction episodes (the paper does not state its budget; as 'hybrid')."""
    num_envs: int = 16
    """Games played in parallel during interaction (not in the paper)."""
    chunk_steps: int = 8
    """Env steps per compiled call; buffer, updates and logs happen in between."""


@dataclass(frozen=True)
class DemoOptions(Options):
    """Phases 1-2: the demonstrations and the pre-training on them."""

    demo_observations: int = 10_000
    """Demonstration observations recorded from a script demonstrator (Section 5.1: 10,000)."""
    pretrain_updates: int = 50_000
    """Minibatch updates on demonstrations only before interacting (Hester et al. 2018: 750,000
    on Atari; these tasks are far smaller, not given in the paper)."""
    pretrain_td: bool = True
    """Pre-train with the TD terms too (DQfD: the full loss, Hester et al. 2018). False: the
    large-margin loss only (pure imitation)."""
    keep_demos: bool = True
    """Keep the demonstrations in the buffer during interaction (DQfD: yes, Hester et al. 2018)."""


@dataclass(frozen=True)
class LossOptions(Options):
    """The loss J(Q) = J_DQ + λ1 J_n + λ2 J_E + λ3 J_L2 (Hester et al. 2018)."""

    gamma: float = 0.995
    """Discount (Section 5.1: λ = 0.995; the baselines use "the same setting", Section 5.2)."""
    n_step: int = 10
    """n of the n-step return (Hester et al. 2018: 10)."""
    lambda_nstep: float = 1.0
    """λ1, weight of the n-step TD loss (Hester et al. 2018: 1.0)."""
    lambda_margin: float = 1.0
    """λ2, weight of the large-margin loss on demonstration samples (Hester et al. 2018: 1.0)."""
    lambda_margin_online: float | None = None
    """λ2 during interaction (default: lambda_margin)."""
    margin_decay_episodes: int = 0
    """Interaction episodes over which λ2 decays linearly to lambda_margin_final (0: it stays
    constant, as in DQfD; OGTL anneals it, docs/baselines.md#ogtl)."""
    lambda_margin_final: float = 0.0
    """λ2 at the end of the decay (only with margin_decay_episodes > 0)."""
    lambda_l2: float = 1e-5
    """λ3, weight of the L2 penalty on the weights (Hester et al. 2018: 1e-5)."""
    margin: float = 0.8
    """Margin l(a_E, a) for a != a_E (Hester et al. 2018: 0.8), in units of the scaled rewards
    (reward_unit)."""
    team_reward: bool = False
    """Learn from the environment's global reward, given to every agent, instead of the
    per-agent rewards of Section 5.2 (an extension, not the paper's setting)."""
    reward_unit: float | None = None
    """Per-agent rewards are divided by this before learning, so that a typical reward event
    is 1, the scale of Atari's clipped rewards that DQfD's margin, Huber threshold and λ's were
    set for (docs/baselines.md#scale). None: measured on the demonstrations, the median |r| of
    the non-zero per-agent rewards (one Marine shot at m5v5: about 0.03). 1: the raw rewards."""


@dataclass(frozen=True)
class ReplayOptions(Options):
    """Prioritised replay, update schedule and target network."""

    batch_size: int = 32
    """Agent-transitions per minibatch (Hester et al. 2018: 32)."""
    train_every: int = 4
    """One update every this many env steps (joint steps summed over the parallel games;
    Hester et al. 2018: every 4 steps on Atari)."""
    updates_per_call: int = 8
    """Minibatches per compiled update call (priorities are refreshed after each call)."""
    target_update_every: int = 10_000
    """Copy the online network to the target network every this many updates (Hester et al.
    2018: C = 10,000)."""
    buffer_size: int = 50_000
    """Joint steps (rows) of agent data kept, FIFO, besides the demonstrations (Hester et al.
    2018: 10^6 transitions; a row holds one transition per agent)."""
    per_alpha: float = 0.4
    """Prioritised replay exponent α (Hester et al. 2018: 0.4; 0 = uniform replay)."""
    per_beta0: float = 0.6
    """Importance-sampling exponent β at the start of interaction, annealed to 1 (Hester et al.
    2018)."""
    per_eps_agent: float = 0.001
    """ε_a, priority bonus of agent transitions (Hester et al. 2018: 0.001)."""
    per_eps_demo: float = 1.0
    """ε_d, priority bonus of demonstration transitions (Hester et al. 2018: 1.0)."""


@dataclass(frozen=True)
class ExplorationOptions(Options):
    """ε-greedy exploration during interaction (legal actions only)."""

    eps_start: float = 0.01
    """ε at the start of interaction (Hester et al. 2018: 0.01)."""
    eps_end: float = 0.01
    """ε after eps_decay_episodes (Hester et al. 2018: 0.01)."""
    eps_decay_episodes: int = 0
    """Episodes of linear decay from eps_start to eps_end (0: none)."""


@dataclass(frozen=True)
class QNetworkOptions(Options):
    """The Q network (the actor's architecture, Section 5.1) and its optimisation."""

    optimizer: Literal["sgd", "adam"] = "sgd"
    """Optimiser (Section 5.1: SGD for all networks; "the same setting", Section 5.2)."""
    lr: float = 1e-3
    """Learning rate (Section 5.1: 10^-3)."""
    actor_hidden: tuple[int, ...] = nets.ACTOR_HIDDEN
    """Q network FC widths before the |A| outputs (the actor's, Section 5.1: 512, 256, 256)."""


@dataclass(frozen=True)
class DQfDConfig(TrainConfig):
    """DQfD: pre-training on demonstrations, then prioritised replay of demonstrations and own
    data with TD, n-step TD, large-margin and L2 losses (Hester et al. 2018)."""

    budget: OmitArgPrefixes[DQfDBudgetOptions] = dataclasses.field(
        default_factory=DQfDBudgetOptions
    )
    demos: OmitArgPrefixes[DemoOptions] = dataclasses.field(default_factory=DemoOptions)
    loss: OmitArgPrefixes[LossOptions] = dataclasses.field(default_factory=LossOptions)
    replay: OmitArgPrefixes[ReplayOptions] = dataclasses.field(default_factory=ReplayOptions)
    exploration: OmitArgPrefixes[ExplorationOptions] = dataclasses.field(
        default_factory=ExplorationOptions
    )
    q_network: OmitArgPrefixes[QNetworkOptions] = dataclasses.field(default_factory=QNetworkOptions)


def hybrid_budget(preset: str, env: str) -> dict[str, int]:
    """The interaction budget of the hybrid method's preset of the same name: its episodes and
    parallel games, which the baselines' presets take so that every learner gets as many
    episodes (and demonstrations) as the method it is compared with."""
    from hybridmarl.algos.hybrid.config import PRESETS as HYBRID_PRESETS

    hybrid = HYBRID_PRESETS[preset](env)
    return {"total_episodes": hybrid.total_episodes, "num_envs": hybrid.num_envs}


def _paper(env: str) -> DQfDConfig:
    """'paper': DQfD with the settings of Hester et al. (AAAI 2018) where they carry over
    (docs/baselines.md) and the paper's shared ones (Section 5.1: SGD, 10^-3, λ = 0.995), on
    rewards in units of a typical reward event (reward_unit). Budget: the hybrid 'paper'
    preset's, 20,000 episodes in 32 parallel games (the paper gives no budget), after 10,000
    demonstration observations and 50,000 pre-training updates."""
    return DQfDConfig().replace(
        env=env,
        demonstrator="always-gas" if env == "traffic_junction" else "attack-closest",
        **hybrid_budget("paper", env),
    )


def _quick(env: str) -> DQfDConfig:
    """'quick': the hybrid 'quick' preset's budget, combat 3,000 episodes in 128 parallel games
    (Traffic Junction 1,500 in 16), after 10,000 demonstration observations and 3,000
    pre-training updates; Adam 3·10^-4, batch 64, target network every 500 updates. Cost at m5v5
    (paper setting, 2026-12-02, 2-core x86-64 CPU VM, shared): 3,000 episodes in 4.3-4.9 CPU-min
    (26-30 min wall at a load of 16-20), less CPU than the hybrid 'quick' preset's 10-23 CPU-min."""
    return _paper(env).replace(
        pretrain_updates=3_000,
        optimizer="adam",
        lr=3e-4,
        batch_size=64,
        updates_per_call=16,
        target_update_every=500,
        buffer_size=20_000,
        checkpoint_every=500,
        **hybrid_budget("quick", env),
    )


def _toy(env: str) -> DQfDConfig:
    """'toy', seconds: a smoke test of the whole pipeline (tests, CI): 4 episodes in 4 games,
    a tiny network, no learning."""
    return _quick(env).replace(
        total_episodes=4,
        num_envs=4,
        chunk_steps=8,
        demo_observations=64,
        pretrain_updates=8,
        batch_size=16,
        updates_per_call=4,
        target_update_every=8,
        buffer_size=256,
        actor_hidden=(16, 16, 16),
        checkpoint_every=2,
        eval_episodes=8,
        tensorboard=False,
    )


#: Preset name -> '(env) -> DQfDConfig' ('--preset').
PRESETS = {"paper": _paper, "quick": _quick, "toy": _toy}
#: The config class of '--algo dqfd'.
CONFIG = DQfDConfig


# -- prioritised replay ---------------------------------------------------------------------------------


class PrioritizedReplay:
    """Rows of joint steps with per-agent transitions; demonstrations in a protected region.

    Row 'r' holds 's_t' and 's_{t+1}' (flattened state arrays), the agents' actions and,
    per agent, the reward, the 1-step discount 'γ·(1 - end)', the n-step return and discount and
    'nidx' (the row whose next state bootstraps the n-step target), 'valid' (the agent is in
    play at 's_t') and the priority 'p^α'. Rows '[0, demo_size)' are the demonstrations
    (never overwritten); agent rows live in '[demo_cap, demo_cap + capacity)', FIFO. A row's
    'nidx' points at a row inserted with it (same episode, later), so FIFO overwriting never
    leaves a live row pointing at a replaced one.
    """

    PER_AGENT = ("actions", "reward", "disc1", "nret", "ndisc", "nidx", "valid", "prio")

    def __init__(
        self,
        capacity: int,
        demo_cap: int,
        num_agents: int,
        state_template: Any,
        *,
        alpha: float,
        eps_agent: float,
        eps_demo: float,
    ) -> None:
        self.capacity, self.demo_cap, self.n = int(capacity), int(demo_cap), int(num_agents)
        self.template = state_template
        self.alpha, self.eps_agent, self.eps_demo = float(alpha), float(eps_agent), float(eps_demo)
        total = self.capacity + self.demo_cap
        proto = flatten_named(state_template)
        self.states = {k: np.zeros((total,) + v.shape, v.dtype) for k, v in proto.items()}
        self.nexts = {k: np.zeros((total,) + v.shape, v.dtype) for k, v in proto.items()}
        dtypes = {"actions": np.int32, "nidx": np.int64, "valid": np.bool_, "prio": np.float64}
        self.cols = {
            k: np.zeros((total, self.n), dtypes.get(k, np.float32)) for k in self.PER_AGENT
        }
        self.demo_size = 0
        self.ptr = 0
        self.size = 0
        self.max_prio = 1.0

    def add(
        self,
        rows: dict[str, np.ndarray],
        done: np.ndarray,
        segment: np.ndarray,
        gamma: float,
        n_step: int,
        *,
        demo: bool = False,
    ) -> None:
        """Insert rows (consecutive within 'segment'; 'state.*', 'next.*', 'actions',
        'agent_reward', 'active', 'active_next') and their targets' ingredients."""
        m = int(done.shape[0])
        if m == 0:
            return
        ends = np.asarray(done, bool)[:, None] | ~np.asarray(rows["active_next"], bool)
        reward = np.asarray(rows["agent_reward"], np.float32)
        nret, ndisc, last = nstep_returns(reward, ends, np.asarray(segment), gamma, n_step)
        cols = {
            "actions": rows["actions"],
            "reward": reward,
            "disc1": np.where(ends, 0.0, gamma).astype(np.float32),
            "nret": nret,
            "ndisc": ndisc,
            "valid": np.asarray(rows["active"], bool),
        }
        if demo:
            if m > self.demo_cap:
                raise ValueError(
                    f"{m} demonstration rows do not fit the protected region of {self.demo_cap}"
                )
            pos = np.arange(m)
            self.demo_size = m
        else:
            if m > self.capacity:  # keep the newest; n-step links only point forward
                drop = m - self.capacity
                cols = {k: v[drop:] for k, v in cols.items()}
                rows = {k: v[drop:] for k, v in rows.items()}
                last = last[drop:] - drop
                m = self.capacity
            pos = self.demo_cap + (self.ptr + np.arange(m)) % self.capacity
            self.ptr = int((self.ptr + m) % self.capacity)
            self.size = int(min(self.size + m, self.capacity))
        for k, v in cols.items():
            self.cols[k][pos] = v
        self.cols["nidx"][pos] = pos[last]
        self.cols["prio"][pos] = np.where(cols["valid"], self.max_prio, 0.0)
        for k in self.states:
            self.states[k][pos] = rows["state." + k]
            self.nexts[k][pos] = rows["next." + k]

    def drop_demos(self) -> None:
        """Stop sampling the demonstrations (OGTL's RL stage). Their states and actions stay
        (the agreement probe reads them)."""
        self.cols["valid"][: self.demo_cap] = False
        self.cols["prio"][: self.demo_cap] = 0.0

    def demos_live(self) -> bool:
        return bool(self.cols["valid"][: self.demo_size].any())

    def demo_probe(self, count: int) -> tuple[Any, np.ndarray]:
        """The first 'count' demonstration rows: (states '[P, ...]', the demonstrator's actions
        '[P, N]'), a fixed probe set for the agreement column."""
        p = min(int(count), self.demo_size)
        states = unflatten_named(
            self.template, {k: v[:p] for k, v in self.states.items()}, batch_dims=1
        )
        return states, self.cols["actions"][:p]

    def live_mask(self) -> np.ndarray:
        rows = np.zeros(self.capacity + self.demo_cap, bool)
        rows[: self.demo_size] = True
        rows[self.demo_cap : self.demo_cap + self.size] = True
        return rows[:, None] & self.cols["valid"]

    def sample(
        self, rng: np.random.Generator, count: int, beta: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """'count' agent-transitions with probability 'p_i / sum p' ('p' already '^α'):
        (rows, agents, importance weights '(M P(i))^-β / max')."""
        p = np.where(self.live_mask(), self.cols["prio"], 0.0).ravel()
        cdf = np.cumsum(p)
        total = float(cdf[-1]) if cdf.size else 0.0
        if total <= 0.0:
            raise ValueError("the replay buffer holds no transition to sample")
        flat = np.searchsorted(cdf, rng.random(count) * total, side="right")
        flat = np.minimum(flat, p.size - 1)
        live = p > 0
        m = int(live.sum())
        prob = p[flat] / total
        w = (m * prob) ** (-beta)
        w_max = (m * p[live].min() / total) ** (-beta)
        return flat // self.n, flat % self.n, (w / w_max).astype(np.float32)

    def update_priorities(self, rows: np.ndarray, agents: np.ndarray, td_abs: np.ndarray) -> None:
        eps = np.where(rows < self.demo_cap, self.eps_demo, self.eps_agent)
        p = (np.abs(np.asarray(td_abs, np.float64)) + eps) ** self.alpha
        self.cols["prio"][rows, agents] = p
        self.max_prio = max(self.max_prio, float(p.max()) if p.size else 0.0)

    def batch(self, rows: np.ndarray, agents: np.ndarray, weights: np.ndarray) -> dict[str, Any]:
        """Host arrays of a sample (leading shape of 'rows') for the compiled update."""
        bidx: np.ndarray = np.asarray(self.cols["nidx"][rows, agents], np.int64)
        shape = rows.shape
        nb = len(shape)
        out: dict[str, Any] = {
            "states": unflatten_named(
                self.template, {k: v[rows] for k, v in self.states.items()}, batch_dims=nb
            ),
            "next": unflatten_named(
                self.template, {k: v[rows] for k, v in self.nexts.items()}, batch_dims=nb
            ),
            "boot": unflatten_named(
                self.template, {k: v[bidx] for k, v in self.nexts.items()}, batch_dims=nb
            ),
            "agent": agents.astype(np.int32).reshape(shape),
            "demo": (rows < self.demo_cap).astype(np.float32),
            "weight": weights.reshape(shape),
        }
        for k in ("actions", "reward", "disc1", "nret", "ndisc"):
            out[k] = self.cols[k][rows, agents]
        return out

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"state." + k: v for k, v in self.states.items()}
        out.update({"next." + k: v for k, v in self.nexts.items()})
        out.update(self.cols)
        out["counters"] = np.asarray(
            [self.capacity, self.demo_cap, self.demo_size, self.ptr, self.size], np.int64
        )
        out["max_prio"] = np.asarray(self.max_prio, np.float64)
        return out

    def load_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        self.capacity, self.demo_cap, self.demo_size, self.ptr, self.size = (
            int(x) for x in arrays["counters"]
        )
        self.states = {k: np.array(arrays["state." + k]) for k in self.states}
        self.nexts = {k: np.array(arrays["next." + k]) for k in self.nexts}
        self.cols = {k: np.array(arrays[k]) for k in self.PER_AGENT}
        self.max_prio = float(arrays["max_prio"])


# -- the compiled pieces -----------------------------------------------------------------------------------


class QLearner:
    """The Q network, its optimiser and the jitted functions of one (task, static settings)."""

    def __init__(
        self,
        task: Task,
        hidden: tuple[int, ...],
        optimizer: str,
        lr: float,
        num_envs: int,
        chunk_steps: int,
        demo_script: str | None,
        agreement: bool = False,
    ) -> None:
        self.task = task
        self.demo_policy = task.demonstrator(demo_script) if demo_script else None
        if agreement and self.demo_policy is None:
            raise TaskError(
                "the agreement bonus (OGTL's reward shaping) needs a script demonstrator, not a dataset"
            )
        self.agreement = agreement
        self.module = nets.actor_module(task.num_actions, hidden)
        self.tx = nets.make_optimizer(optimizer, lr)
        self.b = num_envs
        self.collect_chunk = jax.jit(functools.partial(self._collect_chunk, steps=chunk_steps))
        self.update_block = jax.jit(self._update_block)
        self.resimulate = jax.jit(jax.vmap(self._transition))
        self.probe_agreement = jax.jit(self._probe_agreement)

    def _probe_agreement(self, q_vars: Any, states: Any, actions: jax.Array) -> jax.Array:
        """Fraction of the deciding agents (in play, two or more legal actions) of 'states'
        '[P, ...]' whose legal greedy action equals the recorded 'actions' '[P, N]'."""
        obs = jax.vmap(self.task.observe)(states)
        legal = jax.vmap(self.task.avail)(states)
        q = nets.apply_eval(self.module, q_vars, obs.reshape((-1, obs.shape[-1]))).reshape(
            legal.shape
        )
        choice = jax.vmap(self.task.env.agent_active)(states) & (jnp.sum(legal, axis=-1) >= 2)
        matches, count = greedy_agreement(q, legal, actions, choice)
        return matches / jnp.maximum(count, 1.0)

    def _transition(
        self, state: Any, actions: jax.Array, next_state: Any, done: jax.Array, info: dict
    ) -> dict:
        """What a buffer row needs from one step 'state -> next_state'."""
        task = self.task
        row = {
            "next": next_state,
            "actions": actions.astype(jnp.int32),
            "agent_reward": task.agent_rewards(state, next_state, done, info),
            "active": task.env.agent_active(state),
            "active_next": task.env.agent_active(next_state),
            "done": done,
        }
        if self.agreement and self.demo_policy is not None:
            # 1 where an agent with a choice played what the script plays in the same state
            # (OGTL's optional shaping, Hester et al. 2018). The scripts are deterministic; the fixed
            # key only matters for an ':eps' demonstrator.
            scripted = self.demo_policy(jax.random.key(0), state)
            choice = jnp.sum(task.avail(state), axis=-1) >= 2
            row["agrees"] = ((actions == scripted) & choice & row["active"]).astype(jnp.float32)
        return row

    def _on_step(self, states, actions, next_states, reward, done, info):
        row = jax.vmap(self._transition)(states, actions, next_states, done, info)
        # The environment's global reward, for '--team-reward'.
        row["team_reward"] = jnp.broadcast_to(reward[:, None], row["agent_reward"].shape).astype(
            jnp.float32
        )
        return row

    def _collect_chunk(
        self, pool: Pool, q_vars: Any, eps: jax.Array, use_script: jax.Array, *, steps: int
    ):
        """'steps' steps of ε-greedy play of the shared Q network (legal actions only), or of
        the demonstrator script where 'use_script' (one compiled function for both, so
        recording demonstrations costs no extra compilation)."""
        mod, demo = self.module, self.demo_policy

        def act(carry, key, states, obs, legal):
            greedy = nets.actor_actions(mod, carry, obs, legal)
            k_flip, k_rnd, k_demo = jax.random.split(key, 3)
            rnd = jax.random.categorical(k_rnd, jnp.where(legal, 0.0, -jnp.inf), axis=-1).astype(
                jnp.int32
            )
            flip = jax.random.uniform(k_flip, greedy.shape) < eps
            a = jnp.where(flip, rnd, greedy)
            if demo is not None:
                scripted = jax.vmap(demo)(jax.random.split(k_demo, self.b), states).astype(
                    jnp.int32
                )
                a = jnp.where(use_script, scripted, a)
            return a, carry, {}

        pool, _, out = pool_steps(self.task, act, pool, q_vars, steps, on_step=self._on_step)
        return pool, out

    def _agent_inputs(self, states: Any, agent: jax.Array) -> tuple[jax.Array, jax.Array]:
        obs = jax.vmap(self.task.observe)(states)
        legal = jax.vmap(self.task.avail)(states)
        i = jnp.arange(agent.shape[0])
        return obs[i, agent], legal[i, agent]

    def _update_block(self, q: nets.NetState, target_vars: Any, batch: dict, coeffs: jax.Array):
        """'K' minibatch updates (batch leaves '[K, B, ...]'); 'coeffs' = (λ_DQ, λ1, λ2, λ3,
        margin). Returns the network, |δ_1| '[K, B]' and the mean loss terms."""
        mod, tx = self.module, self.tx

        def one(q: nets.NetState, mb: dict):
            # s, s' and the n-step bootstrap state in one vmapped observation (one copy compiled).
            both = jax.tree.map(lambda *x: jnp.concatenate(x), mb["states"], mb["next"], mb["boot"])
            obs_all, legal_all = self._agent_inputs(both, jnp.tile(mb["agent"], 3))
            b = mb["agent"].shape[0]
            obs, legal = obs_all[:b], legal_all[:b]
            x2, l2 = obs_all[b:], legal_all[b:]
            q_on = nets.apply_eval(mod, {"params": q.params, "batch_stats": q.batch_stats}, x2)
            q_tg = nets.apply_eval(mod, target_vars, x2)
            v = double_q_bootstrap(q_on, q_tg, l2)
            y1 = jax.lax.stop_gradient(mb["reward"] + mb["disc1"] * v[:b])
            yn = jax.lax.stop_gradient(mb["nret"] + mb["ndisc"] * v[b:])

            def loss_fn(params, batch_stats):
                qv, bs = nets.apply_train(mod, params, batch_stats, obs)
                q_sa = jnp.take_along_axis(qv, mb["actions"][:, None], axis=-1)[:, 0]
                td1, tdn = y1 - q_sa, yn - q_sa
                j_e = large_margin_loss(qv, mb["actions"], legal, coeffs[4]) * mb["demo"]
                terms = jnp.stack(
                    [
                        jnp.mean(mb["weight"] * huber(td1)),
                        jnp.mean(mb["weight"] * huber(tdn)),
                        jnp.mean(mb["weight"] * j_e),
                        l2_penalty(params),
                    ]
                )
                return jnp.dot(coeffs[:4], terms), (bs, (td1, terms))

            q, loss, (td1, terms) = nets.sgd_step(q, tx, loss_fn)
            return q, (jnp.abs(td1), jnp.concatenate([loss[None], terms]))

        q, (td, terms) = jax.lax.scan(one, q, batch)
        return q, td, jnp.mean(terms, axis=0)


@functools.lru_cache(maxsize=8)
def build_learner(
    task: Task,
    hidden: tuple[int, ...],
    optimizer: str,
    lr: float,
    num_envs: int,
    chunk_steps: int,
    demo_script: str | None,
    agreement: bool = False,
) -> QLearner:
    """The learner, compiled once per distinct argument list (the arguments are the compile key)."""
    return QLearner(task, hidden, optimizer, lr, num_envs, chunk_steps, demo_script, agreement)


LOSS_NAMES = ("loss", "td_loss", "nstep_loss", "margin_loss", "l2")
#: Demonstration states in the fixed probe set of the train.csv 'agreement' column.
PROBE_ROWS = 1024


# -- demonstrations -> buffer rows ---------------------------------------------------------------------------


def demo_rows(
    learner: QLearner, ds: Any, chunk: int = 256
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, float]:
    """Re-simulate every record of a dataset once ('step(s_t, a_t)') for its next state,
    per-agent rewards and 'done'; returns (rows, done, segment, fraction of records whose
    recorded global reward the re-simulation reproduces)."""
    from hybridmarl.training.demos import state_at

    task = learner.task
    k = ds.size
    parts: list[dict[str, np.ndarray]] = []
    step = _step_batch(task)
    for lo in range(0, k, chunk):
        idx = np.arange(lo, min(lo + chunk, k))
        pad = np.concatenate([idx, np.full(chunk - idx.size, idx[-1])])
        states = state_at(ds, pad, task)
        acts = jnp.asarray(ds.arrays["actions"][pad])
        s2, r, d, info = step(states, acts)
        out = learner.resimulate(states, acts, s2, d, info)
        out = jax.device_get(out)
        row = {"state." + n: v for n, v in flatten_named(jax.device_get(states)).items()}
        row.update({"next." + n: v for n, v in flatten_named(out.pop("next")).items()})
        row.update({n: np.asarray(v) for n, v in out.items()})
        row["reward_env"] = np.asarray(r)
        row["team_reward"] = np.broadcast_to(
            np.asarray(r, np.float32)[:, None], row["agent_reward"].shape
        ).copy()
        parts.append({n: v[: idx.size] for n, v in row.items()})
    rows = {n: np.concatenate([p[n] for p in parts]) for n in parts[0]}
    agree = float(np.mean(np.isclose(rows.pop("reward_env"), ds.arrays["reward"], atol=1e-6)))
    done = rows.pop("done").astype(bool)
    return rows, done, np.asarray(ds.arrays["episode"]), agree


@functools.lru_cache(maxsize=8)
def _step_batch(task: Task):
    def step(states, actions):
        b = actions.shape[0]
        _, s2, r, d, info = jax.vmap(task.step)(
            jax.random.split(jax.random.key(0), b), states, actions
        )
        return s2, r, d, info

    return jax.jit(step)


def online_rows(
    out: dict, asm: EpisodeAssembler
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Finished episodes of a 'collect_chunk' block: (rows, done, segment, episode metrics)."""
    step = jax.device_get(out["step"])
    fields = {"state." + k: v for k, v in flatten_named(jax.device_get(out["state"])).items()}
    fields.update({"next." + k: v for k, v in flatten_named(step.pop("next")).items()})
    fields.update({k: np.asarray(v) for k, v in step.items()})
    rows, _, stats = asm.add_fields(fields, out["reward"], out["done"], out["stats"])
    seg = rows.pop("episode_key")
    rows.pop("t")
    return rows, rows.pop("done").astype(bool), seg, stats


def record_demos(
    learner: QLearner, pool: Pool, q_vars: Any, count: int, gamma: float
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, dict[str, float]]:
    """Play the demonstrator script from random start states until 'count' records of finished
    episodes are in (the last episode is cut at 'count', like 'demos.collect')."""
    asm = EpisodeAssembler(learner.b, gamma)
    parts: list[tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]] = []
    stats_all: dict[str, list[float]] = {}
    got = 0
    while got < count:
        pool, out = learner.collect_chunk(
            pool, q_vars, jnp.zeros((), jnp.float32), jnp.ones((), bool)
        )
        rows, done, seg, stats = online_rows(out, asm)
        parts.append((rows, done, seg))
        got += int(done.size)
        for k, v in stats.items():
            stats_all.setdefault(k, []).extend(v.tolist())
    rows = {k: np.concatenate([p[0][k] for p in parts])[:count] for k in parts[0][0]}
    done = np.concatenate([p[1] for p in parts])[:count]
    seg = np.concatenate([p[2] for p in parts])[:count]
    return rows, done, seg, {k: float(np.mean(v)) for k, v in stats_all.items() if v}


# -- the run ----------------------------------------------------------------------------------------------


@dataclass(kw_only=True)
class DQfDState(RunState):
    """Everything a checkpoint holds: the Q network, its target, the buffer and the counters."""

    q: nets.NetState
    target: Any
    buffer: PrioritizedReplay
    updates: int = 0
    pretrain_done: int = 0
    update_credit: float = 0.0
    next_target: int = 0
    reward_unit: float = 1.0

    TREES: ClassVar[dict[str, str]] = {"actor": "q", "target": "target"}
    BUFFERS: ClassVar[dict[str, str]] = {"buffer": "buffer"}
    COUNTERS: ClassVar[tuple[str, ...]] = (
        *RunState.COUNTERS,
        "updates",
        "pretrain_done",
        "update_credit",
        "next_target",
        "reward_unit",
    )

    def rng(self) -> np.random.Generator:
        return np.random.default_rng(
            np.asarray(jax.random.key_data(self.next_key())).astype(np.uint64)
        )


def _variables(q: nets.NetState) -> dict:
    return {"params": q.params, "batch_stats": q.batch_stats}


def train(
    cfg: DQfDConfig, algo: str = ALGO, shaping: Callable[[int], float] | None = None
) -> TrainResult:
    """The whole run ('algo' names it: 'dqfd', or 'ogtl' with OGTL's switches). Raises a
    'UserError' for bad input and 'TrainingDiverged' when a loss or parameter becomes NaN/inf.

    'shaping(episodes) -> w': in the interaction phase every agent's reward gets 'w' added
    where it played the demonstrator script's action (OGTL's optional agreement bonus; 'w' is
    taken when the transitions enter the buffer). None: no bonus and nothing computed for it."""
    from hybridmarl.training import demos as D

    if cfg.reward_unit is not None and not cfg.reward_unit > 0:
        raise TaskError(f"--reward-unit must be positive, got {cfg.reward_unit}")
    with Run(algo, cfg) as run:
        # ---- Phase 0: set-up ------------------------------------------------------------------------
        task = run.task
        dataset = cfg.demonstrator_is_dataset()
        learner = build_learner(
            task,
            tuple(cfg.actor_hidden),
            cfg.optimizer,
            cfg.lr,
            cfg.num_envs,
            cfg.chunk_steps,
            None if dataset else cfg.demonstrator_name(),
            shaping is not None,
        )
        k_net, k_pool, k_run = jax.random.split(jax.random.key(cfg.seed), 3)
        q = nets.init_net(learner.module, k_net, task.obs_dim, learner.tx)
        template = task.state_template()

        def new_buffer(demo_cap: int) -> PrioritizedReplay:
            return PrioritizedReplay(
                cfg.buffer_size,
                demo_cap,
                task.num_agents,
                template,
                alpha=cfg.per_alpha,
                eps_agent=cfg.per_eps_agent,
                eps_demo=cfg.per_eps_demo,
            )

        st = DQfDState(
            q=q,
            target=_variables(q),
            pool=new_pool(task, k_pool, cfg.num_envs),
            key=key_data(k_run),
            buffer=new_buffer(0),
            assembler=EpisodeAssembler(cfg.num_envs, cfg.gamma),
            next_target=cfg.target_update_every,
        )
        run.start(
            st,
            learner.module,
            lambda: _variables(st.q),
            lambda: prefixed(flatten_named(st.q), "actor"),
            networks={"q_params": nets.num_params(q.params)},
        )

        probe: list[Any] = []

        def agreement() -> float:
            """Agreement with the demonstrator on a fixed probe set: the first PROBE_ROWS
            demonstration states (docs/baselines.md#agreement)."""
            if not probe:
                probe.append(jax.device_put(st.buffer.demo_probe(PROBE_ROWS)))
            states, actions = probe[0]
            return float(learner.probe_agreement(_variables(st.q), states, actions))

        def loss_head(episodes: int, eps: float, lam_e: float, terms: np.ndarray) -> dict[str, Any]:
            """The method's train.csv columns."""
            bonus = shaping(episodes) if shaping is not None else 0.0
            return {
                "updates": st.updates,
                "epsilon": eps,
                "agreement": agreement(),
                "lambda_margin": lam_e,
                "agreement_bonus": bonus,
                **dict(zip(LOSS_NAMES, terms.tolist(), strict=True)),
            }

        def train_updates(count: int, beta: float, coeffs: np.ndarray, where: str) -> np.ndarray:
            """'count' updates (rounded up to whole blocks) on prioritised minibatches; mean loss terms."""
            k = cfg.updates_per_call
            terms_all = []
            if count <= 0:
                return np.full(len(LOSS_NAMES), np.nan)
            for _ in range(-(-count // k)):
                rng = st.rng()
                rows, agents, w = st.buffer.sample(rng, k * cfg.batch_size, beta)
                rows, agents, w = (x.reshape(k, cfg.batch_size) for x in (rows, agents, w))
                st.q, td, terms = learner.update_block(
                    st.q,
                    st.target,
                    st.buffer.batch(rows, agents, w),
                    jnp.asarray(coeffs, jnp.float32),
                )
                st.buffer.update_priorities(rows.ravel(), agents.ravel(), np.asarray(td).ravel())
                st.updates += k
                # The target network is copied every target_update_every updates.
                if st.updates >= st.next_target:
                    st.target = _variables(st.q)
                    st.next_target = (
                        st.updates // cfg.target_update_every + 1
                    ) * cfg.target_update_every
                terms_all.append(np.asarray(terms))
            out = np.mean(terms_all, axis=0) if terms_all else np.full(len(LOSS_NAMES), np.nan)
            check_finite("Q loss", float(out[0]), where)
            check_finite("Q network parameters", st.q.params, where)
            return out

        if st.phase == "pretrain":
            # ---- Phase 1: demonstrations, in the protected region of the buffer -----------------------
            if dataset:
                ds = D.load_dataset(cfg.demonstrator, expect=task)
                rows, done, seg, agree = demo_rows(learner, ds)
                st.demo_stats = {"reward_reproduced": agree}
                how = f"dataset; re-simulation reproduces {agree:.1%} of the recorded rewards"
            else:
                demo_pool = new_pool(task, st.next_key(), cfg.num_envs)
                rows, done, seg, st.demo_stats = record_demos(
                    learner, demo_pool, _variables(st.q), cfg.demo_observations, cfg.gamma
                )
                how = f"{cfg.demonstrator_name()}: " + ", ".join(
                    f"{k} {v:.3f}" for k, v in st.demo_stats.items()
                )
            if cfg.team_reward:
                rows["agent_reward"] = rows["team_reward"]
            # Rewards in units of a typical reward event, the scale DQfD's settings assume.
            st.reward_unit = (
                reward_unit(rows["agent_reward"], rows["active"])
                if cfg.reward_unit is None
                else float(cfg.reward_unit)
            )
            rows["agent_reward"] = np.asarray(rows["agent_reward"], np.float32) / np.float32(
                st.reward_unit
            )
            st.buffer = new_buffer(int(done.size))
            st.buffer.add(rows, done, seg, cfg.gamma, cfg.n_step, demo=True)
            st.demo_stats.update(records=float(done.size), episodes=float(len(np.unique(seg))))
            print(
                f"{done.size} demonstration records from {len(np.unique(seg))} episodes ({how}); reward unit {st.reward_unit:.4g}"
            )
            # ---- Phase 2: pre-training on demonstrations only ----------------------------------------
            t0 = time.time()
            td_on = 1.0 if cfg.pretrain_td else 0.0
            coeffs = np.asarray(
                [td_on, td_on * cfg.lambda_nstep, cfg.lambda_margin, cfg.lambda_l2, cfg.margin]
            )
            terms = train_updates(cfg.pretrain_updates, cfg.per_beta0, coeffs, "pre-training")
            st.pretrain_done = st.updates
            run.log.train.write(
                [
                    run.train_row(
                        loss_head(0, float("nan"), cfg.lambda_margin, terms), 0.0, episodes=0
                    )
                ]
            )
            print(
                f"pre-trained on demonstrations: {st.updates} updates ({time.time() - t0:.0f}s), "
                + ", ".join(f"{n} {v:.4f}" for n, v in zip(LOSS_NAMES, terms, strict=True))
                + f", agreement {agreement():.3f}"
            )
            # Interaction bootstraps from the pre-trained network, not from an older copy.
            st.target = _variables(st.q)
            st.next_target = st.updates + cfg.target_update_every
            st.phase = "online"
            run.save()

        # ---- Phase 3: interaction ---------------------------------------------------------------------
        lam_online = (
            cfg.lambda_margin if cfg.lambda_margin_online is None else cfg.lambda_margin_online
        )
        terms = np.full(len(LOSS_NAMES), np.nan)
        lam_e = lam_online
        with run.loop():
            while run.running():
                # ε-greedy play of the shared Q network (legal actions only), compiled.
                frac = (
                    min(1.0, st.episodes / max(cfg.eps_decay_episodes, 1))
                    if cfg.eps_decay_episodes > 0
                    else 1.0
                )
                eps = cfg.eps_start + (cfg.eps_end - cfg.eps_start) * frac
                st.pool, out = learner.collect_chunk(
                    st.pool, _variables(st.q), jnp.asarray(eps, jnp.float32), jnp.zeros((), bool)
                )
                rows, done, seg, stats = online_rows(out, st.assembler)
                if cfg.team_reward:
                    rows["agent_reward"] = rows["team_reward"]
                if shaping is not None:
                    agrees = rows.pop("agrees")
                    rows["agent_reward"] = (
                        rows["agent_reward"] + np.float32(shaping(st.episodes)) * agrees
                    )
                rows["agent_reward"] = np.asarray(rows["agent_reward"], np.float32) / np.float32(
                    st.reward_unit
                )
                st.buffer.add(rows, done, seg, cfg.gamma, cfg.n_step)
                run.count(stats, cfg.chunk_steps * cfg.num_envs)
                # λ2 (constant, or annealed to lambda_margin_final); without keep_demos the
                # demonstrations leave the buffer once λ2 is 0 (at once when it is 0 throughout).
                lam_e = lam_online
                if cfg.margin_decay_episodes > 0:
                    lam_e = cfg.lambda_margin_final + linear_decay(
                        lam_online - cfg.lambda_margin_final, st.episodes, cfg.margin_decay_episodes
                    )
                if (
                    not cfg.keep_demos
                    and lam_e == 0.0
                    and st.episodes >= cfg.margin_decay_episodes
                    and st.buffer.demos_live()
                ):
                    st.buffer.drop_demos()
                coeffs = np.asarray([1.0, cfg.lambda_nstep, lam_e, cfg.lambda_l2, cfg.margin])
                # One update every train_every env steps, IS exponent β annealed to 1.
                st.update_credit += cfg.chunk_steps * cfg.num_envs / cfg.train_every
                if st.buffer.live_mask().any() and st.update_credit >= cfg.updates_per_call:
                    blocks = int(st.update_credit // cfg.updates_per_call)
                    st.update_credit -= blocks * cfg.updates_per_call
                    beta = cfg.per_beta0 + (1.0 - cfg.per_beta0) * min(
                        1.0, st.episodes / max(cfg.total_episodes, 1)
                    )
                    terms = train_updates(
                        blocks * cfg.updates_per_call, beta, coeffs, f"episode {st.episodes}"
                    )
                run.log_chunk(loss_head(st.episodes, eps, lam_e, terms), f"loss {terms[0]:.4f}")

        # ---- Phase 4: evaluation ----------------------------------------------------------------------------
        return run.finish({"updates": st.updates})


__all__ = [
    "ALGO",
    "CONFIG",
    "PRESETS",
    "DQfDConfig",
    "PrioritizedReplay",
    "QLearner",
    "build_learner",
    "train",
]
