"""Seed 003 navigation frame N and the body of the 18-state (estimators.phase_model's conventions).

N is the body frame (FLU) of the navigation master. Its pose comes each epoch from the master's
own antennas (eq. 29-30 applied to the master: origin = mid wing tips, axes from the antenna
triangle, Euler rates from the antenna velocities), and a world point X (m) with velocity V (m/s)
is, in N,
    X_N = R^T (X - p),   V_N = d/dt X_N = R^T (V - v) + (dR/dt)^T (X - p)
(p, v: N's origin and its velocity, world; R: R_world_from_N; dR/dt its rate).
The follower's body (eq. 29: mid wing tips) from the 18-state x (estimators.phase_model):
p_body = BODY_POS x (3,) m, [p_body, v_body] = BODY_PV x (6,) m, m/s, both in N.
Pure numpy; no mujoco, no testbed.
"""
from __future__ import annotations

import numpy as np

from estimators.phase_model import body_from_antennas
from estimators.so3 import rot_zyx, rot_zyx_dot

def nav_pose_from_antennas(X: np.ndarray, V: np.ndarray) -> tuple[np.ndarray, ...]:
    """Pose of the navigation master from its own antennas, per epoch.

    X, V: (K, 3, 3) world positions / velocities of its ant1..3 (m, m/s). Returns p, v (K, 3)
    (origin = mid wing tips, eq. 29), R (K, 3, 3) R_world_from_N, Rd (K, 3, 3) dR/dt (1/s).
    """
    K = X.shape[0]
    p, v = np.empty((K, 3)), np.empty((K, 3))
    R, Rd = np.empty((K, 3, 3)), np.empty((K, 3, 3))
    for k in range(K):
        y, _ = body_from_antennas(np.concatenate([X[k].ravel(), V[k].ravel()]))
        p[k], v[k] = y[0:3], y[3:6]
        R[k], Rd[k] = rot_zyx(*y[6:9]), rot_zyx_dot(y[6:9], y[9:12])
    return p, v, R, Rd


def to_nav(X: np.ndarray, V: np.ndarray, p, v, R, Rd) -> tuple[np.ndarray, np.ndarray]:
    """World points X (K, ..., 3) and their velocities V to N: R^T (X - p), R^T (V - v) + Rd^T (X - p)."""
    extra = X.ndim - 2
    sl = (slice(None),) + (None,) * extra
    dX = X - p[sl]
    XN = np.einsum("k...i,kij->k...j", dX, R)
    VN = np.einsum("k...i,kij->k...j", V - v[sl], R) + np.einsum("k...i,kij->k...j", dX, Rd)
    return XN, VN


#: (3, 18) the body position (mid wing tips, eq. 29) from the 18-state: (x2 + x3) / 2
BODY_POS = np.zeros((3, 18))
BODY_POS[:, 3:6] = BODY_POS[:, 6:9] = 0.5 * np.eye(3)
#: (6, 18) the body position and velocity from the 18-state: (x2 + x3) / 2, (v2 + v3) / 2
BODY_PV = np.zeros((6, 18))
BODY_PV[:3] = BODY_POS
BODY_PV[3:, 12:15] = BODY_PV[3:, 15:18] = 0.5 * np.eye(3)
