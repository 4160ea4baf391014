"""Loosely coupled IMU + GNSS + UWB error-state EKF of one vehicle (Sola, "Quaternion kinematics
for the error-state Kalman filter", 2017, sections 5 and 7; local attitude error).

Nominal state x (16,): position p (3) m and velocity v (3) m/s of the IMU in the world frame (ENU),
attitude q (4) wxyz body-to-world, accelerometer bias b_a (3) m/s^2 and gyro bias b_g (3) rad/s
(body FLU). Error state dx (15,): dp, dv, dtheta (rad, body frame: R_true = R Exp(dtheta)),
db_a, db_g. Layout: P, V, TH, BA, BG below.

Mechanization with one IMU sample f (specific force, m/s^2) and w (rate, rad/s), held over dt:
    a  = R (f - b_a) + g,  g = (0, 0, -9.81) m/s^2               (Sola eq. 260)
    p <- p + v dt + a dt^2 / 2;  v <- v + a dt;  q <- q (x) Exp((w - b_g) dt)
Error transition (exact Jacobian of that step, `transition`):
    F[P,V] = I dt, F[P,TH] = -R [f - b_a]x dt^2/2, F[P,BA] = -R dt^2/2
    F[V,TH] = -R [f - b_a]x dt, F[V,BA] = -R dt
    F[TH,TH] = Exp((w - b_g) dt)^T, F[TH,BG] = -J_r((w - b_g) dt) dt
Process noise (`process_noise`): white accelerometer and gyro noise of densities n_a, n_g
(unit/sqrt(Hz)) into v and theta (n^2 dt), bias random walks of densities q_ba, q_bg
(unit/sqrt(s)) into the biases (q^2 dt).
Measurements (lever arm l (3,) m of the antenna or tag in the body frame, s = p + R l):
    GNSS position  z = s + v,               H = [I, 0, -R [l]x, 0, 0]
    UWB range      z = |s - a| + v,         H = u^T [I, 0, -R [l]x, 0, 0], u = (s - a) / |s - a|
with a the anchor (or a neighbour's broadcast tag position, its covariance added to the noise).
Update: Kalman gain by Cholesky solve, Joseph form, innovation gate on the NIS; injection
x <- x (+) dx and reset P <- G P G^T, G[TH,TH] = I - [dtheta / 2]x (Sola eq. 287).
Pure numpy/scipy; never imports mujoco or testbed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.core import cho_solve_upper, cholesky_upper, joseph_update, symmetrize
from estimators.so3 import quat_conj, quat_exp, quat_log, quat_mul, quat_to_rotmat, skew, so3_right_jacobian

GRAVITY = np.array([0.0, 0.0, -9.81])  # m/s^2, world ENU
P, V, TH, BA, BG = (slice(3 * k, 3 * k + 3) for k in range(5))  # error-state blocks
N_ERR = 15


@dataclass(frozen=True, slots=True)
class ImuNoise:
    """Densities of the IMU model the filter assumes: accel_density (m/s^2/sqrt(Hz)),
    gyro_density (rad/s/sqrt(Hz)) white noise; accel_walk (m/s^2/sqrt(s)), gyro_walk
    (rad/s/sqrt(s)) bias random walks."""

    accel_density: float
    gyro_density: float
    accel_walk: float
    gyro_walk: float


def split(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(p, v, q, b_a, b_g) views of a nominal state x (16,)."""
    return x[0:3], x[3:6], x[6:10], x[10:13], x[13:16]


def propagate(x: np.ndarray, f: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """Nominal state (16,) after dt (s) with the IMU sample f (3,) m/s^2, w (3,) rad/s held."""
    p, v, q, ba, bg = split(x)
    R = quat_to_rotmat(q)
    # Sola eq. 260: a = R (a_m - a_b) + g
    a = R @ (f - ba) + GRAVITY
    out = x.copy()
    out[0:3] = p + v * dt + 0.5 * dt * dt * a
    out[3:6] = v + a * dt
    qn = quat_mul(q, quat_exp((w - bg) * dt))
    out[6:10] = qn / np.linalg.norm(qn)
    return out


def transition(x: np.ndarray, f: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """Error-state transition F (15, 15) of `propagate` at x (module docstring)."""
    _, _, q, ba, bg = split(x)
    R = quat_to_rotmat(q)
    RF = R @ skew(f - ba)
    phi = (w - bg) * dt
    F = np.eye(N_ERR)
    F[P, V] = np.eye(3) * dt
    F[P, TH] = -0.5 * dt * dt * RF
    F[P, BA] = -0.5 * dt * dt * R
    F[V, TH] = -RF * dt
    F[V, BA] = -R * dt
    F[TH, TH] = quat_to_rotmat(quat_exp(phi)).T
    F[TH, BG] = -so3_right_jacobian(phi) * dt
    return F


def process_noise(noise: ImuNoise, dt: float) -> np.ndarray:
    """Q (15, 15) of one step of dt (s): white noise into v and theta, bias walks (docstring)."""
    q = np.zeros(N_ERR)
    q[V] = noise.accel_density ** 2 * dt
    q[TH] = noise.gyro_density ** 2 * dt
    q[BA] = noise.accel_walk ** 2 * dt
    q[BG] = noise.gyro_walk ** 2 * dt
    return np.diag(q)


def site_position(x: np.ndarray, lever: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World position s = p + R l (3,) of a body site with lever arm l (3,) m, and ds/ddx (3, 15)."""
    R = quat_to_rotmat(x[6:10])
    H = np.zeros((3, N_ERR))
    H[:, P] = np.eye(3)
    # R Exp(dtheta) l ~ R l + R [dtheta]x l = R l - R [l]x dtheta
    H[:, TH] = -R @ skew(lever)
    return x[0:3] + R @ lever, H


def range_model(x: np.ndarray, lever: np.ndarray, anchor: np.ndarray) -> tuple[float, np.ndarray]:
    """Predicted range |s - a| (m) from the site with lever arm l to the point a (3,) world, and H (1, 15)."""
    s, Hs = site_position(x, lever)
    d = s - anchor
    r = float(np.linalg.norm(d))
    return r, (d / r)[None] @ Hs


def inject(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """x (+) dx: the nominal state (16,) corrected by the error state dx (15,)."""
    out = x.copy()
    out[0:6] += dx[0:6]
    qn = quat_mul(x[6:10], quat_exp(dx[TH]))
    out[6:10] = qn / np.linalg.norm(qn)
    out[10:16] += dx[9:15]
    return out


def difference(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The error state dx (15,) with y (+) dx = x (the inverse of inject)."""
    dx = np.empty(N_ERR)
    dx[0:6] = x[0:6] - y[0:6]
    dx[TH] = quat_log(quat_mul(quat_conj(y[6:10]), x[6:10]))
    dx[9:15] = x[10:16] - y[10:16]
    return dx


@dataclass(slots=True)
class Update:
    """Result of one measurement update: accepted, the NIS and its degrees of freedom."""

    accepted: bool
    nis: float
    dof: int


def update(x: np.ndarray, Pm: np.ndarray, residual: np.ndarray, H: np.ndarray, Rn: np.ndarray,
           gate: float) -> tuple[np.ndarray, np.ndarray, Update]:
    """EKF update on the residual z - h(x) (m,) with H (m, 15), noise Rn (m, m); rejected (state
    unchanged) when the NIS exceeds `gate` (a chi-square quantile of m degrees of freedom).
    Returns the corrected state (16,), covariance (15, 15) and what happened."""
    U = cholesky_upper(symmetrize(H @ Pm @ H.T + Rn))  # S = U^T U
    K = cho_solve_upper(U, H @ Pm).T  # P H^T S^-1 (P symmetric)
    nis = float(residual @ cho_solve_upper(U, residual))
    if not np.isfinite(nis) or nis > gate:
        return x, Pm, Update(False, nis, len(residual))
    dx = K @ residual
    Pn = joseph_update(Pm, K, H, Rn)
    # Sola eq. 287: reset of the attitude error block after injection
    G = np.eye(N_ERR)
    G[TH, TH] -= skew(0.5 * dx[TH])
    return inject(x, dx), symmetrize(G @ Pn @ G.T), Update(True, nis, len(residual))
