"""The training curve in the style of the paper's Fig. 3: the terminal hit-points reward of the
training episodes, each point the mean of the *following* 100 episodes."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def forward_mean(values: np.ndarray, window: int = 100) -> np.ndarray:
    """``out[e] = mean(values[e : e + window])`` for every ``e`` with a full window (Fig. 3:
    "the mean value of the following 100 episodes"); shorter series use the whole remainder."""
    v = np.asarray(values, np.float64)
    if v.size == 0:
        return v
    w = min(window, v.size)
    c = np.concatenate([[0.0], np.cumsum(v)])
    return (c[w:] - c[:-w]) / w


def training_curve(
    values: list[float] | np.ndarray,
    path: str | Path,
    *,
    metric: str = "terminal_hp_reward",
    title: str = "",
    baseline: float | None = None,
    window: int = 100,
) -> Path | None:
    """Write the PNG; ``baseline``: the demonstrator's mean (a dashed line). None if no data."""
    v = np.asarray(values, np.float64)
    if v.size == 0:
        return None
    try:
        import matplotlib
    except ImportError:
        # An optional extra: the curve's data is in episodes.csv either way.
        print(
            f"no {Path(path).name}: matplotlib is not installed (pip install 'hybridmarl[plots]')"
        )
        return None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    y = forward_mean(v, window)
    x = np.arange(1, y.size + 1)
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    label = {"terminal_hp_reward": "terminal HP reward", "return": "episode return"}.get(
        metric, metric
    )
    ax.plot(
        x,
        y,
        color="tab:red",
        lw=1.5,
        label=f"ours (mean of the following {min(window, v.size)} episodes)",
    )
    if baseline is not None and np.isfinite(baseline):
        ax.axhline(baseline, color="tab:gray", ls="--", lw=1, label="demonstrator")
    ax.set_xlabel("training episodes")
    ax.set_ylabel(label)
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp)
    plt.close(fig)
    tmp.replace(path)
    return path
