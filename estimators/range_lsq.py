"""Per-epoch least-squares fit of one body from its ranges to known points (scipy least_squares).

The baseline the recursive estimators are compared against: each epoch alone, no motion model.
Unknowns x = [p (3,) m world, theta (3,) rad] with R = exp([theta]x) R0 (body-to-world, the
rotation vector a body-frame increment of the start attitude R0), or x = p alone when the
measured lever arms do not determine an attitude (fewer than three, or all on one line).
Residual of range k between the body's lever arm l_k (body frame, m) and the known point X_k
(world, m):  e_k = (r_k - |p + R l_k - X_k|) / sigma_k.
Covariance at the fit: (J^T J)^-1 of the whitened Jacobian (Gauss-Newton information), so its
consistency rests on the declared sigmas. Never imports mujoco or testbed.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import linalg, optimize
from scipy.stats import chi2

from estimators.geometry import numerical_rank, spanned_dimension
from estimators.so3 import quat_exp, quat_to_rotmat, so3_log, so3_right_jacobian

# Gauss-Newton from a start within the basin takes a handful of evaluations; a fit still moving
# after this many is reported not converged (scipy's own limit, 100 (n + 1), spends seconds on
# the ill-posed fits of small arrays far from their known points)
MAX_EVALUATIONS = 50
#: probability of the chi-square gate within which a fit's cost matches its ranges (mirror_fit)
GATE_PROBABILITY = 0.99

__all__ = ["RangeFit", "determines_attitude", "fit_ranges", "fresh_fit", "mirror_fit"]


class RangeFit(NamedTuple):
    """p (3,) m world; R (3, 3) body-to-world (None when the attitude is not estimated); cov (3, 3)
    or (6, 6) m^2 / rad^2 of [p, theta body frame]; cost: sum of the squared whitened residuals at
    the fit; converged; observable (the information matrix has full rank)."""

    p: np.ndarray
    R: np.ndarray | None
    cov: np.ndarray | None
    cost: float
    converged: bool
    observable: bool


def fit_ranges(arms: np.ndarray, known: np.ndarray, ranges: np.ndarray, sigma: np.ndarray,
               p0: np.ndarray, R0: np.ndarray | None = None) -> RangeFit:
    """Fit a body to ranges k = 1..K: arms (K, 3) m body frame, known (K, 3) m world, ranges (K,)
    m, sigma (K,) m; start p0 (3,) m and, for a pose fit, R0 (3, 3) (None: position only, arms
    taken as they are, e.g. all zero for a point)."""
    arms, known = np.asarray(arms, float).reshape(-1, 3), np.asarray(known, float).reshape(-1, 3)
    r, w = np.asarray(ranges, float), 1.0 / np.asarray(sigma, float)
    pose = R0 is not None

    def rot(x):
        return R0 @ quat_to_rotmat(quat_exp(x[3:])) if pose else np.eye(3)

    def res(x):
        return (r - np.linalg.norm(x[:3] + arms @ rot(x).T - known, axis=1)) * w

    def jac(x, increment=False):
        """d res / dx; increment: with respect to [dp, dtheta] of R exp([dtheta]x) at x instead."""
        R = rot(x)
        d = x[:3] + arms @ R.T - known
        u = d / np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
        J = -u
        if pose:  # d|d| / dtheta = u^T (-R [l]x) J_r = (l x (R^T u)) J_r; the residual's is minus that
            Jr = np.eye(3) if increment else so3_right_jacobian(x[3:])
            J = np.concatenate([J, np.cross(u @ R, arms) @ Jr], axis=1)
        return J * w[:, None]

    x0 = np.concatenate([p0, np.zeros(3)]) if pose else np.asarray(p0, float)
    sol = optimize.least_squares(res, x0, jac=jac, method="lm", xtol=1e-10, ftol=1e-10, max_nfev=MAX_EVALUATIONS)
    J = jac(sol.x, increment=True)  # the covariance of [dp, dtheta body frame] at the fit
    N = J.T @ J
    observable = numerical_rank(N)[0] == N.shape[0]
    cov = linalg.cho_solve(linalg.cho_factor(N), np.eye(N.shape[0])) if observable else None
    return RangeFit(sol.x[:3], rot(sol.x) if pose else None, None if cov is None else 0.5 * (cov + cov.T),
                    2.0 * float(sol.cost), bool(sol.status > 0), observable)


def determines_attitude(arms: np.ndarray) -> bool:
    """True when lever arms (K, 3) m span a plane (three or more not on one line)."""
    return spanned_dimension(np.unique(np.round(np.asarray(arms, float), 9), axis=0)) >= 2


def fresh_fit(arms: np.ndarray, known: np.ndarray, ranges: np.ndarray, sigma: np.ndarray, p0: np.ndarray,
              R0: np.ndarray | None = None, yaw_starts: int = 4) -> RangeFit:
    """A fit without a prior estimate: fit_ranges from p0 and, for a pose, from R0 turned about the
    world z axis by yaw_starts equally spaced angles; the lowest cost wins among the converged
    fits (the first fit when none converged)."""
    if R0 is None:
        return fit_ranges(arms, known, ranges, sigma, p0)
    best = None
    for yaw in 2.0 * np.pi * np.arange(yaw_starts) / yaw_starts:
        Rz = quat_to_rotmat(np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]))
        fit = fit_ranges(arms, known, ranges, sigma, p0, Rz @ R0)
        if best is None or (fit.converged, -fit.cost) > (best.converged, -best.cost):
            best = fit
    return best


def mirror_fit(fit: RangeFit, arms: np.ndarray, known: np.ndarray, ranges: np.ndarray,
               sigma: np.ndarray) -> tuple[RangeFit, bool]:
    """The mirror check of a converged, observable fit (docs/replay.md, "The mirror check"): solve
    again from its start reflected through the least-squares plane of the known points (K, 3) m
    world; arms (K, 3) m body frame, ranges (K,) m, sigma (K,) m as fit_ranges (fit.R None: a
    point fit). Returns (the lower-cost of the two converged, observable minima, flagged): flagged
    when they differ (d^T P^-1 d > 1) and both costs lie within the chi-square gate of K - n dof;
    then the returned covariance is P + d d^T, d (n,) their difference in [p m, theta rad body]."""
    arms, known = np.asarray(arms, float).reshape(-1, 3), np.asarray(known, float).reshape(-1, 3)
    n = 3 if fit.R is None else 6
    X0 = known.mean(axis=0)
    normal = np.linalg.svd(known - X0)[2][-1]  # the least-squares plane's normal
    c = fit.p + (arms.mean(axis=0) @ fit.R.T if fit.R is not None else 0.0)
    other = fit_ranges(arms, known, ranges, sigma, fit.p - 2.0 * normal * (normal @ (c - X0)), fit.R)
    if not (other.converged and other.observable):
        return fit, False
    best, second = (fit, other) if fit.cost <= other.cost else (other, fit)
    d = second.p - best.p
    if n == 6:
        d = np.concatenate([d, so3_log(best.R.T @ second.R)])
    gate = chi2.ppf(GATE_PROBABILITY, ranges.size - n) if ranges.size > n else 0.0
    if d @ np.linalg.solve(best.cov, d) <= 1.0 or second.cost > gate:
        return best, False
    return best._replace(cov=best.cov + np.outer(d, d)), True
