"""OGTL, Opponent-Guided Tactic Learning (Hu et al., IJCAI 2018; the paper's baseline of Section
5.2; docs/baselines.md): imitate the scripted tactic, then improve it by reinforcement learning.

    Stage 1  tactic imitation: the shared Q network (the actor's architecture, |A| outputs) is
             fitted to the demonstrator's actions (the same sub-optimal demonstrator the other
             methods get, playing the role of OGTL's "human-made agent") by the large-margin
             supervised loss, with the 1-step TD term on the same data ('pretrain_td', default
             on) so that stage 2 starts from Q-values on the reward's scale, not only from an
             action ranking. Hu et al. leave the exact stage-1 objective open
             (docs/baselines.md); '--no-pretrain-td' gives the purely supervised variant.
    Stage 2  RL refinement of the imitated policy with the per-agent rewards (docs/baselines.md;
             Section 5.2: "the same to [Hu et al., 2018]"): double DQN with a target network
             seeded from stage 1 and uniform replay. Both stages learn on the same reward scale
             (rewards in units of a typical reward event, 'reward_unit'), and stage 2 leaves
             imitation gradually: the margin loss on the demonstrations, still in the buffer,
             decays linearly from λ2 = 1 to 'lambda_margin_final' = 0.1 over the first half of
             the episodes ('margin_decay_episodes') and stays there. With a final weight of 0
             the demonstrations leave the buffer after the decay and the rest is RL on the
             agents' own transitions only (Hu et al.'s sequential "imitate, then RL"); at m5v5
             that unlearns the imitated policy (docs/baselines.md#ogtl). ε-greedy
             exploration decays from 0.1 to 0.01 over the first quarter of the episodes (not
             given by Hu et al.). '--margin-decay-episodes 0 --lambda-margin-online 0
             --reward-unit 1' switches abruptly from imitation to RL on raw rewards.
    Stage 3  evaluation (legal argmax of Q; 'hybridmarl eval' loads it like an actor).

The machinery (buffer, losses, compiled updates, checkpoints, resume) is DQfD's ('algos.dqfd'); only
the switches differ.

Reward shaping (an option of OGTL's RL stage, docs/baselines.md: a bonus when the agent's action
agrees with the script's action in the same state, scaled by a weight that decays):
'--agreement-bonus W' adds 'w(e) * 1[a_i = script_i(s)]' to every stage-2 per-agent reward
of an agent that had a choice, with 'w(e) = W * max(0, 1 - e / agreement_decay_episodes)' at
episode 'e' (constant 'W' if the decay is 0). Off (0) in every preset; it needs a script
demonstrator (a dataset has no script to ask).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from tyro.conf import OmitArgPrefixes

from hybridmarl.algos import dqfd
from hybridmarl.training.config import Options
from hybridmarl.training.run import TrainResult

ALGO = "ogtl"


@dataclass(frozen=True)
class OGTLDemoOptions(dqfd.DemoOptions):
    """Stage 1: the demonstrations and the imitation of the tactic."""

    keep_demos: bool = False
    """Keep the demonstrations in the buffer for all of stage 2 (OGTL: no, Hu et al. 2018; they
    leave once the margin loss has decayed to 0)."""


@dataclass(frozen=True)
class OGTLLossOptions(dqfd.LossOptions):
    """The loss (stage 1: DQfD's terms on the demonstrations; stage 2: double DQN and the
    decaying margin loss)."""

    margin_decay_episodes: int = 10_000
    """Stage-2 episodes over which λ2 decays linearly from lambda_margin to lambda_margin_final
    (half of total_episodes in the presets)."""
    lambda_margin_final: float = 0.1
    """λ2 after the decay. 0: stage 2 ends with no demonstration loss (Hu et al. 2018) and the
    demonstrations leave the buffer, which unlearns the imitated policy at m5v5
    (docs/baselines.md#ogtl); 0.1 keeps a small margin loss on the demonstrations."""
    lambda_nstep: float = 0.0
    """λ1 of the n-step TD loss (OGTL's RL is plain DQN, Hu et al. 2018: 0)."""


@dataclass(frozen=True)
class OGTLReplayOptions(dqfd.ReplayOptions):
    """Replay (uniform), update schedule and target network."""

    per_alpha: float = 0.0
    """Replay prioritisation exponent (0: DQN's uniform replay, Hu et al. 2018)."""


@dataclass(frozen=True)
class OGTLExplorationOptions(dqfd.ExplorationOptions):
    """ε-greedy exploration in stage 2 (legal actions only)."""

    eps_start: float = 0.1
    """ε-greedy at the start of stage 2 (not given by Hu et al.)."""
    eps_end: float = 0.01
    """ε-greedy after the decay (not given by Hu et al.)."""
    eps_decay_episodes: int = 5_000
    """Episodes of linear ε decay (a quarter of total_episodes; not given by Hu et al.)."""


@dataclass(frozen=True)
class ShapingOptions(Options):
    """The optional agreement bonus of stage 2 (module docstring)."""

    agreement_bonus: float = 0.0
    """W: stage-2 reward bonus for playing the script's action (optional; 0 = off). In units of
    the per-agent reward, where one Marine shot at m5v5 is 0.03."""
    agreement_decay_episodes: int = 0
    """Stage-2 episodes over which the bonus decays linearly to 0 (0: it stays W)."""


@dataclass(frozen=True)
class OGTLConfig(dqfd.DQfDConfig):
    """OGTL: imitation of the demonstrator, then DQN on per-agent rewards with a decaying
    margin loss on the demonstrations."""

    demos: OmitArgPrefixes[OGTLDemoOptions] = dataclasses.field(default_factory=OGTLDemoOptions)
    loss: OmitArgPrefixes[OGTLLossOptions] = dataclasses.field(default_factory=OGTLLossOptions)
    replay: OmitArgPrefixes[OGTLReplayOptions] = dataclasses.field(
        default_factory=OGTLReplayOptions
    )
    exploration: OmitArgPrefixes[OGTLExplorationOptions] = dataclasses.field(
        default_factory=OGTLExplorationOptions
    )
    shaping: OmitArgPrefixes[ShapingOptions] = dataclasses.field(default_factory=ShapingOptions)


#: OGTL's switches on DQfD's machinery: their values come from OGTLConfig, not from DQfD's presets.
SWITCHES = (
    "keep_demos",
    "lambda_margin_online",
    "margin_decay_episodes",
    "lambda_margin_final",
    "lambda_nstep",
    "per_alpha",
    "eps_start",
    "eps_end",
)


def agreement_schedule(cfg: OGTLConfig):
    """'episodes -> bonus weight' for 'dqfd.train', or None when the bonus is off."""
    if cfg.agreement_bonus <= 0:
        return None
    w0, decay = float(cfg.agreement_bonus), int(cfg.agreement_decay_episodes)

    def weight(episodes: int) -> float:
        return w0 if decay <= 0 else w0 * max(0.0, 1.0 - episodes / decay)

    return weight


def _from(make):
    def preset(env: str) -> OGTLConfig:
        # DQfD's preset (and budget) with OGTL's switches; ε decays over the first quarter of the
        # budget, the margin loss over the first half.
        base = make(env)
        kw = {n: getattr(base, n) for n in dqfd.DQfDConfig.field_names() if n not in SWITCHES}
        kw["eps_decay_episodes"] = max(1, base.total_episodes // 4)
        kw["margin_decay_episodes"] = max(1, base.total_episodes // 2)
        return OGTLConfig().replace(**kw)

    preset.__doc__ = (
        f"{make.__doc__} With OGTL's switches: uniform replay, 1-step TD, the margin loss's weight "
        "decaying from 1 to 0.1 over the first half of the episodes."
    )
    return preset


#: Preset name -> '(env) -> OGTLConfig' ('--preset'): DQfD's, with OGTL's switches.
PRESETS = {name: _from(make) for name, make in dqfd.PRESETS.items()}


#: The config class of '--algo ogtl'.
CONFIG = OGTLConfig


def train(cfg: OGTLConfig) -> TrainResult:
    """The OGTL run ('dqfd.train' with OGTL's switches and its optional agreement bonus)."""
    return dqfd.train(cfg, algo=ALGO, shaping=agreement_schedule(cfg))


__all__ = ["ALGO", "CONFIG", "PRESETS", "OGTLConfig", "agreement_schedule", "train"]
