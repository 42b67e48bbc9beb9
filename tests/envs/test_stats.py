"""Interval and paired-test helpers against hand-computed values."""

import math

import numpy as np
import pytest

from hybridmarl.envs.stats import mcnemar_exact, paired_wins, wilson_interval


def test_mcnemar_exact_by_hand():
    # m = 4 discordant pairs split 1/3: P(X <= 1) = (1 + 4) / 16, two-sided 10 / 16.
    assert mcnemar_exact(1, 3) == pytest.approx(10 / 16)
    assert mcnemar_exact(3, 1) == pytest.approx(10 / 16)
    # 0/5: 2 * 1/32.
    assert mcnemar_exact(0, 5) == pytest.approx(2 / 32)
    # An even split is capped at 1; no discordant pair is no evidence.
    assert mcnemar_exact(2, 2) == 1.0
    assert mcnemar_exact(0, 0) == 1.0
    with pytest.raises(ValueError):
        mcnemar_exact(-1, 2)


def test_paired_wins_by_hand():
    a = np.array([1, 1, 0, 1, 0, 1], bool)
    b = np.array([1, 0, 0, 0, 1, 1], bool)
    out = paired_wins(a, b)
    # per-state differences 0, 1, 0, 1, -1, 0: mean 1/6.
    diff = np.array([0, 1, 0, 1, -1, 0], float)
    sd = math.sqrt(((diff - diff.mean()) ** 2).sum() / 5)
    assert (
        out["n"] == 6 and out["W_a"] == pytest.approx(4 / 6) and out["W_b"] == pytest.approx(3 / 6)
    )
    assert out["dW"] == pytest.approx(1 / 6)
    assert out["dW_high"] - out["dW"] == pytest.approx(1.959963984540054 * sd / math.sqrt(6))
    assert (out["only_a"], out["only_b"]) == (2, 1)
    assert out["p_mcnemar"] == pytest.approx(1.0)  # 2/1 of 3: 2 * (1 + 3) / 8 capped at 1
    with pytest.raises(ValueError):
        paired_wins(a, b[:3])


def test_wilson_interval_by_hand():
    # p = 0.41, z^2 = 3.8415: centre (0.41 + 0.019207) / 1.038415 = 0.41333,
    # half 1.96 * sqrt(0.002419 + 0.000096) / 1.038415 = 0.09466.
    lo, hi = wilson_interval(41, 100)
    assert (lo, hi) == pytest.approx((0.31867, 0.50799), abs=1e-4)
