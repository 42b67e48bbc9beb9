"""Confidence intervals of evaluation summaries (shared by every environment's ``summarize``)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["Z95", "mcnemar_exact", "paired_wins", "t_interval", "wilson_interval"]

Z95 = 1.959963984540054


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """95% Wilson score interval of a binomial proportion."""
    if n <= 0:
        return (float("nan"), float("nan"))
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def t_interval(x: np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    """(mean, low, high): Student-t interval of the mean."""
    x = np.asarray(x, np.float64)
    n = x.size
    if n == 0:
        return (float("nan"), float("nan"), float("nan"))
    m = float(x.mean())
    if n == 1:
        return (m, float("nan"), float("nan"))
    from scipy.stats import t as student_t

    half = float(student_t.ppf(0.5 + level / 2, n - 1) * x.std(ddof=1) / math.sqrt(n))
    return (m, m - half, m + half)


def mcnemar_exact(only_a: int, only_b: int) -> float:
    """Two-sided exact McNemar p of paired binary outcomes: under no difference the discordant
    pairs (``only_a`` where only A succeeds, ``only_b`` where only B does) are Binomial(m, 1/2)."""
    if only_a < 0 or only_b < 0:
        raise ValueError("discordant counts must be non-negative")
    k, m = min(only_a, only_b), only_a + only_b
    if m == 0:
        return 1.0
    return min(1.0, 2 * sum(math.comb(m, i) for i in range(k + 1)) / 2**m)


def paired_wins(a_won: np.ndarray, b_won: np.ndarray, z: float = Z95) -> dict[str, float | int]:
    """Paired comparison of two policies' wins on the same start states: each one's W, the mean
    difference ``dW`` = W(a) - W(b) with a normal-approximation interval over the per-state
    differences, the discordant counts and McNemar's exact p."""
    a, b = np.asarray(a_won, bool), np.asarray(b_won, bool)
    if a.shape != b.shape or a.ndim != 1 or a.size == 0:
        raise ValueError(
            f"need two equal, non-empty vectors of outcomes, got shapes {a.shape} and {b.shape}"
        )
    n = a.size
    diff = a.astype(np.float64) - b.astype(np.float64)
    half = z * float(diff.std(ddof=1)) / math.sqrt(n) if n > 1 else float("nan")
    d = float(diff.mean())
    only_a, only_b = int((a & ~b).sum()), int((b & ~a).sum())
    return {
        "n": n,
        "W_a": float(a.mean()),
        "W_b": float(b.mean()),
        "dW": d,
        "dW_low": d - half,
        "dW_high": d + half,
        "only_a": only_a,
        "only_b": only_b,
        "p_mcnemar": mcnemar_exact(only_a, only_b),
    }
