"""What a filter's range innovations say about it: the range noise they show, and divergence.

Per vehicle, the last W ranges' prior innovations nu_k = r_k - h_k(x^-) (m), their filter part
H_k P^- H_k^T (m^2) and declared variances R_k (m^2) are kept (docs/estimators.md, "Range noise
from the innovations" and "Divergence guard"). Both rules take medians, not sums: UWB ranges
have outliers (NLOS), and one 5 m outlier among twenty 0.1 m ranges would dominate any sum
(measured: a sum of the NIS re-initialised nav.eskf two and three times on two of six seeds of
tests/test_loop.py's scenario, its position ANEES 11.8 against [0.80, 7.15]).

Range noise by covariance matching (Mehra 1972; Myers and Tapley 1976), on the median: for a
filter whose range variance is right, nu_k^2 / (H_k P H_k^T + R_k) is chi-square of 1 dof, whose
median is m_1 = chi2.ppf(0.5, 1) = 0.455. The factor lambda on the declared variances is the one
that gives the window that median,

    median_k nu_k^2 / (H_k P H_k^T + lambda R_k) = m_1,   1 <= lambda <= LAMBDA_MAX       (eq. R1)

(the left side falls as lambda grows: solved by bisection on log lambda; lambda = 1 where the
median is already at most m_1, LAMBDA_MAX where it is still above at LAMBDA_MAX), and the next
ranges are taken with variance lambda R_k. Floored at 1: the data can only raise the declared
noise, as the IMU's eq. A2. Capped at LAMBDA_MAX = 25 (a range sigma five times the declared):
innovations beyond that are the filter's own error, not range noise, and are left to eq. D1 (an
uncapped lambda would grow with a diverging filter's innovations and hide it). Until W ranges
are in, lambda = 1.

Divergence, a sign test on the same window at the lambda in force: with NIS_k = nu_k^2 /
(H_k P H_k^T + lambda R_k), a consistent filter's NIS_k exceeds c = chi2.isf(p, 1) with
probability p; more than half of the W ranges doing so has probability
binom.sf(W // 2, W, p), and p is set so that this is alpha:

    #{k : NIS_k > c} > W / 2,   binom.sf(W // 2, W, p) = alpha,  c = chi2.isf(p, 1)      (eq. D1)

(W = 20, alpha = 1e-6: p = 0.10, c = 2.7). Up to half the window may be outliers. As lambda
makes the median NIS m_1 < c whenever it is below its cap, eq. D1 holds only where no range noise
up to five times the declared explains the innovations. The window is emptied when a vehicle is
re-initialised. Ranges of one epoch share the prior's error, so their NIS are correlated when
H P H^T is not small against R: the false-alarm rate is then above alpha. Pure numpy/scipy;
never imports testbed.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.optimize import brentq
from scipy.stats import binom, chi2

WINDOW = 20  # ranges per vehicle: W of eqs. R1 and D1
ALPHA = 1e-6  # false-alarm probability of eq. D1 per test
LAMBDA_MAX = 25.0  # cap of eq. R1 (range sigma at most 5 times the declared)
M1 = float(chi2.ppf(0.5, 1))  # the median of chi-square of 1 dof


@lru_cache(maxsize=None)
def sign_test_threshold(window: int, alpha: float) -> float:
    """c of eq. D1: the chi-square(1) quantile whose exceedance probability p gives
    binom.sf(window // 2, window, p) = alpha (constants only: solved once per pair, then cached)."""
    p = brentq(lambda q: binom.sf(window // 2, window, q) - alpha, 1e-12, 0.5, xtol=1e-14)
    return float(chi2.isf(p, 1))


class RangeInnovations:
    """Eqs. R1 and D1 for n vehicles over their last `window` ranges (W); D1 at false-alarm
    probability alpha; adapt: eq. R1 on (else lambda = 1)."""

    def __init__(self, n: int, window: int = WINDOW, alpha: float = ALPHA, adapt: bool = True):
        self.window, self.adapt = int(window), bool(adapt)
        self.c = sign_test_threshold(self.window, alpha) if self.window > 0 else np.inf
        self.rows = [np.zeros((0, 3)) for _ in range(n)]  # per vehicle: (nu^2, H P H^T, R declared) per range
        self.scale = np.ones(n)  # lambda of eq. R1 in force

    def add(self, i: np.ndarray, nu: np.ndarray, hph: np.ndarray, r_declared: np.ndarray) -> None:
        """Ranges of vehicles i (m,): prior innovations nu (m,) m, their H P^- H^T (m,) m^2,
        declared variances r_declared (m,) m^2; a vehicle's full window then sets its lambda (eq. R1)."""
        i = np.asarray(i, int)
        new = np.column_stack([np.square(nu), hph, r_declared])
        for k in np.unique(i).tolist():
            rows = self.rows[k] = np.concatenate([self.rows[k], new[i == k]])[-self.window:]
            if self.adapt and len(rows) == self.window:
                self.scale[k] = matched_scale(rows)

    def nis(self, k: int) -> np.ndarray:
        """(W,) NIS of vehicle k's window at its lambda in force (empty until the window is full)."""
        rows = self.rows[k]
        if len(rows) < self.window:
            return np.zeros(0)
        return rows[:, 0] / (rows[:, 1] + self.scale[k] * rows[:, 2])

    def diverged(self, k: int) -> bool:
        """Eq. D1 on vehicle k's full window."""
        nis = self.nis(k)
        # eq. D1: more than half the window's NIS above c
        return nis.size > 0 and int((nis > self.c).sum()) > self.window // 2

    def reset(self, k: int) -> None:
        """Vehicle k re-initialised: its window emptied, lambda back to 1."""
        self.rows[k] = np.zeros((0, 3))
        self.scale[k] = 1.0


def matched_scale(rows: np.ndarray) -> float:
    """Eq. R1's lambda of a window rows (W, 3) of (nu^2, H P H^T, R) per range."""
    a, b, c = rows.T

    def excess(log_lam: float) -> float:  # median NIS at lambda less m_1: falls as lambda grows
        return float(np.median(a / (b + np.exp(log_lam) * c))) - M1

    if excess(0.0) <= 0.0:
        return 1.0
    if excess(np.log(LAMBDA_MAX)) >= 0.0:
        return LAMBDA_MAX
    # eq. R1: the lambda whose median NIS is m_1
    return float(np.exp(brentq(excess, 0.0, np.log(LAMBDA_MAX), xtol=1e-6)))
