"""The hybrid learning method (Peng, Xing & Cao, IJCAI 2020), in one file, top to bottom.

    Phase 1  the demonstrator A^D (Section 3): a script, or the behavioural clone θ^D of a
             demonstration dataset;
    Phase 2  critic pre-training (Section 4.1, Eq. 3): play A^D from random start states to
             the end, label every visited state with its discounted return V^D(s) (Eq. 1,
             λ = 0.995), keep the (s, V^D(s)) pairs in the buffer B, fit V by MSE;
    Phase 3  the joint update (Alg. 2), B games in parallel; at every step s_t of every game:
               - Ã(s_t) by best-response dynamics (Alg. 1, ``algos.brd``) on the critic,
                 started from A^D(s_t) or from the actor's own actions (Section 4.3, below);
               - the advantage of every legal action of every agent (Eq. 7) and one SGD step
                 of the shared actor on Eq. 8;
               - every agent plays the legal argmax of the (updated) actor;
             finished episodes push (s_t, V(s_t)) into B and, every E_Update episodes, the critic
             is refitted on B (Eq. 3);
    Phase 4  evaluation (``algos.evaluate``: 100 battles, legal argmax, W and R with 95% CIs)
             of the run's policy (the last actor, or its weight average) and, with ``--eval-every``, of the best frozen actor of the
             periodic evaluations (chosen on other start states; ``common.PeriodicEval``).

Where Alg. 1 starts (``--brd-start``). Section 4.3: "the actor networks can also be used to
generate action ... and these actions are considered as new demonstration actions", while the
critic is refitted on the actor's own returns. The default here is **``actor``**: Alg. 1 starts
from the current actor's legal argmax. That is the reading under which the improvement argument
of Eq. 6 holds for the policy being learned (the critic estimates the actor's value once B holds
its returns, and Alg. 1 starts from that same policy), and it needs no demonstrator after Phase
2 (so "w/o D" and the full method share one code path). ``--brd-start demonstrator`` starts every
Alg. 1 call from the original A^D instead (Alg. 1's "Input: ... demonstration actions").

Extensions, all off by default (the ``paper`` and ``quick-paper`` presets are the paper's method;
the ``quick`` preset turns on the ones of our best CPU recipe):
``lookahead_steps`` (K-step or exact simulation instead of Eq. 2's one step), ``brd_min_gain``
(Alg. 1 switches only for a gain above a margin), ``actor_init = "clone"`` (the actor starts
from θ^D), ``actor_target = "best"`` (cross-entropy toward Alg. 1's ã_g instead of Eq. 8),
``actor_buffer`` (the actor learns from a buffer of Alg. 1's labelled decisions between chunks,
DAgger-style), ``act_before_update`` (training plays the pre-update actor),
``actor_average_from`` (the run's policy is the actor's stochastic weight average). Why they exist:
measured at m5v5 (README, "Results"), Alg. 1 with the one-step critic Q makes the
demonstrator's joint actions worse, while Alg. 1 with exact Q is nearly perfect when executed
centrally; the open problem is the decentralised actor learning it.

The whole of Phase 3's per-step work (Alg. 1 for all games, Eq. 7, Eq. 8, the env step, resets)
runs as one compiled ``lax.scan`` of ``chunk_steps`` steps; the host only assembles finished
episodes, feeds B, refits the critic, logs and checkpoints between chunks.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.algos.hybrid.brd import best_response_dynamics, make_q_fn
from hybridmarl.io import write_json_atomic
from hybridmarl.training import networks as nets
from hybridmarl.training.checkpoint import (
    AVERAGE_PREFIX,
    latest_checkpoint,
    load_checkpoint,
    prefixed,
    save_checkpoint,
    subtree,
)
from hybridmarl.training.config import (
    FINAL_EVAL_SEED,
    PeriodicEval,
    RunClock,
    TrainConfig,
    TrainingDiverged,
    check_finite,
    config_to_dict,
    key_data,
    key_of,
    resolve_run_dir,
)
from hybridmarl.training.losses import actor_loss, advantages, bc_loss, critic_loss
from hybridmarl.training.rollout import (
    EpisodeAssembler,
    LabelBuffer,
    Pool,
    ReplayBuffer,
    new_pool,
    pool_steps,
)
from hybridmarl.training.task import Task, TaskError, flatten_named, make_task, unflatten_named

ALGO = "hybrid"


@dataclass(frozen=True)
class HybridConfig(TrainConfig):
    """The hybrid learning method (critic pre-training, best-response dynamics, actor update)."""

    total_episodes: int = 20_000
    """Training episodes of Alg. 2 (the paper does not state its budget; Fig. 3 plots training
    curves over episodes)."""
    time_limit_min: float = 0.0
    """Also stop Alg. 2 at the first chunk boundary after this many minutes of the run's wall
    time (set-up and pre-training included; with ``--resume``, the earlier processes' time
    too), then checkpoint and evaluate as usual. 0: no limit. For budgets such as "3 hours";
    a run cut by the clock is not reproducible in its episode count."""
    num_envs: int = 32
    """Games played in parallel (the batch of Alg. 1 and of the actor's SGD step)."""
    chunk_steps: int = 8
    """Env steps per compiled call (host work in between: buffer, critic refits, logs)."""
    gamma: float = 0.995
    """Discount factor λ (Section 5.1)."""
    brd_iterations: int = 7
    """Iterations of Alg. 1 (Section 5.1: 7)."""
    e_update: int = 500
    """E_Update of Alg. 2: refit the critic every this many episodes (Section 5.1: 500;
    Traffic Junction, Section 5.3: 100)."""
    pretrain_samples: int = 100_000
    """(state, V^D) pairs simulated to pre-train the critic (Section 5.1: 100,000 trajectories;
    Section 5.3: 20,000 samples). Every state visited by A^D counts as one sample."""
    pretrain_critic: bool = True
    """Pre-train the critic from demonstrations (Section 4.1). False = the "w/o D" ablation of
    Table 2 (critic learned only from the actor's own returns)."""
    brd_start: Literal["actor", "demonstrator"] = "actor"
    """Where Alg. 1 starts: the current actor's actions (Section 4.3, the default; see the module
    docstring) or the original demonstrator A^D."""
    brd_min_gain: float = 0.0
    """Alg. 1 switches an agent's action only when its best response beats the current action
    by more than this (in units of the normalised return; one Marine shot at m5v5 is 0.03).
    0: the paper's plain argmax. A margin keeps near-ties at the start action, so Ã changes
    the start policy only where it matters and is a cleaner target for the actor."""
    brd_work_batch: int = 2
    """Alg. 1's simulation batch: each call simulates ``brd_work_batch x |A|`` candidate joint
    actions (an implementation choice; it does not change Ã). Each visit of Alg. 1 gathers the
    legal (game, action) pairs of the games that still need it and simulates only those; 0: all
    ``num_envs`` games x all |A| actions in every call (the dense schedule, which a GPU may
    prefer). On a CPU with the ``quick`` preset's Q, 2 makes one call of Alg. 1 4-7x faster
    than session 8's schedule (16 games per call) at m18v20, and about as fast at m5v5
    (``python bench/brd_schedule.py --checkpoint ...``; README, "Speed")."""
    lookahead_steps: int = 1
    """Forward simulation per Q estimate in Alg. 1. 1: the paper's one-step simulation,
    Q = r + λ V(s') (Eq. 2, Section 4.2). K > 1 (an extension): the continuation policy (the
    one Alg. 1 starts from, see ``brd_start``) plays K - 1 more steps before the critic
    bootstraps. 0: simulate to the end of the episode, i.e. the exact Q of the continuation
    policy (the paper's "ideal condition" of Eq. 6); the critic is then unused and not fitted."""
    lookahead_policy: Literal["start", "actor", "demonstrator"] = "start"
    """Who plays the K - 1 continuation steps of ``lookahead_steps`` (and the simulation to the
    end with ``lookahead_steps=0``): ``start`` (the default) the policy Alg. 1 starts from
    (``brd_start``), or explicitly the current ``actor`` or the ``demonstrator`` A^D. With the
    actor, its network runs on every simulated state, which is most of the cost of a lookahead
    step (``python bench/train_step.py --preset quick``); a script demonstrator costs
    a fraction of that."""
    clone_script: bool = False
    """Paper-exact A^D for a script demonstrator: record ``demo_observations`` from it and use
    its behavioural clone θ^D (Section 3) instead of the script itself."""
    actor_init: Literal["random", "clone"] = "random"
    """Initial actor parameters: ``random`` (the paper states none), or ``clone``: start the
    actor from the behavioural clone θ^D of the demonstrator (same architecture, Section 5.1),
    so that Alg. 2 starts at the demonstrator's level instead of a random policy's. For a script
    demonstrator this records ``demo_observations`` from the script and clones them (Phase 1);
    the script itself stays A^D unless ``clone_script``."""
    actor_target: Literal["advantage", "best"] = "advantage"
    """The actor update. ``advantage``: Eq. 8, ``sum_a grad log p(a|O) A(s, a)`` over the legal
    actions (the paper). Its fixed point is ``p(a) ∝ A(s, a)``, so under the legal-argmax
    execution of Section 5.1 close advantages make the executed action fragile. ``best``: the
    cross-entropy toward ``ã_g(s) = argmax_a A(s, a)``, the action of Alg. 1's result Ã that
    Eq. 7 defines (Section 4.2: "Ã ... can be used to guide the actor networks")."""
    actor_steps: int = 1
    """Actor gradient steps per environment step (1: one update per step as in Alg. 2). Without
    ``actor_buffer``: steps on the same batch of Alg. 1 results; with it: minibatch steps on the
    buffer after every chunk (``actor_steps * chunk_steps`` of them)."""
    act_before_update: bool = False
    """Which actor plays each training step. False: Alg. 2's order, update θ on s_t by Eq. 8,
    then perform the updated actor's argmax on s_t (the paper). True (an extension): perform the
    argmax of the actor as it was before that update. Either way the actor keeps adapting to
    the games it is playing, so the training ``won_100`` is not a frozen policy's; measured at
    m5v5 (README, "Results"), this flag does not close that gap (training 0.49, evaluation 0.03)."""
    actor_buffer: int = 0
    """0: the actor is updated on-line, on each step's Alg. 1 results, inside the compiled chunk
    (Alg. 2). N > 0 (an extension): keep the last N agent decisions labelled by Alg. 1 (obs,
    legal mask, ã_g, advantages) and train the actor on minibatches of them between chunks, so
    every costly Alg. 1 result is reused (DAgger-style aggregation of the actor's own states)."""
    actor_batch_size: int = 256
    """Minibatch of the actor's buffer steps (``actor_buffer`` > 0; not given in the paper)."""
    actor_average_from: int | None = None
    """None: the run's policy is the last actor (Alg. 2). E (an extension, stochastic weight
    averaging after Izmailov et al. 2018): from training episode E on, also keep the uniform
    average of the actor's parameters and batch-norm statistics after every chunk, and make
    that the run's policy (the final and periodic evaluations, checkpoint ``best``, ``hybridmarl
    eval``; the final evaluation also reports the last actor as ``last_actor``). Training still
    plays the live actor. Why: evaluated checkpoints of one m5v5 run 50 episodes apart swing
    between W 0.20 and 0.70, and the average of the second half's checkpoints is as good as the
    best of them (README, "Results")."""
    demo_observations: int = 10_000
    """Demonstration observations recorded for cloning (Section 5.1: 10,000)."""
    bc_steps: int = 5_000
    """SGD steps of behavioural cloning θ^D (not given in the paper)."""
    bc_batch_size: int = 256
    """Minibatch of behavioural cloning (not given in the paper)."""
    optimizer: Literal["sgd", "adam"] = "sgd"
    """Optimiser of every network (Section 5.1: SGD)."""
    actor_lr: float = 1e-3
    """Actor learning rate η of Eq. 8 (Section 5.1: 10^-3)."""
    critic_lr: float = 1e-3
    """Critic learning rate (Section 5.1: 10^-3)."""
    momentum: float = 0.0
    """SGD momentum (0: plain SGD as in Section 5.1)."""
    critic_batch_size: int = 256
    """Minibatch of critic fits (not given in the paper)."""
    critic_pretrain_steps: int = 10_000
    """SGD steps of the critic's pre-training fit on B (not given in the paper)."""
    critic_update_steps: int = 1_000
    """SGD steps of each E_Update critic refit on B (not given in the paper)."""
    buffer_size: int = 100_000
    """Capacity of the buffer B (FIFO; the paper does not bound it)."""
    actor_hidden: tuple[int, ...] = nets.ACTOR_HIDDEN
    """Actor FC widths before the |A| output (Section 5.1: 512, 256, 256)."""
    critic_hidden: tuple[int, ...] = nets.CRITIC_HIDDEN
    """Critic FC widths before the scalar output (Section 5.1: 256, 128, 128)."""


# -- presets -------------------------------------------------------------------------------------------


def _paper(env: str) -> HybridConfig:
    if env == "traffic_junction":
        # Section 5.3: "Most hyper-parameters are the same ... E_Update = 100, and 20,000 samples".
        return HybridConfig(env=env, demonstrator="always-gas", e_update=100, pretrain_samples=20_000, buffer_size=20_000)
    return HybridConfig(env=env)


def _quick_paper(env: str) -> HybridConfig:
    """``quick-paper``: the paper's method (one-step Q of Eq. 2, Eq. 8, the last actor) at a
    small budget: fewer pre-training samples and episodes, more frequent critic refits, Adam
    instead of SGD for faster progress. At m5v5 it does not beat its demonstrator (README,
    "Results"); ``quick`` adds the extensions that do. It was called ``quick`` before session 10."""
    base = _paper(env)
    if env == "traffic_junction":
        return dataclasses.replace(
            base, total_episodes=1_500, num_envs=16, pretrain_samples=8_000, buffer_size=8_000,
            critic_pretrain_steps=1_500, critic_update_steps=300, e_update=100,
            optimizer="adam", checkpoint_every=500,
        )
    return dataclasses.replace(
        base, total_episodes=3_000, num_envs=32, pretrain_samples=20_000, buffer_size=40_000,
        critic_pretrain_steps=2_000, critic_update_steps=500, e_update=100,
        optimizer="adam", checkpoint_every=500,
    )


def _quick_rollout(env: str) -> HybridConfig:
    """An extension, not the paper's setting: Alg. 1's Q by simulating the demonstrator to the
    end of the episode (``lookahead_steps=0``: exact Q^D, the "ideal condition" of Eq. 6)
    instead of r + λ V(s'); one best-response iteration. No critic is needed."""
    return dataclasses.replace(
        _quick_paper(env), lookahead_steps=0, brd_start="demonstrator", brd_iterations=1,
        total_episodes=400 if env == "combat" else 300, num_envs=16, checkpoint_every=100,
        pretrain_critic=False,
    )


def _quick(env: str) -> HybridConfig:
    """``quick``, minutes on a CPU: the recipe of our best CPU runs (README, "Results"). Not the
    paper's setting: ``quick-paper`` plus extensions. Alg. 1's Q simulates K steps before the
    critic bootstraps (``lookahead_steps``). Combat: K = 8, the 7 continuation steps played by
    the demonstrator script (``lookahead_policy="demonstrator"``: an 8-step Q^D, several times
    cheaper per step than the actor's network), 128 games in parallel, the actor trained by
    cross-entropy toward Alg. 1's ã_g with 4 steps per env step (``actor_target="best"``,
    ``actor_steps=4``) for 3,000 episodes, and the run's policy is the actor's weight average
    from episode 1,500 on (``actor_average_from=1500``), evaluated every 150 episodes. m5v5,
    c vs w: W 0.88-0.93 of 100 battles over seven seeds against D's 0.44, in 10-23 CPU-min;
    m18v20 needs ``--brd-start demonstrator`` (the actor start stalls into draws). Traffic
    Junction keeps K = 4, Eq. 8, the actor as continuation, 32 games and 1,500 episodes
    (failure 0.176 against D's 0.959). Called ``quick-lookahead`` before session 10 (that name
    still works)."""
    base = dataclasses.replace(_quick_paper(env), lookahead_steps=4)
    if env == "traffic_junction":
        return base
    return dataclasses.replace(
        base, lookahead_steps=8, actor_target="best", actor_steps=4, lookahead_policy="demonstrator", num_envs=128,
        total_episodes=3000, actor_average_from=1500, eval_every=150,
    )


def _toy(env: str) -> HybridConfig:
    """Seconds: a smoke test of the whole pipeline (tests, CI). Tiny networks, no learning."""
    return dataclasses.replace(
        _quick_paper(env), total_episodes=8, num_envs=4, chunk_steps=4, pretrain_samples=64, buffer_size=512,
        critic_pretrain_steps=10, critic_update_steps=5, e_update=4, brd_iterations=2,
        actor_hidden=(16, 16, 16), critic_hidden=(16, 8, 8), checkpoint_every=4, eval_episodes=8,
        bc_steps=20, demo_observations=64, tensorboard=False,
    )


def _without_d(make):
    def preset(env: str) -> HybridConfig:
        # No demonstrator after Phase 1 either: Alg. 1 starts from, and its look-ahead is played by, the actor.
        return dataclasses.replace(make(env), pretrain_critic=False, brd_start="actor", lookahead_policy="start")

    return preset


PRESETS = {
    "paper": _paper,
    "quick": _quick,
    "quick-paper": _quick_paper,
    "traffic-junction": lambda env: _paper("traffic_junction"),
    "wo-d": _without_d(_paper),
    "quick-wo-d": _without_d(_quick),  # Table 2's "w/o D" beside ``quick``: the same recipe
    "quick-rollout": _quick_rollout,
    "quick-lookahead": _quick,  # the name of ``quick`` before session 10
    "toy": _toy,
}


# -- the compiled pieces ---------------------------------------------------------------------------------


class Learner:
    """Networks, optimisers and the jitted functions of one (task, static settings) pair."""

    def __init__(self, task: Task, cfg: HybridConfig, demo_script: str | None) -> None:
        self.task = task
        self.actor_mod = nets.actor_module(task.num_actions, cfg.actor_hidden)
        self.critic_mod = nets.critic_module(cfg.critic_hidden)
        self.actor_tx = nets.make_optimizer(cfg.optimizer, cfg.actor_lr, cfg.momentum)
        self.critic_tx = nets.make_optimizer(cfg.optimizer, cfg.critic_lr, cfg.momentum)
        self.b = cfg.num_envs
        demo = task.demonstrator(demo_script) if demo_script else None
        self.demo_script_fn = demo
        actor_mod = self.actor_mod

        def demo_act(clone_vars, key, states, obs, legal):
            """A^D(s) for a batch: the script, or the clone's legal argmax."""
            if demo is not None:
                return jax.vmap(demo)(jax.random.split(key, self.b), states).astype(jnp.int32)
            return nets.actor_actions(actor_mod, clone_vars, obs, legal)

        self.demo_act = demo_act
        self.demo_chunk = jax.jit(functools.partial(self._demo_chunk, steps=cfg.chunk_steps))
        self.train_chunk = jax.jit(
            functools.partial(
                self._train_chunk, steps=cfg.chunk_steps, gamma=cfg.gamma,
                iterations=cfg.brd_iterations, start=cfg.brd_start, continuation=continuation_policy(cfg),
                lookahead=simulated_steps(cfg),
                actor_steps=cfg.actor_steps, target=cfg.actor_target, online=cfg.actor_buffer <= 0,
                min_gain=cfg.brd_min_gain, act_before_update=cfg.act_before_update,
                work_batch=cfg.brd_work_batch,
            )
        )
        self.fit_critic = jax.jit(functools.partial(self._fit_critic, batch=cfg.critic_batch_size))
        self.critic_values = jax.jit(self._critic_values)
        self.fit_actor = jax.jit(functools.partial(self._fit_actor, batch=cfg.actor_batch_size, target=cfg.actor_target))

    # Phase 2's data: A^D plays from random start states.
    def _demo_chunk(self, pool: Pool, clone_vars: Any, *, steps: int):
        def act(carry, key, states, obs, legal):
            return self.demo_act(carry, key, states, obs, legal), carry, {}

        pool, _, out = pool_steps(self.task, act, pool, clone_vars, steps)
        return pool, out

    def value_fn(self, critic_vars: Any):
        def v(states: Any) -> jax.Array:
            feats = jax.vmap(self.task.value_features)(states)
            return nets.apply_eval(self.critic_mod, critic_vars, feats)[:, 0]

        return v

    def _critic_values(self, critic_vars: Any, states: Any) -> jax.Array:
        return self.value_fn(critic_vars)(states)

    # Eq. 3 on the buffer B: minibatch SGD on (V(s) - V^D(s))^2.
    def _fit_critic(self, critic: nets.NetState, states: Any, returns: jax.Array, size: jax.Array, key: jax.Array, num_steps: jax.Array, *, batch: int):
        mod, tx, task = self.critic_mod, self.critic_tx, self.task

        def one(i, c):
            critic, total = c
            idx = jax.random.randint(jax.random.fold_in(key, i), (batch,), 0, jnp.maximum(size, 1))
            feats = jax.vmap(task.value_features)(jax.tree.map(lambda x: x[idx], states))

            def loss_fn(params, batch_stats):
                v, bs = nets.apply_train(mod, params, batch_stats, feats)
                return critic_loss(v[:, 0], returns[idx]), (bs, None)

            critic, loss, _ = nets.sgd_step(critic, tx, loss_fn)
            return critic, total + loss

        critic, total = jax.lax.fori_loop(0, num_steps, one, (critic, jnp.zeros((), jnp.float32)))
        return critic, total / jnp.maximum(num_steps, 1).astype(jnp.float32)

    # The actor on minibatches of Alg. 1's labelled decisions (``actor_buffer`` > 0).
    def _fit_actor(self, actor: nets.NetState, rows: dict, size: jax.Array, key: jax.Array, num_steps: jax.Array, *, batch: int, target: str):
        mod, tx = self.actor_mod, self.actor_tx

        def one(i, c):
            actor, total = c
            idx = jax.random.randint(jax.random.fold_in(key, i), (batch,), 0, jnp.maximum(size, 1))

            def loss_fn(params, batch_stats):
                logits, bs = nets.apply_train(mod, params, batch_stats, rows["obs"][idx])
                if target == "best":
                    return bc_loss(logits, rows["target"][idx], rows["legal"][idx]), (bs, None)
                return actor_loss(logits, rows["adv"][idx], rows["legal"][idx]), (bs, None)

            actor, loss, _ = nets.sgd_step(actor, tx, loss_fn)
            return actor, total + loss

        actor, total = jax.lax.fori_loop(0, num_steps, one, (actor, jnp.zeros((), jnp.float32)))
        return actor, total / jnp.maximum(num_steps, 1).astype(jnp.float32)

    # Phase 3, K steps of Alg. 2 for all B games.
    def brd_q_fn(self, actor: Any, critic_vars: Any, clone_vars: Any, *, gamma: float, lookahead: int, continuation: str):
        """Alg. 1's Q estimate for B games: ``lookahead`` simulated steps (1: Eq. 2's one step;
        ``TO_THE_END``: to the end, critic unused), the later ones played by ``continuation``
        (``actor``: the actor's legal argmax; ``demonstrator``: A^D, the script or the clone)."""
        task, mod = self.task, self.actor_mod

        def batch_step_fn(keys, states, actions):
            _, s2, r, d, _ = task.batch_step(keys, states, actions)
            return r, s2, d

        def policy(keys, flat_states):
            if continuation == "demonstrator" and self.demo_script_fn is not None:
                return jax.vmap(self.demo_script_fn)(keys, flat_states).astype(jnp.int32)
            fobs = jax.vmap(task.observe)(flat_states)
            flegal = jax.vmap(task.avail)(flat_states)
            return nets.actor_actions(mod, actor if continuation == "actor" else clone_vars, fobs, flegal)

        value_fn = self.value_fn(critic_vars) if lookahead < TO_THE_END else (lambda s: jnp.zeros(jax.tree.leaves(s)[0].shape[0]))
        return make_q_fn(task.lookahead, value_fn, gamma, steps=lookahead, policy_fn=policy, batch_step_fn=batch_step_fn)

    def _train_chunk(self, pool: Pool, actor: nets.NetState, critic_vars: Any, clone_vars: Any, *, steps: int, gamma: float, iterations: int, start: str, continuation: str, lookahead: int, actor_steps: int, target: str, online: bool, min_gain: float, act_before_update: bool, work_batch: int):
        task, b, mod, tx = self.task, self.b, self.actor_mod, self.actor_tx

        def act(actor, key, states, obs, legal):
            q_fn = self.brd_q_fn(actor, critic_vars, clone_vars, gamma=gamma, lookahead=lookahead, continuation=continuation)
            k_demo, k_sim = jax.random.split(key)
            n, na = legal.shape[1], legal.shape[2]
            a_actor = nets.actor_actions(mod, actor, obs, legal)
            # Alg. 1 from the actor's actions (Section 4.3) or from A^D.
            a0 = a_actor if start == "actor" else self.demo_act(clone_vars, k_demo, states, obs, legal)
            res = best_response_dynamics(q_fn, jax.random.split(k_sim, b), states, a0, legal, iterations, min_gain, work_batch)
            # Eq. 7: advantage of every legal action of every agent that has a choice.
            adv = advantages(res.q, legal)
            weight = res.q_valid & (jnp.sum(legal, -1) >= 2)
            flat_w = weight.reshape(-1)
            any_w = jnp.any(flat_w)
            bn_mask = jnp.where(any_w, flat_w, jnp.ones_like(flat_w))

            # Eq. 8: theta <- theta + eta * sum_a grad log p(a|O) A(s, a), shared actor.
            def loss_fn(params, batch_stats):
                logits, bs = nets.apply_train(mod, params, batch_stats, obs.reshape(b * n, -1), mask=bn_mask)
                if target == "best":
                    loss = bc_loss(logits, res.actions.reshape(b * n), legal.reshape(b * n, na), flat_w)
                else:
                    loss = actor_loss(logits, adv.reshape(b * n, na), legal.reshape(b * n, na), flat_w)
                return loss, (bs, None)

            def sgd_step(_, c):
                net, _ = c
                net, loss, _ = nets.sgd_step(net, tx, loss_fn)
                return net, loss

            if online:
                new, loss = jax.lax.fori_loop(0, actor_steps, sgd_step, (actor, jnp.zeros((), jnp.float32)))
                actor = jax.tree.map(lambda x, y: jnp.where(any_w, x, y), new, actor)
            else:  # labels leave the chunk for the actor buffer (fit_actor between chunks)
                loss = jnp.asarray(jnp.nan, jnp.float32)
            # Perform the (updated) actor's legal argmax (Alg. 2), or the pre-update one.
            actions = a_actor if act_before_update else nets.actor_actions(mod, actor, obs, legal)
            wf = weight.astype(jnp.float32)
            nw = jnp.maximum(jnp.sum(wf), 1.0)
            aux = {
                "actor_loss": loss,
                "brd_sweeps": res.sweeps.astype(jnp.float32),
                "brd_visits": res.evaluated.astype(jnp.float32) / b,
                "brd_simulated": res.simulated.astype(jnp.float32) / b,
                "brd_changes": jnp.mean(res.changes.astype(jnp.float32)),
                "q_gain": jnp.nanmean(res.q_final - res.q_init),
                "q_final": jnp.nanmean(res.q_final),
                "adv_max": jnp.sum(jnp.max(adv, -1) * wf) / nw,
                "agree": jnp.sum((a_actor == res.actions) * wf) / nw,
                "deciders": jnp.sum(wf) / b,
            }
            if not online:
                aux["labels"] = {"obs": obs, "legal": legal, "target": res.actions, "adv": adv, "w": weight}
            return actions, actor, aux

        pool, actor, out = pool_steps(task, act, pool, actor, steps)
        return pool, actor, out


#: Simulated steps that stand for "to the end of the episode" (``lookahead_steps=0``); the Q
#: loop stops early once every simulated game has ended.
TO_THE_END = 1_000_000


def simulated_steps(cfg: HybridConfig) -> int:
    """Steps of Alg. 1's Q simulation: ``lookahead_steps``, where 0 means ``TO_THE_END``."""
    return cfg.lookahead_steps if cfg.lookahead_steps > 0 else TO_THE_END


def continuation_policy(cfg: HybridConfig) -> str:
    """Who plays a lookahead's continuation steps: ``lookahead_policy``, where ``start`` means
    the policy Alg. 1 starts from."""
    return cfg.brd_start if cfg.lookahead_policy == "start" else cfg.lookahead_policy


@functools.lru_cache(maxsize=8)
def build_learner(task: Task, cfg: HybridConfig, demo_script: str | None) -> Learner:
    # Only fields that shape the compiled functions matter; the rest of cfg is normalised away.
    return Learner(task, cfg, demo_script)


def _static_cfg(cfg: HybridConfig) -> HybridConfig:
    """The config with every field that does not affect compilation reset to its default."""
    keep = {
        "num_envs", "chunk_steps", "gamma", "brd_iterations", "brd_start", "lookahead_steps", "optimizer", "actor_lr",
        "critic_lr", "momentum", "critic_batch_size", "actor_hidden", "critic_hidden", "actor_steps", "actor_target", "actor_buffer", "actor_batch_size", "brd_min_gain",
        "act_before_update", "lookahead_policy", "brd_work_batch",
    }
    return HybridConfig(**{f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if f.name in keep})


# -- training state ------------------------------------------------------------------------------------


@dataclass
class RunState:
    """Everything a checkpoint holds (device pytrees + host buffers + counters)."""

    actor: nets.NetState
    critic: nets.NetState
    clone: nets.NetState | None
    pool: Pool
    key: jax.Array  # raw uint32 key data
    buffer: ReplayBuffer
    assembler: EpisodeAssembler
    labels: LabelBuffer
    phase: str = "pretrain"  # "pretrain" (Phases 1-2 to do) -> "joint" (Phase 3)
    episodes: int = 0
    env_steps: int = 0
    iterations: int = 0
    critic_updates: int = 0
    next_critic_update: int = 0
    critic_loss: float = float("nan")
    demo_stats: dict[str, float] = dataclasses.field(default_factory=dict)
    history: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    average: Any = None  # {"params", "batch_stats"}: the actor's running average (actor_average_from)
    average_count: int = 0

    def policy_vars(self) -> Any:
        """The run's policy: the actor's weight average once it has begun, else the actor."""
        return self.average if self.average_count > 0 else _vars(self.actor)

    def next_key(self) -> jax.Array:
        k, sub = jax.random.split(key_of(self.key))
        self.key = key_data(k)
        return sub

    def arrays(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        out.update(prefixed(flatten_named(self.actor), "actor"))
        if self.average_count > 0:
            out.update(prefixed(flatten_named(self.average), AVERAGE_PREFIX))
        out.update(prefixed(flatten_named(self.critic), "critic"))
        if self.clone is not None:
            out.update(prefixed(flatten_named(self.clone), "clone"))
        out.update(prefixed(flatten_named(self.pool), "pool"))
        out["key"] = np.asarray(self.key)
        out.update(prefixed(self.buffer.to_arrays(), "buffer"))
        out.update(prefixed(self.assembler.to_arrays(), "asm"))
        if self.labels.capacity > 0:
            out.update(prefixed(self.labels.to_arrays(), "labels"))
        for k, v in self.history.items():
            out[f"history.{k}"] = np.asarray(v, np.float32)
        return out

    def meta(self) -> dict[str, Any]:
        return {
            "phase": self.phase,
            "episodes": self.episodes,
            "env_steps": self.env_steps,
            "iterations": self.iterations,
            "critic_updates": self.critic_updates,
            "next_critic_update": self.next_critic_update,
            "critic_loss": self.critic_loss,
            "demo_stats": self.demo_stats,
            "average_count": self.average_count,
        }

    def restore(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        self.actor = unflatten_named(self.actor, subtree(arrays, "actor"))
        self.critic = unflatten_named(self.critic, subtree(arrays, "critic"))
        if self.clone is not None:
            self.clone = unflatten_named(self.clone, subtree(arrays, "clone"))
        self.pool = unflatten_named(self.pool, subtree(arrays, "pool"))
        self.key = jnp.asarray(arrays["key"])
        self.buffer.load_arrays(subtree(arrays, "buffer"))
        self.assembler.load_arrays(subtree(arrays, "asm"))
        if self.labels.capacity > 0:
            self.labels.load_arrays(subtree(arrays, "labels"))
        self.history = {k: np.asarray(v).tolist() for k, v in subtree(arrays, "history").items()}
        for k in ("phase", "episodes", "env_steps", "iterations", "critic_updates", "next_critic_update", "critic_loss", "demo_stats"):
            setattr(self, k, meta[k])
        self.average_count = int(meta.get("average_count", 0))
        if self.average_count > 0:
            self.average = unflatten_named(_vars(self.actor), subtree(arrays, AVERAGE_PREFIX))


@jax.jit
def _running_mean(avg: Any, new: Any, count: jax.Array) -> Any:
    return jax.tree.map(lambda a, x: a + (x - a) / count.astype(a.dtype), avg, new)


def _vars(net: nets.NetState | None) -> Any:
    return None if net is None else {"params": net.params, "batch_stats": net.batch_stats}


# -- the run ---------------------------------------------------------------------------------------------


def train(cfg: HybridConfig) -> int:
    from hybridmarl.training import demos as D
    from hybridmarl.training import evaluate as E
    from hybridmarl.training import plots
    from hybridmarl.training.logger import Progress, RunLogger, recent_status

    # ---- Phase 0: set-up ------------------------------------------------------------------------
    clock = RunClock()
    spec = cfg.task_spec()
    task = make_task(spec)
    run_dir = resolve_run_dir(ALGO, cfg)
    ckpt = latest_checkpoint(run_dir)
    if ckpt is not None and not cfg.resume:
        raise TaskError(f"{run_dir} already holds checkpoints: pass --resume to continue it, or choose another --run-dir")
    log = RunLogger(run_dir, tensorboard=cfg.tensorboard)
    dataset = None
    demo_script: str | None = None
    if cfg.demonstrator_is_dataset():
        dataset = D.load_dataset(cfg.demonstrator, expect=task)
    elif cfg.clone_script:
        pass  # cloned below (Phase 1)
    else:
        demo_script = cfg.demonstrator_name()
    learner = build_learner(task, _static_cfg(cfg), demo_script)
    key = jax.random.key(cfg.seed)
    k_actor, k_critic, k_clone, k_pool, k_run = jax.random.split(key, 5)
    actor = nets.init_net(learner.actor_mod, k_actor, task.obs_dim, learner.actor_tx)
    critic = nets.init_net(learner.critic_mod, k_critic, task.critic_dim, learner.critic_tx)
    needs_clone = demo_script is None or cfg.actor_init == "clone"
    clone = nets.init_net(learner.actor_mod, k_clone, task.obs_dim, learner.actor_tx) if needs_clone else None
    template_state = task.state_template()
    st = RunState(
        actor=actor, critic=critic, clone=clone, pool=new_pool(task, k_pool, cfg.num_envs), key=key_data(k_run),
        buffer=ReplayBuffer(cfg.buffer_size, template_state), assembler=EpisodeAssembler(cfg.num_envs, cfg.gamma),
        labels=LabelBuffer(max(cfg.actor_buffer, 0), task.obs_dim, task.num_actions),
        next_critic_update=cfg.e_update,
    )
    config_doc = {
        "algo": ALGO,
        "config": {**config_to_dict(cfg), "demonstrator_name": cfg.demonstrator_name(), "eval_enemy_name": cfg.eval_enemy_name()},
        "task": spec.to_dict(),
        "networks": {"actor_params": nets.num_params(actor.params), "critic_params": nets.num_params(critic.params)},
        "versions": {"jax": jax.__version__, "hybridmarl": _version()},
    }
    periodic = PeriodicEval(cfg, run_dir, log, st.episodes)
    if ckpt is not None:
        arrays, meta = load_checkpoint(ckpt)
        st.restore(arrays, meta)
        clock.resume(meta)
        periodic.resume(meta, st.episodes)
        log.resume_at(st.episodes)
        print(f"resumed {run_dir} from {ckpt.name} (phase {st.phase}, {st.episodes} episodes)")
    log.write_config(config_doc)

    def ckpt_meta() -> dict[str, Any]:
        return {**st.meta(), **clock.elapsed(), **periodic.meta(), "algo": ALGO, "config": config_doc["config"], "task": spec.to_dict()}

    def save() -> None:
        save_checkpoint(run_dir, st.episodes, st.arrays(), ckpt_meta(), keep=cfg.keep_checkpoints)

    if st.phase == "pretrain":
        # ---- Phase 1: the demonstrator A^D (Section 3) ----------------------------------------
        if needs_clone:
            if dataset is None:
                dataset = D.collect(spec, cfg.demonstrator_name(), cfg.demo_observations, seed=cfg.seed, gamma=cfg.gamma)
            rows = D.bc_rows(dataset)
            assert st.clone is not None
            st.clone, losses = D.fit_bc(st.clone, learner.actor_mod, (cfg.optimizer, cfg.actor_lr), rows, st.next_key(), cfg.bc_steps, cfg.bc_batch_size)
            check_finite("behavioural-cloning loss", float(losses[-1]) if losses.size else 0.0, "the end of cloning")
            acc = D.bc_accuracy(st.clone, learner.actor_mod, rows)
            role = "A^D" if demo_script is None else "θ^D (the actor's start)"
            print(f"{role} = behavioural clone of {dataset.size} observations: final loss {losses[-1]:.4f}, accuracy {acc:.3f}")
            if cfg.actor_init == "clone":
                st.actor = st.actor.replace(params=st.clone.params, batch_stats=st.clone.batch_stats, opt_state=learner.actor_tx.init(st.clone.params))
        # ---- Phase 2: critic pre-training (Section 4.1, Eq. 3) ----------------------------------
        if cfg.pretrain_critic and cfg.pretrain_samples > 0 and cfg.lookahead_steps != 0:
            demo_pool = new_pool(task, st.next_key(), cfg.num_envs)
            asm = EpisodeAssembler(cfg.num_envs, cfg.gamma)
            got, stats_all = 0, {}
            t0 = time.time()
            while got < cfg.pretrain_samples:
                demo_pool, out = learner.demo_chunk(demo_pool, _vars(st.clone))
                states, returns, stats = asm.add(out)
                st.buffer.add(states, returns)
                got += int(returns.size)
                for k, v in stats.items():
                    stats_all.setdefault(k, []).extend(v.tolist())
            st.demo_stats = {k: float(np.mean(v)) for k, v in stats_all.items() if v}
            st.demo_stats["episodes"] = float(len(next(iter(stats_all.values()), [])))
            st.critic, closs = learner.fit_critic(st.critic, *st.buffer.device_arrays(), st.next_key(), jnp.asarray(cfg.critic_pretrain_steps))
            st.critic_loss = float(closs)
            check_finite("critic pre-training loss", st.critic_loss, "pre-training")
            print(
                f"critic pre-trained on {st.buffer.size} (s, V^D) pairs from {int(st.demo_stats['episodes'])} demonstrator episodes "
                f"({time.time() - t0:.0f}s): MSE {st.critic_loss:.5f}; demonstrator: "
                + ", ".join(f"{k} {v:.3f}" for k, v in st.demo_stats.items() if k != "episodes")
            )
        st.phase = "joint"
        save()

    # ---- Phase 3: the joint update (Alg. 2) -----------------------------------------------------
    eval_task = task.against(cfg.eval_enemy_name())
    prog = Progress(cfg.total_episodes, f"{ALGO} {spec.label()}", enabled=cfg.progress, start=st.episodes)
    primary, secondary = task.progress_metrics
    next_ckpt = (st.episodes // cfg.checkpoint_every + 1) * cfg.checkpoint_every

    def evaluate(variables: Any, seed_offset: int) -> dict[str, Any]:
        return E.evaluate_task(eval_task, learner.actor_mod, variables, n=cfg.eval_episodes, seed=cfg.seed + seed_offset)

    def actor_arrays() -> dict[str, np.ndarray]:
        return prefixed(flatten_named(st.policy_vars()), "actor")

    t_phase = time.time()
    steps_at_start = st.env_steps
    time_limited = False
    try:
        while st.phase == "joint" and st.episodes < cfg.total_episodes:
            t0 = time.time()
            st.pool, st.actor, out = learner.train_chunk(st.pool, st.actor, _vars(st.critic), _vars(st.clone))
            labels = out["aux"].pop("labels", None)
            states, returns, stats = st.assembler.add(out)
            st.buffer.add(states, returns)
            if labels is not None:
                lab = jax.device_get(labels)
                w = np.asarray(lab.pop("w")).reshape(-1)
                st.labels.add({k: np.asarray(v).reshape((w.shape[0],) + np.asarray(v).shape[3:])[w] for k, v in lab.items()})
                st.actor, aloss = learner.fit_actor(st.actor, *st.labels.device_arrays(), st.next_key(), jnp.asarray(cfg.actor_steps * cfg.chunk_steps))
                out["aux"]["actor_loss"] = aloss
            n_new = int(next(iter(stats.values())).shape[0]) if stats else 0
            first_ep = st.episodes
            st.episodes += n_new
            st.env_steps += cfg.chunk_steps * cfg.num_envs
            st.iterations += 1
            for k, v in stats.items():
                st.history.setdefault(k, []).extend(v.tolist())
            aux = {k: float(np.nanmean(np.asarray(v))) for k, v in out["aux"].items()}
            check_finite("actor loss", aux["actor_loss"], f"episode {st.episodes}")
            check_finite("actor parameters", st.actor.params, f"episode {st.episodes}")
            # Every E_Update episodes: refit the critic on B (Eq. 3).
            if st.episodes >= st.next_critic_update and cfg.lookahead_steps != 0:
                st.critic, closs = learner.fit_critic(st.critic, *st.buffer.device_arrays(), st.next_key(), jnp.asarray(cfg.critic_update_steps))
                st.critic_loss = float(closs)
                st.critic_updates += 1
                st.next_critic_update = (st.episodes // cfg.e_update + 1) * cfg.e_update
                check_finite("critic loss", st.critic_loss, f"episode {st.episodes}")
                check_finite("critic parameters", st.critic.params, f"episode {st.episodes}")
            # Stochastic weight averaging (an extension, ``actor_average_from``).
            if cfg.actor_average_from is not None and st.episodes >= cfg.actor_average_from:
                st.average_count += 1
                cur = _vars(st.actor)
                st.average = cur if st.average_count == 1 else _running_mean(st.average, cur, jnp.asarray(st.average_count, jnp.float32))
            # Logs.
            dt = time.time() - t0
            # The same keys in every row (the CSV header is the first row's, often written before
            # any episode has finished): NaN until there is history.
            recent = {k: float(np.mean(st.history[k][-100:])) if st.history.get(k) else float("nan") for k in (*task.metric_names, "return")}
            row = {
                "episodes": st.episodes, "env_steps": st.env_steps, "iteration": st.iterations, **aux,
                "critic_loss": st.critic_loss, "critic_updates": st.critic_updates,
                **{f"{k}_100": v for k, v in recent.items()}, "chunk_s": dt,
                "env_steps_per_s": cfg.chunk_steps * cfg.num_envs / max(dt, 1e-9), **clock.elapsed(),
            }
            log.train.write([row])
            log.scalars(st.episodes, row)
            log.episodes.write([
                {"episode": first_ep + i + 1, "env_steps": st.env_steps, **{k: float(v[i]) for k, v in stats.items()}}
                for i in range(n_new)
            ])
            critic = "-" if np.isnan(st.critic_loss) else f"{st.critic_loss:.4f}"  # '-': not fitted yet (w/o D)
            status = f"{recent_status(recent, primary, secondary)}  critic {critic}"
            prog.update(st.episodes, status)
            periodic.maybe_run(st.episodes, lambda off: evaluate(st.policy_vars(), off), actor_arrays, ckpt_meta())
            if st.episodes >= next_ckpt:
                save()
                next_ckpt = (st.episodes // cfg.checkpoint_every + 1) * cfg.checkpoint_every
            if cfg.time_limit_min > 0 and clock.elapsed()["wall_s"] >= 60.0 * cfg.time_limit_min:
                time_limited = True
                break
    except TrainingDiverged as e:
        prog.close()
        log.close()
        import sys

        print(f"hybridmarl: training stopped: {e}", file=sys.stderr)
        return 3
    prog.close()
    save()
    if time_limited:
        print(f"time limit of {cfg.time_limit_min:g} min reached after {st.episodes} episodes: stopping Alg. 2 there")
    train_s = time.time() - t_phase
    sps = (st.env_steps - steps_at_start) / max(train_s, 1e-9)

    # ---- Phase 4: evaluation (Section 5.1) --------------------------------------------------------
    result = evaluate(st.policy_vars(), FINAL_EVAL_SEED)
    if st.average_count > 0:
        result["last_actor"] = evaluate(_vars(st.actor), FINAL_EVAL_SEED)
        result["average_of"] = st.average_count
    result.update(
        enemy=eval_task.enemy, episodes=st.episodes, time_limited=time_limited,
        env_steps_per_s=sps, **clock.elapsed(),
    )
    best = E.evaluate_best(run_dir, lambda v: evaluate(v, FINAL_EVAL_SEED))
    if best is not None:
        result["best"] = best
    write_json_atomic(run_dir / "eval.json", result)
    log.scalars(st.episodes, {k: v for k, v in result.items() if isinstance(v, float)}, prefix="eval")
    demo_level = st.demo_stats.get(secondary)
    plots.training_curve(st.history.get(secondary, []), run_dir / "curve.png", metric=secondary, title=f"{ALGO}: {spec.label()}, A^D = {cfg.demonstrator_name()}", baseline=demo_level)
    log.close()
    print(task.result_line(result) + (f"  (the actor's weight average over {st.average_count} chunks)" if st.average_count else ""))
    if st.average_count:
        print("the last actor: " + task.result_line({**result, **result["last_actor"]}).removeprefix("eval "))
    if best is not None:
        print(E.best_line(task, result, best))
    return 0


def _version() -> str:
    from hybridmarl import __version__

    return __version__


__all__ = ["ALGO", "PRESETS", "HybridConfig", "Learner", "build_learner", "train"]
