"""Figures of the seed 000 reproduction (both measurement modes): the paper's figs. 2-4 analogues and
the bound against the true error covariance. Every function writes one PNG (testbed.outputs.plots.save)."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from testbed.outputs.plots import save


def tracking(path: Path, t: np.ndarray, truth: np.ndarray, xhat: np.ndarray, title: str) -> Path:
    """Fig. 2 analogue: truth (K+1, 3) m and every node's estimate xhat (K+1, N, 3) m against t (K+1,) s."""
    fig = Figure(figsize=(7, 8))
    axs = fig.subplots(3, 1, sharex=True)
    for a, ax in enumerate(axs):
        ax.plot(t, truth[:, a], "k-", lw=2, label="truth")
        for i in range(xhat.shape[1]):
            ax.plot(t, xhat[:, i, a], lw=0.8, label=f"UAV {i + 1}")
        ax.set_ylabel(f"{'xyz'[a]} [m]")
    axs[0].legend(ncol=5, fontsize=7)
    axs[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    return save(fig, path)


def cumulative_J(path: Path, t: np.ndarray, res: dict, keys: Sequence[str], *, emp_title: str, bound_title: str,
                 suptitle: str | None = None) -> Path:
    """Figs. 3-4 analogues: cumulative J(k) (eq. 12; res[k]["cum_emp"], with res[k]["cum_exact"]
    dashed when present) and the bound J_bar(k) (eq. 16; res[k]["cum_bound"]) for the cases `keys`."""
    fig = Figure(figsize=(11, 4))
    a1, a2 = fig.subplots(1, 2)
    for k in keys:
        (ln,) = a1.plot(t, res[k]["cum_emp"], label=f"{k} MC" if "cum_exact" in res[k] else k)
        if "cum_exact" in res[k]:
            a1.plot(t, res[k]["cum_exact"], "--", color=ln.get_color(), lw=0.8)
        a2.semilogy(t, res[k]["cum_bound"], color=ln.get_color(), label=k)
    a1.set_title(emp_title)
    a2.set_title(bound_title)
    for ax in (a1, a2):
        ax.set_xlabel("t [s]")
        ax.legend(fontsize=7)
    if suptitle:
        fig.suptitle(suptitle)
    return save(fig, path)


def bound_vs_cov(path: Path, t: np.ndarray, series: Sequence[tuple[str, str, np.ndarray]], title: str) -> Path:
    """Per node, the traces (K+1, N) m^2 of `series` [(label, line style, values)] on a log scale."""
    n_nodes = series[0][2].shape[1]
    fig = Figure(figsize=(14, 3.5))
    axs = fig.subplots(1, n_nodes, sharey=True)
    for i, ax in enumerate(axs):
        for label, style, values in series:
            ax.semilogy(t, values[:, i], style, label=label)
        ax.set_title(f"UAV {i + 1}")
        ax.set_xlabel("t [s]")
    axs[0].legend(fontsize=7)
    fig.suptitle(title)
    return save(fig, path)
