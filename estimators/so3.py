"""Rotation helpers of every estimator and of the testbed: skew matrices, unit quaternions, SO(3)
exponential and logarithm, ZYX Euler angles. Written once here (testbed imports them; estimators
never import testbed).

Conventions: quaternions are wxyz (scalar first, as MuJoCo), Hamilton product, unit norm;
R(q) maps the rotated frame's coordinates to the reference frame (R_a_from_b for q_a_from_b);
rotation vectors phi (rad) are axis * angle, Exp(phi) the rotation about phi by |phi|.
ZYX Euler angles (yaw psi about z, pitch theta about y, roll phi about x):
R = Rz(psi) Ry(theta) Rx(phi). Quaternion functions are batched over leading axes.

Pure numpy; never imports mujoco or testbed.
"""
from __future__ import annotations

import numpy as np


# --------------------------------------------------------------------------------------------
# Skew-symmetric matrices
# --------------------------------------------------------------------------------------------
def skew(v: np.ndarray) -> np.ndarray:
    """[v]x: (..., 3) -> (..., 3, 3), [v]x w = v x w."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0, 1], out[..., 0, 2] = -z, y
    out[..., 1, 0], out[..., 1, 2] = z, -x
    out[..., 2, 0], out[..., 2, 1] = -y, x
    return out


# --------------------------------------------------------------------------------------------
# Quaternions and SO(3) (batched over leading axes)
# --------------------------------------------------------------------------------------------
def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a (x) b of wxyz quaternions (..., 4); R(a (x) b) = R(a) R(b)."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bw - ax * bx - ay * by - az * bz
    out[..., 1] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 2] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 3] = aw * bz + ax * by - ay * bx + az * bw
    return out


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (inverse of a unit quaternion), (..., 4)."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


# R(q) entry by entry: 1 - 2 (a + b) on the diagonal, 2 (a + s b) off it, with a, b products of
# two components (flat indices into the outer product q q^T, components w, x, y, z = 0..3) and s
# the sign of b: yy+zz, xy-wz, xz+wy / xy+wz, xx+zz, yz-wx / xz-wy, yz+wx, xx+yy
_R_A = np.array([10, 6, 7, 6, 5, 11, 7, 11, 5])
_R_B = np.array([15, 3, 2, 3, 15, 1, 2, 1, 10])
_R_SIGN = np.array([1.0, -1.0, 1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0])
_R_DIAG = np.eye(3, dtype=bool).ravel()
_EPS = np.finfo(float).eps


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) of unit wxyz quaternions (..., 4).

    R = [[1 - 2(y^2 + z^2), 2(xy - wz), 2(xz + wy)], [2(xy + wz), 1 - 2(x^2 + z^2), 2(yz - wx)],
         [2(xz - wy), 2(yz + wx), 1 - 2(x^2 + y^2)]], the nine entries computed at once."""
    q = np.asarray(q, dtype=float)
    qq = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
    t = qq[..., _R_A] + _R_SIGN * qq[..., _R_B]  # gathers may come out in another memory order:
    return np.ascontiguousarray(np.where(_R_DIAG, 1 - 2 * t, 2 * t)).reshape(q.shape[:-1] + (3, 3))  # C order, as callers expect


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """wxyz quaternions (..., 4) (w >= 0) of rotation matrices (..., 3, 3) (Shepperd's method: the
    largest of 4 w^2, 4 x^2, 4 y^2, 4 z^2 found from the trace and the diagonal, the other three
    components from the off-diagonal sums and differences divided by it)."""
    R = np.asarray(R, dtype=float)
    d = np.diagonal(R, axis1=-2, axis2=-1)
    tr = d[..., 0] + d[..., 1] + d[..., 2]
    i = np.argmax(np.stack([tr, d[..., 0], d[..., 1], d[..., 2]], axis=-1), axis=-1)
    # 4 q_i^2 = 1 + tr (i = w), 1 + R_aa - R_bb - R_cc (i = x, y, z with (a, b, c) cyclic from i)
    big = np.stack([1.0 + tr, 1.0 + d[..., 0] - d[..., 1] - d[..., 2], 1.0 + d[..., 1] - d[..., 2] - d[..., 0],
                    1.0 + d[..., 2] - d[..., 0] - d[..., 1]], axis=-1)
    s = 2.0 * np.sqrt(np.take_along_axis(big, i[..., None], axis=-1)[..., 0])
    # antisymmetric (w row) and symmetric (x, y, z rows) off-diagonal combinations, 4 q_i q_j
    x = R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]
    y = R[..., 1, 0] + R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] + R[..., 1, 2]
    rows = np.stack([np.stack([0.25 * s, x[0] / s, x[1] / s, x[2] / s], axis=-1),
                     np.stack([x[0] / s, 0.25 * s, y[0] / s, y[1] / s], axis=-1),
                     np.stack([x[1] / s, y[0] / s, 0.25 * s, y[2] / s], axis=-1),
                     np.stack([x[2] / s, y[1] / s, y[2] / s, 0.25 * s], axis=-1)], axis=-2)
    q = np.take_along_axis(rows, i[..., None, None], axis=-2)[..., 0, :]
    q = q / np.sqrt(np.vecdot(q, q))[..., None]  # |q| summed as np.linalg.norm sums one quaternion
    return np.where(q[..., :1] >= 0, q, -q)


def quat_exp(phi: np.ndarray) -> np.ndarray:
    """Unit quaternion (..., 4) of the rotation vector phi (..., 3) rad: Exp(phi)."""
    phi = np.asarray(phi, dtype=float)
    th = np.sqrt(np.add.reduce(phi * phi, axis=-1, keepdims=True))  # |phi|, as np.linalg.norm sums it
    # sin(th/2)/th = 0.5 sinc(th / (2 pi)), sinc(x) = sin(pi x) / (pi x) and 1 at 0 (numpy's sinc
    # without its call overhead: on 36 vehicles the overhead was most of the cost)
    y = np.pi * (th / (2.0 * np.pi))
    y = np.where(y, y, _EPS)
    return np.concatenate([np.cos(0.5 * th), 0.5 * (np.sin(y) / y) * phi], axis=-1)


def quat_log(q: np.ndarray) -> np.ndarray:
    """Rotation vector (..., 3) rad of unit quaternions (..., 4), shortest rotation (|phi| <= pi)."""
    q = np.where(q[..., :1] < 0, -q, q)
    w, v = q[..., :1], q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    small = s < 1e-8
    s_safe = np.where(small, 1.0, s)
    w_safe = np.where(w > 0.5, w, 1.0)   # small s implies w ~ 1
    factor = np.where(small, 2.0 / w_safe * (1.0 - s * s / (3.0 * w_safe * w_safe)),
                      2.0 * np.arctan2(s, w) / s_safe)
    return factor * v


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrices Exp(phi) = exp([phi]x) (..., 3, 3) of rotation vectors phi (..., 3) rad
    (through the unit quaternion: one exponential in the tree)."""
    return quat_to_rotmat(quat_exp(phi))


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors Log(R) (..., 3) rad, |phi| <= pi, of rotation matrices R (..., 3, 3)
    (through the unit quaternion: one logarithm in the tree)."""
    return quat_log(rotmat_to_quat(R))


def so3_right_jacobian(phi: np.ndarray) -> np.ndarray:
    """Right Jacobian J_r(phi) (..., 3, 3) of rotation vectors phi (..., 3) rad: Exp(phi + d) =
    Exp(phi) Exp(J_r(phi) d) to first order."""
    phi = np.asarray(phi, dtype=float)
    th = np.sqrt(np.add.reduce(phi * phi, axis=-1))[..., None, None]  # |phi|
    K = skew(phi)
    small = th < 1e-4
    ts = np.where(small, 1.0, th)  # th where the closed form is used (no 0 / 0 elsewhere)
    a = np.where(small, 0.5 - th * th / 24.0, (1.0 - np.cos(ts)) / ts ** 2)
    b = np.where(small, 1.0 / 6.0 - th * th / 120.0, (ts - np.sin(ts)) / ts ** 3)
    return np.eye(3) - a * K + b * (K @ K)


def so3_right_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """J_r^-1(phi) (..., 3, 3): Log(Exp(phi) Exp(d)) = phi + J_r^-1(phi) d to first order, phi (..., 3) rad
    (batched over leading axes)."""
    phi = np.asarray(phi, dtype=float)
    th = np.sqrt(phi[..., None, :] @ phi[..., :, None])[..., 0, 0]
    K = skew(phi)
    small = th < 1e-8
    t = np.where(small, 1.0, th)
    c = np.where(small, 0.0, 1.0 / (t * t) - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    return np.eye(3) + 0.5 * K + (c[..., None, None] * K) @ K


# --------------------------------------------------------------------------------------------
# ZYX Euler angles
# --------------------------------------------------------------------------------------------
def rot_zyx(psi: float, theta: float, phi: float) -> np.ndarray:
    """R_N_from_body = Rz(psi) Ry(theta) Rx(phi), (3, 3). Angles in rad (yaw, pitch, roll)."""
    cps, sps = np.cos(psi), np.sin(psi)
    cth, sth = np.cos(theta), np.sin(theta)
    cph, sph = np.cos(phi), np.sin(phi)
    return np.array([
        [cps * cth, cps * sth * sph - sps * cph, cps * sth * cph + sps * sph],
        [sps * cth, sps * sth * sph + cps * cph, sps * sth * cph - cps * sph],
        [-sth, cth * sph, cth * cph],
    ])


def rot_zyx_dot(euler: np.ndarray, euler_rate: np.ndarray) -> np.ndarray:
    """d/dt of R_N_from_body for ZYX Euler angles (psi, theta, phi) and their rates, (3, 3), 1/s."""
    psi, theta, phi = euler
    dpsi, dtheta, dphi = euler_rate
    c, s = np.cos, np.sin
    Rz = np.array([[c(psi), -s(psi), 0], [s(psi), c(psi), 0], [0, 0, 1.0]])
    Ry = np.array([[c(theta), 0, s(theta)], [0, 1.0, 0], [-s(theta), 0, c(theta)]])
    Rx = np.array([[1.0, 0, 0], [0, c(phi), -s(phi)], [0, s(phi), c(phi)]])
    dRz = np.array([[-s(psi), -c(psi), 0], [c(psi), -s(psi), 0], [0, 0, 0.0]])
    dRy = np.array([[-s(theta), 0, c(theta)], [0, 0, 0.0], [-c(theta), 0, -s(theta)]])
    dRx = np.array([[0.0, 0, 0], [0, -s(phi), -c(phi)], [0, c(phi), -s(phi)]])
    return dpsi * dRz @ Ry @ Rx + dtheta * Rz @ dRy @ Rx + dphi * Rz @ Ry @ dRx


def euler_from_rotation(R: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (yaw psi, pitch theta, roll phi), rad, of R = Rz(psi) Ry(theta) Rx(phi)."""
    return np.array([
        np.arctan2(R[1, 0], R[0, 0]),
        np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0])),
        np.arctan2(R[2, 1], R[2, 2]),
    ])
