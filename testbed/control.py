"""Geometric tracking controller on SE(3) (Lee, Leok, McClamroch 2010), vectorized over vehicles.

Tracks position, velocity, acceleration and yaw of the reference; the commanded body moments and
collective thrust are mapped to the four rotor thrusts through the airframe's mixer (built from
the rotor sites and actuator gears of the compiled model) and clipped to the rotor limits. The
desired angular velocity is taken as zero (the references are smooth and slow next to the
attitude loop's bandwidth of about 8 rad/s).
"""
from __future__ import annotations

import numpy as np

from testbed.reference import GRAVITY
from testbed.scenario import Control
from testbed.world import Physics

_I1, _I2 = np.array([1, 2, 0]), np.array([2, 0, 1])
_VEE = np.array([7, 2, 3])  # flat indices of S[2,1], S[0,2], S[1,0] in a 3x3 matrix


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (np.cross costs ~20x more on small arrays)."""
    return a[:, _I1] * b[:, _I2] - a[:, _I2] * b[:, _I1]


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
        xy = m.site_pos[m.actuator_trnid[ids, 0], :2]
        A = np.vstack([np.ones(4), xy[:, 1], -xy[:, 0], m.actuator_gear[ids, 5]])
        mix_inv = np.linalg.inv(A)
        self.mix_f = self.mass * mix_inv[:, 0]
        self.mix_m = (mix_inv[:, 1:] * self.J).T  # moments are computed per unit inertia
        self.lo, self.hi = m.actuator_ctrlrange[ids, 0], m.actuator_ctrlrange[ids, 1]

    def __call__(self, pos, vel, R, omega, ref_pos, ref_vel, ref_acc, ref_yaw) -> np.ndarray:
        """Rotor thrusts (N, 4) in newtons.

        pos, vel: (N, 3) world; R: (N, 3, 3) body-to-world; omega: (N, 3) body rad/s;
        ref_pos, ref_vel, ref_acc: (N, 3) world; ref_yaw: (N,) rad.
        """
        g = self.gains
        # desired force per unit mass F/m = -kx e_x - kv e_v + g e3 + a_d (world)
        a = ref_acc - g.kx * (pos - ref_pos) - g.kv * (vel - ref_vel)
        a[:, 2] += GRAVITY
        # collective thrust per unit mass f/m = (F/m) . R e3
        f = np.einsum("ni,ni->n", a, R[:, :, 2])
        b3 = a / np.sqrt(np.einsum("ni,ni->n", a, a))[:, None]
        # b2d = b3d x b1c / |.| with b1c = (cos yaw, sin yaw, 0); b1d = b2d x b3d
        c, s = np.cos(ref_yaw), np.sin(ref_yaw)
        b2 = np.column_stack((-b3[:, 2] * s, b3[:, 2] * c, b3[:, 0] * s - b3[:, 1] * c))
        b2 /= np.sqrt(np.einsum("ni,ni->n", b2, b2))[:, None]
        Rd = np.stack((_cross(b2, b3), b2, b3), axis=2)
        # e_R = vee(Rd^T R - R^T Rd) / 2; moment per unit inertia -kr e_R - kw w + J^-1 (w x J w)
        E = R.transpose(0, 2, 1) @ Rd
        e_R = 0.5 * (E.transpose(0, 2, 1) - E).reshape(-1, 9)[:, _VEE]
        m = -g.kr * e_R - g.kw * omega + _cross(omega, omega * self.J) / self.J
        return np.clip(f[:, None] * self.mix_f + m @ self.mix_m, self.lo, self.hi)
