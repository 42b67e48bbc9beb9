"""The hybrid method's options, in groups (one box each in 'hybridmarl train --algo hybrid
--help'), and its presets. Every default says where it comes from: a section of the paper, or
"not given in the paper" (then ours)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

from tyro.conf import OmitArgPrefixes

from hybridmarl.training import networks as nets
from hybridmarl.training.config import Options, TrainConfig


@dataclass(frozen=True)
class BudgetOptions(Options):
    """Budget and parallelism of Alg. 2."""

    RUN_ONLY = frozenset({"total_episodes", "time_limit_min"})

    total_episodes: int = 20_000
    """Training episodes of Alg. 2 (the paper does not state its budget; Fig. 3 plots training
    curves over episodes)."""
    time_limit_min: float = 0.0
    """Also stop Alg. 2 at the first chunk boundary after this many minutes of the run's wall
    time (set-up and pre-training included; with --resume, the earlier processes' time too),
    then checkpoint and evaluate as usual. 0: no limit. For budgets such as "3 hours"; a run
    cut by the clock is not reproducible in its episode count."""
    num_envs: int = 32
    """Games played in parallel (the batch of Alg. 1 and of the actor's SGD step)."""
    chunk_steps: int = 8
    """Env steps per compiled call (host work in between: buffer, critic refits, logs)."""


@dataclass(frozen=True)
class CloneOptions(Options):
    """Phase 1: the behavioural clone θ^D of the demonstrator (Section 3)."""

    RUN_ONLY = frozenset({"demo_observations", "bc_steps", "bc_batch_size"})

    demo_observations: int = 10_000
    """Demonstration observations recorded for cloning (Section 5.1: 10,000)."""
    bc_steps: int = 5_000
    """SGD steps of behavioural cloning θ^D (not given in the paper)."""
    bc_batch_size: int = 256
    """Minibatch of behavioural cloning (not given in the paper)."""


@dataclass(frozen=True)
class CriticOptions(Options):
    """Phase 2 and the critic refits of Alg. 2 (Section 4.1, Eq. 3)."""

    # Host-side schedules and sizes: the compiled critic fit takes its step count as an argument.
    RUN_ONLY = frozenset(
        {
            "pretrain_critic",
            "pretrain_samples",
            "pretrain_trajectories",
            "e_update",
            "buffer_size",
            "critic_pretrain_steps",
            "critic_update_steps",
        }
    )

    gamma: float = 0.995
    """Discount factor λ (Section 5.1)."""
    pretrain_critic: bool = True
    """Pre-train the critic from demonstrations (Section 4.1). False = the "w/o D" ablation of
    Table 2 (critic learned only from the actor's own returns)."""
    pretrain_samples: int = 100_000
    """(state, V^D) pairs simulated to pre-train the critic (Section 5.1: 100,000 trajectories;
    Section 5.3: 20,000 samples). Every state visited by A^D counts as one sample."""
    pretrain_trajectories: int = 0
    """If > 0: simulate this many A^D trajectories and keep ONE (s, V^D(s)) sample from each, a
    state drawn uniformly among the trajectory's visited states, labelled with the return from
    it to the end (Section 5.1: "100,000 trajectories are simulated to pre-train the critic";
    Section 4.1 simulates one trajectory per sample state). Replaces pretrain_samples, which
    keeps every visited state (correlated samples, far fewer trajectories)."""
    e_update: int = 500
    """E_Update of Alg. 2: refit the critic every this many episodes (Section 5.1: 500;
    Traffic Junction, Section 5.3: 100)."""
    buffer_size: int = 100_000
    """Capacity of the buffer B (FIFO; the paper does not bound it)."""
    critic_batch_size: int = 256
    """Minibatch of critic fits (not given in the paper)."""
    critic_pretrain_steps: int = 10_000
    """SGD steps of the critic's pre-training fit on B (not given in the paper)."""
    critic_update_steps: int = 1_000
    """SGD steps of each E_Update critic refit on B (not given in the paper)."""


@dataclass(frozen=True)
class BRDOptions(Options):
    """Alg. 1, best-response dynamics on the critic (Section 4.2)."""

    brd_iterations: int = 7
    """Iterations of Alg. 1 (Section 5.1: 7)."""
    brd_start: Literal["actor", "demonstrator"] = "actor"
    """Where Alg. 1 starts: the current actor's actions (Section 4.3, the default; see
    docs/methods.md) or the original demonstrator A^D."""
    engine: Literal["auto", "native", "jax"] = "auto"
    """The engine Alg. 1 simulates its candidate joint actions on (an implementation choice):
    'native' runs the whole of Alg. 1 for all games of an env step in one host call on the
    native engine (combat against a scripted enemy, with Eq. 2's one-step Q or a look-ahead
    continued by the demonstrator script; docs/engine-backends.md); 'jax' runs it under jit on
    the JAX engine; 'auto' takes native on a CPU where it applies, else jax. The same engine
    plays the critic's pre-training rollouts and the demonstrations of Phase 1 when A^D is a
    script. The simulated returns are identical; the critic's values differ by float rounding,
    which can flip a near-tie in Alg. 1."""
    brd_work_batch: int = 2
    """Alg. 1's simulation batch: each call simulates brd_work_batch x |A| candidate joint
    actions (an implementation choice; it does not change Ã). Each visit of Alg. 1 gathers the
    legal (game, action) pairs of the games that still need it and simulates only those; 0: all
    num_envs games x all |A| actions in every call (the dense schedule, which a GPU may
    prefer). On a CPU with the 'quick' preset's Q, 2 makes one call of Alg. 1 4-7x faster than
    16 games per call at m18v20, and about as fast at m5v5 ('python bench/brd_schedule.py
    --checkpoint ...')."""
    lookahead_steps: int = 1
    """Forward simulation per Q estimate in Alg. 1. 1: the paper's one-step simulation,
    Q = r + λ V(s') (Eq. 2, Section 4.2). K > 1 (an extension): the continuation policy (the
    one Alg. 1 starts from, see brd_start) plays K - 1 more steps before the critic
    bootstraps. 0: simulate to the end of the episode, i.e. the exact Q of the continuation
    policy (the paper's "ideal condition" of Eq. 6); the critic is then unused and not fitted."""
    lookahead_policy: Literal["start", "actor", "demonstrator"] = "start"
    """Who plays the K - 1 continuation steps of lookahead_steps (and the simulation to the end
    with lookahead_steps=0): 'start' (the default) the policy Alg. 1 starts from (brd_start),
    or explicitly the current 'actor' or the 'demonstrator' A^D. With the actor, its network
    runs on every simulated state, which is most of the cost of a lookahead step ('python
    bench/train_step.py --preset quick'); a script demonstrator costs a fraction of that."""


@dataclass(frozen=True)
class ActorOptions(Options):
    """The actor update of Alg. 2 (Eq. 8) and the run's policy."""

    # actor_lr_decay_from is a host-side schedule: the compiled step takes the scale as an argument.
    RUN_ONLY = frozenset({"actor_init", "actor_average_from", "actor_lr_decay_from"})

    actor_init: Literal["random", "clone"] = "random"
    """Initial actor parameters: 'random' (the paper states none), or 'clone': start the actor
    from the behavioural clone θ^D of the demonstrator (same architecture, Section 5.1), so
    that Alg. 2 starts at the demonstrator's level instead of a random policy's. For a script
    demonstrator this records demo_observations from the script and clones them (Phase 1);
    the script itself stays A^D."""
    actor_target: Literal["advantage", "best"] = "advantage"
    """The actor update. 'advantage': Eq. 8, sum_a grad log p(a|O) A(s, a) over the legal
    actions (the paper). Its fixed point is p(a) ∝ A(s, a), so under the legal-argmax
    execution of Section 5.1 close advantages make the executed action fragile. 'best': the
    cross-entropy toward ã_g(s) = argmax_a A(s, a), the action of Alg. 1's result Ã that Eq. 7
    defines (Section 4.2: "Ã ... can be used to guide the actor networks")."""
    actor_steps: int = 1
    """Actor gradient steps per environment step, on the same batch of Alg. 1 results (1: one
    update per step as in Alg. 2)."""
    actor_average_from: int | None = None
    """None: the run's policy is the last actor (Alg. 2). E (an extension, stochastic weight
    averaging after Izmailov et al. 2018): from training episode E on, also keep the uniform
    average of the actor's parameters and batch-norm statistics after every chunk, and make
    that the run's policy (the final and periodic evaluations, checkpoint 'best', 'hybridmarl
    eval'; the final evaluation also reports the last actor as 'last_actor'). Training still
    plays the live actor. Why: evaluated checkpoints of one m5v5 run 50 episodes apart swing
    between W 0.20 and 0.70, and the average of the second half's checkpoints is as good as the
    best of them (docs/results.md)."""
    actor_lr_decay_from: int | None = None
    """None: the actor's learning rate stays actor_lr (Alg. 2). E (an extension): from training
    episode E on, the actor's steps are scaled by a factor that falls linearly from 1 at episode
    E to 0 at total_episodes (set at each chunk from the episodes played so far), so that the
    live actor settles instead of swinging at the end of training. A resume that changes
    total_episodes changes the schedule from there. docs/results.md#a-decaying-actor-learning-rate."""


@dataclass(frozen=True)
class NetworkOptions(Options):
    """Networks and their optimisation (Section 5.1)."""

    optimizer: Literal["sgd", "adam"] = "sgd"
    """Optimiser of every network (Section 5.1: SGD)."""
    actor_lr: float = 1e-3
    """Actor learning rate η of Eq. 8 (Section 5.1: 10^-3)."""
    critic_lr: float = 1e-3
    """Critic learning rate (Section 5.1: 10^-3)."""
    actor_hidden: tuple[int, ...] = nets.ACTOR_HIDDEN
    """Actor FC widths before the |A| output (Section 5.1: 512, 256, 256)."""
    critic_hidden: tuple[int, ...] = nets.CRITIC_HIDDEN
    """Critic FC widths before the scalar output (Section 5.1: 256, 128, 128)."""


@dataclass(frozen=True)
class HybridConfig(TrainConfig):
    """The hybrid learning method (critic pre-training, best-response dynamics, actor update)."""

    budget: OmitArgPrefixes[BudgetOptions] = dataclasses.field(default_factory=BudgetOptions)
    clone: OmitArgPrefixes[CloneOptions] = dataclasses.field(default_factory=CloneOptions)
    critic: OmitArgPrefixes[CriticOptions] = dataclasses.field(default_factory=CriticOptions)
    brd: OmitArgPrefixes[BRDOptions] = dataclasses.field(default_factory=BRDOptions)
    actor: OmitArgPrefixes[ActorOptions] = dataclasses.field(default_factory=ActorOptions)
    networks: OmitArgPrefixes[NetworkOptions] = dataclasses.field(default_factory=NetworkOptions)


# -- presets -------------------------------------------------------------------------------------------


def _paper(env: str) -> HybridConfig:
    """'paper': the paper's method and settings. Combat (Section 5.1): A^D simulated for 100,000
    trajectories, one critic sample from each; Alg. 1 started from A^D (its input, Alg. 1 and
    Eq. 6) with 7 iterations and Eq. 2's one-step Q; E_Update 500; SGD at 10^-3 for every
    network; λ 0.995; 20,000 episodes in 32 games (the paper gives no budget). Traffic Junction
    (Section 5.3): the same with E_Update 100 and 20,000 samples, A^D = always-gas."""
    if env == "traffic_junction":
        # Section 5.3: "Most hyper-parameters are the same ... E_Update = 100, and 20,000 samples".
        return HybridConfig().replace(
            env=env,
            demonstrator="always-gas",
            e_update=100,
            pretrain_samples=20_000,
            buffer_size=20_000,
            brd_start="demonstrator",
        )
    return HybridConfig().replace(env=env, pretrain_trajectories=100_000, brd_start="demonstrator")


def _quick_paper(env: str) -> HybridConfig:
    """'quick-paper': 'paper' at a CPU budget, everything else as written: combat 20,000 A^D
    trajectories (one critic sample each), 3,000 episodes in 32 games, E_Update 500, SGD at
    10^-3; Traffic Junction 8,000 samples, 1,500 episodes in 16 games, E_Update 100. Where it
    stands against its demonstrator: docs/results.md."""
    base = _paper(env)
    if env == "traffic_junction":
        return base.replace(
            total_episodes=1_500,
            num_envs=16,
            pretrain_samples=8_000,
            buffer_size=8_000,
            critic_pretrain_steps=1_500,
            critic_update_steps=300,
            checkpoint_every=500,
        )
    return base.replace(
        total_episodes=3_000,
        num_envs=32,
        pretrain_trajectories=20_000,
        buffer_size=40_000,
        critic_pretrain_steps=2_000,
        critic_update_steps=500,
        checkpoint_every=500,
    )


def _cpu_base(env: str) -> HybridConfig:
    """The small CPU budget our extensions start from (not a preset): the paper's one-step
    method with 20,000 pre-training samples (every visited state of A^D's episodes), Alg. 1
    from the actor (Section 4.3), critic refits every 100 episodes and Adam."""
    base = HybridConfig().replace(env=env)
    if env == "traffic_junction":
        return base.replace(
            demonstrator="always-gas",
            total_episodes=1_500,
            num_envs=16,
            pretrain_samples=8_000,
            buffer_size=8_000,
            critic_pretrain_steps=1_500,
            critic_update_steps=300,
            e_update=100,
            optimizer="adam",
            checkpoint_every=500,
        )
    return base.replace(
        total_episodes=3_000,
        num_envs=32,
        pretrain_samples=20_000,
        buffer_size=40_000,
        critic_pretrain_steps=2_000,
        critic_update_steps=500,
        e_update=100,
        optimizer="adam",
        checkpoint_every=500,
    )


def _quick_rollout(env: str) -> HybridConfig:
    """'quick-rollout', an extension, not the paper's setting: Alg. 1's Q by simulating the
    demonstrator to the end of the episode (lookahead_steps=0: exact Q^D, the "ideal condition"
    of Eq. 6) instead of r + λ V(s'); one best-response iteration; no critic. Budget: 400
    episodes (combat) or 300 (Traffic Junction), 16 games; the rest as 'quick-paper'."""
    return _cpu_base(env).replace(
        lookahead_steps=0,
        brd_start="demonstrator",
        brd_iterations=1,
        total_episodes=400 if env == "combat" else 300,
        num_envs=16,
        checkpoint_every=100,
        pretrain_critic=False,
    )


def _quick(env: str) -> HybridConfig:
    """'quick', minutes on a CPU: the recipe of our best CPU runs (docs/results.md). Not the
    paper's setting: 'quick-paper' plus extensions. Alg. 1's Q simulates K steps before the
    critic bootstraps (lookahead_steps). Combat: K = 8, the 7 continuation steps played by the
    demonstrator script (lookahead_policy=demonstrator: an 8-step Q^D, several times cheaper
    per step than the actor's network), 128 games in parallel, the actor trained by
    cross-entropy toward Alg. 1's ã_g with 4 steps per env step (actor_target=best,
    actor_steps=4) for 3,000 episodes, and the run's policy is the actor's weight average from
    episode 1,500 on (actor_average_from=1500), evaluated every 150 episodes. m5v5, c vs w:
    W 0.88-0.93 of 100 battles over seven seeds against D's 0.44, in 10-23 CPU-min; m18v20
    needs --brd-start demonstrator (the actor start stalls into draws). Traffic Junction keeps
    K = 4, Eq. 8, the actor as continuation, 32 games and 1,500 episodes (failure 0.176
    against D's 0.959)."""
    base = _cpu_base(env).replace(lookahead_steps=4)
    if env == "traffic_junction":
        return base
    return base.replace(
        lookahead_steps=8,
        actor_target="best",
        actor_steps=4,
        lookahead_policy="demonstrator",
        num_envs=128,
        total_episodes=3000,
        actor_average_from=1500,
        eval_every=150,
    )


def _toy(env: str) -> HybridConfig:
    """'toy', seconds: a smoke test of the whole pipeline (tests, CI): 8 episodes, 4 games,
    tiny networks, no learning."""
    return _cpu_base(env).replace(
        total_episodes=8,
        num_envs=4,
        chunk_steps=4,
        pretrain_samples=64,
        buffer_size=512,
        critic_pretrain_steps=10,
        critic_update_steps=5,
        e_update=4,
        brd_iterations=2,
        actor_hidden=(16, 16, 16),
        critic_hidden=(16, 8, 8),
        checkpoint_every=4,
        eval_episodes=8,
        bc_steps=20,
        demo_observations=64,
        tensorboard=False,
    )


def _without_d(make):
    def preset(env: str) -> HybridConfig:
        # No demonstrator after Phase 1 either: Alg. 1 starts from, and its look-ahead is played by, the actor.
        return make(env).replace(pretrain_critic=False, brd_start="actor", lookahead_policy="start")

    preset.__doc__ = (
        f"Table 2's \"w/o D\" ablation of '{make.__doc__.split(chr(39))[1]}' (same budget): no critic "
        "pre-training, and Alg. 1 starts from, and its look-ahead is played by, the actor."
    )
    return preset


#: Preset name -> '(env) -> HybridConfig' ('--preset'); every preset works for both envs.
PRESETS = {
    "paper": _paper,
    "quick": _quick,
    "quick-paper": _quick_paper,
    "wo-d": _without_d(_paper),
    "quick-wo-d": _without_d(_quick),
    "quick-rollout": _quick_rollout,
    "toy": _toy,
}


__all__ = [
    "PRESETS",
    "ActorOptions",
    "BRDOptions",
    "BudgetOptions",
    "CloneOptions",
    "CriticOptions",
    "HybridConfig",
    "NetworkOptions",
]
