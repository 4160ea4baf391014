"""IMU stream `imu`: MuJoCo's accelerometer and gyro on every vehicle's `imu` site, with errors.

Clean values are MuJoCo's own sensors (specific force including gravity and all rigid-body terms,
angular velocity), in the imu site frame (= body FLU). Errors: seed 004 eqs. 1-4,
w_meas = (I + K_g) w + b_g + eta_gv, a_meas = (I + K_a) a + b_a + eta_av, with bias
b = constant + turn-on + random walk + first-order Gauss-Markov (testbed.sensors.noise).

Log: imu/value, imu/clean (M, 6) = [f_x, f_y, f_z (m/s^2), w_x, w_y, w_z (rad/s)], imu site
frame; imu/vehicle (M,) 1-based; imu/src = "uav{i}/imu", imu/dst = ""; imu/bias (M, 6) the true
total bias at the sample (for diagnostics, never for estimators).
"""
from __future__ import annotations

import numpy as np

from testbed.sensors.base import Recorder, common_keys
from testbed.sensors.config import ImuConfig
from testbed.sensors.noise import TriadErrors
from testbed.world import Physics


class Imu:
    name = "imu"

    def __init__(self, cfg: ImuConfig, physics: Physics, rng: np.random.Generator, period_ticks: int, tick: float):
        self.cfg, self.rng, self.period_ticks = cfg, rng, period_ticks
        self.vehicles = np.array(cfg.vehicles or range(1, physics.n + 1), dtype=int)
        self.sensordata_idx = physics.imu_idx[self.vehicles - 1]  # (V, 6): accelerometer, gyro
        V = len(self.vehicles)
        dt = period_ticks * tick
        self.accel = TriadErrors(cfg.accel, V, dt, rng)
        self.gyro = TriadErrors(cfg.gyro, V, dt, rng)
        self.src = np.array([f"uav{i}/imu" for i in self.vehicles])
        self.rec = Recorder("imu", {**common_keys(6), "vehicle": ((), "i8"), "bias": ((6,), "f8")})
        self.clean: list[np.ndarray] = []  # (V, 6) per sample
        self.times: list[tuple[float, int]] = []  # (t, state_index) per sample

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        """Keep MuJoCo's clean readings; errors are applied to the whole series in arrays()."""
        self.clean.append(physics.data.sensordata[self.sensordata_idx])
        self.times.append((t, state_index))

    def arrays(self) -> dict[str, np.ndarray]:
        """Errors of the whole series at once (same draws as sample by sample: one generator,
        consumed in time order, accelerometer then gyro normals per sample)."""
        V, n = len(self.vehicles), len(self.times)
        if n == 0:
            return self.rec.arrays()
        clean = np.array(self.clean).reshape(n, V, 6)
        normals = self.rng.standard_normal((n, 2, 3, V, 3))
        am = self.accel.apply(clean[:, :, :3], normals[:, 0])
        wm = self.gyro.apply(clean[:, :, 3:], normals[:, 1])
        t, k = np.array(self.times, dtype=float).reshape(n, 2).T
        rows = n * V
        self.rec.add(
            time=np.repeat(t, V), arrival=np.repeat(t + self.cfg.latency, V), state_index=np.repeat(k.astype(np.int64), V),
            value=np.concatenate([am, wm], axis=2).reshape(rows, 6), clean=clean.reshape(rows, 6),
            src=np.tile(self.src, n), dst=np.full(rows, ""), vehicle=np.tile(self.vehicles, n),
            bias=np.concatenate([self.accel.bias_series, self.gyro.bias_series], axis=2).reshape(rows, 6),
        )
        return self.rec.arrays()
