"""`ranging.lsq`: the per-epoch least-squares baseline (estimators.range_lsq) as a plugin estimator.

Each epoch (the ranges of one time of validity) is fitted alone, without a motion model: every
body that is not known (no pose on the stream "mocap") and has ranges to known points (anchors,
sites of known bodies at their latest pose) is fitted by scipy least_squares. A body whose
measured lever arms determine an attitude (three or more, not on one line) is a pose (position
and attitude of the body); otherwise each of its measured sites is a point. The fit starts from
the body's previous fit, else (estimators.range_lsq.fresh_fit) from the centroid of the epoch's
known points, at four headings.
Covariance: the Gauss-Newton (J^T J)^-1 with the rows' declared sigmas (range_sigma where none).
A fit with fewer ranges than unknowns, or whose information matrix is singular, is withheld and
counted; so is one that did not converge (it is never a start either). Every converged fit is
solved again from its start mirrored through the known points' plane (estimators.range_lsq.mirror_fit):
the lower-cost minimum is published, flagged with the covariance P + d d^T when the ranges fit both.

health(): epochs, fitted (bodies fitted, summed over epochs), underdetermined, unobservable,
nonconverged (withheld fits), mirror_flagged (fits published with both mirror minima in their
covariance), unknown_end_rows (ranges whose other end is not known).
params: range_sigma (m, 0.1), streams (range streams, ["uwb"]).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.range_lsq import determines_attitude, fit_ranges, fresh_fit, mirror_fit
from estimators.so3 import quat_to_rotmat, rotmat_to_quat
from testbed.config import check_fields, key
from testbed.plugins.api import Context, Estimate, Measurement, MeasurementBatch
from testbed.plugins.params import read


@dataclass(frozen=True, kw_only=True, slots=True)
class LsqParams:
    """Parameters of ranging.lsq ([[estimators]] params)."""

    range_sigma: float = key(0.1, lo=0, lo_open=True, unit="m", doc="sigma of the ranges that declare none")
    streams: tuple[str, ...] = key(("uwb",), doc="the range streams")

    def __post_init__(self) -> None:
        check_fields(self)


class RangeLsq:
    """Per-epoch least-squares fit of each unknown body from its ranges (the baseline)."""

    description = "per-epoch least-squares fit (scipy) of each unknown body from its ranges, no motion model"

    Params = LsqParams

    def __init__(self, context: Context, params: dict):
        self.p = read(LsqParams, params, "ranging.lsq")
        self.vehicles = context.vehicles
        self.sites = {s: (b, np.asarray(a, float)) for s, (b, a) in context.sites.items()}
        self.anchors = {k: np.asarray(v, float) for k, v in context.anchors.items()}
        self.known: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # body -> latest (p, R) from mocap
        self.last: dict[str, tuple[np.ndarray, np.ndarray | None]] = {}  # body -> previous fit
        self.t: float | None = None
        self.rows: list[tuple[str, str, float, float]] = []  # (src, dst, range m, sigma m)
        self.counts = {"epochs": 0, "fitted": 0, "underdetermined": 0, "unobservable": 0, "nonconverged": 0,
                       "mirror_flagged": 0, "unknown_end_rows": 0}

    def process_batch(self, b: MeasurementBatch) -> list[Estimate]:
        if b.stream not in self.p.streams:
            return [e for m in b.rows() for e in self.process(m)]
        out: list[Estimate] = []
        sigma = np.where(b.has_sigma(), b.sigma[:, 0], self.p.range_sigma) if b.sigma is not None else \
            np.full(len(b), self.p.range_sigma)
        times, src, dst, d, s = b.time.tolist(), b.src.tolist(), b.dst.tolist(), b.value[:, 0].tolist(), sigma.tolist()
        cut = [0] + [i for i in range(1, len(times)) if times[i] != times[i - 1]] + [len(times)]
        for lo, hi in zip(cut[:-1], cut[1:]):
            out += self._advance(times[lo])
            self.rows += list(zip(src[lo:hi], dst[lo:hi], d[lo:hi], s[lo:hi]))
        return out

    def process(self, m: Measurement) -> list[Estimate]:
        out = self._advance(m.time)
        if m.stream in self.p.streams and m.dst:
            self.rows.append((m.src, m.dst, float(m.value[0]), float(m.sigma[0]) if m.sigma is not None else self.p.range_sigma))
        elif m.stream == "mocap" and m.src in self.vehicles:
            self.known[m.src] = (np.asarray(m.value[:3], float), quat_to_rotmat(np.asarray(m.value[3:7], float)))
        return out

    def finish(self) -> list[Estimate]:
        return self._advance(None)

    def health(self) -> dict[str, int]:
        return dict(self.counts)

    def _advance(self, t: float | None) -> list[Estimate]:
        out = []
        if self.t is not None and (t is None or t > self.t) and self.rows:
            out = self._solve(self.t)
            self.rows = []
        if t is not None:
            self.t = t
        return out

    def _point(self, name: str) -> np.ndarray | None:
        """World position (3,) m of a known end (an anchor, a site of a known body), else None."""
        if name in self.anchors:
            return self.anchors[name]
        body, arm = self.sites.get(name, (name, np.zeros(3)))
        if body in self.known:
            p, R = self.known[body]
            return p + R @ arm
        return None

    def _solve(self, t: float) -> list[Estimate]:
        self.counts["epochs"] += 1
        per_body: dict[str, list[tuple[str, np.ndarray, np.ndarray, float, float]]] = {}
        for a, b, d, s in self.rows:
            for mine, other in ((a, b), (b, a)):
                body = self.sites[mine][0] if mine in self.sites else (mine if mine in self.vehicles else None)
                if body is None or body in self.known:
                    continue
                X = self._point(other)
                if X is None:
                    self.counts["unknown_end_rows"] += 1
                    continue
                arm = self.sites[mine][1] if mine in self.sites else np.zeros(3)
                per_body.setdefault(body, []).append((mine, arm, X, d, s))
        out = []
        for body, rows in per_body.items():
            names, arms, X, d, s = zip(*rows)
            arms, X, d, s = np.array(arms), np.array(X), np.array(d), np.array(s)
            if determines_attitude(arms):
                out += self._fit(t, body, body, arms, X, d, s, pose=True)
            else:
                for site in dict.fromkeys(names):
                    k = np.array([n == site for n in names])
                    out += self._fit(t, site, site, np.zeros((k.sum(), 3)), X[k], d[k], s[k], pose=False)
        return out

    def _fit(self, t, key, target, arms, X, d, s, *, pose: bool) -> list[Estimate]:
        if d.size < (6 if pose else 3):
            self.counts["underdetermined"] += 1
            return []
        prev = self.last.get(key)
        if prev is None:
            fit = fresh_fit(arms, X, d, s, X.mean(axis=0), np.eye(3) if pose else None)
        else:
            fit = fit_ranges(arms, X, d, s, prev[0], prev[1] if pose else None)
        if not fit.observable:
            self.counts["unobservable"] += 1
            return []
        if not fit.converged:
            self.counts["nonconverged"] += 1
            return []
        fit, flagged = mirror_fit(fit, arms, X, d, s)
        self.counts["fitted"] += 1
        self.counts["mirror_flagged"] += int(flagged)
        self.last[key] = (fit.p, fit.R)
        out = [Estimate(time=t, target=target, quantity="position", value=fit.p, cov=fit.cov[:3, :3])]
        if pose:
            out.append(Estimate(time=t, target=target, quantity="attitude", value=rotmat_to_quat(fit.R), cov=fit.cov[3:, 3:]))
        return out
