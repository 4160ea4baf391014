"""Shared pieces of every estimator: the Gaussian belief, the linear Kalman steps, consistency.

The estimator interface of the project (DESIGN.md) is two pure functions per filter,

    predict(belief, dt, u) -> belief
    update(belief, measurement) -> belief

returning new objects. Variants override one step (the sigma-point rule, the measurement update)
instead of copying a whole filter. This module never imports mujoco or testbed: estimators run on
data that did not come from MuJoCo.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg


@dataclass(frozen=True, slots=True)
class Gaussian:
    """A Gaussian belief.

    mean: (n,) state estimate; cov: (n, n) symmetric positive definite covariance, same units.
    """

    mean: np.ndarray
    cov: np.ndarray

    def __post_init__(self) -> None:
        n = self.mean.shape[0]
        if self.mean.ndim != 1 or self.cov.shape != (n, n):
            raise ValueError(f"Gaussian: mean {self.mean.shape} and cov {self.cov.shape} do not match")


def symmetrize(P: np.ndarray) -> np.ndarray:
    """(P + P^T) / 2: removes the round-off asymmetry of a covariance product."""
    return 0.5 * (P + P.T)


def is_spd(P: np.ndarray) -> bool:
    """True if P is symmetric (to round-off) and its Cholesky factorization succeeds."""
    if not np.allclose(P, P.T, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(P).max()))):
        return False
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return False
    return True


def kalman_gain(P_xz: np.ndarray, S: np.ndarray) -> np.ndarray:
    """K = P_xz S^-1 by a Cholesky solve (never an explicit inverse).

    P_xz: (n, m) state-measurement cross covariance; S: (m, m) innovation covariance (SPD).
    """
    return linalg.cho_solve(linalg.cho_factor(S), P_xz.T).T


def joseph_update(P: np.ndarray, K: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Joseph-form covariance update (I - K H) P (I - K H)^T + K R K^T, symmetrized.

    Stays positive definite for any gain K, unlike (I - K H) P.
    """
    I_KH = np.eye(P.shape[0]) - K @ H
    return symmetrize(I_KH @ P @ I_KH.T + K @ R @ K.T)


def kf_predict(belief: Gaussian, F: np.ndarray, Q: np.ndarray, u: np.ndarray | None = None) -> Gaussian:
    """Linear prediction x' = F x + u, P' = F P F^T + Q."""
    x = F @ belief.mean if u is None else F @ belief.mean + u
    return Gaussian(x, symmetrize(F @ belief.cov @ F.T + Q))


def kf_update(belief: Gaussian, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> Gaussian:
    """Linear Kalman measurement update with the Joseph-form covariance.

    z: (m,) measurement; H: (m, n); R: (m, m) measurement noise covariance.
    """
    P = belief.cov
    S = symmetrize(H @ P @ H.T + R)
    K = kalman_gain(P @ H.T, S)
    x = belief.mean + K @ (z - H @ belief.mean)
    return Gaussian(x, joseph_update(P, K, H, R))


def nees(error: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Normalized estimation error squared e^T P^-1 e.

    error: (..., n) estimate minus true value; cov: (..., n, n). Returns (...,).
    """
    e = np.asarray(error)[..., None]
    sol = np.linalg.solve(cov, e)
    return (e * sol).sum(axis=(-2, -1))


def chi2_interval(dof: int, runs: int, level: float = 0.99) -> tuple[float, float]:
    """Two-sided interval for the ANEES of `runs` independent NEES samples of `dof` degrees each.

    runs * ANEES ~ chi2(runs * dof) for a consistent filter; returns the interval divided by runs,
    so a consistent filter's ANEES (expected value dof) lies inside with probability `level`.
    """
    from scipy.stats import chi2

    a = (1.0 - level) / 2.0
    k = runs * dof
    return float(chi2.ppf(a, k) / runs), float(chi2.ppf(1.0 - a, k) / runs)
