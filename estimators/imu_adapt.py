"""The IMU white-noise densities an inertial filter assumes, measured on the samples themselves.

At rest an IMU shows its data-sheet noise; in flight the rotors shake it, and on a recording of
three quadrotors the accelerometer's sample noise was 7-17 times the static figure (docs/sensors.md,
rotor vibration). A filter that keeps the static density is then overconfident. The rule here
(docs/estimators.md, "IMU noise from the data"): per vehicle and instrument (accelerometer, gyro),
over blocks of W successive samples y_k (3,) taken dt_k apart,

    sigma^2 = (1 / (3 (W - 1))) sum_k |y_k - y_{k-1}|^2 / 2                  (eq. A1)
    n       = max(n_declared, sigma sqrt(mean dt))                               (eq. A2)

Eq. A1: the first difference of white noise of per-sample variance sigma^2 has variance 2 sigma^2
per axis; the true signal's own change between two samples is counted as noise too (a filter that
holds each sample over dt makes an error of that size), so sigma errs large, never small. Eq. A2:
the white density of that per-sample sigma (sigma = n / sqrt(dt)), floored at the declared density
(the preset's static figure): the data can only raise it. The densities of a block hold from the
end of that block until the end of the next.

With `average` M > 1, eqs. A1-A2 take the means of M successive samples as their samples (y_k the
k-th mean, dt_k the span between two means, M sample intervals; a block is then W means): sigma^2
is the Allan variance at tau = M dt, and eq. A2 its white-equivalent density sqrt(AVAR(tau) tau).
Of white noise that is the density M = 1 gives; of the rotors' vibration, narrow-band far above
1 / (2 tau), the means keep little (docs/estimators.md, "Flights: sparse ranging without GNSS",
where the filters' need of it is measured). Pure numpy; never imports mujoco or testbed.
"""
from __future__ import annotations

import numpy as np

WINDOW = 100  # samples per block (1 s at 100 Hz): W of eq. A1


class DifferenceNoise:
    """Eqs. A1-A2 for n vehicles. floor (n, 2): the declared white densities (accel
    m/s^2/sqrt(Hz), gyro rad/s/sqrt(Hz)) of each; window: W; average: M, samples per mean
    (module docstring; 1: the samples themselves)."""

    def __init__(self, floor: np.ndarray, window: int = WINDOW, average: int = 1):
        self.floor = np.asarray(floor, float).reshape(-1, 2)
        n = len(self.floor)
        self.window = int(window)
        self.average = int(average)
        self.sum = np.zeros((n, 6))  # each vehicle's running sum of its current mean
        self.summed = np.zeros(n, int)
        self.last = np.full((n, 6), np.nan)  # each vehicle's previous sample
        self.t_last = np.full(n, np.nan)
        self.sq = np.zeros((n, 2))  # sum of |dy|^2 / 2 over the block, accel and gyro
        self.dt = np.zeros(n)  # sum of the sample intervals in the block, s
        self.count = np.zeros(n, int)  # differences in the block
        self.density = self.floor.copy()  # (n, 2) the densities in force

    def add(self, i: np.ndarray, t: float, y: np.ndarray) -> np.ndarray:
        """Samples y (k, 6) [accel m/s^2, gyro rad/s] of vehicles i (k,) at t (s). Returns the
        vehicles (indices) whose block has just closed: their `density` rows are new."""
        i = np.asarray(i, int)
        y = np.asarray(y, float).reshape(len(i), 6)
        if self.average > 1:  # only each vehicle's M-th sample goes on, as the mean of its last M
            self.sum[i] += y
            self.summed[i] += 1
            full = self.summed[i] >= self.average
            i, y = i[full], self.sum[i[full]] / self.average
            self.sum[i], self.summed[i] = 0.0, 0
        seen = np.isfinite(self.t_last[i]) & (t > self.t_last[i])
        k = i[seen]
        d = y[seen] - self.last[k]
        self.sq[k, 0] += 0.5 * (d[:, :3] ** 2).sum(axis=1)
        self.sq[k, 1] += 0.5 * (d[:, 3:] ** 2).sum(axis=1)
        self.dt[k] += t - self.t_last[k]
        self.count[k] += 1
        self.last[i], self.t_last[i] = y, t
        done = k[self.count[k] >= self.window - 1]
        if done.size:
            c = self.count[done][:, None]
            sigma = np.sqrt(self.sq[done] / (3.0 * c))  # eq. A1
            # eq. A2: density of that per-sample sigma, floored at the declared one
            self.density[done] = np.maximum(self.floor[done], sigma * np.sqrt(self.dt[done] / c[:, 0])[:, None])
            self.sq[done], self.dt[done], self.count[done] = 0.0, 0.0, 0
        return done
