"""A UWB + GNSS extended Kalman filter written as a testbed plugin (docs/estimators.md).

Shows: the plugin protocol (constructor with the Context, `process` fed one measurement at a time
in order of arrival, `finish`), a filter over all vehicles at once (constant velocity per
vehicle; GNSS position updates; UWB tag-to-tag range updates), and estimates with covariances
that the testbed scores beside the built-ins:

    testbed run coop-fg --estimator examples/uwb_ekf.py:UwbEkf --duration 30 --out D

State: [p_1, v_1, ..., p_N, v_N] of the vehicles' `uwb` sites (m, m/s, world ENU); params:
UwbEkfParams (`--param q=2`).
"""
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from testbed.config import check_fields, key
from testbed.plugins import Estimate
from testbed.plugins.params import read


@dataclass(frozen=True, kw_only=True)
class UwbEkfParams:
    q: float = key(1.0, lo=0, unit="m^2/s^3", doc="white-acceleration PSD per axis")
    v0_sigma: float = key(2.0, lo=0, lo_open=True, unit="m/s", doc="initial velocity, 1 sigma per axis")

    def __post_init__(self):
        check_fields(self)


class UwbEkf:
    description = "example: constant-velocity EKF over all vehicles, GNSS + UWB tag-tag ranges"
    Params = UwbEkfParams

    def __init__(self, context, params):
        self.names = list(context.vehicles)
        self.idx = {f"{v}/uwb": i for i, v in enumerate(self.names)}
        n = 6 * len(self.names)
        self.x, self.P = np.zeros(n), np.eye(n) * 1e6
        p = read(UwbEkfParams, params, "UwbEkf")
        self.q, self.v0 = p.q, p.v0_sigma
        self.t, self.started = None, set()

    def _predict(self, t):
        dt = t - self.t
        for i in range(len(self.names)):
            s = slice(6 * i, 6 * i + 6)
            F = np.eye(6)
            F[:3, 3:] = dt * np.eye(3)
            Q = self.q * np.kron([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]], np.eye(3))
            self.x[s] = F @ self.x[s]
            self.P[s, :] = F @ self.P[s, :]
            self.P[:, s] = self.P[:, s] @ F.T
            self.P[s, s] += Q

    def _update(self, r, H, sigma):
        S = cho_factor(H @ self.P @ H.T + np.diag(sigma**2))
        K = cho_solve(S, H @ self.P).T  # P H^T S^-1 (P and S symmetric)
        self.x += K @ r
        self.P -= K @ H @ self.P
        self.P = 0.5 * (self.P + self.P.T)

    def _estimates(self):
        return [Estimate(time=self.t, target=f"{v}/uwb", quantity="position", value=self.x[6 * i:6 * i + 3].copy(),
                         cov=self.P[6 * i:6 * i + 3, 6 * i:6 * i + 3].copy())
                for i, v in enumerate(self.names) if i in self.started]

    def process(self, m):
        out = []
        if self.t is not None and m.time > self.t:
            out = self._estimates()  # the epoch at self.t is complete: report it, then predict
            self._predict(m.time)
        self.t = m.time
        i = self.idx.get(m.src)
        if m.stream == "gnss" and i is not None:
            s = slice(6 * i, 6 * i + 3)
            if i not in self.started:  # first fix: initialize position and velocity
                self.started.add(i)
                self.x[s], self.x[6 * i + 3:6 * i + 6] = m.value, 0.0
                self.P[6 * i:6 * i + 6, :] = self.P[:, 6 * i:6 * i + 6] = 0.0
                self.P[s, s] = np.diag(m.sigma**2)
                self.P[6 * i + 3:6 * i + 6, 6 * i + 3:6 * i + 6] = self.v0**2 * np.eye(3)
                return out
            H = np.zeros((3, self.x.size))
            H[:, s] = np.eye(3)
            self._update(m.value - self.x[s], H, m.sigma)
        elif m.stream == "uwb" and i is not None and self.idx.get(m.dst) in self.started and i in self.started:
            j = self.idx[m.dst]
            d = self.x[6 * i:6 * i + 3] - self.x[6 * j:6 * j + 3]
            u = d / np.linalg.norm(d)
            H = np.zeros((1, self.x.size))
            H[0, 6 * i:6 * i + 3], H[0, 6 * j:6 * j + 3] = u, -u
            self._update(m.value - np.linalg.norm(d), H, m.sigma)
        return out

    def finish(self):
        return self._estimates() if self.t is not None else []
