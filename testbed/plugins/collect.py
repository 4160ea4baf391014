"""Checking and collecting the estimates one estimator returns.

An estimate must be an `Estimate` of a known target (a vehicle body or one of its sites), a
known quantity, frame "world" or a vehicle body (the same for every estimate of one target and
quantity), a finite time within the run, a finite value of the right shape
(attitude: a unit quaternion to 1e-6, renormalized) and, if given, a finite symmetric positive
definite (3, 3) covariance. Anything else is a PluginError naming the estimator, when and what.
Every check but the covariance's is made as the estimate arrives; the covariances (the costly
check, tens of microseconds per estimate one at a time) are checked together, all at once, when
the track is built (`Collector.track`, at the end of the run), and the first bad one in arrival
order is reported with the same message, naming when it was returned. An `EstimateBatch` gets
the same checks on all its rows at once, the first bad row named.
"""
from __future__ import annotations

import math
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from testbed.errors import PluginError, RunError
from testbed.plugins.api import VALUE_SIZE, Estimate, EstimateBatch
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


@dataclass(frozen=True, slots=True)
class Joint:
    """A joint covariance of several estimates at one time (EstimateBatch.cov_joint): time s,
    targets (n,) in the order of cov's blocks (their quantities: its key in Track.joint), frame,
    cov (3n, 3n)."""

    time: float
    targets: tuple[str, ...]
    frame: str
    cov: np.ndarray


class Track(dict):
    """{(target, quantity): Series}; `joint` {quantity: [Joint, ...] in arrival order}, the joint
    covariances an estimator gave, keyed by the batch's quantity, or by the tuple of its rows'
    quantities (n,) for a batch of several (empty for most; not kept in estimates.npz);
    `navigation` the estimator's NavigationStates (testbed.plugins.api) when it exposes them
    (navigation_states()), else None (not kept in estimates.npz)."""

    def __init__(self, *args, joint: dict | None = None, navigation=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.joint = joint or {}
        self.navigation = navigation


class Collector:
    """Validates estimates as they come and builds the Track at the end. An EstimateBatch is
    checked and kept as columns (no object per row); its rows are the estimates it stands for."""

    def __init__(self, plugin: Plugin, targets: set[str], duration: float, frames: set[str] = frozenset({"world"})):
        self.plugin, self.targets, self.duration, self.frames = plugin, targets, duration, frames
        # per (target, quantity): single estimates (time, value, cov or None, arrival number, call)
        self._rows: dict[tuple[str, str], list[tuple[float, np.ndarray, np.ndarray | None, int, int]]] = {}
        # batches: (quantity, targets (k-tuple), time (k,), value (k, d), cov (k, 3, 3) or None, first arrival number, call)
        self._batches: list[tuple[str, tuple, np.ndarray, np.ndarray, np.ndarray | None, int, int]] = []
        self._frame: dict[tuple[str, str], str] = {}
        self._checked: set[tuple] = set()  # (targets, quantity, frame) of batches whose keys were checked
        self._calls: list[str] = []  # `where` of each add() call
        self._joint: dict[str, list[Joint]] = {}
        self._seq = 0

    def _fail(self, where: str, e: object, reason: str, time: float | None = None) -> PluginError:
        what = (f"estimate of {e[0]} {e[1]}" if isinstance(e, tuple) else f"estimate of {e.target} {e.quantity}" if isinstance(e, Estimate)
                else f"estimates of {'/'.join(dict.fromkeys(e.quantities()))} (a batch of {len(e)})" if isinstance(e, EstimateBatch) else f"estimate of {type(e).__name__}")
        return PluginError(f"estimator {self.plugin.key!r} ({self.plugin.entry}) {where}: {what}: {reason}", time)

    def add(self, estimates: list, where: str) -> None:
        self._calls.append(where)
        for e in estimates:
            if isinstance(e, EstimateBatch):
                self._add_batch(e, where)
            else:
                self._add(e, where)

    def _check_key(self, where: str, e: object, target: str, quantity: str, frame: str) -> None:
        """Target, quantity and frame of an estimate (or of a batch's rows of one target)."""
        if quantity not in VALUE_SIZE:
            raise self._fail(where, e, f"quantity must be one of {list(VALUE_SIZE)}")
        if target not in self.targets:
            raise self._fail(where, e, "unknown target (a vehicle such as 'uav1' or a site such as 'uav1/uwb')")
        if frame not in self.frames:
            raise self._fail(where, e, f"frame {frame!r} is not scored ('world' or a vehicle such as 'uav1')")
        if frame == target:
            raise self._fail(where, e, f"a target relative to itself (frame {frame!r})")
        if self._frame.setdefault((target, quantity), frame) != frame:
            raise self._fail(where, e, f"frame {frame!r} after {self._frame[(target, quantity)]!r}: one frame per target and quantity")

    def _add(self, e: object, where: str) -> None:
        if not isinstance(e, Estimate):
            raise self._fail(where, e, "not a testbed.plugins.Estimate")
        self._check_key(where, e, e.target, e.quantity, e.frame)
        t = float(e.time)
        if not math.isfinite(t) or not -1e-9 <= t <= self.duration + 1e-9:
            raise self._fail(where, e, f"time {t} s is outside the run [0, {self.duration:g}] s")
        value = np.asarray(e.value, dtype=float)
        d = VALUE_SIZE[e.quantity]
        if value.shape != (d,):
            raise self._fail(where, e, f"value has shape {value.shape}, expected ({d},)")
        if not all(map(math.isfinite, value.tolist())):  # plain floats: this runs per estimate
            raise self._fail(where, e, f"value is not finite: {value.tolist()}")
        if e.quantity == "attitude":
            norm = float(quaternion_norm(value))
            if abs(norm - 1.0) > 1e-6:
                raise self._fail(where, e, f"quaternion norm {norm:.9g} is not 1")
            value = value / norm
        cov = None
        if e.cov is not None:
            cov = np.asarray(e.cov, dtype=float)
            if cov.shape != (3, 3):
                raise self._fail(where, e, f"cov has shape {cov.shape}, expected (3, 3)")
        self._rows.setdefault((e.target, e.quantity), []).append((t, value, cov, self._seq, len(self._calls) - 1))
        self._seq += 1

    def _add_batch(self, b: EstimateBatch, where: str) -> None:
        """The checks of _add on every row of b at once; the first bad row is named. A batch of
        several quantities: each quantity's rows as one batch, then its cov_joint."""
        if not isinstance(b.quantity, str):
            qs = b.quantities()
            if len(qs) != len(b) or not all(q in VALUE_SIZE for q in qs):
                raise self._fail(where, b, f"quantity must be one of {list(VALUE_SIZE)} or a sequence of them, one per target")
            if len(b.value) != len(b):
                raise self._fail(where, b, f"value has {len(b.value)} rows, expected {len(b)} for {len(b)} targets")
            for part in b.parts():
                self._add_batch(part, where)
            if b.cov_joint is not None:
                cov = None if b.cov is None else np.asarray(b.cov, dtype=float)
                self._add_joint(b, where, tuple(b.target), np.asarray(b.time, dtype=float), cov)
            return
        if b.quantity not in VALUE_SIZE:
            raise self._fail(where, b, f"quantity must be one of {list(VALUE_SIZE)}")
        signature = (tuple(b.target), b.quantity, b.frame)
        if signature not in self._checked:  # an estimator gives the same targets again and again
            for name in dict.fromkeys(signature[0]):
                self._check_key(where, (name, b.quantity), name, b.quantity, b.frame)
            self._checked.add(signature)
        target = signature[0]
        k, d = len(target), VALUE_SIZE[b.quantity]
        t = np.asarray(b.time, dtype=float)
        value = np.asarray(b.value, dtype=float)
        cov = None if b.cov is None else np.asarray(b.cov, dtype=float)
        for what, a, shape in (("time", t, (k,)), ("value", value, (k, d)), ("cov", cov, (k, 3, 3))):
            if a is not None and a.shape != shape:
                raise self._fail(where, b, f"{what} has shape {a.shape}, expected {shape} for {k} targets")
        if k and not -1e-9 <= t.min() <= t.max() <= self.duration + 1e-9:  # NaN fails too
            late = np.flatnonzero(~((t >= -1e-9) & (t <= self.duration + 1e-9)))[0]
            raise self._fail(where, (target[late], b.quantity), f"time {t[late]} s is outside the run [0, {self.duration:g}] s")
        if not np.isfinite(value).all():
            bad = np.flatnonzero(~np.isfinite(value).all(axis=1))[0]
            raise self._fail(where, (target[bad], b.quantity), f"value is not finite: {value[bad].tolist()}")
        if b.quantity == "attitude":
            norm = quaternion_norm(value)
            if np.abs(norm - 1.0).max(initial=0.0) > 1e-6:
                bad = np.flatnonzero(np.abs(norm - 1.0) > 1e-6)[0]
                raise self._fail(where, (target[bad], b.quantity), f"quaternion norm {norm[bad]:.9g} is not 1")
            value = value / norm[:, None]
        if b.cov_joint is not None:
            self._add_joint(b, where, target, t, cov)
        self._batches.append((b.quantity, target, t, value, cov, self._seq, len(self._calls) - 1))
        self._seq += k

    def _add_joint(self, b: EstimateBatch, where: str, target: tuple, t: np.ndarray, cov: np.ndarray | None) -> None:
        """Check a batch's cov_joint (EstimateBatch) and keep it."""
        k = len(target)
        C = np.asarray(b.cov_joint, dtype=float)
        reason = (f"has shape {C.shape}, expected {(3 * k, 3 * k)} for {k} targets" if C.shape != (3 * k, 3 * k)
                  else "needs rows of one time of validity" if k and np.ptp(t) > 0
                  else "is not finite" if not np.isfinite(C).all()
                  else "is not symmetric" if not np.allclose(C, C.T, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(C).max(initial=0.0)))
                  else "needs cov, its (3, 3) diagonal blocks" if cov is None
                  else "does not have cov as its (3, 3) diagonal blocks"
                  if not np.allclose(np.stack([C[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(k)]).reshape(cov.shape), cov,
                                     rtol=1e-9, atol=1e-12 * max(1.0, np.abs(C).max(initial=0.0)))
                  else None)
        if reason is not None:
            raise self._fail(where, b, f"cov_joint {reason}")
        if k:
            key = b.quantity if isinstance(b.quantity, str) else b.quantities()
            self._joint.setdefault(key, []).append(Joint(float(t[0]), target, b.frame, C))

    def _series(self) -> dict[tuple[str, str], list[tuple[np.ndarray, ...]]]:
        """Per (target, quantity), its estimates in parts: time (K,), value (K, d), cov (K, 3, 3)
        (NaN where none), has_cov (K,), arrival number (K,), add() call (K,)."""
        out: dict[tuple[str, str], list[tuple[np.ndarray, ...]]] = {}
        for key, rows in self._rows.items():
            out[key] = [(np.array([r[0] for r in rows]), np.stack([r[1] for r in rows]),
                         np.stack([r[2] if r[2] is not None else NAN33 for r in rows]),
                         np.array([r[2] is not None for r in rows]), np.array([r[3] for r in rows]),
                         np.array([r[4] for r in rows]))]
        for q in sorted({b[0] for b in self._batches}):
            bs = [b for b in self._batches if b[0] == q]
            target = np.array([name for b in bs for name in b[1]], dtype=str)
            t, value = (np.concatenate([b[k] for b in bs]) for k in (2, 3))
            cov = np.concatenate([b[4] if b[4] is not None else np.broadcast_to(NAN33, (len(b[1]), 3, 3)) for b in bs])
            has = np.concatenate([np.full(len(b[1]), b[4] is not None) for b in bs])
            seq = np.concatenate([b[5] + np.arange(len(b[1])) for b in bs])
            call = np.concatenate([np.full(len(b[1]), b[6]) for b in bs])
            for name in np.unique(target).tolist():
                m = target == name
                out.setdefault((name, q), []).append((t[m], value[m], cov[m], has[m], seq[m], call[m]))
        return out

    def track(self) -> Track:
        """The Track, every covariance checked first (module docstring: the first bad one in
        arrival order raises)."""
        series = {key: [np.concatenate(c) for c in zip(*parts)] for key, parts in self._series().items()}
        first = None
        for key, (time, _, cov, has, seq, call) in series.items():
            idx = np.flatnonzero(has)
            reasons = cov_problems(cov[idx]) if idx.size else []
            bad = [k for k, r in enumerate(reasons) if r is not None]
            if bad:
                k = min(bad, key=lambda k: seq[idx[k]])
                if first is None or seq[idx[k]] < first[0]:
                    first = (seq[idx[k]], self._calls[call[idx[k]]], key, reasons[k], float(time[idx[k]]))
        if first is not None:  # its time: the bad estimate's
            raise self._fail(*first[1:])
        out = {}
        for key in sorted(series, key=lambda kq: natural(kq[0]) + [kq[1]]):
            time, value, cov, has, seq, _ = series[key]
            order = np.lexsort((seq, time))  # by time; ties keep arrival order
            out[key] = Series(time[order], value[order], cov[order], has[order], self._frame[key])
        return Track(out, joint=self._joint)


NAN33 = np.full((3, 3), np.nan)
ESTIMATES_FILE = "estimates.npz"  # a run's or a replay's plugin estimates (track_arrays)


def track_arrays(key: str, track: Track) -> dict[str, np.ndarray]:
    """The arrays of estimates.npz (a run's or a replay's) for estimator `key`:
    `KEY/TARGET/QUANTITY/time` (K,) s, `.../value` (K, d), `.../cov` (K, 3, 3) NaN where an
    estimate had none, and `.../frame` (the vehicle the values are relative to) unless "world"."""
    out = {}
    for (target, q), s in track.items():
        out[f"{key}/{target}/{q}/time"] = s.time
        out[f"{key}/{target}/{q}/value"] = s.value
        out[f"{key}/{target}/{q}/cov"] = s.cov
        if s.frame != "world":
            out[f"{key}/{target}/{q}/frame"] = np.array(s.frame)
    return out


def load_tracks(path: Path) -> dict[str, Track]:
    """{estimator key: Track} of an estimates.npz (read_tracks); {} when the file is absent;
    RunError naming the file when it is there but unreadable."""
    path = Path(path)
    if not path.is_file():
        return {}
    try:
        with np.load(path, allow_pickle=False) as z:
            return read_tracks({k: z[k] for k in z.files})
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        raise RunError(f"{path}: not readable as a run's estimates ({type(e).__name__}: "
                       f"{' '.join(str(e).split())[:200]})") from None


def read_tracks(arrays) -> dict[str, Track]:
    """{estimator key: Track} from the arrays of an estimates.npz (a mapping, as numpy.load
    gives): the inverse of track_arrays; other keys (`KEY/diagnostics/NAME`) are left out."""
    out: dict[str, Track] = {}
    for name in arrays:
        key, _, rest = name.partition("/")
        target, _, q = rest.rpartition("/")[0].rpartition("/")
        if not name.endswith("/time") or q not in VALUE_SIZE:
            continue
        stem = name[: -len("/time")]
        cov = arrays[f"{stem}/cov"]
        frame = str(arrays[f"{stem}/frame"]) if f"{stem}/frame" in arrays else "world"
        out.setdefault(key, {})[(target, q)] = Series(arrays[name], arrays[f"{stem}/value"], cov,
                                                      ~np.isnan(cov).any(axis=(1, 2)), frame)
    return out


def quaternion_norm(q: np.ndarray) -> np.ndarray:
    """|q| of quaternions q (..., 4), summed in one fixed order: one estimate and a batch's rows
    give the same bits."""
    return np.sqrt(((q[..., 0] * q[..., 0] + q[..., 1] * q[..., 1]) + q[..., 2] * q[..., 2]) + q[..., 3] * q[..., 3])
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
