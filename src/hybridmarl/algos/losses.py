"""The method's pure numerical pieces: returns (Eq. 1), critic loss (Eq. 3), advantage (Eq. 7),
actor loss (Eq. 8) and the behavioural-cloning loss (Section 3).

All functions are pure and jittable and take plain arrays, so the tests can feed them
hand-computed numbers.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from hybridmarl.algos.networks import masked_log_softmax


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
