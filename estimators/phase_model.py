"""Seed 003 models: carrier-phase ranges between three-antenna UAVs, and the antenna <-> body maps.

Paper: Pan, Yin, Xu, "A new method for relative positioning of UAV group ...", Ordnance Industry
Automation 2023 (docs/papers.md). Pure numpy; no mujoco, no testbed.

Frames and conventions (the testbed's, not the paper's)
-------------------------------------------------------
- Navigation frame N: the body frame of the reference master (z up). Every position here is in N,
  metres; every velocity is d/dt of such a position, m/s, in N.
- Body frame FLU (x forward, y left, z up). Antenna sites: ant1 = (+a, 0, 0) nose,
  ant2 = (0, +b, 0) left wing tip, ant3 = (0, -b, 0) right wing tip. Body origin = midpoint of
  ant2 and ant3 (paper eq. 29).
- Attitude: ZYX Euler angles (yaw psi about z, pitch theta about y, roll phi about x),
  R_N_from_body = Rz(psi) Ry(theta) Rx(phi). With FLU, positive pitch puts the nose DOWN and
  positive roll puts the right wing down. The paper's (psi, theta, gamma) (body x fwd, y up,
  z right) map to ours as psi = psi_paper, theta = -theta_paper, phi = gamma_paper.

Filter state (paper eq. 13), x: (18,)
    x = [x1, x2, x3, v1, v2, v3]: follower antenna positions x_j (3,) m, then their velocities
    v_j (3,) m/s, all in N. `x[:9].reshape(3, 3)[j]` is antenna j+1.

Masters: M masters with antenna positions X0: (M, 3, 3) [master m, master slot i, xyz] and
velocities V0: (M, 3, 3). These are an INPUT stream (the masters' own navigation solution), never
the simulator's state.

Measurement row ordering (paper eq. 12, 25): for each master m (in the order of X0), 9 ranges
then 9 range rates; inside each group the master slot i is the slow index, the follower antenna
j the fast one:

    row(m, kind, i, j) = 18 m + 9 kind + 3 i + j,   kind 0 = range r_mij, kind 1 = rate rdot_mij

with r_mij = |X0[m, i] - x_j| (eq. 5) and rdot_mij = d r_mij / dt = u_mij . (v_j - V0[m, i])
(eq. 10 written with the relative velocity; the paper's masters are static in N), where
u_mij = (x_j - X0[m, i]) / r_mij is the unit line of sight, master -> follower.
Five masters give 90 rows (eq. 25-26).
"""
from __future__ import annotations

import numpy as np

from estimators.so3 import skew

N_STATE = 18
ROWS_PER_MASTER = 18
#: names of the 12 body-state components returned by `body_from_antennas`
BODY_STATE_NAMES = (
    "x", "y", "z", "vx", "vy", "vz",
    "yaw", "pitch", "roll", "yaw_rate", "pitch_rate", "roll_rate",
)


# ------------------------------------------------------------------------------------------------
# Antenna <-> body maps
# ------------------------------------------------------------------------------------------------
def antenna_offsets(a: float = 1.0, b: float = 1.0) -> np.ndarray:
    """Antenna sites in the FLU body frame, (3, 3) [antenna j, xyz], metres, relative to the body origin."""
    return np.array([[a, 0.0, 0.0], [0.0, b, 0.0], [0.0, -b, 0.0]])


def antenna_state_from_body(p: np.ndarray, v: np.ndarray, R: np.ndarray, R_dot: np.ndarray,
                            a: float = 1.0, b: float = 1.0) -> np.ndarray:
    """Forward map body -> filter state (paper eq. 1, 3 and 8 in the FLU frame).

    p, v: (3,) body-origin position (m) and velocity (m/s) in N; R: (3, 3) R_N_from_body;
    R_dot: (3, 3) its time derivative (1/s). Returns x: (18,) = [x1 x2 x3 v1 v2 v3].
    """
    s = antenna_offsets(a, b)
    # eq. 1 / 3: x_j = X_o + C^T s_j
    pos = p[None, :] + s @ R.T
    # eq. 8: xdot_j = Xdot_o + d(C^T)/dt s_j
    vel = v[None, :] + s @ R_dot.T
    return np.concatenate([pos.reshape(-1), vel.reshape(-1)])


# ------------------------------------------------------------------------------------------------
# Measurement model (eq. 5, 10, 12, 25-28)
# ------------------------------------------------------------------------------------------------
def stack_rows(ranges: np.ndarray, range_rates: np.ndarray) -> np.ndarray:
    """Stack (M, 3, 3) ranges and (M, 3, 3) range rates into the (18 M,) row order of eq. 12/25."""
    M = ranges.shape[0]
    return np.concatenate([ranges.reshape(M, 9), range_rates.reshape(M, 9)], axis=1).reshape(-1)


def row_label(row: int) -> tuple[int, str, int, int]:
    """(master m, 'range' | 'range_rate', master slot i, follower antenna j), all 0-based, of a row."""
    m, rem = divmod(int(row), ROWS_PER_MASTER)
    kind, rem = divmod(rem, 9)
    i, j = divmod(rem, 3)
    return m, ("range", "range_rate")[kind], i, j


def measurement_model(x: np.ndarray, master_pos: np.ndarray, master_vel: np.ndarray,
                      jacobian: bool = True, rate_window: float | np.ndarray | None = None,
                      ) -> tuple[np.ndarray, np.ndarray | None]:
    """h(x) and its analytic Jacobian for M masters (paper eq. 12, 25-28, derived anew).

    x: (18,) follower antenna state in N (m, m/s); master_pos, master_vel: (M, 3, 3) master antenna
    positions (m) and velocities (m/s) in N, [master, slot, xyz].
    Returns h: (18 M,) [m, m/s] in the row order of the module docstring, and H: (18 M, 18)
    (None if jacobian is False). Vectorized over masters and antenna pairs.

    Jacobian (eq. 27-28 corrected): with d = x_j - X0[m,i], r = |d|, u = d / r,
    w = v_j - V0[m,i] (relative velocity) and rdot = u . w,
        d r    / d x_j = u^T,
        d rdot / d x_j = (w - u rdot)^T / r = w^T / r - d^T (d . w) / r^3,
        d rdot / d v_j = u^T,
    and zero on the other antennas' blocks.

    rate_window: None = the paper's instantaneous range rate (eq. 10). Otherwise W (s), a scalar
    or (M, 3, 3) (entries > 0): the rate rows model eq. 7 as it is really measured, the MEAN
    range rate over the window [t - W, t], i.e. (r(t) - r(t - W)) / W, with the follower antenna
    moved back along the constant-velocity model (eq. 24), x_j(t - W) = x_j - W v_j, and the
    master antenna likewise, X0(t - W) = X0 - W V0. With d0 = d - W w, r0 = |d0|, u0 = d0 / r0:
        h = (r - r0) / W,   d h / d x_j = (u - u0)^T / W,   d h / d v_j = u0^T,
    which tends to eq. 10 and its Jacobian as W -> 0.
    """
    X = np.asarray(x, dtype=float)
    X0 = np.asarray(master_pos, dtype=float)
    V0 = np.asarray(master_vel, dtype=float)
    M = X0.shape[0]
    # d[m, i, j] = x_j - X0[m, i], w[m, i, j] = v_j - V0[m, i]: (M, 3, 3, 3)
    d = X[:9].reshape(1, 1, 3, 3) - X0[:, :, None, :]
    w = X[9:].reshape(1, 1, 3, 3) - V0[:, :, None, :]
    # h[m, kind, i, j] is row 18 m + 9 kind + 3 i + j (eq. 12 / 25): ranges, then range rates
    h = np.empty((M, 2, 3, 3))
    r = h[:, 0]
    # eq. 5: r_ij = |X_i0 - X_j|   (= np.linalg.norm(d, axis=-1), without its overhead)
    np.sqrt(np.add.reduce(d * d, axis=-1), out=r)
    u = d / r[..., None]
    if rate_window is None:
        # eq. 10 (relative velocity): rdot_ij = u_ij . (v_j - v_i0)
        rdot = np.einsum("mijk,mijk->mij", u, w, out=h[:, 1])
    else:
        # eq. 7 as measured: mean rate over [t - W, t] = (r(t) - r(t - W)) / W, CV back-propagation
        W = np.broadcast_to(np.asarray(rate_window, dtype=float), r.shape)[..., None]
        d0 = d - W * w
        r0 = np.sqrt(np.add.reduce(d0 * d0, axis=-1))
        u0 = d0 / r0[..., None]
        rdot = np.divide(r - r0, W[..., 0], out=h[:, 1])
    h = h.reshape(-1)
    if not jacobian:
        return h, None
    # Row (m, kind, i, j) of H is nonzero only on antenna j's columns: position 3 j + (0..2),
    # velocity 9 + 3 j + (0..2). Jb stores the rows j = 0, 1, 2 of each (m, kind, i) with 21
    # entries instead of 18: entry c of row j sits at offset 21 j + c = 18 j + (3 j + c), which is
    # column 3 j + c of row j once each group of 3 x 21 entries is cut back to its first 3 x 18.
    # So the blocks of all antennas are written at entries c = 0..2 and 9..11 of every row.
    Jb = np.zeros((M, 2, 3, 3, 21))
    # eq. 27: range rows [A_j, 0]
    Jb[:, 0, :, :, 0:3] = u
    if rate_window is None:
        # eq. 28 (corrected): range-rate rows, position block (w - u rdot) / r, velocity block u
        Jb[:, 1, :, :, 0:3] = (w - u * rdot[..., None]) / r[..., None]
        Jb[:, 1, :, :, 9:12] = u
    else:
        # window form: d h / d x_j = (u - u0) / W, d h / d v_j = u0
        Jb[:, 1, :, :, 0:3] = (u - u0) / W
        Jb[:, 1, :, :, 9:12] = u0
    H = Jb.reshape(M * 6, 63)[:, :54].reshape(M * ROWS_PER_MASTER, N_STATE)
    return h, H


# ------------------------------------------------------------------------------------------------
# Body state from the antennas (eq. 29-30 redone in FLU)
# ------------------------------------------------------------------------------------------------
def _normalize_with_rate(v, vd, Jv, Jvd):
    """e = v/|v| and its rate ed = (I - e e^T) vd / |v|, with Jacobians wrt the 18-state.

    v, vd: (3,); Jv, Jvd: (3, 18) Jacobians of v and vd. Returns e, ed, Je, Jed.
    """
    n = np.linalg.norm(v)
    e = v / n
    A = (_I3 - np.outer(e, e)) / n
    ed = A @ vd
    # d ed / d v = -[(e . vd) A + e ed^T + ed e^T] / n ; d ed / d vd = A
    Dv = -((e @ vd) * A + np.outer(e, ed) + np.outer(ed, e)) / n
    return e, ed, A @ Jv, Dv @ Jv + A @ Jvd


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of (..., 3) vectors (broadcast on the leading axes): np.cross's products and
    differences in its order (the same bits), without its axis handling, which costs several times
    the arithmetic on one vector."""
    a, b = a.T, b.T  # components first
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]).T


def _cross_with_rate(a, ad, Ja, Jad, b, bd, Jb, Jbd):
    """c = a x b and cd = ad x b + a x bd with Jacobians wrt the 18-state."""
    c = _cross(a, b)
    cd = _cross(ad, b) + _cross(a, bd)
    Jc = skew(a) @ Jb - skew(b) @ Ja
    Jcd = skew(ad) @ Jb - skew(b) @ Jad + skew(a) @ Jbd - skew(bd) @ Ja
    return c, cd, Jc, Jcd


def rotation_from_antennas(x: np.ndarray) -> np.ndarray:
    """R_N_from_body (3, 3) built from the antenna positions x[:9] (see `body_from_antennas`)."""
    P = np.asarray(x, dtype=float)[:9].reshape(3, 3)
    u = P[0] - 0.5 * (P[1] + P[2])
    w = P[1] - P[2]
    ex = u / np.linalg.norm(u)
    ez = np.cross(u, w)
    ez /= np.linalg.norm(ez)
    return np.column_stack([ex, np.cross(ez, ex), ez])


_I3 = np.eye(3)
# selectors (3, 9) of u = x1 - (x2 + x3)/2 and w = x2 - x3 from the antenna positions, and (3, 18)
# of u, w and of their rates from the 18-state (body_from_antennas)
_LU = np.hstack([_I3, -0.5 * _I3, -0.5 * _I3])
_LW = np.hstack([np.zeros((3, 3)), _I3, -_I3])
_JU, _JUD = np.hstack([_LU, np.zeros((3, 9))]), np.hstack([np.zeros((3, 9)), _LU])
_JW, _JWD = np.hstack([_LW, np.zeros((3, 9))]), np.hstack([np.zeros((3, 9)), _LW])
for _a in (_I3, _LU, _LW, _JU, _JUD, _JW, _JWD):
    _a.flags.writeable = False


def body_from_antennas(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Follower body state from the antenna state, and its analytic Jacobian (eq. 29-30 in FLU).

    x: (18,) antenna state in N. Returns y: (12,) and J = dy/dx: (12, 18), with
    y = [p (3) m, v (3) m/s, yaw psi, pitch theta, roll phi (rad), their rates (rad/s)]:
    - eq. 29: p = (x2 + x3) / 2, v = (v2 + v3) / 2 (body origin between the wing tips);
    - body axes (FLU) from the antenna triangle, Gram-Schmidt with the nose line first:
        u = x1 - (x2 + x3)/2 (forward), w = x2 - x3 (left),
        e_x = u / |u|, e_z = (u x w) / |u x w|, e_y = e_z x e_x,   R = [e_x e_y e_z];
      neither a nor b is needed (the axes are normalized);
    - eq. 30 redone for R = Rz(psi) Ry(theta) Rx(phi):
        psi = atan2(e_x,y, e_x,x), theta = -asin(e_x,z), phi = atan2(e_y,z, e_z,z);
    - Euler rates: the exact time derivative of these formulas, with d e/dt propagated from the
      antenna velocities (u_dot = v1 - (v2 + v3)/2, w_dot = v2 - v3). Singular at |pitch| = 90 deg.
    """
    x = np.asarray(x, dtype=float)
    P = x[:9].reshape(3, 3)
    V = x[9:].reshape(3, 3)
    I3 = _I3
    Lu, Lw, Ju, Jud, Jw, Jwd = _LU, _LW, _JU, _JUD, _JW, _JWD
    u, ud = Lu @ P.reshape(-1), Lu @ V.reshape(-1)
    w, wd = Lw @ P.reshape(-1), Lw @ V.reshape(-1)

    ex, exd, Jex, Jexd = _normalize_with_rate(u, ud, Ju, Jud)
    c, cd, Jc, Jcd = _cross_with_rate(u, ud, Ju, Jud, w, wd, Jw, Jwd)
    ez, ezd, Jez, Jezd = _normalize_with_rate(c, cd, Jc, Jcd)
    ey, eyd, Jey, Jeyd = _cross_with_rate(ez, ezd, Jez, Jezd, ex, exd, Jex, Jexd)

    y = np.empty(12)
    J = np.zeros((12, 18))
    # eq. 29: body position and velocity = mean of wing-tip antennas 2 and 3
    y[0:3] = 0.5 * (P[1] + P[2])
    y[3:6] = 0.5 * (V[1] + V[2])
    J[0:3, 3:9] = np.hstack([0.5 * I3, 0.5 * I3])
    J[3:6, 12:18] = np.hstack([0.5 * I3, 0.5 * I3])

    # eq. 30 (FLU, ZYX): yaw from the horizontal projection of the nose axis
    h2 = ex[0] ** 2 + ex[1] ** 2
    h = np.sqrt(h2)
    y[6] = np.arctan2(ex[1], ex[0])
    J[6] = (ex[0] * Jex[1] - ex[1] * Jex[0]) / h2
    # eq. 30: pitch = -asin(e_x,z), evaluated as atan2 for accuracy
    y[7] = np.arctan2(-ex[2], h)
    J[7] = (-h * Jex[2] + ex[2] * (ex[0] * Jex[0] + ex[1] * Jex[1]) / h) / (h2 + ex[2] ** 2)
    # eq. 30: roll from the z components of the left and up axes
    q2 = ey[2] ** 2 + ez[2] ** 2
    y[8] = np.arctan2(ey[2], ez[2])
    J[8] = (ez[2] * Jey[2] - ey[2] * Jez[2]) / q2

    # eq. 30 (rates): psi_dot = (ex_x exd_y - ex_y exd_x) / h^2
    num = ex[0] * exd[1] - ex[1] * exd[0]
    y[9] = num / h2
    dnum = exd[1] * Jex[0] + ex[0] * Jexd[1] - exd[0] * Jex[1] - ex[1] * Jexd[0]
    J[9] = dnum / h2 - num * (2 * ex[0] * Jex[0] + 2 * ex[1] * Jex[1]) / h2 ** 2
    # theta_dot = -exd_z / sqrt(1 - ex_z^2) = -exd_z / h   (|e_x| = 1)
    y[10] = -exd[2] / h
    J[10] = -Jexd[2] / h + exd[2] * (ex[0] * Jex[0] + ex[1] * Jex[1]) / h ** 3
    # phi_dot = (ez_z eyd_z - ey_z ezd_z) / (ey_z^2 + ez_z^2)
    num = ez[2] * eyd[2] - ey[2] * ezd[2]
    y[11] = num / q2
    dnum = eyd[2] * Jez[2] + ez[2] * Jeyd[2] - ezd[2] * Jey[2] - ey[2] * Jezd[2]
    J[11] = dnum / q2 - num * (2 * ey[2] * Jey[2] + 2 * ez[2] * Jez[2]) / q2 ** 2
    return y, J


# ------------------------------------------------------------------------------------------------
# Rigid rotation of the antenna triangle: angular velocity and centripetal acceleration
# ------------------------------------------------------------------------------------------------
def lever_arms(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The antennas' lever arms rho_j = x_j - (x_2 + x_3) / 2 from the body origin (eq. 29) and
    their rates rho_dot_j = v_j - (v_2 + v_3) / 2, each (3, 3) [antenna j, xyz] (m, m/s, in N),
    of the antenna state x (18,). The nose arm u = rho_1 and the wing arm w = x_2 - x_3 = rho_2 - rho_3."""
    X = np.asarray(x, dtype=float)
    P, V = X[:9].reshape(3, 3), X[9:].reshape(3, 3)
    return P - 0.5 * (P[1] + P[2]), V - 0.5 * (V[1] + V[2])


#: (9, 9) d rho / d x[:9]: the lever arms of lever_arms, stacked [antenna j, xyz], from the antenna positions
LEVER_ARMS_JACOBIAN = np.kron(np.eye(3) - 0.5 * np.array([[0.0, 1.0, 1.0]] * 3), np.eye(3))
LEVER_ARMS_JACOBIAN.flags.writeable = False


def _omega(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, ...]]:
    """(omega (3,), A (3, 3), rho_dot (3, 3), (u, u_dot, w, w_dot)) of angular_velocity at the
    antenna state x (18,): the arms once for angular_velocity and centripetal_acceleration."""
    rho, rho_dot = lever_arms(x)
    X = np.asarray(x, dtype=float)
    u, ud = rho[0], rho_dot[0]
    w, wd = X[3:6] - X[6:9], X[12:15] - X[15:18]
    A = (u @ u + w @ w) * _I3 - np.outer(u, u) - np.outer(w, w)
    return np.linalg.solve(A, _cross(u, ud) + _cross(w, wd)), A, rho_dot, (u, ud, w, wd)


def angular_velocity(x: np.ndarray) -> np.ndarray:
    """Angular velocity omega (3,) rad/s in N of the antenna triangle of the antenna state x (18,).

    With the arms u = x1 - (x2 + x3)/2 and w = x2 - x3 (m) and their rates (m/s) (lever_arms), a
    rigid body has u_dot = omega x u and w_dot = omega x w; omega is the least-squares solution of
    these six equations (exact when the state is a rigid motion):
        A omega = u x u_dot + w x w_dot,   A = (|u|^2 + |w|^2) I - u u^T - w w^T,
    A invertible whenever u and w are not parallel.
    """
    return _omega(x)[0]


def centripetal_acceleration(x: np.ndarray, jacobian: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Centripetal accelerations a (9,) m/s^2 of the three antennas about the body origin for the
    antenna state x (18,) in N, [antenna j, xyz]; with jacobian, also d a / d x (9, 18) (1/s^2, 1/s).

    A rigid body turning at omega (angular_velocity) moves antenna j, at rho_j = x_j - (x2 + x3)/2
    from the body origin with relative velocity rho_dot_j = omega x rho_j (lever_arms), with acceleration
        a_j = alpha x rho_j + omega x (omega x rho_j) = alpha x rho_j + omega x rho_dot_j.
    The constant-velocity model of eq. 24 has neither term; the angular acceleration alpha is the
    rotational process noise (estimators.phase_ekf.ProcessNoise), the centripetal term
    omega x rho_dot_j is returned here. Since rho_dot_2 + rho_dot_3 = 0 the body origin gets none.

    Jacobian: with A omega = c, c = u x u_dot + w x w_dot (angular_velocity),
        d omega = A^-1 (dc - dA omega),  dc = [u]x du_dot - [u_dot]x du + (the same in w),
        dA omega = (2 omega u^T - (u . omega) I - u omega^T) du + (the same in w),
        d a_j = [omega]x d rho_dot_j - [rho_dot_j]x d omega.
    """
    omega, A, rho_dot, (u, ud, w, wd) = _omega(x)
    a = _cross(omega, rho_dot).reshape(-1)
    if not jacobian:
        return a

    def d_a_omega(v: np.ndarray) -> np.ndarray:
        # d (A omega) / d v at fixed omega, for v = u or w
        return 2.0 * np.outer(omega, v) - (v @ omega) * _I3 - np.outer(v, omega)

    # (3, 18): d omega / d x through u, u_dot, w, w_dot and their selectors
    rhs = ((skew(u) @ _JUD - skew(ud) @ _JU - d_a_omega(u) @ _JU)
           + (skew(w) @ _JWD - skew(wd) @ _JW - d_a_omega(w) @ _JW))
    d_omega = np.linalg.solve(A, rhs)
    # d a_j = [omega]x d rho_dot_j - [rho_dot_j]x d omega, the three antennas at once
    return a, (skew(omega) @ _D_RHO_DOT - skew(rho_dot) @ d_omega).reshape(9, 18)


#: (3, 3, 18) d rho_dot_j / d x of the three antennas' velocities relative to the body origin,
#: rho_dot_j = v_j - (v_2 + v_3) / 2 (centripetal_acceleration)
_D_RHO_DOT = np.hstack([np.zeros((9, 9)), LEVER_ARMS_JACOBIAN]).reshape(3, 3, 18)
_D_RHO_DOT.flags.writeable = False


# ------------------------------------------------------------------------------------------------
# Which attitude directions the filter's covariance leaves unobserved
# ------------------------------------------------------------------------------------------------
#: rad: a rotation axis whose standard deviation (the filter's own covariance) exceeds this is
#: reported unobserved. The attitude of eq. 30 is linearized at the estimate (body_from_antennas'
#: J); at 0.1 rad its neglected second-order terms (~ sd^2 / 2 = 0.005 rad) are 5 % of the sd and grow
#: from there, so beyond it J P J^T no longer describes the attitude error. Measured on the built-in
#: scenarios (docs/papers.md, seed 003; 200 s, seed 1): the seven other formations stay below it at
#: every scored epoch, line H000 (standard deviations of 20 to 500 degrees) is above it at 93 % of them.
ATTITUDE_SD_LIMIT_RAD = 0.1


def rotation_covariance(x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(3, 3) rad^2: covariance of the follower's small rotation dphi in N (R_true = Exp(dphi)
    R_est) implied by the 18-state covariance P (18, 18) at the antenna state x (18,), to first
    order: the Euler-angle block J[6:9] P J[6:9]^T of body_from_antennas mapped by
    dphi = E d(psi, theta, phi), E = [e_z, Rz(psi) e_y, Rz(psi) Ry(theta) e_x] (the axes of the
    ZYX angles in N)."""
    y, J = body_from_antennas(x)
    ps, th = y[6], y[7]
    E = np.array([[0.0, -np.sin(ps), np.cos(ps) * np.cos(th)],
                  [0.0, np.cos(ps), np.sin(ps) * np.cos(th)],
                  [1.0, 0.0, -np.sin(th)]])
    Ja = E @ J[6:9]
    return Ja @ P @ Ja.T


def unobserved_rotation_axes(x: np.ndarray, P: np.ndarray, limit: float = ATTITUDE_SD_LIMIT_RAD) -> np.ndarray:
    """The rotation axes (unit vectors in N) of the follower's attitude that the filter does not
    observe: the eigenvectors of rotation_covariance(x, P) whose standard deviation exceeds
    `limit` (rad). Returns (d, 3), d = 0..3 (largest sd first), each axis signed so that its
    largest component is positive (an eigenvector's sign is arbitrary); an empty (0, 3) when the
    attitude is observed in every direction. Uses the filter's mean x (18,) and covariance P (18, 18) only."""
    lam, V = np.linalg.eigh(rotation_covariance(x, P))
    A = V[:, lam > limit ** 2][:, ::-1].T
    return A * np.sign(A[np.arange(len(A)), np.argmax(np.abs(A), axis=1)])[:, None]


# ------------------------------------------------------------------------------------------------
# A line of masters: the rotation about it is not observable
# ------------------------------------------------------------------------------------------------
#: masters whose antennas lie along one line: the second singular value of their centred positions
#: below this share of the first. Ranges from points on a line are unchanged when the follower's
#: whole trajectory turns about that line; the antennas' offsets from it (1 m triangles) observe
#: the turn only weakly. The built-in formations: line H000 0.0033 (antennas within 0.67 m of one
#: line over 402 m), every other one 0.31 or more; 0.03 lies a decade from both.
LINE_RATIO = 0.03


def masters_line(master_pos: np.ndarray, master_vel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The line the masters' antennas lie along, or None when they do not (LINE_RATIO).

    master_pos, master_vel: (M, 3, 3) master antenna positions (m) and velocities (m/s), any one
    frame (the masters' own navigation, an input). Returns (c (3,) m the antennas' centroid,
    c_dot (3,) m/s its velocity, e (3,) the unit direction of the line, signed so that its largest
    component is positive)."""
    X = np.asarray(master_pos, float).reshape(-1, 3)
    c = X.mean(axis=0)
    _, sv, Vt = np.linalg.svd(X - c)
    if sv[1] >= LINE_RATIO * sv[0]:
        return None
    e = Vt[0] * np.sign(Vt[0][np.argmax(np.abs(Vt[0]))])
    return c, np.asarray(master_vel, float).reshape(-1, 3).mean(axis=0), e


def line_rotation(p: np.ndarray, v: np.ndarray, line: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """(6,) the change of a body's position p (3,) m and velocity v (3,) m/s when its trajectory
    turns by 1 rad about the masters' line (c, c_dot, e) = masters_line(...), same frame:
        d p = e x (p - c),   d v = e x (v - c_dot)      (m/rad, m/s/rad; the line's own turn neglected).
    The ranges from points on the line do not change when the trajectory turns about it (for any
    angle): the direction the ranges of a line of masters do not observe."""
    c, c_dot, e = line
    return np.concatenate([np.cross(e, p - c), np.cross(e, v - c_dot)])
