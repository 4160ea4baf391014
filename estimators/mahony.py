"""Mahony explicit complementary attitude filter on an IMU, vectorized over N vehicles.

Mahony, Hamel, Pflimlin, "Nonlinear complementary filters on the special orthogonal group",
IEEE TAC 2008, eqs. 32 (explicit complementary filter with bias estimation), with the measured
direction v_a the accelerometer's specific force and its reference in the world frame the
expected specific force direction u = (a_ref + g e3) / |a_ref + g e3| (a_ref: the commanded
acceleration; u = e3 in hover). Per IMU sample, with gyro w (N, 3) rad/s and accelerometer
f (N, 3) m/s^2 in the body (FLU) frame, estimate q (N, 4) wxyz body-to-world, bias b (N, 3) rad/s:

    e     = f / |f|  x  R(q)^T u                      (rad, body; 0 where |f| < 0.1 g)
    w_c   = w - b + kp e                              (rad/s)
    b    <- b - ki e dt                               (rad/s)
    q    <- q (x) Exp(w_c dt), renormalized

kp (1/s) sets the crossover of the tilt correction, ki (1/s^2) the gyro-bias integrator. Yaw is
not observed by the accelerometer: it is the gyro's integral (no magnetometer), and the z bias
estimate moves only through tilt coupling. Pure numpy; never imports mujoco or testbed.
"""
from __future__ import annotations

import numpy as np

from estimators.so3 import quat_exp, quat_mul, quat_to_rotmat

G0 = 9.81  # m/s^2: magnitude below which (x 0.1) an accelerometer sample carries no tilt information


class Mahony:
    """The filter state of N vehicles: q (N, 4) wxyz body-to-world, bias (N, 3) rad/s, rate (N, 3)
    rad/s the last bias-corrected gyro rate, R (N, 3, 3) the attitude as a rotation matrix."""

    def __init__(self, q0: np.ndarray, kp: float, ki: float):
        self.q = np.array(q0, dtype=float).reshape(-1, 4)
        self.kp, self.ki = float(kp), float(ki)
        self.bias = np.zeros((len(self.q), 3))
        self.rate = np.zeros((len(self.q), 3))
        self.R = quat_to_rotmat(self.q)

    def update(self, gyro: np.ndarray, accel: np.ndarray, u_world: np.ndarray, dt: float) -> None:
        """One IMU sample of every vehicle: gyro (N, 3) rad/s, accel (N, 3) m/s^2 body frame,
        u_world (N, 3) the expected specific-force direction in the world frame, dt (s) since the last."""
        n = np.linalg.norm(accel, axis=1, keepdims=True)
        valid = n > 0.1 * G0
        a = np.where(valid, accel / np.where(valid, n, 1.0), 0.0)
        u = u_world / np.linalg.norm(u_world, axis=1, keepdims=True)
        v = np.einsum("nji,nj->ni", self.R, u)  # R^T u: the reference direction in the body frame
        # Mahony 2008 eq. 32: innovation e = v_a x v_hat (the vex of P_a(R_tilde))
        e = np.cross(a, v)
        self.rate = gyro - self.bias
        w = self.rate + self.kp * e
        self.bias = self.bias - self.ki * e * dt
        q = quat_mul(self.q, quat_exp(w * dt))
        self.q = q / np.linalg.norm(q, axis=1, keepdims=True)
        self.R = quat_to_rotmat(self.q)
