"""A per-vehicle UWB anchor-ranging EKF written as a testbed plugin (docs/plugins.md).

Each vehicle's `uwb` tag alone, from its own ranges to the surveyed anchors (no GNSS, no
cooperation, no messages): the baseline a fusion of the vehicles' estimates should beat, e.g. in
the seed 000 reproduction:

    testbed reproduce bandwidth --runs 20 --estimator examples/anchor_ekf.py:AnchorEkf --out D

State per vehicle: [p, v] of its `uwb` site (m, m/s, world ENU), constant velocity with a white
acceleration of PSD q per axis. Start: the linear least-squares fix of the first instant at which
the tag has ranges to at least 4 anchors (|p - a_j|^2 = r_j^2 less the first anchor's equation:
2 (a_j - a_0)^T p = r_0^2 - r_j^2 + |a_j|^2 - |a_0|^2), position covariance sigma^2 (H^T H)^-1 of
that fix scaled by the number of anchors, velocity v0_sigma per axis. Update: one range at a time,
r = |p - a| + noise of the declared sigma (Measurement.sigma). Estimates: every started tag's
position with its (3, 3) covariance, at each instant of its ranges once all rows of that instant
are in. params: AnchorEkfParams (`--param q=0.5`).
"""
from dataclasses import dataclass

import numpy as np

from testbed.config import check_fields, key
from testbed.plugins import Estimate
from testbed.plugins.params import read

MIN_ANCHORS = 4  # a 3-D fix from ranges alone


@dataclass(frozen=True, kw_only=True)
class AnchorEkfParams:
    q: float = key(0.1, lo=0, unit="m^2/s^3", doc="white-acceleration PSD per axis")
    v0_sigma: float = key(1.0, lo=0, lo_open=True, unit="m/s", doc="initial velocity, 1 sigma per axis")

    def __post_init__(self):
        check_fields(self)


class AnchorEkf:
    description = "example: per-vehicle constant-velocity EKF on UWB ranges to anchors (no GNSS, no cooperation)"
    Params = AnchorEkfParams

    def __init__(self, context, params):
        p = read(AnchorEkfParams, params, "AnchorEkf")
        self.q, self.v0 = p.q, p.v0_sigma
        self.anchors = {k: np.asarray(v, float) for k, v in context.anchors.items()}
        self.x, self.P, self.t = {}, {}, {}  # per tag: (6,) state, (6, 6) covariance, time of the state (s)
        self.first = {}  # per tag not yet started: [(anchor (3,), range, sigma)] of its first instant
        self.pending = None  # the instant whose ranges are being processed (s)
        self.touched = set()  # the tags updated at that instant

    def _predict(self, tag, t):
        dt = t - self.t[tag]
        F = np.eye(6)
        F[:3, 3:] = dt * np.eye(3)
        Q = self.q * np.kron([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]], np.eye(3))
        self.x[tag], self.P[tag], self.t[tag] = F @ self.x[tag], F @ self.P[tag] @ F.T + Q, t

    def _start(self, tag):
        rows = self.first[tag]
        if len(rows) < MIN_ANCHORS:
            return
        a = np.array([r[0] for r in rows])
        r = np.array([r[1] for r in rows])
        H = 2.0 * (a[1:] - a[0])
        b = r[0] ** 2 - r[1:] ** 2 + (a[1:] ** 2).sum(1) - (a[0] ** 2).sum()
        if np.linalg.matrix_rank(H) < 3:  # coplanar anchors: wait for a better instant
            self.first[tag] = []
            return
        p = np.linalg.lstsq(H, b, rcond=None)[0]
        sigma = max(r[2] for r in rows)
        self.x[tag] = np.concatenate([p, np.zeros(3)])
        self.P[tag] = np.zeros((6, 6))
        # the fix's own covariance: unit-direction Jacobian of the ranges at p, range sigma
        u = (p - a) / np.linalg.norm(p - a, axis=1, keepdims=True)
        self.P[tag][:3, :3] = sigma**2 * np.linalg.inv(u.T @ u)
        self.P[tag][3:, 3:] = self.v0**2 * np.eye(3)
        self.t[tag] = self.pending
        del self.first[tag]

    def _close(self):
        """The instant self.pending is complete: start the tags that can, report the updated ones."""
        out = []
        for tag in sorted(self.touched):
            if tag in self.first:
                self._start(tag)
            if tag in self.x:
                out.append(Estimate(time=self.pending, target=tag, quantity="position", value=self.x[tag][:3].copy(),
                                    cov=self.P[tag][:3, :3].copy()))
        self.touched = set()
        return out

    def process(self, m):
        if m.stream != "uwb" or m.dst not in self.anchors or m.sigma is None:
            return None
        out = self._close() if self.pending is not None and m.time > self.pending else []
        if self.pending is None or m.time > self.pending:
            self.first = {tag: [] for tag in self.first}  # a start uses the ranges of one instant only
        self.pending = m.time
        tag, a, r, sigma = m.src, self.anchors[m.dst], float(m.value[0]), float(m.sigma[0])
        self.touched.add(tag)
        if tag not in self.x:
            self.first.setdefault(tag, []).append((a, r, sigma))
            return out
        if m.time > self.t[tag]:
            self._predict(tag, m.time)
        d = self.x[tag][:3] - a
        H = np.concatenate([d / np.linalg.norm(d), np.zeros(3)])[None]
        S = float((H @ self.P[tag] @ H.T)[0, 0]) + sigma**2
        K = (self.P[tag] @ H.T)[:, 0] / S
        self.x[tag] = self.x[tag] + K * (r - np.linalg.norm(d))
        self.P[tag] = self.P[tag] - np.outer(K, H @ self.P[tag])
        self.P[tag] = 0.5 * (self.P[tag] + self.P[tag].T)
        return out

    def finish(self):
        return self._close() if self.pending is not None else []
