"""The paper's actor and critic networks (Section 5.1) and the small amount of state they carry.

- **Actor** (``θ^π``, also the behavioural clone ``θ^D`` of Section 3): FC 512-256-256-|A|, a
  batch-norm layer after each of the first three FC layers, softmax output. One actor is shared
  by all homogeneous agents (Section 5.1, after Gupta et al. 2017).
- **Critic** (``θ^V``): FC 256-128-128-1 with the same batch-norm layers.

The paper does not name the hidden non-linearity; we use ReLU after each batch norm (FC → BN →
ReLU), the usual arrangement.

Batch norm, train vs eval (Flax linen ``BatchNorm``):

- *train mode* (``train=True``): normalise with the statistics of the current minibatch and
  update the running averages (``batch_stats`` collection, ``mutable``). Only valid rows count:
  a ``mask`` ([batch] bool) leaves padding rows (empty agent slots, agents with a single legal
  action) out of the statistics, so they cannot skew them.
- *eval mode* (``train=False``): normalise with the running averages; the output for one input
  does not depend on the rest of the batch. Acting, best-response dynamics (Alg. 1) and
  evaluation always use eval mode.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.typing import ArrayLike

ACTOR_HIDDEN = (512, 256, 256)  # paper Section 5.1
CRITIC_HIDDEN = (256, 128, 128)  # paper Section 5.1
BN_MOMENTUM = 0.99  # Flax default; the paper does not give one
NEG_INF = -1e9  # finite "minus infinity" for masked logits (keeps gradients NaN-free)


class MLP(nn.Module):
    """FC layers with batch norm + ReLU after every hidden FC layer, then a linear output."""

    hidden: Sequence[int]
    out: int

    @nn.compact
    def __call__(
        self, x: jax.Array, train: bool = False, mask: jax.Array | None = None
    ) -> jax.Array:
        x = x.reshape((x.shape[0], -1)).astype(jnp.float32)
        bn_mask = None if mask is None else mask[:, None]
        for width in self.hidden:
            x = nn.Dense(width)(x)
            x = nn.BatchNorm(use_running_average=not train, momentum=BN_MOMENTUM)(x, mask=bn_mask)
            x = nn.relu(x)
        return nn.Dense(self.out)(x)


def actor_module(num_actions: int, hidden: Sequence[int] = ACTOR_HIDDEN) -> MLP:
    """Logits of the actor; the softmax (Section 5.1) is applied over the legal actions."""
    return MLP(hidden=tuple(hidden), out=num_actions)


def critic_module(hidden: Sequence[int] = CRITIC_HIDDEN) -> MLP:
    return MLP(hidden=tuple(hidden), out=1)


class NetState(struct.PyTreeNode):
    """Parameters, batch-norm running statistics and optimizer state of one network."""

    params: Any
    batch_stats: Any
    opt_state: Any
    step: jax.Array  # int32 [] optimizer steps taken


def make_optimizer(name: str, lr: float) -> optax.GradientTransformation:
    """Plain ``sgd`` (the paper's choice, Section 5.1, lr 1e-3) or ``adam``."""
    if name == "sgd":
        return optax.sgd(lr)
    if name == "adam":
        return optax.adam(lr)
    raise ValueError(f"unknown optimizer {name!r} (known: sgd, adam)")


def init_net(
    module: MLP, key: jax.Array, in_dim: int, tx: optax.GradientTransformation
) -> NetState:
    variables = init_variables(module, key, in_dim)
    params = variables["params"]
    return NetState(
        params=params,
        batch_stats=variables["batch_stats"],
        opt_state=tx.init(params),
        step=jnp.zeros((), jnp.int32),
    )


def sgd_step(
    net: NetState,
    tx: optax.GradientTransformation,
    loss_fn: Callable[[Any, Any], tuple[jax.Array, tuple[Any, Any]]],
    lr_scale: ArrayLike | None = None,
) -> tuple[NetState, jax.Array, Any]:
    """One optimiser step of ``net``: ``loss_fn(params, batch_stats) -> (loss, (new_batch_stats,
    extra))``; returns ``(net', loss, extra)`` (the one place every learner updates a network).
    ``lr_scale`` multiplies the step: for SGD and Adam that is the learning rate times
    ``lr_scale``, with the optimiser's state unchanged in shape (a schedule set from the host)."""
    (loss, (bs, extra)), grads = jax.value_and_grad(loss_fn, has_aux=True)(
        net.params, net.batch_stats
    )
    updates, opt = tx.update(grads, net.opt_state, net.params)
    if lr_scale is not None:
        updates = jax.tree.map(lambda u: u * lr_scale, updates)
    net = net.replace(
        params=optax.apply_updates(net.params, updates),
        batch_stats=bs,
        opt_state=opt,
        step=net.step + 1,
    )
    return net, loss, extra


def init_variables(module: MLP, key: jax.Array, in_dim: int) -> dict:
    """``module.init`` as one compiled call (eager initialisation is slow)."""
    return _init_fn(module_spec(module), in_dim)(key)


@functools.lru_cache(maxsize=32)
def _init_fn(spec: tuple[tuple[int, ...], int], in_dim: int):
    module = from_spec(spec)
    return jax.jit(lambda key: module.init(key, jnp.zeros((2, in_dim), jnp.float32), train=False))


def apply_eval(module: MLP, net: NetState | dict, x: jax.Array) -> jax.Array:
    """Eval mode (running batch-norm statistics); ``net`` is a NetState or a variables dict."""
    if isinstance(net, NetState):
        variables = {"params": net.params, "batch_stats": net.batch_stats}
    else:
        variables = net
    return cast(jax.Array, module.apply(variables, x, train=False))


def apply_train(
    module: MLP, params: Any, batch_stats: Any, x: jax.Array, mask: jax.Array | None = None
) -> tuple[jax.Array, Any]:
    """Train mode: minibatch statistics over the rows in ``mask``; returns (out, new batch_stats)."""
    out, updates = module.apply(
        {"params": params, "batch_stats": batch_stats},
        x,
        train=True,
        mask=mask,
        mutable=["batch_stats"],
    )
    return out, updates["batch_stats"]


def masked_log_softmax(logits: jax.Array, legal: jax.Array) -> jax.Array:
    """log p(a|O) over the legal actions only (illegal actions get probability 0)."""
    z = jnp.where(legal, logits, NEG_INF)
    return jax.nn.log_softmax(z, axis=-1)


def legal_argmax(logits: jax.Array, legal: jax.Array) -> jax.Array:
    """The legal action with the largest probability (paper Section 5.1, "In test, ...")."""
    return jnp.argmax(jnp.where(legal, logits, -jnp.inf), axis=-1).astype(jnp.int32)


def actor_actions(module: MLP, net: NetState | dict, obs: jax.Array, legal: jax.Array) -> jax.Array:
    """Legal argmax actions ``[..., N]`` for observations ``[..., N, obs]`` (eval mode)."""
    lead = obs.shape[:-1]
    logits = apply_eval(module, net, obs.reshape((-1, obs.shape[-1])))
    return legal_argmax(logits.reshape(lead + (-1,)), legal)


def module_spec(module: MLP) -> tuple[tuple[int, ...], int]:
    """A hashable description of an MLP (cache key): (hidden widths, outputs)."""
    return (tuple(module.hidden), int(module.out))


def from_spec(spec: tuple[tuple[int, ...], int]) -> MLP:
    return MLP(hidden=spec[0], out=spec[1])


def num_params(tree: Any) -> int:
    return int(sum(x.size for x in jax.tree.leaves(tree)))
