"""Loosely coupled IMU + GNSS + UWB error-state EKF of one vehicle (Sola, "Quaternion kinematics
for the error-state Kalman filter", 2017, sections 5 and 7; local attitude error).

Nominal state x (34 + E,): position p (3) m and velocity v (3) m/s of the IMU in the world frame
(ENU), attitude q (4) wxyz body-to-world, accelerometer bias b_a (3) m/s^2 and gyro bias b_g (3)
rad/s (body FLU), the accelerometer's and the gyro's scale-factor and misalignment matrices K_a,
K_g (9 each, row-major, dimensionless: the sensor reads (I + K) x + b, testbed.sensors.noise),
then E constant extra states c (e.g. UWB antenna delays, m). Error state dx (33 + E,): dp, dv,
dtheta (rad, body frame: R_true = R Exp(dtheta)), db_a, db_g, dK_a, dK_g, dc (additive).
Layout: P, V, TH, BA, BG, KA, KG below; extra k is error index 33 + k, nominal index 34 + k.

Mechanization with one IMU sample f (specific force, m/s^2) and w (rate, rad/s), held over dt,
corrected f_c = M_a (f - b_a), w_c = M_g (w - b_g), M = (I + K)^-1 (seed 004 eqs. 1-4 inverted):
    a  = R f_c + g,  g = (0, 0, -9.81) m/s^2                      (Sola eq. 260)
    p <- p + v dt + a dt^2 / 2;  v <- v + a dt;  q <- q (x) Exp(w_c dt)
Error transition (exact Jacobian of that step; `step` gives both, batched over vehicles; d f_c = -M_a (db_a + dK_a f_c),
dK_a f_c = (I kron f_c^T) dvec(K_a)):
    F[P,V] = I dt, F[P,TH] = -R [f_c]x dt^2/2, F[P,BA] = -R M_a dt^2/2,
    F[P,KA] = -R M_a (I kron f_c^T) dt^2/2
    F[V,TH] = -R [f_c]x dt, F[V,BA] = -R M_a dt, F[V,KA] = -R M_a (I kron f_c^T) dt
    F[TH,TH] = Exp(w_c dt)^T, F[TH,BG] = -J_r(w_c dt) M_g dt,
    F[TH,KG] = -J_r(w_c dt) M_g (I kron w_c^T) dt
Process noise (`process_noise`): white accelerometer and gyro noise of densities n_a, n_g
(unit/sqrt(Hz)) into v and theta (n^2 dt), bias random walks of densities q_ba, q_bg
(unit/sqrt(s)) into the biases (q^2 dt).
Measurements (lever arm l (3,) m of the antenna or tag in the body frame, s = p + R l):
    GNSS position  z = s + v,               H = [I, 0, -R [l]x, 0, 0]
    UWB range      z = |s - a| + sum_k c_k + v,   H = [u^T [I, 0, -R [l]x, 0, 0], 1 at each k]
with a the anchor, u = (s - a) / |s - a|, and c_k the extra states that bias this range (the
antenna delays of its two ends: constant per device, so they do not average out).
Update: iterated (Gauss-Newton) Kalman update, gain by Cholesky solve, Joseph form,
innovation gate on the NIS; injection
x <- x (+) dx and reset P <- G P G^T, G[TH,TH] = I - [dtheta / 2]x (Sola eq. 287).
Held states (`update`'s `hold`, Schmidt's "consider" states): their rows of the gain are zero, so
the update never moves them nor shrinks their variance, while their covariance with the other
states still enters every gain (Joseph form: the covariance of that suboptimal gain, exact).
ACCEL_BIAS_ACROSS: the accelerometer bias across the body z axis (docs/estimators.md, "The
attitude over a long run"): a multirotor's specific force stays along its body z axis (the
thrust), so that bias and the tilt error move the velocity alike (|f| dtheta_y against db_x);
updated, they were separated wrongly (tests/test_loop.py's scenario, 30 s, calibration seeds
101-112: attitude ANEES 5.10 at 29.5 s against the 95 % interval [1.78, 4.54]; held: 2.49).
Pure numpy/scipy; never imports mujoco or testbed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.core import cho_solve_upper, cholesky_upper, joseph_update, symmetrize
from estimators.so3 import (quat_conj, quat_exp, quat_log, quat_mul, quat_to_rotmat, rot_zyx, rotmat_to_quat, skew,
                            so3_right_jacobian)

GRAVITY = np.array([0.0, 0.0, -9.81])  # m/s^2, world ENU
P, V, TH, BA, BG = (slice(3 * k, 3 * k + 3) for k in range(5))  # error-state blocks
KA, KG = slice(15, 24), slice(24, 33)  # scale-factor and misalignment error blocks
N_ERR = 33
ACCEL_BIAS_ACROSS = (9, 10)  # error indices of the accelerometer bias's body x and y (held, module docstring)


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
    """(p, v, q, b_a, b_g) views of a nominal state x (34 + E,)."""
    return x[0:3], x[3:6], x[6:10], x[10:13], x[13:16]


def _mv(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """M v for matrices (..., 3, 3) and vectors (..., 3): (..., 3)."""
    return (M @ v[..., None])[..., 0]


def corrected(x: np.ndarray, f: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The IMU sample corrected by the state's errors: f_c (..., 3) m/s^2, w_c (..., 3) rad/s, and
    M_a, M_g (..., 3, 3) = (I + K)^-1 (module docstring). Batched: x (..., 34 + E), f, w (..., 3)."""
    Ma = np.linalg.inv(np.eye(3) + x[..., 16:25].reshape(x.shape[:-1] + (3, 3)))
    Mg = np.linalg.inv(np.eye(3) + x[..., 25:34].reshape(x.shape[:-1] + (3, 3)))
    return _mv(Ma, f - x[..., 10:13]), _mv(Mg, w - x[..., 13:16]), Ma, Mg


def error_size(x: np.ndarray) -> int:
    """Length of the error state of nominal state x (..., 34 + E): 33 + extras."""
    return x.shape[-1] - 1


def _times_kron(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A (I kron v^T) (..., 3, 9) for A (..., 3, 3), v (..., 3): column 3 k + j is A[:, k] v[j]
    (the product with the block-diagonal matrix written out: no 3 x 9 matrix built, no
    multiplication by its zeros; the same numbers)."""
    return (A[..., :, :, None] * v[..., None, None, :]).reshape(A.shape[:-2] + (3, 9))


def step(x: np.ndarray, f: np.ndarray, w: np.ndarray, dt) -> tuple[np.ndarray, np.ndarray]:
    """One IMU step (module docstring), batched over leading axes (one vehicle each): the nominal
    state (..., 34 + E) after dt (s, scalar or (...,)) with the sample f (..., 3) m/s^2, w (..., 3)
    rad/s held, and the error-state transition F (..., n, n) of that step at x (extras constant)."""
    p, v, q = x[..., 0:3], x[..., 3:6], x[..., 6:10]
    R = quat_to_rotmat(q)
    fc, wc, Ma, Mg = corrected(x, f, w)
    dt = np.asarray(dt, float)[..., None, None]
    dtv = dt[..., 0]
    phi = wc * dtv
    dq = quat_exp(phi)
    # Sola eq. 260: a = R (a_m - a_b) + g, with a_m corrected for scale factor and misalignment
    a = _mv(R, fc) + GRAVITY
    out = x.copy()
    out[..., 0:3] = p + v * dtv + 0.5 * dtv * dtv * a
    out[..., 3:6] = v + a * dtv
    qn = quat_mul(q, dq)
    out[..., 6:10] = qn / np.sqrt(np.add.reduce(qn * qn, axis=-1, keepdims=True))
    RF = R @ skew(fc)
    RM = R @ Ma
    JM = so3_right_jacobian(phi) @ Mg
    n = error_size(x)
    F = np.broadcast_to(np.eye(n), x.shape[:-1] + (n, n)).copy()
    F[..., P, V] = np.eye(3) * dt
    F[..., P, TH] = -0.5 * dt * dt * RF
    F[..., P, BA] = -0.5 * dt * dt * RM
    F[..., P, KA] = _times_kron(-0.5 * dt * dt * RM, fc)
    F[..., V, TH] = -RF * dt
    F[..., V, BA] = -RM * dt
    F[..., V, KA] = _times_kron(-RM, fc) * dt
    F[..., TH, TH] = np.swapaxes(quat_to_rotmat(dq), -1, -2)
    F[..., TH, BG] = -JM * dt
    F[..., TH, KG] = _times_kron(-JM, wc) * dt
    return out, F


def process_noise(noise, dt, n: int = N_ERR) -> np.ndarray:
    """Q (k, n, n) of one step of dt (s) (scalar or (k,)) of k vehicles, noise a sequence of k
    ImuNoise (one each): white noise into v and theta, bias walks (docstring); none on the extras."""
    dts = np.broadcast_to(np.asarray(dt, float), (len(noise),))
    # Python floats (numpy's square may round differently)
    qs = np.array([[m.accel_density ** 2 * d, m.gyro_density ** 2 * d, m.accel_walk ** 2 * d, m.gyro_walk ** 2 * d]
                   for m, d in zip(noise, dts.tolist())], float).reshape(-1, 4)
    q = np.zeros((len(noise), n))
    for k, block in enumerate((V, TH, BA, BG)):
        q[:, block] = qs[:, k, None]
    Q = np.zeros((len(noise), n, n))
    Q.reshape(len(noise), n * n)[:, ::n + 1] = q
    return Q


def site_position(x: np.ndarray, lever: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World position s = p + R l (3,) of a body site with lever arm l (3,) m, and ds/ddx (3, n)."""
    R = quat_to_rotmat(x[6:10])
    H = np.zeros((3, error_size(x)))
    H[:, P] = np.eye(3)
    # R Exp(dtheta) l ~ R l + R [dtheta]x l = R l - R [l]x dtheta
    H[:, TH] = -R @ skew(lever)
    return x[0:3] + R @ lever, H


def range_model(x: np.ndarray, lever: np.ndarray, anchor: np.ndarray, extras: tuple[int, ...] = ()) -> tuple[float, np.ndarray]:
    """Predicted range |s - a| + sum of the extra states `extras` (indices k) (m) from the site
    with lever arm l to the point a (3,) world, and H (1, n)."""
    s, Hs = site_position(x, lever)
    d = s - anchor
    r = float(np.linalg.norm(d))
    H = (d / r)[None] @ Hs
    for k in extras:
        r += float(x[N_ERR + 1 + k])
        H[0, N_ERR + k] += 1.0
    return r, H


def level(f: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """Attitude q (4,) wxyz of a vehicle at rest from its bias-corrected specific force f (3,)
    m/s^2 (roll and pitch) and a heading yaw (rad, ZYX), and J (3, 3): the attitude error
    dtheta = J db_a that an accelerometer bias error db_a (true minus assumed) leaves.

    At rest f = R^T (-g) + b_a, so the levelled body-frame vertical v = f / |f| errs by
    v - v_true = (I - v v^T) db_a / |f|; with R_true = R Exp(dtheta), v_true = v + v x dtheta, so
    the tilt part of dtheta is -v x (v_true - v) = [v]x db_a / |f| (the part of db_a along v
    changes nothing); the heading about v is not measured (J has rank 2)."""
    roll, pitch = np.arctan2(f[1], f[2]), np.arctan2(-f[0], np.hypot(f[1], f[2]))
    R = rot_zyx(yaw, pitch, roll)
    v = f / np.linalg.norm(f)
    return rotmat_to_quat(R), skew(v) / np.linalg.norm(f)


def inject(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """x (+) dx: the nominal state (34 + E,) corrected by the error state dx (33 + E,)."""
    out = x.copy()
    out[0:6] += dx[0:6]
    qn = quat_mul(x[6:10], quat_exp(dx[TH]))
    out[6:10] = qn / np.linalg.norm(qn)
    out[10:] += dx[9:]
    return out


def difference(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The error state dx (33 + E,) with y (+) dx = x (the inverse of inject)."""
    dx = np.empty(error_size(x))
    dx[0:6] = x[0:6] - y[0:6]
    dx[TH] = quat_log(quat_mul(quat_conj(y[6:10]), x[6:10]))
    dx[9:] = x[10:] - y[10:]
    return dx


@dataclass(slots=True)
class Update:
    """Result of one measurement update: accepted, the NIS and its degrees of freedom."""

    accepted: bool
    nis: float
    dof: int


def screen(Pm: np.ndarray, residual: np.ndarray, H: np.ndarray, Rn: np.ndarray, gate: float) -> np.ndarray:
    """Which of m scalar measurements pass their own innovation gate: (m,) bool, residual_i^2 /
    S_ii <= gate (a chi-square quantile of 1 degree of freedom), S = H P H^T + Rn (H (m, n))."""
    S = np.einsum("ij,jk,ik->i", H, Pm, H) + np.diag(Rn)
    return residual ** 2 <= gate * S


def update(x: np.ndarray, Pm: np.ndarray, z: np.ndarray, model, Rn: np.ndarray, gate: float,
           iterations: int = 1, hold: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray, Update]:
    """Iterated EKF update (Gauss-Newton on the error state) of the measurement z (m,) with the
    model h(x), H = dh/ddx (m, n) given by `model(x) -> (h, H)`, noise Rn (m, m); rejected (state
    unchanged) when the NIS of the innovation at the prior exceeds `gate` (a chi-square quantile
    of m degrees of freedom). Iterate i relinearises at x_i = x (+) dx_i:
        dx_{i+1} = Z K_i (z - h(x_i) + H_i dx_i),  K_i = P H_i^T (H_i P H_i^T + Rn)^-1
    with Z the identity less the error indices `hold` (held states, module docstring: rows of
    the gain zero; the covariance from the Joseph form of that gain) (iterations = 1 is the EKF),
    kept only while it lowers the MAP cost
        J(dx) = dx^T P^-1 dx + r^T Rn^-1 r,  r = z - h(x (+) dx)
    (dx = P u with u = H_i^T S_i^-1 (...), so dx^T P^-1 dx = u^T P u: no inverse of P, which may
    be singular; with held states, u^T P u is the cost's prior term of the step before Z). A
    range whose prior error is a sizeable fraction of its length (an SPP first fix 5 m off,
    anchors 30 m away) has a second-order term |e_perp|^2 / (2 r) well above its
    noise: the single linearisation biases the update and the covariance then claims a certainty
    the state does not have. Returns the corrected state (n + 1,), covariance (n, n) and what
    happened."""
    h, H = model(x)
    residual = np.atleast_1d(z - h)
    U = cholesky_upper(symmetrize(H @ Pm @ H.T + Rn))  # S = U^T U
    nis = float(residual @ cho_solve_upper(U, residual))
    if not np.isfinite(nis) or nis > gate:
        return x, Pm, Update(False, nis, len(residual))
    dx, cost = np.zeros(len(Pm)), np.inf
    for i in range(iterations):
        if i:
            U = cholesky_upper(symmetrize(H @ Pm @ H.T + Rn))
        u_new = H.T @ cho_solve_upper(U, np.atleast_1d(z - h) + H @ dx)
        dx_new = Pm @ u_new
        dx_new[list(hold)] = 0.0
        h_new, H_new = model(inject(x, dx_new))
        r_new = np.atleast_1d(z - h_new)
        cost_new = float(u_new @ Pm @ u_new + r_new @ np.linalg.solve(Rn, r_new))
        if cost_new >= cost:
            break
        dx, cost, K, H_used = dx_new, cost_new, cho_solve_upper(U, H @ Pm).T, H  # K = P H^T S^-1
        K[list(hold)] = 0.0
        h, H = h_new, H_new
    H = H_used
    Pn = joseph_update(Pm, K, H, Rn)
    # Sola eq. 287: reset of the attitude error block after injection
    G = np.eye(len(dx))
    G[TH, TH] -= skew(0.5 * dx[TH])
    return inject(x, dx), symmetrize(G @ Pn @ G.T), Update(True, nis, len(residual))
