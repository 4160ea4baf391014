"""What a filter's range innovations say about it: the range noise they show, and divergence.

Per vehicle, over the last epochs that hold W ranges, each epoch's prior innovations nu_k =
r_k - h_k(x^-) (m), their predicted covariance H P^- H^T (m^2, the filter's own part) and the
declared range variances R_k (m^2) are kept (docs/estimators.md, "Range noise from the innovations" and "Divergence guard").

Range noise by covariance matching (Mehra 1972; Myers and Tapley 1976): E[nu^2] = H P H^T + R for
a filter whose R is right, so the factor on the declared variances the window shows is

    lambda = min(LAMBDA_MAX, max(1, sum_k (nu_k^2 - H_k P_k H_k^T) / sum_k R_k))      (eq. R1)

and the next ranges are taken with variance lambda R_k. Floored at 1: the data can only raise
the declared noise, as the IMU's eq. A2. Capped at LAMBDA_MAX = 25 (a range sigma five times the
declared): innovations beyond that are the filter's own error, not range noise, and are left to
eq. D1 (an uncapped lambda would grow with a diverging filter's innovations and hide it). Until W
ranges are in, lambda = 1.

Divergence: with the range variances the window shows (eq. R1's lambda after the window: a range
noise above the declared is matched, not taken for divergence), an epoch e's ranges have the
joint innovation covariance S_e = H_e P_e H_e^T + lambda R_e (its ranges correlated through the
one prior), and a consistent filter's nu_e^T S_e^-1 nu_e is chi-square of m_e dof (its ranges),
independent between epochs. Over the last epochs holding W ranges or more (M = sum m_e):

    sum_e nu_e^T S_e^-1 nu_e > chi2.isf(alpha, M)   =>  diverged                       (eq. D1)

A filter that has drifted away from its ranges (its error far beyond its covariance) fails it,
whatever its gate and its robust weights do with those ranges. The window is emptied when a
vehicle is re-initialised. Pure numpy/scipy; never imports testbed.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2

WINDOW = 20  # ranges per vehicle: W of eqs. R1 and D1
ALPHA = 1e-6  # false-alarm probability of eq. D1 per test
LAMBDA_MAX = 25.0  # cap of eq. R1 (range sigma at most 5 times the declared)


class RangeInnovations:
    """Eqs. R1 and D1 for n vehicles, over windows of the last epochs holding at least `window`
    ranges (W), D1 at false-alarm probability alpha; adapt: eq. R1 on (else lambda = 1)."""

    def __init__(self, n: int, window: int = WINDOW, alpha: float = ALPHA, adapt: bool = True):
        self.window, self.adapt, self.alpha = int(window), bool(adapt), float(alpha)
        self.epochs = [[] for _ in range(n)]  # per vehicle: (nu (m,), H P H^T (m, m), R declared (m,)) per epoch
        self.scale = np.ones(n)  # lambda of eq. R1 in force

    def add(self, i: np.ndarray, nu: np.ndarray, hph: np.ndarray, r_declared: np.ndarray) -> None:
        """One epoch's ranges of vehicles i (m,): prior innovations nu (m,) m, H P^- H^T (m, m) m^2
        (the rows of one vehicle correlated through its prior; of two vehicles of a distributed
        filter zero), declared variances r_declared (m,) m^2; a vehicle's full window then sets its
        lambda (eq. R1)."""
        i = np.asarray(i, int)
        for k in np.unique(i).tolist():
            sel = np.flatnonzero(i == k)
            epochs = self.epochs[k]
            epochs.append((np.asarray(nu, float)[sel], np.asarray(hph, float)[np.ix_(sel, sel)],
                           np.asarray(r_declared, float)[sel]))
            while len(epochs) > 1 and sum(e[0].size for e in epochs[1:]) >= self.window:
                del epochs[0]  # the last epochs that hold W ranges
            if self.adapt and self.full(k):
                nu2 = sum(float(e[0] @ e[0]) for e in epochs)
                hph_sum = sum(float(np.trace(e[1])) for e in epochs)
                # eq. R1
                self.scale[k] = min(LAMBDA_MAX, max(1.0, (nu2 - hph_sum) / sum(float(e[2].sum()) for e in epochs)))

    def full(self, k: int) -> bool:
        """Vehicle k's window holds W ranges."""
        return sum(e[0].size for e in self.epochs[k]) >= self.window

    def nis(self, k: int) -> tuple[float, int]:
        """(eq. D1's sum over vehicle k's window, its degrees of freedom: the window's ranges)."""
        total, dof = 0.0, 0
        for nu, hph, r in self.epochs[k]:
            # eq. D1: an epoch's ranges jointly, S = H P H^T + lambda R, at the lambda of eq. R1 in force
            total += float(nu @ np.linalg.solve(hph + self.scale[k] * np.diag(r), nu))
            dof += nu.size
        return total, dof

    def bound(self, dof: int) -> float:
        """Eq. D1's chi-square quantile 1 - alpha of dof degrees of freedom."""
        return float(chi2.isf(self.alpha, dof))

    def diverged(self, k: int) -> bool:
        """Eq. D1 on vehicle k's full window."""
        if self.window <= 0 or not self.full(k):
            return False
        total, dof = self.nis(k)
        return total > self.bound(dof)

    def reset(self, k: int) -> None:
        """Vehicle k re-initialised: its window emptied, lambda back to 1."""
        self.epochs[k] = []
        self.scale[k] = 1.0
