"""Standard figures of navigation papers, written as PNG with matplotlib's Agg backend."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def save(fig, path: Path) -> Path:
    """Lay out, write as PNG (110 dpi, parent folders created) and close a figure."""
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def error_envelope(t: np.ndarray, err: np.ndarray, sigma: np.ndarray | None, path: Path, *,
                   title: str, ylabel: str, labels=("x", "y", "z"), nsigma: float = 3.0) -> Path:
    """Error per axis against time with the filter's +/- nsigma envelope, one panel per axis.

    t: (K,) s; err: (K, d) estimate minus truth; sigma: (K, d) filter standard deviations or None.
    """
    d = err.shape[1]
    fig, axes = plt.subplots(d, 1, figsize=(7.5, 1.9 * d + 0.6), sharex=True)
    axes = np.atleast_1d(axes)
    for i, ax in enumerate(axes):
        ax.plot(t, err[:, i], lw=0.9, color="C0", label="error")
        if sigma is not None:
            ax.fill_between(t, -nsigma * sigma[:, i], nsigma * sigma[:, i], color="C1", alpha=0.25, lw=0, label=f"±{nsigma:g}σ")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"{labels[i]} [{ylabel}]")
        ax.grid(alpha=0.3)
    axes[0].set_title(title)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    return save(fig, path)


def compare_bars(names: list[str], means: np.ndarray, lo: np.ndarray, hi: np.ndarray, path: Path, *,
                 title: str, ylabel: str) -> Path:
    """Bar chart of a score per method with confidence intervals (lo, hi)."""
    fig, ax = plt.subplots(figsize=(1.1 * len(names) + 2.5, 3.2))
    means, lo, hi = map(np.asarray, (means, lo, hi))
    ax.bar(names, means, yerr=[means - lo, hi - means], capsize=4, color=[f"C{i}" for i in range(len(names))])
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    return save(fig, path)
