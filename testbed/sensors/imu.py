"""IMU stream `imu`: MuJoCo's accelerometer and gyro on every vehicle's `imu` site, with errors.

Clean values are MuJoCo's own sensors (specific force including gravity and all rigid-body terms,
angular velocity), in the imu site frame (= body FLU). Errors: seed 004 eqs. 1-4,
w_meas = (I + K_g) w + b_g + eta_gv, a_meas = (I + K_a) a + b_a + eta_av, with bias
b = constant + turn-on + random walk + first-order Gauss-Markov (testbed.sensors.noise).

Seeding: every vehicle draws all its IMU errors (scale factors, misalignments, turn-on and
Gauss-Markov starts, then the white, walk and Gauss-Markov normals of its samples) from its own
child stream `device_rng(stream_rng(seed, "imu"), "uav{i}")`: two vehicles' biases are
independent draws, and adding a vehicle never changes another vehicle's readings.

Online (`online = True`, set by testbed.sim.simulate when an onboard estimator or attitude filter
reads the IMU in the loop): the errors are applied at each sample, all vehicles at once, with
each vehicle's normals drawn from its own generator in blocks of BLOCK samples (the same
sequence of draws as above); the log then holds exactly the values read online.

Rotor vibration (testbed.sensors.vibration) in flown runs when [sensors.imu.vibration] is enabled:
added to the clean values before the errors, a_meas = (I + K_a)(a + a_vib) + b_a + eta_av (and
the gyro alike); imu/clean stays the rigid body's reading, so value - clean holds the vibration.

Log: imu/value, imu/clean (M, 6) = [f_x, f_y, f_z (m/s^2), w_x, w_y, w_z (rad/s)], imu site
frame; imu/vehicle (M,) 1-based; imu/src = "uav{i}/imu", imu/dst = ""; imu/bias (M, 6) the true
total bias at the sample (for diagnostics, never for estimators).
"""
from __future__ import annotations

import numpy as np

from testbed.sensors.base import Recorder, common_keys
from testbed.sensors.config import ImuConfig
from testbed.sensors.noise import TriadErrors, device_rng
from testbed.sensors.vibration import RotorVibration
from testbed.sim.world import Physics


BLOCK = 256  # samples of normals drawn per vehicle at a time in online mode


class Imu:
    name = "imu"
    online = False
    mujoco_sensors = True  # reads sensordata: MuJoCo must evaluate its sensors at this stream's ticks

    def __init__(self, cfg: ImuConfig, physics: Physics, rng: np.random.Generator, period_ticks: int, tick: float,
                 flown: bool = False):
        """flown: the rotors' thrusts are the controller's (ctrl), so their vibration exists."""
        self.cfg, self.period_ticks = cfg, period_ticks
        self.vehicles = np.array(cfg.vehicles or range(1, physics.n + 1), dtype=int)
        self.sensordata_idx = physics.imu_idx[self.vehicles - 1]  # (V, 6): accelerometer, gyro
        dt = period_ticks * tick
        self.rngs = [device_rng(rng, f"uav{i}") for i in self.vehicles]  # one child stream per vehicle
        self.accel = [TriadErrors(cfg.accel, 1, dt, r) for r in self.rngs]
        self.gyro = [TriadErrors(cfg.gyro, 1, dt, r) for r in self.rngs]
        self.vibration = None
        if flown and cfg.vibration.enabled:
            self.vibration = RotorVibration(cfg.vibration, physics, [device_rng(rng, f"uav{i}/vibration") for i in self.vehicles],
                                            dt, cfg.rate_hz)
            self.actuator_idx = physics.actuator_idx[self.vehicles - 1]  # (V, 4) rotor1..rotor4
        self.thrusts: list[np.ndarray] = []  # (V, 4) rotor thrusts (N) per sample, only when vibrating
        self.src = np.array([f"uav{i}/imu" for i in self.vehicles])
        self.rec = Recorder("imu", {**common_keys(6), "vehicle": ((), "i8"), "bias": ((6,), "f8")})
        self.clean: list[np.ndarray] = []  # (V, 6) per sample
        self.times: list[tuple[float, int]] = []  # (t, state_index) per sample

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        """Keep MuJoCo's clean readings; errors are applied to the whole series in arrays(), or
        now when online."""
        clean = physics.data.sensordata[self.sensordata_idx]
        thrust = physics.data.ctrl[self.actuator_idx] if self.vibration is not None else None
        if self.online:
            self._sample_online(clean, thrust, t, state_index)
            return
        self.clean.append(clean)
        if thrust is not None:
            self.thrusts.append(thrust)
        self.times.append((t, state_index))

    def _sensed(self, clean: np.ndarray, thrusts: list[np.ndarray]) -> np.ndarray:
        """(n, V, 6) what the sensing elements feel: the clean values plus the rotor vibration."""
        if self.vibration is None:
            return clean
        return clean + self.vibration.sample(np.array(thrusts))

    def _sample_online(self, clean: np.ndarray, thrust: np.ndarray | None, t: float, state_index: int) -> None:
        """Errors of one sample of every vehicle (V, 6), recorded at once (module docstring)."""
        V = len(self.vehicles)
        if not self.times:  # first online sample: the vehicles' triads as one
            self._acc_all, self._gyr_all = TriadErrors.stacked(self.accel), TriadErrors.stacked(self.gyro)
            self._block, self._used = np.empty((0, 2, 3, V, 3)), 0
        if self._used == len(self._block):  # (BLOCK, 2, 3, V, 3): each vehicle's next normals
            self._block = np.stack([r.standard_normal((BLOCK, 2, 3, 1, 3))[:, :, :, 0] for r in self.rngs], axis=3)
            self._used = 0
        normals = self._block[self._used : self._used + 1]
        self._used += 1
        self.times.append((t, state_index))
        clean = clean.reshape(1, V, 6)
        sensed = self._sensed(clean, [thrust])
        am = self._acc_all.apply(sensed[:, :, :3], normals[:, 0])
        wm = self._gyr_all.apply(sensed[:, :, 3:], normals[:, 1])
        self.rec.add(
            time=np.full(V, t), arrival=np.full(V, t + self.cfg.latency), state_index=np.full(V, state_index),
            value=np.concatenate([am, wm], axis=2)[0], clean=clean[0], src=self.src, dst=np.full(V, ""),
            vehicle=self.vehicles, bias=np.concatenate([self._acc_all.bias_series, self._gyr_all.bias_series], axis=2)[0],
        )

    def arrays(self) -> dict[str, np.ndarray]:
        """Errors of the whole series at once (same draws as sample by sample: each vehicle's
        generator consumed in time order, accelerometer then gyro normals per sample)."""
        V, n = len(self.vehicles), len(self.times)
        if n == 0 or self.online:
            return self.rec.arrays()
        clean = np.array(self.clean).reshape(n, V, 6)
        sensed = self._sensed(clean, self.thrusts)
        am, wm = np.empty((n, V, 3)), np.empty((n, V, 3))
        for v, (r, acc, gyr) in enumerate(zip(self.rngs, self.accel, self.gyro)):
            normals = r.standard_normal((n, 2, 3, 1, 3))
            am[:, v:v + 1] = acc.apply(sensed[:, v:v + 1, :3], normals[:, 0])
            wm[:, v:v + 1] = gyr.apply(sensed[:, v:v + 1, 3:], normals[:, 1])
        bias = np.concatenate([np.concatenate([a.bias_series for a in self.accel], axis=1),
                               np.concatenate([g.bias_series for g in self.gyro], axis=1)], axis=2)  # (n, V, 6)
        t, k = np.array(self.times, dtype=float).reshape(n, 2).T
        rows = n * V
        self.rec.add(
            time=np.repeat(t, V), arrival=np.repeat(t + self.cfg.latency, V), state_index=np.repeat(k.astype(np.int64), V),
            value=np.concatenate([am, wm], axis=2).reshape(rows, 6), clean=clean.reshape(rows, 6),
            src=np.tile(self.src, n), dst=np.full(rows, ""), vehicle=np.tile(self.vehicles, n),
            bias=bias.reshape(rows, 6),
        )
        return self.rec.arrays()
