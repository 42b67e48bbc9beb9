"""The method's pure numerical pieces: returns (Eq. 1), critic loss (Eq. 3), advantage (Eq. 7),
actor loss (Eq. 8) and the behavioural-cloning loss (Section 3); and the DQfD / OGTL baselines'
Q-learning pieces (Hester et al., AAAI 2018; docs/baselines.md): legal max, the double-Q bootstrap, the TD
error's Huber loss, the large-margin supervised loss, the L2 penalty and the n-step returns.

All functions are pure and jittable and take plain arrays, so the tests can feed them
hand-computed numbers.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.training.networks import masked_log_softmax


def discounted_returns(rewards: np.ndarray | jax.Array, gamma: float) -> np.ndarray:
    """``V(s_t) = sum_{i >= t} gamma^(i-t) r_i`` for one finished episode (Eq. 1 and the
    ``V(s_t)`` line of Alg. 2). ``rewards[t]`` is the reward of the step taken in ``s_t``.

    Host-side (numpy, float64 accumulation, float32 out): episodes are assembled on the host.
    """
    r = np.asarray(rewards, dtype=np.float64)
    out = np.empty_like(r)
    acc = 0.0
    for t in range(r.shape[0] - 1, -1, -1):
        acc = r[t] + gamma * acc
        out[t] = acc
    return out.astype(np.float32)


def discounted_returns_jax(rewards: jax.Array, dones: jax.Array, gamma: float) -> jax.Array:
    """Jittable version over a time-major ``[T, ...]`` block; ``dones[t]`` cuts the sum after
    step ``t`` (the episode ended there). Values after the last ``done`` are partial sums."""

    def body(acc, x):
        r, d = x
        acc = r + gamma * acc * (1.0 - d.astype(jnp.float32))
        return acc, acc

    _, out = jax.lax.scan(body, jnp.zeros_like(rewards[0]), (rewards, dones), reverse=True)
    return out


def critic_loss(values: jax.Array, targets: jax.Array) -> jax.Array:
    """Eq. 3: mean squared error between ``V(s, θ)`` and the simulated return."""
    return jnp.mean((values - targets) ** 2)


def advantages(q: jax.Array, legal: jax.Array) -> jax.Array:
    """Eq. 7: ``A^g(s, a) = Q(s, a, Ã_-g) - min_{a' legal} Q(s, a', Ã_-g)``; 0 on illegal actions.

    ``q``: ``[..., A]`` Q values of each action of one agent with the others fixed at Ã;
    ``legal``: ``[..., A]`` bool. An agent with no legal action gets all zeros.
    """
    qmin = jnp.min(jnp.where(legal, q, jnp.inf), axis=-1, keepdims=True)
    adv = jnp.where(legal, q - qmin, 0.0)
    return jnp.where(jnp.isfinite(adv), adv, 0.0)


def actor_loss(
    logits: jax.Array, adv: jax.Array, legal: jax.Array, weight: jax.Array | None = None
) -> jax.Array:
    """Eq. 8 as a loss to minimise: ``-sum_a log p(a|O) A(s, a)`` over the legal actions, averaged
    over the weighted samples (``weight`` [...]: 1 for an agent that has a choice, else 0).

    ``p`` is the softmax over the legal actions (illegal ones are masked out). The advantage is a
    constant (no gradient flows into the critic or the simulator).
    """
    logp = masked_log_softmax(logits, legal)
    adv = jax.lax.stop_gradient(adv)
    per_sample = -jnp.sum(jnp.where(legal, logp * adv, 0.0), axis=-1)
    if weight is None:
        return jnp.mean(per_sample)
    w = weight.astype(jnp.float32)
    return jnp.sum(per_sample * w) / jnp.maximum(jnp.sum(w), 1.0)


def bc_loss(
    logits: jax.Array, actions: jax.Array, legal: jax.Array, weight: jax.Array | None = None
) -> jax.Array:
    """Behavioural cloning (Section 3, ``θ^D``): cross-entropy of the demonstrated action under
    the legal softmax (0 when the clone puts all its mass on it, positive otherwise)."""
    logp = masked_log_softmax(logits, legal)
    nll = -jnp.take_along_axis(logp, actions[..., None].astype(jnp.int32), axis=-1)[..., 0]
    if weight is None:
        return jnp.mean(nll)
    w = weight.astype(jnp.float32)
    return jnp.sum(nll * w) / jnp.maximum(jnp.sum(w), 1.0)


# -- DQfD / OGTL (Hester et al., AAAI 2018; docs/baselines.md) -------------------------------------------------------


def legal_max(q: jax.Array, legal: jax.Array) -> jax.Array:
    """``max_{a legal} q[..., a]`` (0 where no action is legal)."""
    m = jnp.max(jnp.where(legal, q, -jnp.inf), axis=-1)
    return jnp.where(jnp.any(legal, axis=-1), m, 0.0)


def double_q_bootstrap(
    q_online_next: jax.Array, q_target_next: jax.Array, legal_next: jax.Array
) -> jax.Array:
    """Double DQN: ``Q_target(s', argmax_{a legal} Q_online(s', a))`` (0 where nothing is legal)."""
    a = jnp.argmax(jnp.where(legal_next, q_online_next, -jnp.inf), axis=-1)
    v = jnp.take_along_axis(q_target_next, a[..., None], axis=-1)[..., 0]
    return jnp.where(jnp.any(legal_next, axis=-1), v, 0.0)


def huber(x: jax.Array, delta: float = 1.0) -> jax.Array:
    """Huber loss of a TD error (DQN's error clipping; quadratic within ``delta``)."""
    a = jnp.abs(x)
    return jnp.where(a <= delta, 0.5 * x * x, delta * (a - 0.5 * delta))


def large_margin_loss(
    q: jax.Array, expert: jax.Array, legal: jax.Array, margin: float | jax.Array = 0.8
) -> jax.Array:
    """DQfD's J_E per sample: ``max_{a legal} [Q(s, a) + l(a_E, a)] - Q(s, a_E)``, ``l`` = ``margin``
    for ``a != a_E`` and 0 for ``a_E`` (>= 0; 0 iff ``a_E`` beats every other legal action by
    the margin)."""
    onehot = jax.nn.one_hot(expert, q.shape[-1], dtype=bool)
    aug = jnp.where(onehot, q, q + margin)
    best = jnp.max(jnp.where(legal | onehot, aug, -jnp.inf), axis=-1)
    q_e = jnp.take_along_axis(q, expert[..., None].astype(jnp.int32), axis=-1)[..., 0]
    return best - q_e


def l2_penalty(params) -> jax.Array:
    """``sum w^2`` over every parameter array (J_L2)."""
    return sum(
        (jnp.sum(jnp.square(x)) for x in jax.tree.leaves(params)), jnp.zeros((), jnp.float32)
    )


def nstep_returns(
    rewards: np.ndarray, ends: np.ndarray, segment: np.ndarray, gamma: float, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-agent n-step returns over consecutive rows (host, numpy).

    ``rewards``/``ends``: ``[M, N]`` (``ends[t, i]``: agent i's episode ends with step t);
    ``segment`` ``[M]``: rows of one episode are consecutive and share an id (a segment may be
    cut short, as a dataset's last episode: its rows then bootstrap from the last row's next
    state). Returns ``(ret [M, N], disc [M, N], last [M, N])``:
    ``ret = sum_{k<K} gamma^k r_{t+k}`` over the ``K <= n`` steps up to the end of the agent's
    episode or the segment, ``last = t + K - 1`` (the row whose *next* state bootstraps) and
    ``disc = gamma^K`` if the agent's episode goes on after row ``last``, else 0. The n-step
    target is ``ret + disc * V(next state of row last)``.
    """
    r = np.asarray(rewards, np.float64)
    e = np.asarray(ends, bool)
    m = r.shape[0]
    t = np.arange(m)
    ret = np.zeros(r.shape, np.float64)
    last = np.repeat(t[:, None], r.shape[1], axis=1)
    count = np.zeros(r.shape, np.int64)
    going = np.ones(r.shape, bool)
    for k in range(n):
        j = t + k
        inside = (j < m) & (segment[np.minimum(j, m - 1)] == segment)
        take = going & inside[:, None]
        jj = np.minimum(j, m - 1)
        ret += np.where(take, gamma**k * r[jj], 0.0)
        last = np.where(take, jj[:, None], last)
        count += take
        going = take & ~e[jj]
    ended = np.take_along_axis(e, last, axis=0)
    disc = np.where(ended, 0.0, float(gamma) ** count)
    return ret.astype(np.float32), disc.astype(np.float32), last


# -- the baselines' scale and schedules (docs/baselines.md#scale) ------------------------------------------


def reward_unit(rewards: np.ndarray, valid: np.ndarray) -> float:
    """The typical size of one reward event: the median of ``|r|`` over the non-zero rewards of
    agents in play (``valid``), or 1.0 when there is none. DQfD's Atari settings (margin 0.8,
    Huber threshold 1, λ's) assume rewards whose events are of order 1 (clipped or log-scaled
    scores); dividing the rewards by this unit puts any task on that scale."""
    r = np.abs(np.asarray(rewards, np.float64)[np.asarray(valid, bool)])
    r = r[r > 0]
    return float(np.median(r)) if r.size else 1.0


def linear_decay(weight: float, episodes: float, decay_episodes: int) -> float:
    """``weight · max(0, 1 - episodes / decay_episodes)``; ``weight`` throughout if
    ``decay_episodes <= 0``."""
    if decay_episodes <= 0:
        return float(weight)
    return float(weight) * max(0.0, 1.0 - float(episodes) / float(decay_episodes))


def greedy_agreement(
    q: jax.Array, legal: jax.Array, expert: jax.Array, choice: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """How often the legal greedy action equals the demonstrator's: ``(matches, count)`` over
    the samples where ``choice`` (an agent in play with at least two legal actions). Ties
    break toward the lowest action index, as ``argmax`` does when the policy plays."""
    greedy = jnp.argmax(jnp.where(legal, q, -jnp.inf), axis=-1)
    c = choice.astype(jnp.float32)
    return jnp.sum((greedy == expert).astype(jnp.float32) * c), jnp.sum(c)
