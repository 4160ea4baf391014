"""The factors of every factor graph of the testbed, as vectorized measurement functions with
analytic Jacobians (batched over leading axes), and their whitening.

- GNSS (position prior) factor: h(p) = p, p (3,) m world; whitened by the square-root
  information W = L^-1 of its covariance L L^T (`sqrt_information`): b = W (z - h).
- Range factor: h = |p_i - p_j| (m), dh/dp_i = u (unit vector from j to i), dh/dp_j = -u; a
  co-located pair gets a fixed direction per factor (`coincident_directions`). With a lever arm
  the points are p + R l (estimators.graph.model, estimators.graph.batch).
- A neighbour's broadcast (position, covariance) as the far end of a range: the range variance
  inflated by the broadcast's covariance along u (`inflated_range_variance`; the distributed
  schemes of estimators.factor_graph and estimators.window).
Used by estimators.factor_graph (seed 001), estimators.graph.model, estimators.graph.batch,
estimators.graph.gbp and estimators.window. Never imports mujoco, testbed or gtsam.
"""
from __future__ import annotations

import numpy as np

__all__ = ["gnss_h", "gnss_jacobian", "range_h", "range_terms", "range_jacobian", "coincident_directions",
           "sqrt_information", "inflated_range_variance"]


def gnss_h(p: np.ndarray) -> np.ndarray:
    """GNSS measurement function h(p) = p. p: (..., 3) metres ENU -> (..., 3) metres."""
    return np.asarray(p, dtype=float)


def gnss_jacobian(p: np.ndarray) -> np.ndarray:
    """dh/dp of the GNSS factor: (..., 3, 3) identity (unitless)."""
    p = np.asarray(p, dtype=float)
    return np.broadcast_to(np.eye(3), p.shape[:-1] + (3, 3)).copy()


def range_h(p_i: np.ndarray, p_j: np.ndarray) -> np.ndarray:
    """Range measurement function |p_i - p_j|. p_i, p_j: (..., 3) metres -> (...,) metres."""
    return np.linalg.norm(np.asarray(p_i, float) - np.asarray(p_j, float), axis=-1)


def range_terms(p_i: np.ndarray, p_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(h, u) of the range factor at once: h = |p_i - p_j| (...,) m and u = dh/dp_i (..., 3),
    unitless, for p_i, p_j (..., 3) m (see `range_jacobian`)."""
    diff = np.asarray(p_i, float) - np.asarray(p_j, float)
    r = np.linalg.norm(diff, axis=-1, keepdims=True)
    h = r[..., 0]
    if np.any(r == 0.0):
        zero = h == 0.0
        diff = np.where(zero[..., None], coincident_directions(diff.shape[:-1]), diff)
        r = np.where(zero[..., None], 1.0, r)
    return h, diff / r


def range_jacobian(p_i: np.ndarray, p_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dh/dp_i, dh/dp_j) of the range factor: (..., 3) each, unitless.

    dh/dp_i = u = (p_i - p_j) / |p_i - p_j| (unit vector from j to i), dh/dp_j = -u.
    At coincident points (co-located initial guesses) the range is not differentiable; any unit
    vector is a valid subgradient direction, and `coincident_directions` gives each factor of the
    batch its own fixed one, so that co-located nodes separate in different directions.
    """
    u = range_terms(p_i, p_j)[1]
    return u, -u


def coincident_directions(shape: tuple[int, ...]) -> np.ndarray:
    """Deterministic unit vectors (*shape, 3), one per element: a golden-angle spiral on the
    sphere indexed by the element's flat index (directions of co-located range factors)."""
    k = np.arange(int(np.prod(shape, dtype=np.int64))) + 0.5
    z = 1.0 - 2.0 * ((k * 0.6180339887498949) % 1.0)
    phi = k * 2.399963229728653  # golden angle, rad
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=-1).reshape(tuple(shape) + (3,))


def sqrt_information(cov: np.ndarray) -> np.ndarray:
    """Square-root information W = L^-1 of covariances cov = L L^T (..., d, d) (L lower Cholesky),
    so that W^T W = cov^-1 and W (z - h) is the whitened residual; (..., d, d)."""
    return np.linalg.inv(np.linalg.cholesky(cov))


def inflated_range_variance(var: np.ndarray, u: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Variance (m,) m^2 of a range whose far end is a neighbour's broadcast position with
    covariance cov (m, 3, 3) m^2, seen along the unit vectors u (m, 3): var + u^T cov u, var (m,)
    the range's own variance (the Schur complement of the neighbour's prior, seed 001 section 2.3.2)."""
    return var + np.einsum("ka,kab,kb->k", u, cov, u)
