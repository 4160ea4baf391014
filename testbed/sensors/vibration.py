"""Rotor vibration seen by a vehicle's IMU in flight ([sensors.imu.vibration], docs/sensors.md).

A sensor model, not a physics one: the forces are far too fast (41 Hz and 83 Hz at hover) for the
2.5 ms physics step to carry, and the IMU is the only thing that sees them. Per rotor r of a
vehicle, with thrust T_r (N, the rotor's ctrl) and rotation frequency f_r = sqrt(T_r / k) (rev/s;
k the thrust coefficient, T = k f^2), harmonic h = 1, 2, .. adds

    accel (body FLU):  a_r,h(t) = Re[ H(h f_r) T_r (c_xy,h (1, -i s_r, 0) + c_z,h (0, 0, 1)) e^{i h phi_r(t)} ]
    gyro  (body FLU):  w_r,h(t) = Re[ H(h f_r) J^-1 (p_r x m T_r (...)) / (i 2 pi h f_r) e^{i h phi_r(t)} ]

- the amplitude is proportional to the thrust because an imbalance force m e omega^2 is (omega^2
  proportional to T); c_xy is the rotor-plane component (a vector turning with the rotor, s_r = +1
  for the counter-clockwise rotors 1 and 3, -1 for 2 and 4), c_z the axial one;
- the gyro term is the rigid body's answer to the same forces: torque p_r x F at the rotor hub p_r
  (body frame, m), divided by the vehicle's inertia J and by i 2 pi h f_r (angular acceleration
  integrated at that frequency); m the vehicle's mass (F = m a);
- H is the IMU's anti-alias low-pass, second-order Butterworth with -3 dB at cutoff_ratio x rate_hz:
  H(f) = 1 / (1 - x^2 + i sqrt(2) x), x = f / f_c;
- phi_r is the rotor's angle: a random start per rotor (uniform, from the vehicle's own child stream
  `uav{i}/vibration` of the `imu` stream, so the IMU's other draws do not change), then
  phi_r,k = phi_r,k-1 + 2 pi f_r,k dt at the IMU samples. Evaluating the filtered sinusoids only at the
  sample instants aliases every harmonic above the Nyquist frequency, as a real sampler does.

Neglected: the accelerations of angular vibration at an IMU away from the centre of mass (the
`imu` site is at it), gyroscopic coupling, frame resonances (folded into the amplitudes).
"""
from __future__ import annotations

import numpy as np

from testbed.sensors.config import Vibration
from testbed.sim.world import Physics

SPIN = np.array([1.0, -1.0, 1.0, -1.0])  # rotors 1, 3 counter-clockwise, 2, 4 clockwise (docs/models.md)


class RotorVibration:
    """The vibration of V vehicles' IMUs, sample after sample, keeping the rotors' angles.

    cfg: the [sensors.imu.vibration] table; rngs: one generator per vehicle (V); dt: IMU sample
    period (s); rate_hz: IMU rate (Hz).
    """

    def __init__(self, cfg: Vibration, physics: Physics, rngs: list[np.random.Generator], dt: float, rate_hz: float):
        self.cfg, self.dt = cfg, dt
        self.cutoff = cfg.cutoff_ratio * rate_hz
        self.hub = physics.model.site_pos[physics.rotor_site_idx[0]].copy()  # (4, 3) body frame, m
        self.mass, self.inertia = physics.vehicle_mass, physics.vehicle_inertia
        self.phase = np.stack([r.uniform(0.0, 2.0 * np.pi, 4) for r in rngs])  # (V, 4) rad

    def sample(self, thrust: np.ndarray) -> np.ndarray:
        """(n, V, 4) rotor thrusts (N) at n successive IMU samples -> (n, V, 6) vibration
        [accel (m/s^2), gyro (rad/s)] in the imu site frame (= body FLU)."""
        thrust = np.maximum(thrust, 0.0)
        f = np.sqrt(thrust / self.cfg.thrust_coefficient)  # (n, V, 4) rev/s
        steps = np.concatenate([self.phase[None], 2.0 * np.pi * f * self.dt])
        phase = np.cumsum(steps, axis=0)[1:]  # (n, V, 4) rad, added in sample order (never wrapped:
        self.phase = phase[-1]                # sample by sample or all at once, the same numbers)
        out = np.zeros(thrust.shape[:2] + (6,))
        direction_xy = np.stack([np.ones(4), -1j * SPIN, np.zeros(4)], axis=1)  # (4, 3)
        for h, (cxy, cz) in enumerate(zip(self.cfg.accel_xy, self.cfg.accel_z), start=1):
            x = h * f / self.cutoff
            gain = thrust / (1.0 - x**2 + 1j * np.sqrt(2.0) * x) * np.exp(1j * h * phase)  # (n, V, 4)
            acc = gain[..., None] * (cxy * direction_xy + cz * np.array([0.0, 0.0, 1.0]))  # (n, V, 4, 3)
            torque = np.cross(self.hub, self.mass * acc)
            omega_h = 2.0 * np.pi * h * f
            rate = np.divide(torque / self.inertia, 1j * omega_h[..., None], out=np.zeros_like(torque),
                             where=omega_h[..., None] > 0.0)
            out[..., :3] += acc.sum(axis=2).real
            out[..., 3:] += rate.sum(axis=2).real
        return out
