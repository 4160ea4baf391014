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
        self.idx = self.vehicles - 1
        V = len(self.vehicles)
        dt = period_ticks * tick
        self.accel = TriadErrors(cfg.accel, V, dt, rng)
        self.gyro = TriadErrors(cfg.gyro, V, dt, rng)
        self.src = np.array([f"uav{i}/imu" for i in self.vehicles])
        self.rec = Recorder("imu", {**common_keys(6), "vehicle": ((), "i8"), "bias": ((6,), "f8")})

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        V = len(self.idx)
        a = physics.accelerometer[self.idx]
        w = physics.gyro[self.idx]
        normals = self.rng.standard_normal((2, 1, 3, V, 3))
        am = self.accel.apply(a[None], normals[0])[0]
        wm = self.gyro.apply(w[None], normals[1])[0]
        self.rec.add(
            time=np.full(V, t), arrival=np.full(V, t + self.cfg.latency), state_index=np.full(V, state_index),
            value=np.concatenate([am, wm], axis=1), clean=np.concatenate([a, w], axis=1),
            src=self.src, dst=np.full(V, ""), vehicle=self.vehicles,
            bias=np.concatenate([self.accel.bias(), self.gyro.bias()], axis=1),
        )

    def arrays(self) -> dict[str, np.ndarray]:
        return self.rec.arrays()
