"""The hybrid learning method (Peng, Xing & Cao, IJCAI 2020): the run, top to bottom.

    Phase 1  the demonstrator A^D (Section 3): a script, or the behavioural clone θ^D of a
             demonstration dataset;
    Phase 2  critic pre-training (Section 4.1, Eq. 3): play A^D from random start states to
             the end, label every visited state with its discounted return V^D(s) (Eq. 1,
             λ = 0.995), keep the (s, V^D(s)) pairs in the buffer B, fit V by MSE;
    Phase 3  the joint update (Alg. 2), B games in parallel; at every step s_t of every game:
               - Ã(s_t) by best-response dynamics (Alg. 1, 'brd') on the critic, started from
                 A^D(s_t) or from the actor's own actions (Section 4.3, below);
               - the advantage of every legal action of every agent (Eq. 7) and one SGD step
                 of the shared actor on Eq. 8;
               - every agent plays the legal argmax of the updated actor;
             finished episodes push (s_t, V(s_t)) into B and, every E_Update episodes, the critic
             is refitted on B (Eq. 3);
    Phase 4  evaluation (Section 5.1: 100 battles, legal argmax, W and R with 95% CIs) of the
             run's policy (the last actor, or its weight average) and, with --eval-every, of the
             best frozen policy of the periodic evaluations (chosen on other start states).

Where Alg. 1 starts (--brd-start). Section 4.3: "the actor networks can also be used to generate
action ... and these actions are considered as new demonstration actions", while the critic is
refitted on the actor's own returns. The default here is 'actor': Alg. 1 starts from the
current actor's legal argmax. That is the reading under which the improvement argument of Eq. 6
holds for the policy being learned (the critic estimates the actor's value once B holds its
returns, and Alg. 1 starts from that same policy), and it needs no demonstrator after Phase 2
(so "w/o D" and the full method share one code path). --brd-start demonstrator starts every
Alg. 1 call from the original A^D instead (Alg. 1's "Input: ... demonstration actions").

Extensions, all off by default (the 'paper' and 'quick-paper' presets are the paper's method;
the 'quick' preset turns on the ones of our best CPU recipe): lookahead_steps (K-step or exact
simulation instead of Eq. 2's one step), actor_init = clone (the actor starts from θ^D),
actor_target = best (cross-entropy toward Alg. 1's ã_g instead of Eq. 8), actor_average_from
(the run's policy is the actor's stochastic weight average). See docs/methods.md.

The options are in 'config', the compiled learner (Phase 3's whole per-step work as one
'lax.scan' of chunk_steps steps) in 'learner', the run skeleton in 'hybridmarl.training.run'.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.algos.hybrid.config import HybridConfig
from hybridmarl.algos.hybrid.learner import build_learner
from hybridmarl.training import networks as nets
from hybridmarl.training.checkpoint import AVERAGE_PREFIX, prefixed, subtree
from hybridmarl.training.config import check_finite, key_data
from hybridmarl.training.rollout import EpisodeAssembler, ReplayBuffer, new_pool
from hybridmarl.training.run import Run, RunState, TrainResult
from hybridmarl.training.task import flatten_named, unflatten_named

ALGO = "hybrid"


@dataclass(kw_only=True)
class HybridState(RunState):
    """Everything a checkpoint holds: the networks, the buffer B and the counters."""

    actor: nets.NetState
    critic: nets.NetState
    clone: nets.NetState | None
    buffer: ReplayBuffer
    iterations: int = 0
    critic_updates: int = 0
    next_critic_update: int = 0
    critic_loss: float = float("nan")
    average: Any = (
        None  # {"params", "batch_stats"}: the actor's running average (actor_average_from)
    )
    average_count: int = 0

    TREES: ClassVar[dict[str, str]] = {
        "actor": "actor",
        AVERAGE_PREFIX: "average",
        "critic": "critic",
        "clone": "clone",
    }
    BUFFERS: ClassVar[dict[str, str]] = {"buffer": "buffer"}
    COUNTERS: ClassVar[tuple[str, ...]] = (
        *RunState.COUNTERS,
        "iterations",
        "critic_updates",
        "next_critic_update",
        "critic_loss",
        "average_count",
    )

    def policy_vars(self) -> Any:
        """The run's policy: the actor's weight average once it has begun, else the actor."""
        return self.average if self.average_count > 0 else _vars(self.actor)

    def restore(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        super().restore(arrays, meta)
        if self.average_count > 0:
            self.average = unflatten_named(_vars(self.actor), subtree(arrays, AVERAGE_PREFIX))


def actor_lr_scale(cfg: HybridConfig, episodes: int) -> float | None:
    """The factor on the actor's learning rate for the chunk that starts after ``episodes``
    training episodes (``actor_lr_decay_from``): None without the schedule, else 1 until
    episode E, then linear to 0 at ``total_episodes``."""
    start = cfg.actor_lr_decay_from
    if start is None:
        return None
    if episodes <= start:
        return 1.0
    return max(0.0, 1.0 - (episodes - start) / max(cfg.total_episodes - start, 1))


@jax.jit
def _running_mean(avg: Any, new: Any, count: jax.Array) -> Any:
    return jax.tree.map(lambda a, x: a + (x - a) / count.astype(a.dtype), avg, new)


def _vars(net: nets.NetState | None) -> Any:
    return None if net is None else {"params": net.params, "batch_stats": net.batch_stats}


def one_state_per_episode(
    states: dict[str, np.ndarray], returns: np.ndarray, rng: np.random.Generator
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """From the rows of finished episodes ('EpisodeAssembler.add': grouped by 'episode_key'),
    one row per episode, drawn uniformly."""
    keys = np.asarray(states["episode_key"])
    if keys.size == 0:
        return states, returns
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    lengths = np.diff(np.r_[starts, keys.size])
    rows = starts + (rng.random(starts.size) * lengths).astype(np.int64)
    return {k: v[rows] for k, v in states.items()}, returns[rows]


def train(cfg: HybridConfig) -> TrainResult:
    """Train the hybrid method; prints progress and the result lines. Raises a 'UserError' for
    bad input and 'TrainingDiverged' when a loss or parameter becomes NaN/inf."""
    from hybridmarl.training import demos as D

    with Run(ALGO, cfg) as run:
        # ---- Phase 0: set-up ------------------------------------------------------------------------
        task, spec = run.task, run.spec
        dataset = (
            D.load_dataset(cfg.demonstrator, expect=task) if cfg.demonstrator_is_dataset() else None
        )
        demo_script = None if dataset is not None else cfg.demonstrator_name()
        learner = build_learner(task, cfg, demo_script)
        if learner.engine_note:
            print(learner.engine_note)
        k_actor, k_critic, k_clone, k_pool, k_run = jax.random.split(jax.random.key(cfg.seed), 5)
        actor = nets.init_net(learner.actor_mod, k_actor, task.obs_dim, learner.actor_tx)
        critic = nets.init_net(learner.critic_mod, k_critic, task.critic_dim, learner.critic_tx)
        needs_clone = demo_script is None or cfg.actor_init == "clone"
        clone = (
            nets.init_net(learner.actor_mod, k_clone, task.obs_dim, learner.actor_tx)
            if needs_clone
            else None
        )
        st = HybridState(
            actor=actor,
            critic=critic,
            clone=clone,
            pool=new_pool(task, k_pool, cfg.num_envs),
            key=key_data(k_run),
            buffer=ReplayBuffer(cfg.buffer_size, task.state_template()),
            assembler=EpisodeAssembler(cfg.num_envs, cfg.gamma),
            next_critic_update=cfg.e_update,
        )
        run.start(
            st,
            learner.actor_mod,
            st.policy_vars,
            lambda: prefixed(flatten_named(st.policy_vars()), "actor"),
            networks={
                "actor_params": nets.num_params(actor.params),
                "critic_params": nets.num_params(critic.params),
            },
        )

        if st.phase == "pretrain":
            # ---- Phase 1: the demonstrator A^D (Section 3) ------------------------------------------
            if needs_clone:
                if dataset is None:
                    dataset = D.collect(
                        spec,
                        cfg.demonstrator_name(),
                        cfg.demo_observations,
                        seed=cfg.seed,
                        gamma=cfg.gamma,
                        engine=cfg.engine,
                    )
                rows = D.bc_rows(dataset)
                assert st.clone is not None
                st.clone, losses = D.fit_bc(
                    st.clone,
                    learner.actor_mod,
                    (cfg.optimizer, cfg.actor_lr),
                    rows,
                    st.next_key(),
                    cfg.bc_steps,
                    cfg.bc_batch_size,
                )
                check_finite(
                    "behavioural-cloning loss",
                    float(losses[-1]) if losses.size else 0.0,
                    "the end of cloning",
                )
                acc = D.bc_accuracy(st.clone, learner.actor_mod, rows)
                role = "A^D" if demo_script is None else "θ^D (the actor's start)"
                print(
                    f"{role} = behavioural clone of {dataset.size} observations: final loss {losses[-1]:.4f}, accuracy {acc:.3f}"
                )
                if cfg.actor_init == "clone":
                    st.actor = st.actor.replace(
                        params=st.clone.params,
                        batch_stats=st.clone.batch_stats,
                        opt_state=learner.actor_tx.init(st.clone.params),
                    )
            # ---- Phase 2: critic pre-training (Section 4.1, Eq. 3) ------------------------------------
            per_trajectory = cfg.pretrain_trajectories > 0
            wanted = cfg.pretrain_trajectories if per_trajectory else cfg.pretrain_samples
            if cfg.pretrain_critic and wanted > 0 and cfg.lookahead_steps != 0:
                demo_pool = new_pool(task, st.next_key(), cfg.num_envs)
                asm = EpisodeAssembler(cfg.num_envs, cfg.gamma)
                got, stats_all = 0, {}
                pick = np.random.default_rng(np.asarray(jax.random.key_data(st.next_key())))
                t0 = time.time()
                while got < wanted:
                    demo_pool, out = learner.demo_chunk(demo_pool, _vars(st.clone))
                    states, returns, stats = asm.add(out)
                    if per_trajectory:
                        # One sample per trajectory (Section 5.1's "100,000 trajectories"): a
                        # uniformly drawn visited state and its return to the end.
                        states, returns = one_state_per_episode(states, returns, pick)
                    st.buffer.add(states, returns)
                    got += int(returns.size)
                    for k, v in stats.items():
                        stats_all.setdefault(k, []).extend(v.tolist())
                st.demo_stats = {k: float(np.mean(v)) for k, v in stats_all.items() if v}
                st.demo_stats["episodes"] = float(len(next(iter(stats_all.values()), [])))
                st.critic, closs = learner.fit_critic(
                    st.critic,
                    *st.buffer.device_arrays(),
                    st.next_key(),
                    jnp.asarray(cfg.critic_pretrain_steps),
                )
                st.critic_loss = float(closs)
                check_finite("critic pre-training loss", st.critic_loss, "pre-training")
                print(
                    f"critic pre-trained on {st.buffer.size} (s, V^D) pairs from {int(st.demo_stats['episodes'])} demonstrator episodes "
                    f"({time.time() - t0:.0f}s): MSE {st.critic_loss:.5f}; demonstrator: "
                    + ", ".join(f"{k} {v:.3f}" for k, v in st.demo_stats.items() if k != "episodes")
                )
            st.phase = "joint"
            run.save()

        # ---- Phase 3: the joint update (Alg. 2) -----------------------------------------------------
        t_phase, steps_at_start = time.time(), st.env_steps
        with run.loop():
            while run.running():
                # B games x chunk_steps steps of Alg. 1, Eq. 7, Eq. 8 and the env, compiled.
                scale = actor_lr_scale(cfg, st.episodes)
                st.pool, st.actor, out = learner.train_chunk(
                    st.pool,
                    st.actor,
                    _vars(st.critic),
                    _vars(st.clone),
                    None if scale is None else np.float32(scale),
                )
                states, returns, stats = st.assembler.add(out)
                st.buffer.add(states, returns)
                run.count(stats, cfg.chunk_steps * cfg.num_envs)
                st.iterations += 1
                aux = {k: float(np.nanmean(np.asarray(v))) for k, v in out["aux"].items()}
                check_finite("actor loss", aux["actor_loss"], f"episode {st.episodes}")
                check_finite("actor parameters", st.actor.params, f"episode {st.episodes}")
                # Every E_Update episodes: refit the critic on B (Eq. 3).
                if st.episodes >= st.next_critic_update and cfg.lookahead_steps != 0:
                    st.critic, closs = learner.fit_critic(
                        st.critic,
                        *st.buffer.device_arrays(),
                        st.next_key(),
                        jnp.asarray(cfg.critic_update_steps),
                    )
                    st.critic_loss = float(closs)
                    st.critic_updates += 1
                    st.next_critic_update = (st.episodes // cfg.e_update + 1) * cfg.e_update
                    check_finite("critic loss", st.critic_loss, f"episode {st.episodes}")
                    check_finite("critic parameters", st.critic.params, f"episode {st.episodes}")
                # Stochastic weight averaging (an extension, actor_average_from).
                if cfg.actor_average_from is not None and st.episodes >= cfg.actor_average_from:
                    st.average_count += 1
                    cur = _vars(st.actor)
                    st.average = (
                        cur
                        if st.average_count == 1
                        else _running_mean(
                            st.average, cur, jnp.asarray(st.average_count, jnp.float32)
                        )
                    )
                critic_status = (
                    "-" if np.isnan(st.critic_loss) else f"{st.critic_loss:.4f}"
                )  # '-': not fitted yet (w/o D)
                run.log_chunk(
                    {
                        "iteration": st.iterations,
                        **aux,
                        "critic_loss": st.critic_loss,
                        "critic_updates": st.critic_updates,
                        **({} if scale is None else {"actor_lr_scale": scale}),
                    },
                    f"critic {critic_status}",
                    per_second={"env_steps_per_s": cfg.chunk_steps * cfg.num_envs},
                )
        if run.time_limited:
            print(
                f"time limit of {cfg.time_limit_min:g} min reached after {st.episodes} episodes: stopping Alg. 2 there"
            )
        sps = (st.env_steps - steps_at_start) / max(time.time() - t_phase, 1e-9)

        # ---- Phase 4: evaluation (Section 5.1) --------------------------------------------------------
        last = (
            {"last_actor": run.evaluate(_vars(st.actor)), "average_of": st.average_count}
            if st.average_count > 0
            else {}
        )
        n_avg = st.average_count
        return run.finish(
            {"time_limited": run.time_limited, "env_steps_per_s": sps},
            before=last,
            baseline=st.demo_stats.get(task.progress_metrics[1]),
            note=f"  (the actor's weight average over {n_avg} chunks)" if n_avg else "",
            lines=lambda r: (
                [
                    "the last actor: "
                    + task.result_line({**r, **r["last_actor"]}).removeprefix("eval ")
                ]
                if n_avg
                else []
            ),
        )


__all__ = ["ALGO", "HybridState", "one_state_per_episode", "train"]
