"""Geometric tracking controller on SE(3) (Lee, Leok, McClamroch 2010), vectorized over vehicles.

Tracks position, velocity, acceleration and yaw of the reference; the commanded body moments and
collective thrust are mapped to the four rotor thrusts through the airframe's mixer (built from
the rotor sites and actuator gears of the compiled model). Where they exceed the rotor limits
the command is allocated by priority (`GeometricController._allocate`): roll and pitch first,
then the collective thrust, the yaw moment last (docs/control.md, "Rotor limits"). The
desired angular velocity is taken as zero (the references are smooth and slow next to the
attitude loop's bandwidth of about 8 rad/s).

It runs at every controller tick on arrays of a few vehicles, where each numpy call costs more
than its arithmetic: the code keeps the number of calls small and cheap (no einsum, stack, clip
or fancy indexing; results written in place), and fixes the summation order of every dot product.
"""
from __future__ import annotations

import numpy as np

from testbed.reference import GRAVITY
from testbed.config.scenario import Control
from testbed.sim.world import Physics

# a[:, _CROSS_A] * b[:, _CROSS_B] = (a_I1 b_I2, a_I2 b_I1) with I1 = (1, 2, 0), I2 = (2, 0, 1)
# (gathers use ndarray.take: a third of the cost of fancy indexing on small arrays)
_CROSS_A = np.array([[1, 2, 0], [2, 0, 1]])
_CROSS_B = np.array([[2, 0, 1], [1, 2, 0]])
_B2 = np.array([2, 2, 0, 1])  # components of b3d multiplied by heading() into b2d
# flat indices of E[1,2], E[2,0], E[0,1] and E[2,1], E[0,2], E[1,0] in a 3x3 matrix: their
# differences are vee(E^T - E)
_SKEW = np.array([5, 6, 1, 7, 2, 3])
MIN_LIFT = 0.5  # with max_tilt_deg on: the least vertical part of the commanded F/m, in g


def heading(yaw: np.ndarray) -> np.ndarray:
    """Yaw terms (..., 4) = (-sin, cos, sin, cos) of reference yaw (...) rad, as the controller
    takes them (computed once for a chunk of ticks)."""
    s, c = np.sin(yaw), np.cos(yaw)
    return np.stack((-s, c, s, c), axis=-1)


def _cross(a: np.ndarray, b: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (np.cross costs ~20x more on small arrays)."""
    p = a.take(_CROSS_A, axis=1) * b.take(_CROSS_B, axis=1)
    return np.subtract(p[:, 0], p[:, 1], out=out)


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
        # along body z, drag torque gear[5] * thrust about body z (gear[5] in both rotor routes).
        xy = m.site_pos[physics.rotor_site_idx[0], :2]
        A = np.vstack([np.ones(4), xy[:, 1], -xy[:, 0], m.actuator_gear[ids, 5]])
        mix_inv = np.linalg.inv(A)
        self.mix_f = self.mass * mix_inv[:, 0]
        self.mix_m = (mix_inv[:, 1:] * self.J).T  # moments are computed per unit inertia
        self.lo, self.hi = m.actuator_ctrlrange[ids, 0], m.actuator_ctrlrange[ids, 1]
        self._lo_max, self._hi_min = float(self.lo.max()), float(self.hi.min())
        # tilt limit: tan of the largest angle of F/m from the vertical (0: off), and the least
        # vertical part of F/m kept when it is on (m/s^2)
        self._tan_tilt = float(np.tan(np.radians(gains.max_tilt_deg)))
        self._az_min = MIN_LIFT * GRAVITY
        self._kr_half = -0.5 * gains.kr  # e_R carries a factor 1/2 (exact: a power of two)
        self._b = np.empty((3, physics.n, 3))  # desired body axes b1d, b2d, b3d (world), contiguous rows
        self._b1, self._b2, self._b3 = self._b

    def _limit_tilt(self, a: np.ndarray) -> None:
        """Saturate the desired force per unit mass a (N, 3) world in place: vertical part at
        least MIN_LIFT g, horizontal part scaled down (direction kept) to at most
        a_z tan(max_tilt), so the commanded thrust axis b3d leans at most max_tilt."""
        np.maximum(a[:, 2], self._az_min, out=a[:, 2])
        p = a[:, :2] * a[:, :2]
        h = np.sqrt(p[:, 0] + p[:, 1])
        # h + tiny: a zero horizontal part stays zero (scale 1 at most)
        a[:, :2] *= np.minimum(1.0, a[:, 2] * self._tan_tilt / (h + 1e-300))[:, None]

    def __call__(self, pos, vel, R, omega, ref_pos, ref_vel, ref_acc, ref_heading, out=None) -> np.ndarray:
        """Rotor thrusts (N, 4) in newtons, written to `out` (N, 4) if given.

        pos, vel: (N, 3) world; R: (N, 3, 3) body-to-world; omega: (N, 3) body rad/s (views into
        MjData are fine); ref_pos, ref_vel, ref_acc: (N, 3) world; ref_heading: (N, 4) heading(ref_yaw).
        """
        g = self.gains
        # contiguous copies: arithmetic on strided (N, 3) views costs ~3x
        pos, vel, omega = pos.copy(), vel.copy(), omega.copy()
        # desired force per unit mass F/m = -kx e_x - kv e_v + g e3 + a_d (world)
        a = ref_acc - g.kx * (pos - ref_pos) - g.kv * (vel - ref_vel)
        a[:, 2] += GRAVITY
        if self._tan_tilt:
            self._limit_tilt(a)
        # collective thrust per unit mass f/m = (F/m) . R e3
        p = a * R[:, :, 2]
        f = p[:, 0] + p[:, 1] + p[:, 2]
        b1, b2, b3 = self._b1, self._b2, self._b3
        p = a * a
        np.divide(a, np.sqrt(p[:, 0] + p[:, 2] + p[:, 1])[:, None], out=b3)
        # b2d = b3d x b1c / |.| with b1c = (cos yaw, sin yaw, 0); b1d = b2d x b3d
        t = b3.take(_B2, axis=1) * ref_heading  # (-b3z s, b3z c, b3x s, b3y c)
        t[:, 2] -= t[:, 3]
        p = t[:, :3] * t[:, :3]
        np.divide(t[:, :3], np.sqrt(p[:, 0] + p[:, 2] + p[:, 1])[:, None], out=b2)
        _cross(b2, b3, out=b1)
        Rd = self._b.transpose(1, 2, 0).copy()  # (N, 3, 3) columns b1d, b2d, b3d
        # e_R = vee(Rd^T R - R^T Rd) / 2; moment per unit inertia -kr e_R - kw w + J^-1 (w x J w)
        E = (R.transpose(0, 2, 1) @ Rd).reshape(-1, 9).take(_SKEW, axis=1)
        m = self._kr_half * (E[:, :3] - E[:, 3:]) - g.kw * omega + _cross(omega, omega * self.J) / self.J
        thrust = f[:, None] * self.mix_f + m @ self.mix_m
        if thrust.min() < self._lo_max or thrust.max() > self._hi_min:  # a cheap necessary test first
            rows = np.flatnonzero(((thrust < self.lo) | (thrust > self.hi)).any(axis=1))
            if rows.size:
                thrust[rows] = self._allocate(f[rows], m[rows])
        np.maximum(thrust, self.lo, out=thrust)  # rounding only: _allocate keeps the limits
        return np.minimum(thrust, self.hi, out=out if out is not None else thrust)

    def _allocate(self, f: np.ndarray, m: np.ndarray) -> np.ndarray:
        """Rotor thrusts (K, 4) N within the rotor limits for K vehicles whose mixed command
        exceeds them: collective f (K,) and moments m (K, 3) per unit mass and inertia, m/s^2 and body rad/s^2.

        Priorities (docs/control.md, "Rotor limits"): the roll and pitch moments keep their
        direction, scaled down only if their spread over the rotors exceeds the rotor range; the
        collective is moved to the nearest value at which they fit; the yaw moment gets what room
        is left, scaled down (direction kept) to fit. A quadrotor's yaw moment is the rotors'
        drag, k_m = 0.016 m times their thrust, so a small yaw demand needs large thrust
        differences: clipped rotor by rotor, it would take the roll and pitch authority with it."""
        lo, hi, mix_f = self.lo, self.hi, self.mix_f
        rp = m[:, :2] @ self.mix_m[:2]  # (K, 4) N: roll and pitch
        yaw = m[:, 2:] * self.mix_m[2]  # (K, 4) N: yaw
        spread = rp.max(axis=1) - rp.min(axis=1)
        rp *= np.minimum(1.0, (hi - lo).min() / np.maximum(spread, 1e-300))[:, None]
        # the collective nearest f with every rotor of roll and pitch within its limits
        f = np.minimum(np.maximum(f, ((lo - rp) / mix_f).max(axis=1)), ((hi - rp) / mix_f).min(axis=1))
        base = f[:, None] * mix_f + rp
        # the largest share s in [0, 1] of the yaw moment that keeps every rotor within its limits
        room = np.where(yaw > 0.0, hi - base, lo - base)
        share = np.divide(room, yaw, out=np.full_like(yaw, np.inf), where=yaw != 0.0)
        s = np.clip(share.min(axis=1), 0.0, 1.0)
        return base + s[:, None] * yaw
