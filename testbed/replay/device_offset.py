"""Device time offsets from the links' residuals (docs/calibration.md, cal. 10, 10b): a radio whose
timestamps run late or early by gamma seconds makes every link it ends measure the distance of
another instant, r(t) = d(t + c) ~ d(t) + c d'(t), c = gamma_src + gamma_dst.

Given, per link l, its residuals res_{l,i} after its bias and scale (cal. 2) and the true range
rate rdot_{l,i} (m/s) at the same rows, its range noise sigma_l and its residuals' integrated time
tau_l (rows), the device offsets gamma (D,) s solve by weighted least squares, the minimum norm,

    res_{l,i} = (gamma_src(l) + gamma_dst(l)) rdot_{l,i} + n_{l,i},
    w_l = 1 / (tau_l sigma_l^2),   N = A^T W A,   gamma = N^+ A^T W res,   cov = N^+       (cal. 10)

A (rows, D) has rdot in the columns of the row's two devices; the weight w_l counts a link's n_l
correlated rows as n_l / tau_l independent ones (as cal. 2 does). The minimum norm fixes what the
links cannot tell apart (with links only between anchors and tags, c added to every anchor and
taken from every tag); each link's total c_l = gamma_src + gamma_dst is what replay applies.

The rule that keeps them (cal. 10b), both of:
- they predict rows they were not fitted on: two-fold cross-validation in time, each link's rows
  split into halves in time order, gamma fitted on every link's first halves and tested on the
  second halves and the other way round; the summed weighted squared error with the offsets is
  below that of no offsets;
- they differ from zero: gamma^T N gamma > chi2_r(1 - OFFSET_ALARM), r the rank of N (a Wald test).
A time offset is applied on replay as a correction without an uncertainty of its own, so a
spurious one must be rare. Never imports mujoco.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from testbed.replay.device_bias import incidence

__all__ = ["OFFSET_ALARM", "OffsetFit", "device_offsets"]

#: the false-alarm probability of cal. 10b's Wald test
OFFSET_ALARM = 0.05


@dataclass(frozen=True, slots=True)
class OffsetFit:
    """devices {name: (gamma s, its sigma s)}; cv_with, cv_without: cal. 10b's summed held-out
    weighted squared errors; wald: gamma^T N gamma and its rank r; kept: cal. 10b holds."""

    devices: dict[str, tuple[float, float]]
    cv_with: float
    cv_without: float
    wald: float
    rank: int
    kept: bool


def _normal(ends, rows, col: dict, D: int) -> tuple[np.ndarray, np.ndarray]:
    """N (D, D) and A^T W res (D,) of cal. 10 over rows [(res (n,), rdot (n,), w)] of the links ends."""
    N, g = np.zeros((D, D)), np.zeros(D)
    for (a, b), (res, rate, w) in zip(ends, rows):
        j = [col[a], col[b]]
        rr, rs = w * float(rate @ rate), w * float(rate @ res)
        N[np.ix_(j, j)] += rr
        g[j] += rs
    return N, g


def device_offsets(ends: list[tuple[str, str]], res: list[np.ndarray], rate: list[np.ndarray],
                   weight: np.ndarray) -> OffsetFit:
    """cal. 10, 10b for the links ends [(src, dst)], each with its residuals res[l] (n_l,) m in time
    order, true range rates rate[l] (n_l,) m/s and weight w_l = 1 / (tau_l sigma_l^2) (L,) 1/m^2."""
    col, A = incidence(ends)
    D = len(col)
    rows = list(zip(res, rate, np.asarray(weight, float)))
    N, g = _normal(ends, rows, col, D)
    # eq. cal. 10
    cov = np.linalg.pinv(N, hermitian=True)
    gamma = cov @ g
    rank = int(np.linalg.matrix_rank(N, hermitian=True)) if D else 0
    # eq. cal. 10b: two-fold cross-validation in time, then the Wald test
    err = {True: 0.0, False: 0.0}
    halves = [[(x[:x.size // 2], y[:y.size // 2], w) for x, y, w in rows], [(x[x.size // 2:], y[y.size // 2:], w) for x, y, w in rows]]
    for fit, test in ((0, 1), (1, 0)):
        Nf, gf = _normal(ends, halves[fit], col, D)
        c = A @ (np.linalg.pinv(Nf, hermitian=True) @ gf)
        for (x, y, w), cl in zip(halves[test], c):
            err[True] += w * float(np.sum((x - cl * y) ** 2))
            err[False] += w * float(np.sum(x ** 2))
    wald = float(gamma @ N @ gamma)
    kept = bool(rank > 0 and err[True] < err[False] and wald > chi2.ppf(1.0 - OFFSET_ALARM, rank))
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return OffsetFit({n: (float(gamma[j]), float(sig[j])) for n, j in col.items()}, err[True], err[False], wald, rank, kept)
