"""The factors of every factor graph of the testbed, as vectorized measurement functions with
analytic Jacobians (batched over leading axes), and their whitening.

- GNSS (position prior) factor: h(p) = p, p (3,) m world; whitened by the square-root
  information W = L^-1 of its covariance L L^T (`sqrt_information`): b = W (z - h).
- Range factor: h = |p_i - p_j| (m), dh/dp_i = u (unit vector from j to i), dh/dp_j = -u; a
  co-located pair gets a fixed direction per factor (`coincident_directions`). With a lever arm
  the points are p + R l (estimators.graph.model, estimators.graph.batch).
- Motion (white-noise acceleration of density q, m^2/s^3 per axis, between epochs dt s apart):
  the residual [p1 - p0 - v0 dt - dp; v1 - v0 - dv] ~ N(0, Q (x) I3), Q = q [[dt^3/3, dt^2/2],
  [dt^2/2, dt]] (`motion_covariance`, `motion_jacobian`; in information form over a vehicle's
  [p, v] at both epochs `motion_blocks`, with a known input [dp, dv] `motion_input_blocks`).
- A neighbour's broadcast (position, covariance) as the far end of a range: the range variance
  inflated by the broadcast's covariance along u (`inflated_range_variance`; the distributed
  schemes of estimators.factor_graph and estimators.window).
Used by estimators.factor_graph (seed 001), estimators.graph.model, estimators.graph.batch,
estimators.graph.gbp and estimators.window. Never imports mujoco, testbed or gtsam.
"""
from __future__ import annotations

import functools

import numpy as np

from estimators.core import white_acceleration_q

__all__ = ["gnss_h", "gnss_jacobian", "range_h", "range_terms", "range_jacobian", "coincident_directions",
           "sqrt_information", "inflated_range_variance", "motion_covariance", "motion_jacobian", "motion_blocks",
           "motion_input_blocks"]


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
    diff = np.subtract(p_i, p_j, dtype=float)
    h = np.sqrt(np.add.reduce(diff * diff, axis=-1))  # |diff| summed as np.linalg.norm sums it, without its overhead
    if h.all():
        return h, diff / h[..., None]
    zero = h == 0.0
    diff = np.where(zero[..., None], coincident_directions(diff.shape[:-1]), diff)
    return h, diff / np.where(zero, 1.0, h)[..., None]


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


@functools.lru_cache(maxsize=64)
def motion_blocks(dt: float, q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Information blocks (M00, M01, M11), each (6, 6) over one vehicle's [p, v] at k and k+1, of
    the white-noise-acceleration factor (module docstring) over dt (s) with density q (m^2/s^3)."""
    Q = motion_covariance(dt, q)
    J = motion_jacobian(dt)
    M = np.kron(J.T @ np.linalg.solve(Q, J), np.eye(3))  # (12, 12): ordering [p0, v0, p1, v1] x axis
    return M[:6, :6], M[:6, 6:], M[6:, 6:]


def motion_covariance(dt: float, q: float) -> np.ndarray:
    """Covariance Q (2, 2) per axis of the motion residual [e_p, e_v] over dt (s) with density q
    (m^2/s^3): q [[dt^3/3, dt^2/2], [dt^2/2, dt]] (m^2, m^2/s, m^2/s^2)."""
    return q * white_acceleration_q(dt)


def motion_jacobian(dt: float) -> np.ndarray:
    """(2, 4) d[e_p, e_v]/d[p0, v0, p1, v1] of the motion residual, per axis."""
    return np.array([[-1.0, -dt, 1.0, 0.0], [0.0, -1.0, 0.0, 1.0]])


@functools.lru_cache(maxsize=64)
def motion_input_blocks(dt: float, q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(G0, G1, W), each (6, 6), of the motion factor's known input u = [dp, dv] (6,) over dt (s)
    with density q (m^2/s^3): the factor's cost 1/2 (J x - u)^T Q^-1 (J x - u) adds -(G0 u) . x0
    - (G1 u) . x1 + 1/2 u^T W u to the input-free one (x0, x1 (6,) one vehicle's [p, v] at k, k+1;
    G = J^T Q^-1 (x) I3 split by epoch, W = Q^-1 (x) I3)."""
    Qi = np.linalg.inv(motion_covariance(dt, q))
    G = np.kron(motion_jacobian(dt).T @ Qi, np.eye(3))  # (12, 6)
    return G[:6], G[6:], np.kron(Qi, np.eye(3))
