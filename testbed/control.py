"""Geometric tracking controller on SE(3) (Lee, Leok, McClamroch 2010), vectorized over vehicles.

Tracks position, velocity, acceleration and yaw of the reference; the commanded body moments and
collective thrust are mapped to the four rotor thrusts through the airframe's mixer (built from
the rotor sites and actuator gears of the compiled model) and clipped to the rotor limits.
"""
from __future__ import annotations

import numpy as np

from testbed.reference import GRAVITY
from testbed.scenario import Control
from testbed.world import Physics

E3 = np.array([0.0, 0.0, 1.0])


_I1, _I2 = np.array([1, 2, 0]), np.array([2, 0, 1])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (np.cross costs ~20x more on small arrays)."""
    return a[:, _I1] * b[:, _I2] - a[:, _I2] * b[:, _I1]


def _vee(S: np.ndarray) -> np.ndarray:
    """(N, 3, 3) skew-symmetric -> (N, 3)."""
    return S.reshape(-1, 9)[:, [7, 2, 3]]


class GeometricController:
    """Lee et al. 2010 controller for N identical quadrotors.

    Gains are per unit mass (kx, kv) and per unit inertia (kr, kw), so one set fits any airframe.
    """

    def __init__(self, physics: Physics, gains: Control):
        m = physics.model
        self.gains = gains
        self.mass = physics.vehicle_mass
        self.J = physics.vehicle_inertia
        ids = physics.actuator_idx[0]
        # Mixer: [f, Mx, My, Mz] = A @ thrusts; rotor site at (x, y) in the body frame, thrust
        # along body z, drag torque gear[5] * thrust about body z.
        sites = m.actuator_trnid[ids, 0]
        xy = m.site_pos[sites, :2]
        A = np.vstack([np.ones(4), xy[:, 1], -xy[:, 0], m.actuator_gear[ids, 5]])
        self.mix_inv = np.linalg.inv(A)
        self.lo, self.hi = m.actuator_ctrlrange[ids, 0], m.actuator_ctrlrange[ids, 1]

    def __call__(self, pos, vel, R, omega, ref_pos, ref_vel, ref_acc, ref_yaw, ref_omega=None) -> np.ndarray:
        """Rotor thrusts (N, 4) in newtons.

        pos, vel: (N, 3) world; R: (N, 3, 3) body-to-world; omega: (N, 3) body rad/s;
        ref_pos, ref_vel, ref_acc: (N, 3) world; ref_yaw: (N,) rad; ref_omega: (N, 3) body
        angular velocity of the reference attitude (feed-forward, optional).
        """
        g = self.gains
        # Lee eq. (position loop): desired force per unit mass, world frame
        a_cmd = -g.kx * (pos - ref_pos) - g.kv * (vel - ref_vel) + ref_acc + GRAVITY * E3
        b3 = R[:, :, 2]
        thrust = self.mass * (a_cmd * b3).sum(axis=1)
        b3d = a_cmd / np.linalg.norm(a_cmd, axis=1, keepdims=True)
        b1c = np.zeros_like(ref_pos)
        b1c[:, 0], b1c[:, 1] = np.cos(ref_yaw), np.sin(ref_yaw)
        b2d = _cross(b3d, b1c)
        b2d /= np.linalg.norm(b2d, axis=1, keepdims=True)
        Rd = np.stack([_cross(b2d, b3d), b2d, b3d], axis=2)
        # attitude errors e_R = vee(Rd^T R - R^T Rd) / 2, e_w = w - R^T Rd w_d
        Rt_Rd = R.transpose(0, 2, 1) @ Rd
        e_R = 0.5 * _vee(Rt_Rd.transpose(0, 2, 1) - Rt_Rd)
        e_w = omega if ref_omega is None else omega - (Rt_Rd @ ref_omega[:, :, None])[:, :, 0]
        Jw = self.J * omega
        moment = self.J * (-g.kr * e_R - g.kw * e_w) + _cross(omega, Jw)
        thrusts = thrust[:, None] * self.mix_inv[:, 0] + moment @ self.mix_inv[:, 1:].T
        return np.clip(thrusts, self.lo, self.hi)
