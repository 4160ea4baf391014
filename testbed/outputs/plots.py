"""Standard figures of navigation papers, written as PNG.

Figures are `matplotlib.figure.Figure` objects drawn on an Agg canvas: no pyplot state, no global
backend choice (`matplotlib.use` is never called), so importing this module changes nothing for
the caller and figures are freed with their last reference.

Every PNG carries its own map from pixels to data (`axes_map`, in the text chunk AXES_KEY): the
box of each axes in the image, its limits and scales. A copied PNG keeps it; the interactive
report.html reads it back (`read_axes_map`) to show the data values under the cursor.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image  # matplotlib's own dependency: it writes PNGs through Pillow
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from testbed.interrupt import poll

#: the PNG text chunk that holds a figure's axes_map
AXES_KEY = "testbed:axes"
#: a value axis whose positive values span more than this ratio is drawn on a log scale (spans_decades)
LOG_RATIO = 30.0


def figure(**kwargs) -> Figure:
    """A new figure on its own Agg canvas; kwargs go to `Figure` (figsize in inches, ...)."""
    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig


def axes_map(fig: Figure) -> list[dict]:
    """Where each axes of a laid-out `fig` is and what it shows, one dict per axes: "box" [left,
    top, right, bottom] as fractions of the image's width and height from its top-left corner;
    "xlim", "ylim" (data units at the box's left/right and bottom/top edges); "xscale", "yscale"
    ("linear" or "log"); "xlabel", "ylabel", "title"; "xcat": the category names at x = 0, 1, ...
    when the x axis is categorical (bar charts), else None."""
    out = []
    for ax in fig.axes:
        b = ax.get_position()
        cats = [lbl.get_text() for lbl in ax.get_xticklabels()] if ax.xaxis.units is not None else None
        out.append({"box": [b.x0, 1.0 - b.y1, b.x1, 1.0 - b.y0], "xlim": list(ax.get_xlim()), "ylim": list(ax.get_ylim()),
                    "xscale": ax.get_xscale(), "yscale": ax.get_yscale(), "xlabel": ax.get_xlabel(),
                    "ylabel": ax.get_ylabel(), "title": ax.get_title(), "xcat": cats})
    return out


def read_axes_map(path: Path) -> list[dict]:
    """The axes_map a PNG written by `save` carries; [] for any other image."""
    with Image.open(path) as im:
        text = getattr(im, "text", {}).get(AXES_KEY)
    return json.loads(text) if text else []


def save(fig: Figure, path: Path) -> Path:
    """Lay out and write a figure as PNG (110 dpi, parent folders created) with its axes_map."""
    poll()  # a worker asked to stop does so between figures (testbed.interrupt)
    fig.tight_layout()
    poll()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, metadata={AXES_KEY: json.dumps(axes_map(fig))})
    return path


def error_envelope(t: np.ndarray, err: np.ndarray, sigma: np.ndarray | None, path: Path, *,
                   title: str, ylabel: str, labels=("x", "y", "z"), nsigma: float = 3.0) -> Path:
    """Error per axis against time with the filter's +/- nsigma envelope, one panel per axis.

    t: (K,) s; err: (K, d) estimate minus truth; sigma: (K, d) filter standard deviations or None.
    """
    d = err.shape[1]
    fig = figure(figsize=(7.5, 1.9 * d + 0.6))
    axes = np.atleast_1d(fig.subplots(d, 1, sharex=True))
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


def spans_decades(values: np.ndarray, ratio: float = LOG_RATIO) -> bool:
    """True when `values` (any shape) are all finite and positive and the largest exceeds `ratio`
    times the smallest: on a linear axis the small ones would be flattened (87 m beside 0.3 m)."""
    v = np.asarray(values, dtype=float).ravel()
    return v.size > 1 and bool(np.all(np.isfinite(v)) and np.all(v > 0)) and v.max() > ratio * v.min()


def compare_bars(names: list[str], means: np.ndarray, lo: np.ndarray, hi: np.ndarray, path: Path, *,
                 title: str, ylabel: str) -> Path:
    """Bar chart of a score per method with confidence intervals (lo, hi); the value axis is
    logarithmic when the means span decades (`spans_decades`), and says so."""
    fig = figure(figsize=(1.1 * len(names) + 2.5, 3.2))
    ax = fig.subplots()
    means, lo, hi = map(np.asarray, (means, lo, hi))
    ax.bar(names, means, yerr=[means - lo, hi - means], capsize=4, color=[f"C{i}" for i in range(len(names))])
    if spans_decades(means):
        ax.set_yscale("log")
        ylabel += " (log scale)"
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    return save(fig, path)


def grouped_bars(groups: list[str], names: list[str], means: np.ndarray, lo: np.ndarray, hi: np.ndarray, path: Path, *,
                 title: str, ylabel: str) -> Path:
    """Bars of a score per group (x axis) and method (one colour each, in the legend) with confidence
    intervals; means, lo, hi (G, E) for the G groups and E names, NaN where a method has no value
    (no bar). Logarithmic value axis when the means span decades (`spans_decades`), said so."""
    means, lo, hi = (np.asarray(a, float).reshape(len(groups), len(names)) for a in (means, lo, hi))
    fig = figure(figsize=(max(4.0, 0.35 * len(groups) * (len(names) + 1) + 2.5), 3.4))
    ax = fig.subplots()
    x, w = np.arange(len(groups)), 0.8 / len(names)
    for j, name in enumerate(names):
        m = means[:, j]
        ax.bar(x + (j - 0.5 * (len(names) - 1)) * w, m, w, yerr=[m - lo[:, j], hi[:, j] - m], capsize=2,
               color=f"C{j}", label=name)
    ax.set_xticks(x, groups, rotation=30 if len(groups) > 3 else 0, fontsize=8)
    if spans_decades(means[np.isfinite(means)]):
        ax.set_yscale("log")
        ylabel += " (log scale)"
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(axis="y", alpha=0.3)
    return save(fig, path)
