"""The method's pure numerics against hand-computed values: discounted returns (Eq. 1 / Alg. 2),
the advantage (Eq. 7), the actor loss (Eq. 8), the BC loss, legal masking, the evaluation
intervals and the Fig. 3 curve smoothing."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybridmarl.training.config import TrainingDiverged, check_finite
from hybridmarl.training.evaluate import t_interval, wilson_interval
from hybridmarl.training.losses import (
    actor_loss,
    advantages,
    bc_loss,
    critic_loss,
    discounted_returns,
    discounted_returns_jax,
)
from hybridmarl.training.networks import legal_argmax, masked_log_softmax
from hybridmarl.training.plots import forward_mean


def test_discounted_returns_by_hand():
    # V(s_t) = sum_i lambda^(i-t) r_i with lambda = 0.5: rewards 1, 0, 2, -1
    r = [1.0, 0.0, 2.0, -1.0]
    # t=3: -1; t=2: 2 + 0.5*-1 = 1.5; t=1: 0 + 0.5*1.5 = 0.75; t=0: 1 + 0.5*0.75 = 1.375
    np.testing.assert_allclose(discounted_returns(r, 0.5), [1.375, 0.75, 1.5, -1.0])
    # The paper's lambda = 0.995 on a sparse reward: only the last step pays 1.
    out = discounted_returns([0.0, 0.0, 1.0], 0.995)
    np.testing.assert_allclose(out, [0.995**2, 0.995, 1.0], rtol=1e-6)
    assert discounted_returns([], 0.9).shape == (0,)


def test_discounted_returns_jax_cuts_at_done():
    # Two episodes back to back in one block: [1, 2 | 3]
    r = jnp.asarray([1.0, 2.0, 3.0])
    d = jnp.asarray([False, True, True])
    np.testing.assert_allclose(discounted_returns_jax(r, d, 0.5), [2.0, 2.0, 3.0])


def test_advantage_eq7_by_hand():
    q = jnp.asarray([[0.3, -0.2, 0.5, 9.0], [1.0, 2.0, 3.0, 4.0]])
    legal = jnp.asarray([[True, True, True, False], [False, True, False, False]])
    adv = advantages(q, legal)
    # Row 0: min over legal {0.3, -0.2, 0.5} = -0.2 -> [0.5, 0, 0.7, 0 (illegal)]
    np.testing.assert_allclose(adv[0], [0.5, 0.0, 0.7, 0.0], atol=1e-6)
    # Row 1: one legal action -> advantage 0 (no preference to learn)
    np.testing.assert_allclose(adv[1], [0.0, 0.0, 0.0, 0.0])
    # No legal action at all: all zeros, no NaN/inf.
    assert np.all(np.asarray(advantages(q[:1], jnp.zeros((1, 4), bool))) == 0.0)


def test_actor_loss_eq8_by_hand():
    logits = jnp.asarray([[0.0, math.log(3.0), 5.0]])
    legal = jnp.asarray([[True, True, False]])
    adv = jnp.asarray([[0.5, 0.0, 7.0]])  # the illegal action's advantage must be ignored
    # Legal softmax over {0, log 3}: p = [1/4, 3/4]; loss = -(0.5 * log 1/4 + 0 * log 3/4)
    expected = -(0.5 * math.log(0.25))
    assert float(actor_loss(logits, adv, legal)) == pytest.approx(expected, rel=1e-6)
    # Gradient = -(sum_a A_a (onehot_a - p)) on the legal logits: A = [0.5, 0] -> [-(0.5 - 0.5*1/4), -(-0.5*3/4)]
    g = jax.grad(lambda z: actor_loss(z, adv, legal))(logits)
    np.testing.assert_allclose(g[0, :2], [-(0.5 - 0.5 * 0.25), 0.5 * 0.75], atol=1e-6)
    assert float(g[0, 2]) == 0.0  # masked action gets no gradient
    # Weights: a zero-weight row does not count, the mean is over weighted rows.
    two = jnp.concatenate([logits, logits])
    w = jnp.asarray([1.0, 0.0])
    assert float(
        actor_loss(two, jnp.concatenate([adv, 10 * adv]), jnp.concatenate([legal, legal]), w)
    ) == pytest.approx(expected, rel=1e-6)


def test_gradient_step_raises_best_action_probability():
    """Eq. 8 moves probability towards actions with larger advantage."""
    logits = jnp.zeros((1, 3))
    legal = jnp.ones((1, 3), bool)
    adv = advantages(jnp.asarray([[1.0, 3.0, 2.0]]), legal)  # [0, 2, 1]
    g = jax.grad(lambda z: actor_loss(z, adv, legal))(logits)
    new = logits - 0.1 * g
    p = jax.nn.softmax(new)[0]
    assert int(jnp.argmax(p)) == 1 and p[1] > 1 / 3


def test_bc_and_critic_losses_by_hand():
    logits = jnp.asarray([[0.0, 0.0, 100.0]])
    legal = jnp.asarray([[True, True, False]])
    assert float(bc_loss(logits, jnp.asarray([0]), legal)) == pytest.approx(math.log(2.0), rel=1e-6)
    assert float(critic_loss(jnp.asarray([1.0, 2.0]), jnp.asarray([0.0, 4.0]))) == pytest.approx(
        2.5
    )


def test_legal_masking():
    logits = jnp.asarray([[5.0, 1.0, 2.0], [0.0, 0.0, 0.0]])
    legal = jnp.asarray([[False, True, True], [False, False, True]])
    np.testing.assert_array_equal(legal_argmax(logits, legal), [2, 2])
    p = jnp.exp(masked_log_softmax(logits, legal))
    np.testing.assert_allclose(p.sum(-1), [1.0, 1.0], rtol=1e-6)
    assert float(p[0, 0]) == 0.0 and float(p[1, 2]) == pytest.approx(1.0)


def test_intervals_and_curve():
    lo, hi = wilson_interval(98, 100)
    assert lo == pytest.approx(0.9300, abs=1e-3) and hi == pytest.approx(0.9945, abs=1e-3)
    assert wilson_interval(0, 10)[0] == 0.0
    m, lo, hi = t_interval(np.asarray([1.0, 2.0, 3.0]))
    # mean 2, sd 1, t_{0.975, 2} = 4.302653 -> half width 4.302653 / sqrt(3)
    assert m == 2.0 and hi - m == pytest.approx(4.302653 / math.sqrt(3), rel=1e-5)
    np.testing.assert_allclose(forward_mean(np.arange(5.0), window=2), [0.5, 1.5, 2.5, 3.5])


def test_check_finite():
    check_finite("x", 1.0, "here")
    check_finite("tree", {"a": jnp.ones(3), "b": jnp.zeros((), jnp.int32)}, "here")
    with pytest.raises(TrainingDiverged, match="critic loss became NaN/inf at episode 7"):
        check_finite("critic loss", float("nan"), "episode 7")
    with pytest.raises(TrainingDiverged, match="actor parameters"):
        check_finite("actor parameters", {"w": jnp.asarray([1.0, jnp.inf])}, "episode 3")


@pytest.mark.parametrize("scale", [1.0, 0.5, 0.0])
def test_sgd_step_lr_scale_by_hand(scale):
    """lr_scale multiplies the step: SGD at 0.1 on L = |w|^2 / 2 (gradient w) moves w by
    -0.1 w scale; Adam's first step is -lr sign(g) (up to its epsilon), times scale."""
    import optax

    from hybridmarl.training.networks import NetState, sgd_step

    w = jnp.array([1.0, -2.0])

    def loss_fn(params, batch_stats):
        return 0.5 * jnp.sum(params["w"] ** 2), (batch_stats, None)

    for tx, want in (
        (optax.sgd(0.1), [1.0 - 0.1 * scale, -2.0 + 0.2 * scale]),
        (optax.adam(0.1), [1.0 - 0.1 * scale, -2.0 + 0.1 * scale]),
    ):
        net = NetState(
            params={"w": w},
            batch_stats={},
            opt_state=tx.init({"w": w}),
            step=jnp.zeros((), jnp.int32),
        )
        out, loss, _ = sgd_step(net, tx, loss_fn, jnp.float32(scale))
        np.testing.assert_allclose(np.asarray(out.params["w"]), want, rtol=1e-6)
        assert float(loss) == 2.5 and int(out.step) == 1
