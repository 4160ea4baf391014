"""Checking and collecting the estimates one estimator returns.

An estimate must be an `Estimate` of a known target (a vehicle body or one of its sites), a
known quantity, frame "world" or a vehicle body (the same for every estimate of one target and
quantity), a finite time within the run, a finite value of the right shape
(attitude: a unit quaternion to 1e-6, renormalized) and, if given, a finite symmetric positive
definite (3, 3) covariance. Anything else is a PluginError naming the estimator, when and what.
Every check but the covariance's is made as the estimate arrives; the covariances (the costly
check, tens of microseconds per estimate one at a time) are checked together, all at once, when
the track is built (`Collector.track`, at the end of the run), and the first bad one in arrival
order is reported with the same message, naming when it was returned.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from testbed.errors import PluginError
from testbed.plugins.api import VALUE_SIZE, Estimate
from testbed.plugins.loading import Plugin


@dataclass(frozen=True, slots=True)
class Series:
    """The estimates of one (target, quantity), sorted by time: time (K,) s, value (K, d),
    cov (K, 3, 3) with NaN where an estimate had none, has_cov (K,) bool; frame: "world" or the
    vehicle body the values are relative to (Estimate.frame)."""

    time: np.ndarray
    value: np.ndarray
    cov: np.ndarray
    has_cov: np.ndarray
    frame: str = "world"


# {(target, quantity): Series}
Track = dict[tuple[str, str], Series]


class Collector:
    """Validates estimates as they come and builds the Track at the end."""

    def __init__(self, plugin: Plugin, targets: set[str], duration: float, frames: set[str] = frozenset({"world"})):
        self.plugin, self.targets, self.duration, self.frames = plugin, targets, duration, frames
        self._rows: dict[tuple[str, str], list[tuple[float, np.ndarray, np.ndarray | None]]] = {}
        self._frame: dict[tuple[str, str], str] = {}
        # per (target, quantity): (arrival number, where) of each estimate with a covariance
        self._covs: dict[tuple[str, str], list[tuple[int, str]]] = {}
        self._seq = 0

    def _fail(self, where: str, e: object, reason: str) -> PluginError:
        what = f"{e[0]} {e[1]}" if isinstance(e, tuple) else f"{e.target} {e.quantity}" if isinstance(e, Estimate) else type(e).__name__
        return PluginError(f"estimator {self.plugin.key!r} ({self.plugin.entry}) {where}: estimate of {what}: {reason}")

    def add(self, estimates: list, where: str) -> None:
        for e in estimates:
            self._add(e, where)

    def _add(self, e: object, where: str) -> None:
        if not isinstance(e, Estimate):
            raise self._fail(where, e, "not a testbed.plugins.Estimate")
        if e.quantity not in VALUE_SIZE:
            raise self._fail(where, e, f"quantity must be one of {list(VALUE_SIZE)}")
        if e.target not in self.targets:
            raise self._fail(where, e, "unknown target (a vehicle such as 'uav1' or a site such as 'uav1/uwb')")
        if e.frame not in self.frames:
            raise self._fail(where, e, f"frame {e.frame!r} is not scored ('world' or a vehicle such as 'uav1')")
        if e.frame == e.target:
            raise self._fail(where, e, f"a target relative to itself (frame {e.frame!r})")
        if self._frame.setdefault((e.target, e.quantity), e.frame) != e.frame:
            raise self._fail(where, e, f"frame {e.frame!r} after {self._frame[(e.target, e.quantity)]!r}: one frame per target and quantity")
        t = float(e.time)
        if not np.isfinite(t) or not -1e-9 <= t <= self.duration + 1e-9:
            raise self._fail(where, e, f"time {t} s is outside the run [0, {self.duration:g}] s")
        value = np.asarray(e.value, dtype=float)
        d = VALUE_SIZE[e.quantity]
        if value.shape != (d,):
            raise self._fail(where, e, f"value has shape {value.shape}, expected ({d},)")
        if not all(map(math.isfinite, value.tolist())):  # plain floats: this runs per estimate
            raise self._fail(where, e, f"value is not finite: {value.tolist()}")
        if e.quantity == "attitude":
            norm = float(np.linalg.norm(value))
            if abs(norm - 1.0) > 1e-6:
                raise self._fail(where, e, f"quaternion norm {norm:.9g} is not 1")
            value = value / norm
        cov = None
        if e.cov is not None:
            cov = np.asarray(e.cov, dtype=float)
            if cov.shape != (3, 3):
                raise self._fail(where, e, f"cov has shape {cov.shape}, expected (3, 3)")
            self._covs.setdefault((e.target, e.quantity), []).append((self._seq, where))
        self._seq += 1
        self._rows.setdefault((e.target, e.quantity), []).append((t, value, cov))

    def _check_covs(self) -> None:
        """The covariance check of every estimate (module docstring): the first bad one in
        arrival order raises."""
        first = None
        for key, rows in self._rows.items():
            checks = self._covs.get(key)
            if not checks:
                continue
            reasons = cov_problems(np.stack([c for _, _, c in rows if c is not None]))
            bad = [k for k, r in enumerate(reasons) if r is not None]
            if bad and (first is None or checks[bad[0]][0] < first[0]):
                first = (checks[bad[0]][0], checks[bad[0]][1], key, reasons[bad[0]])
        if first is not None:
            raise self._fail(first[1], first[2], first[3])

    def track(self) -> Track:
        self._check_covs()
        out = {}
        for key, rows in sorted(self._rows.items(), key=lambda kv: natural(kv[0][0]) + [kv[0][1]]):
            order = sorted(range(len(rows)), key=lambda i: rows[i][0])  # stable: ties keep arrival order
            time = np.array([rows[i][0] for i in order])
            value = np.stack([rows[i][1] for i in order])
            has = np.array([rows[i][2] is not None for i in order])
            cov = np.stack([rows[i][2] if rows[i][2] is not None else np.full((3, 3), np.nan) for i in order])
            out[key] = Series(time, value, cov, has, self._frame[key])
        return out


SINGULAR = 1e-14  # relative Cholesky pivot below which a covariance is singular to double precision


def cov_problems(C: np.ndarray) -> list[str | None]:
    """Why each of K (3, 3) covariances C (K, 3, 3) is not finite, symmetric (to 1e-9 relative, as
    numpy.allclose(c, c.T, rtol=1e-9, atol=1e-12 max(1, max |c|))) and positive definite with a
    condition a NEES can be computed at (Cholesky pivots of the symmetric part > SINGULAR times its
    largest diagonal entry); None where it is. All at once (numpy over K)."""
    C = np.asarray(C, float).reshape(-1, 3, 3)
    finite = np.isfinite(C).all(axis=(1, 2))
    c = np.where(finite[:, None, None], C, 1.0)
    ct = np.swapaxes(c, 1, 2)
    atol = 1e-12 * np.maximum(1.0, np.abs(c).max(axis=(1, 2)))
    symmetric = ~(np.abs(c - ct) > atol[:, None, None] + 1e-9 * np.abs(ct)).any(axis=(1, 2))
    a, b, d = c[:, 0, 0], 0.5 * (c[:, 0, 1] + c[:, 1, 0]), 0.5 * (c[:, 0, 2] + c[:, 2, 0])
    e, f, g = c[:, 1, 1], 0.5 * (c[:, 1, 2] + c[:, 2, 1]), c[:, 2, 2]
    # Cholesky of [[a, b, d], [b, e, f], [d, f, g]]: pivots a, e - b^2/a, g - d^2/a - (f - b d/a)^2 / p2
    with np.errstate(divide="ignore", invalid="ignore"):
        p2 = e - b * b / a
        h = f - b * d / a
        p3 = g - d * d / a - h * h / p2
    pd = (a > 0.0) & (p2 > 0.0) & (p3 > 0.0)
    singular = np.minimum(np.minimum(a, p2), p3) <= SINGULAR * np.maximum(np.maximum(a, e), g)
    out: list[str | None] = [None] * len(C)
    for k in np.flatnonzero(~finite | ~symmetric | ~pd | singular).tolist():
        out[k] = ("cov is not finite" if not finite[k] else "cov is not symmetric" if not symmetric[k]
                  else "cov is not positive definite" if not pd[k]
                  else f"cov is numerically singular (a Cholesky pivot below {SINGULAR:g} of the largest variance)")
    return out


def cov_problem(c) -> str | None:
    """cov_problems of one (3, 3) covariance c (array or nested lists)."""
    return cov_problems(np.asarray(c, float)[None])[0]



def natural(name: str) -> list:
    """Sort key putting uav2 before uav10."""
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", name)]
