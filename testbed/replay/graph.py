"""`graph.poses`: a per-epoch centralized factor graph over multi-antenna robots, as a plugin estimator.

Each epoch (the measurements of one time of validity, or of one bin of `epoch` seconds) is one
factor graph (estimators.graph.batch, the factors of estimators.graph.model): a robot measured at
two or more distinct lever arms is a pose (position m world, attitude body-to-world), a robot
measured at one site only is a point at that site; anchors (Context.anchors) and robots whose pose
is known at the epoch (stream "mocap") are fixed. Factors: ranges of streams "uwb" (and "phase" with
use_phase) between any two sites with their lever arms, GNSS fixes (stream "gnss", a position prior
on the antenna with the fix's sigma), heights (stream "height", the up coordinate of a site or body).
Robust loss on the ranges (params loss, loss_scale). Epochs are buffered and solved `batch` at a
time (Levenberg-Marquardt, all epochs at once); each starts from its GNSS fix where it has one,
else from a constant-velocity and body-rate fit to the robot's estimates of the last
`motion_window` seconds (warm start, estimators.graph.warmstart) -- never predicted more than
`horizon` seconds past the robot's last estimate: a batch is solved in consecutive parts, each
within the horizon of the estimates of the part before --, else from a fresh start (a
least-squares fit of the robot alone to its ranges to fixed points, estimators.range_lsq.fresh_fit,
from params `initial` or the fixed points' centroid), else from `initial`, else near the epoch's
fixed points. An epoch that does not converge from its warm start is solved again from a fresh
start (a recovery, counted when it then converges); one that still does not converge is flagged
when its two iterates agree (AGREE_LEVEL: the lower-cost one published, its covariance inflated
by their difference, never a warm start, counted), else withheld: no estimate, never a warm start,
counted. Estimates: a pose robot's position and attitude (body), a point robot's site
position, with the marginal covariances; an epoch that is unobservable (gauge freedom) gives no
estimate. Counted in health(): epochs, nonconverged_epochs (withheld), flagged_epochs, recoveries, fresh_starts
(epochs solved from a fresh start at once: no estimate within the horizon), unobservable_epochs,
late_measurements (older than the epoch being collected), unused_measurements, lm_iterations (linear
solves, summed over the epochs solved) and lm_iterations_max (of one epoch); per epoch, in
diagnostics(): time, iterations, final cost, converged, observable, flagged.

The variable kind of each robot is decided from the sites measured in the first batch of epochs.

Range bias (bias_states = true; docs/replay.md, "Range bias"): one bias unknown b per link (a
range stream and its two ends), r = |e_a - e_b| + b, a random constant, with a Gaussian belief
over every link seen: a link joins it with mean 0 and sigma its calibrated bias_sigma
(Context.sensors["uwb"]), else params bias_sigma, else its first range's sigma. Each epoch of a
solve gets the belief's marginal over its part's links as a prior (estimators.graph.batch); after
the part, the likelihood each converged, unflagged epoch gave the biases (its posterior over the
prior, in information form) is added to the belief. bias_estimates() gives it. With the motion
model, the biases are states of its belief instead (estimators.graph.motion: random constants,
each epoch's solve over its robots' poses and its links' biases with their joint prediction as
prior, mo. 3 over both).

Motion model (q_translation set; docs/replay.md, "graph.poses with a motion model"): the epochs
are solved one at a time in time order, each over the started robots it names with the prediction
of a joint constant-velocity belief (estimators.graph.motion) as a prior on their poses (the state
prior of estimators.graph.batch), and the belief updated from its posterior (mo. 1-3); the range
sigmas grown for correlated errors (range_correlation, cal. 8); a robot starts from its epochs of
the last init_window s, solved alone with a level prior (level_sigma) for a pose, when its ranges
determine its position and heading (waiting_epochs before). No warm start, batch or recovery: the
prediction is the start; a solve that does not converge is withheld (nonconverged_epochs). A pose
robot whose measured lever arms lie on one line gets no attitude estimate, in either mode.
A link with a time offset c (Context.sensors["uwb"]["time_offset"], docs/calibration.md cal. 10:
its range at t is the distance at t + c) has its range corrected by the prediction's range rate,
r - c rdot, before the epoch's solve (mo. 4).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Literal
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from scipy.stats import chi2

from estimators.graph.batch import EpochFactors, EpochsResult, solve_epochs
from estimators.graph.motion import POSE_DIMS, MotionBelief
from estimators.graph.warmstart import MotionFit, fit_motion
from estimators.graph.losses import Loss
from estimators.range_lsq import determines_attitude, fresh_fit
from estimators.range_start import grown_sigma
from estimators.sensor_models import correlated_sigma
from estimators.so3 import quat_to_rotmat, rotmat_to_quat, so3_log
from testbed.config import check_fields, key, require
from testbed.plugins.api import Context, Estimate, Measurement, MeasurementBatch
from testbed.plugins.params import read

# An epoch that converged from neither its warm start nor its fresh start is published (flagged)
# when the two final iterates x_w, x_f are one solution by a chi-square test at this level:
# (x_w - x_f)^T P^-1 (x_w - x_f) <= chi2_k(AGREE_LEVEL), k its unknowns, P the covariance of the
# lower-cost iterate; what is published is that iterate with covariance P + (x_w - x_f)(x_w - x_f)^T.
AGREE_LEVEL = 0.999
#: m^2, rad^2: the variance a robot's pose joins the motion model's belief with before the start's
#: solve updates it (bias_states; its cross-covariances are zero, so mo. 3's gain ignores it: any
#: value gives the same update)
UNINFORMED = 1e6


@dataclass(frozen=True, kw_only=True, slots=True)
class GraphParams:
    """Parameters of graph.poses ([[estimators]] params).

    An epoch has converged when a step is below step_tol, or an accepted step lowers the cost by
    less than cost_tol or is shorter than step_sigma standard deviations of the estimate
    (sqrt(delta^T N delta); 0: off). The warm start fits a constant velocity and body rate to the
    robot's estimates of the last motion_window seconds (0: the last estimate, held) and never
    predicts further than horizon past the robot's last estimate (the rule of the default, 2 s:
    twice the default motion_window, a line is never extrapolated further than twice the span it
    was fitted on).
    """

    epoch: float = key(0.0, lo=0, unit="s", doc="width of the bins grouping measurements into an epoch (0: one per time of validity)")
    batch: int = key(16, lo=1, hi=100_000, doc="epochs solved together")
    range_sigma: float = key(0.1, lo=0, lo_open=True, unit="m", doc="sigma of the ranges that declare none")
    height_sigma: float = key(0.1, lo=0, lo_open=True, unit="m", doc="sigma of the heights that declare none")
    use_phase: bool = key(False, doc="phase links are ranges too")
    loss: Literal["none", "huber", "cauchy"] = key("none", doc="robust loss of the ranges")
    loss_scale: float = key(1.345, lo=0, lo_open=True, unit="sigma", doc="scale of the robust loss")
    max_iter: int = key(50, lo=1, hi=10_000, doc="Levenberg-Marquardt iterations per epoch")
    step_tol: float = key(1e-6, lo=0, lo_open=True, unit="m, rad", doc="converged when a step is below it")
    cost_tol: float = key(1e-9, lo=0, lo_open=True, doc="converged when a step lowers the cost by less, relative")
    step_sigma: float = key(1e-3, lo=0, unit="sigma", doc="converged when a step is shorter, in standard deviations (0: off)")
    motion_window: float = key(1.0, lo=0, unit="s", doc="span of estimates the warm start fits (0: the last, held)")
    horizon: float = key(2.0, lo=0, unit="s", doc="the warm start never predicts further past the last estimate")
    initial: dict = key(factory=dict, unit="m", range="{body: [x, y, z] or [x, y, z, qw, qx, qy, qz]}",
                        doc="starting pose of robots without a fix or an estimate, world, quaternion body-to-world")
    bias_states: bool = key(False, doc="a range-bias unknown per link (docs/replay.md, Range bias)")
    bias_sigma: float | None = key(None, lo=0, lo_open=True, unit="m",
                                   doc="prior sigma of a link's bias without a calibrated one (none: the link's range sigma)")
    q_translation: float | None = key(None, lo=0, unit="m^2/s^3",
                                      doc="white acceleration of a robot between epochs (none: no motion model, each epoch alone)")
    q_rotation: float = key(1e-2, lo=0, unit="rad^2/s^3", doc="white angular acceleration of a pose robot between epochs (with q_translation)")
    v_sigma: float = key(1.0, lo=0, lo_open=True, unit="m/s", doc="a robot's velocity at its first estimate, 1 sigma per axis (with q_translation)")
    rate_sigma: float = key(1.0, lo=0, lo_open=True, unit="rad/s", doc="a pose robot's body rate at its first estimate, 1 sigma per axis (with q_translation)")
    level_sigma: float = key(math.pi / 4, lo=0, lo_open=True, unit="rad",
                             doc="a pose robot's tilt at its first estimate, 1 sigma per axis (with q_translation)")
    init_window: float = key(2.0, lo=0, unit="s", doc="span of the ranges that start a robot together (with q_translation)")
    range_correlation: float = key(0.0, lo=0, unit="s",
                                   doc="correlation time of the range errors (with q_translation; docs/calibration.md, cal. 8)")

    def __post_init__(self) -> None:
        check_fields(self)
        for body, p in self.initial.items():
            require(isinstance(p, list) and len(p) in (3, 7) and all(isinstance(x, (int, float)) and np.isfinite(x) for x in p),
                    f"initial.{body}", p, "expected [x, y, z] (m, world) or [x, y, z, qw, qx, qy, qz]")
            require(len(p) == 3 or abs(float(np.linalg.norm(p[3:])) - 1.0) < 1e-6, f"initial.{body}", p,
                    "the quaternion wxyz must have unit norm")


@dataclass
class _Epoch:
    """The measurements of one epoch (times in s; names are sites or bodies); the ranges as
    columns: src, dst names, d m, sigma m, time s (each range's own: `times` holds every row's)."""

    times: list = field(default_factory=list)
    r_src: list = field(default_factory=list)
    r_dst: list = field(default_factory=list)
    r_d: list = field(default_factory=list)
    r_sigma: list = field(default_factory=list)
    r_stream: list = field(default_factory=list)
    r_time: list = field(default_factory=list)
    fixes: list = field(default_factory=list)    # (name, z (3,) m, sigma (3,) m)
    heights: list = field(default_factory=list)  # (name, z m, sigma m)
    mocap: dict = field(default_factory=dict)    # body -> (p (3,), R (3, 3))


class PoseGraph:
    """Per-epoch centralized factor graph over multi-antenna robots, anchors and known robots."""

    description = "per-epoch factor graph: multi-antenna robot poses, lever arms, anchors, known robots, GNSS, height"

    Params = GraphParams

    def __init__(self, context: Context, params: dict):
        self.p = read(GraphParams, params, "graph.poses")
        unknown = sorted(set(self.p.initial) - set(context.vehicles))
        if unknown:
            raise ValueError(f"params initial names unknown bodies {unknown}")
        self.vehicles = context.vehicles
        self.sites = {s: (b, np.asarray(a, float)) for s, (b, a) in context.sites.items()}
        self.anchors = {k: np.asarray(v, float) for k, v in context.anchors.items()}
        self.ranging = ("uwb", "phase") if self.p.use_phase else ("uwb",)
        self.loss = {"range": Loss(kind=self.p.loss, scale=self.p.loss_scale)}
        self.kind: dict[str, tuple[str, str | None]] | None = None  # body -> ("pose", None) | ("point", site)
        self.on_line: set[str] = set()  # pose robots whose measured lever arms lie on one line: no attitude published
        self.history: dict[str, list[tuple[float, np.ndarray, np.ndarray]]] = {}  # body -> recent (t, p, R)
        self.key = None
        self.current: _Epoch | None = None
        self.pending: list[_Epoch] = []
        self.counts = {"epochs": 0, "nonconverged_epochs": 0, "flagged_epochs": 0, "recoveries": 0, "fresh_starts": 0, "unobservable_epochs": 0,
                       "late_measurements": 0,
                       "unused_measurements": 0, "lm_iterations": 0, "lm_iterations_max": 0}
        self.per_epoch: dict[str, list[np.ndarray]] = {k: [] for k in ("time", "iterations", "cost", "converged", "observable", "flagged")}
        # range biases (bias_states): {(stream, end, end) sorted ends: index}, their belief N(mean, cov) m, m^2,
        # the prior sigma of a calibrated link {src: {dst: m}} (testbed.replay.calibration)
        self.bias_index: dict[tuple[str, str, str], int] = {}
        self.bias_mean, self.bias_cov = np.zeros(0), np.zeros((0, 0))
        self.calibrated = (context.sensors.get("uwb") or {}).get("bias_sigma") or {}
        # each link's time offset {src: {dst: s}} (cal. 10), applied with the motion model only
        self.offsets = (context.sensors.get("uwb") or {}).get("time_offset") or {}
        # the motion model (q_translation): the joint belief of the started robots, the epochs of each
        # robot not started yet (its last init_window s), each link's last range time (cal. 8)
        self.belief = None if self.p.q_translation is None else MotionBelief(self.p.q_translation, self.p.q_rotation)
        self.pool: dict[str, list[_Epoch]] = {}
        if self.belief is not None:
            self.counts["waiting_epochs"] = 0
        self.last_range: dict[tuple[str, str, str], float] = {}

    # ---------------------------------------------------------------- collecting
    def _bin(self, t: float):
        return t if self.p.epoch == 0 else math.floor(t / self.p.epoch + 1e-9)

    def _advance(self, key, out: list) -> bool:
        """Move to the epoch of bin `key` (a full batch of epochs is solved into out); False if the
        key is older than the current epoch's (a late measurement)."""
        if self.key is not None and key < self.key:
            return False
        if self.key is None or key > self.key:
            if self.current is not None:
                self.pending.append(self.current)
                if len(self.pending) >= self.p.batch and self._kinds_known():
                    out += self._solve()
            self.key, self.current = key, _Epoch()
        return True

    def process_batch(self, b: MeasurementBatch) -> list[Estimate]:
        """As process() on each row of b, with the ranges of an epoch taken as columns."""
        out: list[Estimate] = []
        if b.stream not in self.ranging:
            for m in b.rows():
                out += self.process(m)
            return out
        times = b.time.tolist()
        keys = times if self.p.epoch == 0 else np.floor(b.time / self.p.epoch + 1e-9).astype(np.int64).tolist()
        cut = [0] + [i for i in range(1, len(keys)) if keys[i] != keys[i - 1]] + [len(keys)]
        linked = b.dst != ""
        sigma = np.where(b.has_sigma(), b.sigma[:, 0], self.p.range_sigma) if b.sigma is not None else \
            np.full(len(b), self.p.range_sigma)
        for lo, hi in zip(cut[:-1], cut[1:]):
            if not self._advance(keys[lo], out):
                self.counts["late_measurements"] += hi - lo
                continue
            ep = self.current
            ep.times += times[lo:hi]
            use = linked[lo:hi]
            self.counts["unused_measurements"] += int((~use).sum())
            ep.r_src += b.src[lo:hi][use].tolist()
            ep.r_dst += b.dst[lo:hi][use].tolist()
            ep.r_d += b.value[lo:hi, 0][use].tolist()
            ep.r_sigma += sigma[lo:hi][use].tolist()
            ep.r_stream += [b.stream] * int(use.sum())
            ep.r_time += b.time[lo:hi][use].tolist()
        return out

    def process(self, m: Measurement) -> list[Estimate]:
        out: list[Estimate] = []
        if not self._advance(self._bin(m.time), out):
            self.counts["late_measurements"] += 1
            return out
        ep = self.current
        ep.times.append(m.time)
        if m.stream in self.ranging and m.dst:
            ep.r_src.append(m.src)
            ep.r_dst.append(m.dst)
            ep.r_d.append(float(m.value[0]))
            ep.r_sigma.append(float(m.sigma[0]) if m.sigma is not None else self.p.range_sigma)
            ep.r_stream.append(m.stream)
            ep.r_time.append(m.time)
        elif m.stream == "gnss":
            sigma = np.asarray(m.sigma, float) if m.sigma is not None else None
            if sigma is None:
                self.counts["unused_measurements"] += 1
            else:
                ep.fixes.append((m.src, np.asarray(m.value, float), sigma))
        elif m.stream == "height":
            ep.heights.append((m.src, float(m.value[0]), float(m.sigma[0]) if m.sigma is not None else self.p.height_sigma))
        elif m.stream == "mocap" and m.src in self.vehicles:
            ep.mocap[m.src] = (np.asarray(m.value[:3], float), quat_to_rotmat(np.asarray(m.value[3:], float)))
        else:
            self.counts["unused_measurements"] += 1
        return out

    def finish(self) -> list[Estimate]:
        if self.current is not None:
            self.pending.append(self.current)
            self.current = None
        return self._solve() if self.pending else []

    def health(self) -> dict[str, int]:
        return dict(self.counts)

    def diagnostics(self) -> dict[str, np.ndarray]:
        """Per solved epoch, in time order: time s, iterations (linear solves), cost (final robust
        cost, whitened), converged, observable and flagged (published without converging; 1 or 0)."""
        cols = {k: np.concatenate(v) if v else np.zeros(0) for k, v in self.per_epoch.items()}
        order = np.argsort(cols["time"], kind="stable")
        return {k: v[order] for k, v in cols.items()}

    # ---------------------------------------------------------------- variables
    def _arm(self, name: str) -> tuple[str | None, np.ndarray]:
        """(body, lever arm) of a site or body name; (None, world point) for an anchor; (None, None) otherwise."""
        if name in self.sites:
            return self.sites[name]
        if name in self.vehicles:
            return name, np.zeros(3)
        return None, self.anchors.get(name)

    def _decide_kinds(self) -> None:
        arms: dict[str, dict[tuple, str]] = {v: {} for v in self.vehicles}
        for ep in self.pending:
            names = [n for pair in zip(ep.r_src, ep.r_dst) for n in pair] + [f[0] for f in ep.fixes] + [h[0] for h in ep.heights]
            for n in dict.fromkeys(names):
                body, arm = self._arm(n)
                if body is not None:
                    arms[body].setdefault(tuple(np.round(arm, 9)), n)
        self.kind = {}
        for v, seen in arms.items():
            if len(seen) >= 2:
                self.kind[v] = ("pose", None)
                if not determines_attitude(np.array(list(seen))):
                    self.on_line.add(v)
            elif len(seen) == 1:
                self.kind[v] = ("point", next(iter(seen.values())))

    # ---------------------------------------------------------------- solving
    def _end(self, name: str, ep: _Epoch, free: dict):
        """(var index or -1, arm or world point) of a factor end; None if it cannot be used."""
        body, arm = self._arm(name)
        if body is None:
            return None if arm is None else (-1, arm)
        if body in ep.mocap:
            p, R = ep.mocap[body]
            return -1, p + R @ arm
        if body not in free:
            return None
        kind, site = self.kind[body]
        if kind == "point":  # only the site it stands for (or another name for the same point)
            return (free[body], np.zeros(3)) if np.allclose(arm, self._arm(site)[1]) else None
        return free[body], arm

    def _motion(self, body: str) -> MotionFit | None:
        """The warm-start model of a robot from its recent estimates, or None before its first."""
        h = self.history.get(body)
        if not h:
            return None
        return fit_motion(np.array([x[0] for x in h]), np.stack([x[1] for x in h])[:, None],
                          np.stack([x[2] for x in h])[:, None])

    def _remember(self, body: str, t: float, p: np.ndarray, R: np.ndarray) -> None:
        """Add an estimate to the robot's history, keeping those of the last motion_window s."""
        h = self.history.setdefault(body, [])
        if h and h[-1][0] >= t:
            return
        h.append((t, p, R))
        while h[0][0] < t - self.p.motion_window - 1e-9:
            h.pop(0)

    def _initial(self, body: str, ep: _Epoch, guess: tuple | None, fixed_points: list, index: int) -> tuple[np.ndarray, np.ndarray, str]:
        """Starting (p, R) of a robot at an epoch and how it was found: "fix", "warm" (the guess),
        "fresh" (a fit to its ranges to fixed points), "initial" or "centre" (near the fixed points)."""
        init = self.p.initial.get(body)
        R = guess[1] if guess is not None else (quat_to_rotmat(np.array(init[3:], float)) if init and len(init) == 7 else np.eye(3))
        kind, site = self.kind[body]
        for name, z, _ in ep.fixes:
            b, arm = self._arm(name)
            if b == body:
                return (z - R @ arm if kind == "pose" else z.copy()), R, "fix"
        if guess is not None:
            return guess[0], R, "warm"
        fresh = self._fresh(body, ep, None if not init else np.array(init[:3], float), R)
        if fresh is not None:
            return fresh[0], fresh[1], "fresh"
        if init:
            return np.array(init[:3], float), R, "initial"
        centre = np.mean(fixed_points, axis=0) if fixed_points else np.zeros(3)
        return centre + np.array([1.0 + index, 0.5 * index, 0.0]), R, "centre"

    def _fresh(self, body: str, ep: _Epoch, p0: np.ndarray | None, R0: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """A fresh start of a robot: the least-squares fit of it alone to the epoch's ranges between
        its sites and fixed points (estimators.range_lsq.fresh_fit, from p0, else the fixed points'
        centroid lifted to the robot's measured height when it has one -- the side of a plane of
        fixed points --, and R0 at four headings); None when those ranges do not determine it or the fit
        fails. A pose robot whose measured lever arms do not determine an attitude gets none."""
        kind, site = self.kind[body]
        rows = []
        for a, b, d, sigma in zip(ep.r_src, ep.r_dst, ep.r_d, ep.r_sigma):
            for mine, other in ((a, b), (b, a)):
                owner, arm = self._arm(mine)
                end = self._end(other, ep, {}) if owner == body else None  # {}: only fixed ends
                if end is None or (kind == "point" and not np.allclose(arm, self._arm(site)[1])):
                    continue
                rows.append((arm if kind == "pose" else np.zeros(3), end[1], d, sigma))
        if not rows:
            return None
        arms, X, d, sigma = (np.array(c) for c in zip(*rows))
        pose = kind == "pose"
        if len(d) < (6 if pose else 3) or (pose and not determines_attitude(arms)):
            return None
        if p0 is None:
            p0 = X.mean(axis=0)
            for name, z, _ in ep.heights:
                owner, arm = self._arm(name)
                if owner == body:
                    p0[2] = z - (R0 @ arm)[2] if pose else z
        fit = fresh_fit(arms, X, d, sigma, p0, R0 if pose else None)
        if not (fit.converged and fit.observable):
            return None
        return fit.p, (fit.R if pose else R0)

    def _factors(self, ep: _Epoch, free: dict, e: int, rows: dict, ends: dict) -> None:
        """Append the factors of epoch e to rows; ranges as indices into ends ({"var": [], "arm": []}:
        the distinct factor ends of the group, one per name and epoch; -1: unusable)."""
        index = {}
        for name in set(ep.r_src) | set(ep.r_dst):
            x = self._end(name, ep, free)
            index[name] = -1 if x is None else len(ends["var"])
            if x is not None:
                ends["var"].append(x[0])
                ends["arm"].append(x[1])
        rows["r_e"].append(np.full(len(ep.r_d), e, np.int64))
        rows["r_a"].append([index[n] for n in ep.r_src])
        rows["r_b"].append([index[n] for n in ep.r_dst])
        rows["r_d"].append(ep.r_d)
        rows["r_sigma"].append(ep.r_sigma)
        if self.p.bias_states:
            rows["r_key"] += [_link(stream, a, b) for stream, a, b in zip(ep.r_stream, ep.r_src, ep.r_dst)]
        for name, z, sigma in ep.fixes:
            end = self._end(name, ep, free)
            if end is None or end[0] < 0:
                self.counts["unused_measurements"] += 1
                continue
            rows["q"].append((e, end[0], end[1], z, np.diag(sigma ** 2)))
        for name, z, sigma in ep.heights:
            end = self._end(name, ep, free)
            if end is None or end[0] < 0:
                self.counts["unused_measurements"] += 1
                continue
            rows["h"].append((e, end[0], end[1], z, sigma))

    def _range_rows(self, rows: dict, ends: dict) -> dict:
        """The usable range rows as arrays (a range needs two ends, not both fixed, not one variable)."""
        var = np.array(ends["var"] + [-2], np.int64)  # index -1 (unusable) reads -2
        arm = np.concatenate([np.reshape(ends["arm"], (-1, 3)), np.zeros((1, 3))])
        ia, ib = (np.concatenate([np.asarray(x, np.int64) for x in rows[k]]) for k in ("r_a", "r_b"))
        va, vb = var[ia], var[ib]
        ok = (va != -2) & (vb != -2) & (va != vb)
        self.counts["unused_measurements"] += int((~ok).sum())
        if self.p.bias_states:
            rows["r_key"] = [k for k, use in zip(rows["r_key"], ok) if use]
        return {"r_epoch": np.concatenate(rows["r_e"])[ok], "r_a": va[ok], "r_b": vb[ok], "r_arm_a": arm[ia[ok]],
                "r_arm_b": arm[ib[ok]], "r_d": np.concatenate([np.asarray(x, float) for x in rows["r_d"]])[ok],
                "r_sigma": np.concatenate([np.asarray(x, float) for x in rows["r_sigma"]])[ok]}

    def _present(self, ep: _Epoch) -> tuple[str, ...]:
        """Robots with a variable at this epoch: decided, not known by mocap, named by a measurement."""
        names = set(ep.r_src) | set(ep.r_dst) | {f[0] for f in ep.fixes} | {h[0] for h in ep.heights}
        bodies = {self._arm(n)[0] for n in names} - {None} - set(ep.mocap)
        return tuple(v for v in self.vehicles if v in bodies and v in self.kind)

    def _kinds_known(self) -> bool:
        """Whether the pending epochs decide the robots' kinds: always, but with the motion model
        (sparse ranging names a few sites an epoch), only once they span init_window."""
        if self.kind is not None or self.belief is None:
            return True
        return self.pending[-1].times[-1] - self.pending[0].times[0] >= self.p.init_window

    def _solve(self) -> list[Estimate]:
        if self.kind is None:
            self._decide_kinds()
        if self.belief is not None:
            eps, self.pending = self.pending, []
            return [est for ep in eps for est in self._filter(ep)]
        groups: dict[tuple, list[_Epoch]] = {}
        for ep in self.pending:
            groups.setdefault(self._present(ep), []).append(ep)
        self.pending = []
        out = []
        for present, eps in groups.items():
            self.counts["epochs"] += len(eps)
            if present:
                out += self._solve_group(present, eps)
            else:
                self.counts["unobservable_epochs"] += len(eps)
        return sorted(out, key=lambda est: est.time)

    def _solve_group(self, present: tuple[str, ...], eps: list[_Epoch]) -> list[Estimate]:
        """Solve the epochs of one set of present robots in consecutive parts, each no further than
        `horizon` past every present robot's last estimate (at least one epoch per part)."""
        times = np.array([np.mean(ep.times) for ep in eps])
        out, i = [], 0
        while i < len(eps):
            last = min((self.history[v][-1][0] if self.history.get(v) else -math.inf) for v in present)
            j = i + 1
            while j < len(eps) and times[j] <= last + self.p.horizon + 1e-9:
                j += 1
            out += self._solve_part(present, eps[i:j], times[i:j])
            i = j
        return out

    def _starts(self, present: tuple[str, ...], eps: list[_Epoch], times: np.ndarray, warm: bool,
                only: np.ndarray | None = None) -> tuple:
        """Starting p0 (E, V, 3), R0 (E, V, 3, 3) and how each was found (E, V) (see _initial);
        warm: use the warm start where it is within the horizon; only: (E,) bool, the epochs to
        start (the others are left at the origin, how None)."""
        E, V = len(eps), len(present)
        fits = {v: fit for v in present if warm and (fit := self._motion(v)) is not None}
        guesses = {v: fit.predict(times) for v, fit in fits.items()}
        p0, R0, how = np.zeros((E, V, 3)), np.tile(np.eye(3), (E, V, 1, 1)), np.empty((E, V), object)
        for e, ep in enumerate(eps):
            if only is not None and not only[e]:
                continue
            fixed = [self.anchors[n] for pair in zip(ep.r_src, ep.r_dst) for n in pair if n in self.anchors] + \
                [p for p, _ in ep.mocap.values()]
            for i, v in enumerate(present):
                near = v in guesses and times[e] - fits[v].t_last <= self.p.horizon + 1e-9
                guess = (guesses[v][0][e, 0], guesses[v][1][e, 0]) if near else None
                p0[e, i], R0[e, i], how[e, i] = self._initial(v, eps[e], guess, fixed, i)
        return p0, R0, how

    def _solve_part(self, present: tuple[str, ...], eps: list[_Epoch], times: np.ndarray) -> list[Estimate]:
        free = {v: i for i, v in enumerate(present)}
        kinds = tuple(self.kind[v][0] for v in present)
        rows: dict[str, list] = {"r_e": [], "r_a": [], "r_b": [], "r_d": [], "r_sigma": [], "r_key": [], "q": [], "h": []}
        ends: dict[str, list] = {"var": [], "arm": []}
        for e, ep in enumerate(eps):
            self._factors(ep, free, e, rows, ends)
        f = _factor_arrays(kinds, self._range_rows(rows, ends), rows)
        sel = None
        if self.p.bias_states:
            f, sel = self._with_biases(f, rows["r_key"])
        solve = lambda p0, R0: solve_epochs(f, p0, R0, losses=self.loss, max_iter=self.p.max_iter,  # noqa: E731
                                            step_tol=self.p.step_tol, step_sigma=self.p.step_sigma, cost_tol=self.p.cost_tol)
        p0, R0, how = self._starts(present, eps, times, warm=True)
        self.counts["fresh_starts"] += int((how == "fresh").any(axis=1).sum())
        res = solve(p0, R0)
        iterations = res.iterations.copy()
        retry = ~res.converged & res.observable & (how == "warm").any(axis=1)
        flagged = np.zeros(len(eps), bool)
        if retry.any():  # a recovery: the epochs that failed from their warm start, again from fresh starts
            p1, R1, _ = self._starts(present, eps, times, warm=False, only=retry)
            p1[~retry], R1[~retry] = res.p[~retry], res.R[~retry]  # the others restart at their solution
            again = solve(p1, R1)
            self.counts["recoveries"] += int((retry & again.converged).sum())
            iterations += np.where(retry, again.iterations, 0)
            pick = lambda a, b: np.where(retry.reshape((-1,) + (1,) * (a.ndim - 1)), b, a)  # noqa: E731
            first = res
            res = dataclasses.replace(res, **{k: pick(getattr(res, k), getattr(again, k))
                                              for k in ("p", "R", "cov", "cost", "converged", "observable", "b")
                                              if getattr(res, k) is not None})
            flagged, res = _flag(kinds, first, res, retry)
        ok = (res.converged | flagged) & res.observable
        self.counts["nonconverged_epochs"] += int((~res.converged & ~flagged & res.observable).sum())
        self.counts["flagged_epochs"] += int(flagged.sum())
        self.counts["unobservable_epochs"] += int((~res.observable).sum())
        self._record(times, res, iterations, flagged)
        out = []
        if sel is not None:
            self._fuse_biases(sel, res, res.converged & res.observable & ~flagged)
        for e in np.flatnonzero(ok):  # a non-converged epoch is flagged or withheld, and never a warm start
            t = float(times[e])
            for v, i in free.items():
                if not flagged[e]:
                    self._remember(v, t, res.p[e, i], res.R[e, i])
            out += self._publish(t, tuple(free), res, e)
        return out

    def _publish(self, t: float, names: tuple[str, ...], res: EpochsResult, e: int) -> list[Estimate]:
        """The estimates of epoch e of res at time t: a pose robot's position and attitude, a point
        robot's site position, with their marginal covariances. A pose robot whose measured lever
        arms lie on one line gets no attitude: no range measures its rotation about that line, and
        its covariance there is only what a prior and the linearization left (a level prior and the
        motion model), not a measurement."""
        out = []
        for i, v in enumerate(names):
            o = res.offsets[i]
            kind, site = self.kind[v]
            p, R, cov = res.p[e, i], res.R[e, i], res.cov[e]
            out.append(Estimate(time=t, target=site if kind == "point" else v, quantity="position", value=p,
                                cov=_sym(cov[o:o + 3, o:o + 3])))
            if kind == "pose" and v not in self.on_line:
                out.append(Estimate(time=t, target=v, quantity="attitude", value=rotmat_to_quat(R),
                                    cov=_sym(cov[o + 3:o + 6, o + 3:o + 6])))
        return out

    def _record(self, times: np.ndarray, res: EpochsResult, iterations: np.ndarray, flagged: np.ndarray) -> None:
        """Count a solve's iterations and keep its per-epoch diagnostics."""
        self.counts["lm_iterations"] += int(iterations.sum())
        self.counts["lm_iterations_max"] = max(self.counts["lm_iterations_max"], int(iterations.max(initial=0)))
        for k, v in (("time", times), ("iterations", iterations), ("cost", res.cost), ("converged", res.converged),
                     ("observable", res.observable), ("flagged", flagged)):
            self.per_epoch[k].append(np.asarray(v, float))

    # ---------------------------------------------------------------- the motion model
    def _filter(self, ep: _Epoch) -> list[Estimate]:
        """One epoch with the motion model (q_translation; docs/replay.md, "graph.poses with a
        motion model"): the robots it names that have started are solved together with the belief's
        prediction as their prior (estimators.graph.motion, mo. 1-3); each other one it names tries
        to start from its epochs of the last init_window seconds."""
        t = float(np.mean(ep.times))
        self.counts["epochs"] += 1
        present = self._present(ep)
        if not present:
            self.counts["unobservable_epochs"] += 1
            return []
        if self.p.bias_states:
            self._join_biases(ep)
        ep = self._decorrelated(ep)
        tracked = tuple(v for v in present if v in self.belief)
        out = self._track(tracked, ep, t) if tracked else []
        for v in present:
            if v not in self.belief:
                out += self._start(v, ep, t)
        return out

    def _decorrelated(self, ep: _Epoch) -> _Epoch:
        """ep with each range's sigma grown for its link's errors correlated in time over
        range_correlation s (docs/calibration.md, cal. 8; estimators.sensor_models.correlated_sigma)."""
        if self.p.range_correlation <= 0:
            return ep
        sigma = []
        for stream, a, b, s, t in zip(ep.r_stream, ep.r_src, ep.r_dst, ep.r_sigma, ep.r_time):
            link = _link(stream, a, b)
            last = self.last_range.get(link)
            self.last_range[link] = t
            sigma.append(correlated_sigma(s, self.p.range_correlation, None if last is None else t - last))
        return dataclasses.replace(ep, r_sigma=sigma)

    def _track(self, names: tuple[str, ...], ep: _Epoch, t: float) -> list[Estimate]:
        """Solve epoch ep (time t) over the started robots `names` with the belief's prediction to t
        as their prior; a converged, observable solve updates the belief (mo. 3) and is published,
        another is withheld (nonconverged_epochs), the belief left at its prediction."""
        free = {v: i for i, v in enumerate(names)}
        rows: dict[str, list] = {"r_e": [], "r_a": [], "r_b": [], "r_d": [], "r_sigma": [], "r_key": [], "q": [], "h": []}
        ends: dict[str, list] = {"var": [], "arm": []}
        if self.offsets:
            self.belief.predict(t)
            ep = self._timed(ep)
        self._factors(ep, free, 0, rows, ends)
        ranges = self._range_rows(rows, ends)
        if not (ranges["r_d"].size or rows["q"] or rows["h"]):
            return []
        self.belief.predict(t)
        links = tuple(dict.fromkeys(rows["r_key"]))  # the epoch's links, in order (bias_states; else none)
        p0, R0, cov0 = self.belief.prior(names, links)
        biased = {}
        if links:
            b0 = self.belief.biases(links)
            at = {k: i for i, k in enumerate(links)}
            biased = {"r_bias": np.array([at[k] for k in rows["r_key"]], np.int64), "b_mean": b0, "x_b": b0[None]}
        f = _factor_arrays(tuple(self.kind[v][0] for v in names), ranges, rows, x_p=p0[None], x_R=R0[None],
                           x_info=np.linalg.inv(cov0)[None], **biased)
        res = self._solve_one(f, p0, R0)
        ok = bool(res.converged[0] and res.observable[0])
        self.counts["nonconverged_epochs"] += int(not ok)
        self._record(np.array([t]), res, res.iterations, np.zeros(1))
        if not ok:
            return []
        self.belief.update(names, res.p[0], res.R[0], res.cov[0], links, None if res.b is None else res.b[0])
        return self._publish(t, names, res, 0)

    def _bias_sigma0(self, a: str, b: str, sigma: float) -> float:
        """The prior sigma (m) of link a-b's bias: its calibrated bias_sigma, else params
        bias_sigma, else sigma, its first range's (before cal. 8's growth)."""
        return self.calibrated.get(a, {}).get(b) or self.p.bias_sigma or float(sigma)

    def _join_biases(self, ep: _Epoch) -> None:
        """Add to the motion model's belief a bias state for each link of ep's ranges it does not
        hold yet: mean 0, sigma its calibrated bias_sigma, else params bias_sigma, else its first
        range's sigma (before cal. 8's growth), a random constant."""
        for stream, a, b, sigma in zip(ep.r_stream, ep.r_src, ep.r_dst, ep.r_sigma):
            link = _link(stream, a, b)
            if link not in self.belief.bias_at:
                self.belief.add_bias(link, self._bias_sigma0(a, b, sigma))

    def _timed(self, ep: _Epoch) -> _Epoch:
        """ep with each uwb range of a link with a time offset c (s) corrected by the prediction's
        range rate (mo. 4, docs/replay.md; docs/calibration.md cal. 10), the belief predicted to ep:

            r <- r - c rdot,   rdot = u^T (v_a - v_b),   sigma^2 <- sigma^2 + c^2 u^T (C_a + C_b) u

        u the unit vector from end b to end a at the prediction; an end's velocity v (m/s world) is
        its robot's predicted v + R (w x l) (a site at lever arm l; C the robot's velocity
        covariance), zero for an anchor or a robot known by motion capture (C = 0)."""
        d, sigma = list(ep.r_d), list(ep.r_sigma)
        for i, (a, b, stream) in enumerate(zip(ep.r_src, ep.r_dst, ep.r_stream)):
            c = self.offsets.get(a, {}).get(b, 0.0) if stream == "uwb" else 0.0
            if c == 0.0:
                continue
            (ea, va, ca), (eb, vb, cb) = self._end_motion(a, ep), self._end_motion(b, ep)
            u = (ea - eb) / max(float(np.linalg.norm(ea - eb)), 1e-9)
            # mo. 4
            d[i] -= c * float(u @ (va - vb))
            sigma[i] = math.sqrt(sigma[i] ** 2 + c * c * float(u @ (ca + cb) @ u))
        return dataclasses.replace(ep, r_d=d, r_sigma=sigma)

    def _end_motion(self, name: str, ep: _Epoch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position m, velocity m/s, velocity covariance (3, 3)) of a range end at the belief's
        prediction: a tracked robot's site, else a fixed point at rest."""
        body, arm = self._arm(name)
        b = self.belief
        rest = np.zeros(3), np.zeros((3, 3))
        if body is None:  # an anchor (None: an unknown name, whose range _range_rows drops)
            return (np.zeros(3) if arm is None else arm), *rest
        if body in ep.mocap:
            return ep.mocap[body][0] + ep.mocap[body][1] @ arm, *rest
        if body not in b:  # a robot not started: its ranges are dropped by _range_rows
            return np.zeros(3), *rest
        R = b.R[body]
        if self.kind[body][0] == "point":
            arm = np.zeros(3)
        i = b.start[body] + POSE_DIMS[b.kinds[body]]
        return b.p[body] + R @ arm, b.v[body] + R @ np.cross(b.w[body], arm), b.cov[i:i + 3, i:i + 3]

    def _solve_one(self, f: EpochFactors, p0: np.ndarray, R0: np.ndarray) -> EpochsResult:
        """One epoch's solve from p0 (V, 3), R0 (V, 3, 3) with the params' loss and stopping rules."""
        return solve_epochs(f, p0[None], R0[None], losses=self.loss, max_iter=self.p.max_iter, step_tol=self.p.step_tol,
                            step_sigma=self.p.step_sigma, cost_tol=self.p.cost_tol)

    def _start(self, v: str, ep: _Epoch, t: float) -> list[Estimate]:
        """Try to start robot v at epoch ep (time t) from its epochs of the last init_window s, each
        range, height and fix taken as one at t with its sigma grown by the motion since (the robot
        moves at v ~ N(0, v_sigma^2 I)); a pose robot with the prior that it is level within
        level_sigma (its position and heading uninformed: the ranges must determine them). On a
        converged, observable solve the robot joins the belief and its first estimate is published;
        else the epoch waits (waiting_epochs)."""
        pool = [e for e in self.pool.get(v, []) if e.times[-1] >= t - self.p.init_window - 1e-9] + [ep]
        self.pool[v] = pool
        rows: dict[str, list] = {"r_e": [], "r_a": [], "r_b": [], "r_d": [], "r_sigma": [], "r_key": [], "q": [], "h": []}
        ends: dict[str, list] = {"var": [], "arm": []}
        unused = self.counts["unused_measurements"]
        grown = [_grown(e, self.p.v_sigma, t - float(np.mean(e.times))) for e in pool]
        for e in grown:
            self._factors(e, {v: 0}, 0, rows, ends)
        ranges = self._range_rows(rows, ends)
        self.counts["unused_measurements"] = unused  # a waiting epoch's rows are counted once it is tracked
        kind = self.kind[v][0]
        if ranges["r_d"].size + len(rows["h"]) + 3 * len(rows["q"]) < (6 if kind == "pose" else 3):
            self.counts["waiting_epochs"] += 1
            return []
        merged = _Epoch(times=[t], mocap=ep.mocap, **{k: [x for e in grown for x in getattr(e, k)]
                                                     for k in ("r_src", "r_dst", "r_d", "r_sigma", "r_stream", "r_time", "fixes", "heights")})
        fixed = [self.anchors[n] for n in set(merged.r_src) | set(merged.r_dst) if n in self.anchors] + [p for p, _ in ep.mocap.values()]
        p0, R0, _ = self._initial(v, merged, None, fixed, 0)
        prior = {}
        info = np.zeros((POSE_DIMS[kind], POSE_DIMS[kind]))
        if kind == "pose":  # level within level_sigma: information on the tilt (body x, y at a level R0) only
            R0 = _heading(R0)
            info = np.diag([0.0] * 3 + [self.p.level_sigma ** -2] * 2 + [0.0])
            prior = {"x_p": p0[None, None], "x_R": R0[None, None], "x_info": info[None]}
        links = tuple(dict.fromkeys(rows["r_key"]))  # bias_states: the start's links, their biases solved too
        if links:
            cbb, b0 = self.belief.bias_cov(links), self.belief.biases(links)
            at = {k: i for i, k in enumerate(links)}
            prior = {"x_p": p0[None, None], "x_R": R0[None, None], "x_info": scipy.linalg.block_diag(info, np.linalg.inv(cbb))[None],
                     "r_bias": np.array([at[k] for k in rows["r_key"]], np.int64), "b_mean": b0, "x_b": b0[None]}
        f = _factor_arrays((kind,), ranges, rows, **prior)
        res = self._solve_one(f, p0[None], R0[None])
        iterations = res.iterations
        if kind == "pose" and res.converged[0] and res.observable[0]:
            # again with the level prior about the solution's own heading: about another heading, the
            # tilt of Log(R0^T R) would mix with the heading difference
            f = dataclasses.replace(f, x_p=res.p, x_R=_heading(res.R[0, 0])[None, None])
            res = self._solve_one(f, res.p[0], res.R[0])
            iterations = iterations + res.iterations
        ok = bool(res.converged[0] and res.observable[0])
        self._record(np.array([t]), res, iterations, np.zeros(1))
        if not ok:
            self.counts["waiting_epochs"] += 1
            return []
        self.pool.pop(v)
        if not links:
            self.belief.add(v, kind, t, res.p[0, 0], res.R[0, 0], res.cov[0], self.p.v_sigma, self.p.rate_sigma)
        else:  # joins uninformed and independent, then the start's solve updates it with its links' biases (mo. 3)
            k = POSE_DIMS[kind]
            self.belief.add(v, kind, t, res.p[0, 0], res.R[0, 0], UNINFORMED * np.eye(k), self.p.v_sigma, self.p.rate_sigma)
            self.belief.update((v,), res.p[0], res.R[0], res.cov[0], links, res.b[0])
        return self._publish(t, (v,), res, 0)


    # ---------------------------------------------------------------- range biases
    def _with_biases(self, f: EpochFactors, keys: list[tuple[str, str, str]]) -> tuple[EpochFactors, np.ndarray]:
        """f with a bias unknown for each link of its ranges (docs/replay.md, "Range bias"): a link seen
        the first time joins the belief with mean 0 and sigma its calibrated bias_sigma, else params
        bias_sigma, else its first range's sigma; the prior of every epoch of f is the belief's
        marginal over f's links. Returns f and those links' indices (B,) in the belief."""
        for link, sigma in zip(keys, f.r_sigma):
            if link not in self.bias_index:
                _, a, b = link
                s0 = self._bias_sigma0(a, b, sigma)
                self.bias_index[link] = len(self.bias_index)
                n = self.bias_mean.size
                self.bias_mean = np.append(self.bias_mean, 0.0)
                cov = np.zeros((n + 1, n + 1))
                cov[:n, :n], cov[n, n] = self.bias_cov, s0 ** 2
                self.bias_cov = cov
        glob = np.array([self.bias_index[k] for k in keys], np.int64)
        sel, local = np.unique(glob, return_inverse=True)
        return dataclasses.replace(f, r_bias=local.astype(np.int64), b_mean=self.bias_mean[sel],
                                   b_cov=self.bias_cov[np.ix_(sel, sel)]), sel

    def _fuse_biases(self, sel: np.ndarray, res: EpochsResult, use: np.ndarray) -> None:
        """The belief over the biases after the epochs `use` (E,) of res, each solved from the same
        prior N(m0, C0) of the links sel: epochs share nothing but the biases, so each one's
        likelihood of them is its posterior over the prior, information Lambda_e - Lambda_0 and
        Lambda_e b_e - Lambda_0 m0 (Lambda = C^-1; exact for a linear model), and they add up."""
        if not use.any() or sel.size == 0:
            return
        kv = res.cov.shape[1] - sel.size
        L0 = np.linalg.inv(self.bias_cov[np.ix_(sel, sel)])
        eta0 = L0 @ self.bias_mean[sel]
        Le = np.linalg.inv(res.cov[use][:, kv:, kv:])
        info = (Le - L0).sum(axis=0)
        vec = (np.einsum("eij,ej->ei", Le, res.b[use]) - eta0).sum(axis=0)
        Lam = np.linalg.inv(self.bias_cov)
        eta = Lam @ self.bias_mean
        Lam[np.ix_(sel, sel)] += info
        eta[sel] += vec
        self.bias_cov = _sym(np.linalg.inv(Lam))
        self.bias_mean = self.bias_cov @ eta

    def bias_estimates(self) -> dict[tuple[str, str, str], tuple[float, float]]:
        """{(stream, end, end): (bias m, its sigma m)} of the bias states (bias_states), ends sorted."""
        if self.belief is not None:
            b = self.belief
            return {k: (b.bias[k], float(np.sqrt(b.cov[i, i]))) for k, i in b.bias_at.items()}
        return {k: (float(self.bias_mean[i]), float(np.sqrt(self.bias_cov[i, i]))) for k, i in self.bias_index.items()}


def _link(stream: str, a: str, b: str) -> tuple[str, str, str]:
    """The key of the link between ends a and b on stream (either direction)."""
    return (stream,) + tuple(sorted((a, b)))


def _flag(kinds: tuple[str, ...], first: EpochsResult, second: EpochsResult, retry: np.ndarray) -> tuple[np.ndarray, EpochsResult]:
    """The epochs (E,) bool solved from two starts (retry: first from the warm start, second from
    the fresh one) that converged from neither but whose iterates agree (AGREE_LEVEL), and second
    with those epochs' lower-cost iterate and its covariance inflated by the iterates' difference
    d (k,) in the tangent space (per variable dp m world and, of a pose, Log(R_hi^T R_lo) rad body)."""
    both = retry & ~first.converged & ~second.converged & first.observable & second.observable
    flagged = np.zeros(both.shape, bool)
    if not both.any():
        return flagged, second
    p, R, cov, cost = second.p.copy(), second.R.copy(), second.cov.copy(), second.cost.copy()
    bias = None if second.b is None else second.b.copy()
    for e in np.flatnonzero(both):
        lo, hi = (first, second) if first.cost[e] <= second.cost[e] else (second, first)
        d = np.concatenate([lo.p[e, i] - hi.p[e, i] if kind == "point" else
                            np.concatenate([lo.p[e, i] - hi.p[e, i], so3_log(hi.R[e, i].T @ lo.R[e, i])])
                            for i, kind in enumerate(kinds)] + ([lo.b[e] - hi.b[e]] if lo.b is not None else []))
        if d @ np.linalg.solve(lo.cov[e], d) <= chi2.ppf(AGREE_LEVEL, d.size):
            flagged[e] = True
            p[e], R[e], cost[e], cov[e] = lo.p[e], lo.R[e], lo.cost[e], lo.cov[e] + np.outer(d, d)
            if bias is not None:
                bias[e] = lo.b[e]
    return flagged, dataclasses.replace(second, p=p, R=R, cov=cov, cost=cost, b=bias)


def _grown(ep: _Epoch, v_sigma: float, age: float) -> _Epoch:
    """ep with every range, height and fix sigma grown by the motion over age s at v_sigma m/s
    (eq. S1, estimators.range_start.grown_sigma)."""
    if v_sigma * age <= 0:
        return ep
    return dataclasses.replace(ep, r_sigma=grown_sigma(np.array(ep.r_sigma, float), v_sigma, age).tolist(),
                               heights=[(n, z, float(grown_sigma(x, v_sigma, age))) for n, z, x in ep.heights],
                               fixes=[(n, z, grown_sigma(x, v_sigma, age)) for n, z, x in ep.fixes])


def _heading(R: np.ndarray) -> np.ndarray:
    """The level rotation (3, 3) about world z with the heading of R's body x axis (its y axis
    where x is vertical)."""
    x = np.hypot(R[0, 0], R[1, 0]) > 1e-6
    psi = math.atan2(R[1, 0], R[0, 0]) if x else math.atan2(R[1, 1], R[0, 1]) - math.pi / 2
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _sym(c: np.ndarray) -> np.ndarray:
    return 0.5 * (c + c.T)


def _factor_arrays(kinds: tuple[str, ...], ranges: dict, rows: dict[str, list], **state_prior) -> EpochFactors:
    """EpochFactors from the range arrays (PoseGraph._range_rows) and the prior and height row
    tuples (see PoseGraph._factors), with the state prior x_p, x_R, x_info (and the biases r_bias,
    b_mean, x_b) when given."""
    q, h = rows["q"], rows["h"]
    col = lambda rs, k, shape=(): np.array([x[k] for x in rs], float).reshape((len(rs),) + shape)  # noqa: E731
    idx = lambda rs, k: np.array([x[k] for x in rs], np.int64).reshape(len(rs))  # noqa: E731
    return EpochFactors(
        kinds=kinds, **ranges,
        h_epoch=idx(h, 0), h_var=idx(h, 1), h_arm=col(h, 2, (3,)), h_z=col(h, 3), h_sigma=col(h, 4),
        q_epoch=idx(q, 0), q_var=idx(q, 1), q_arm=col(q, 2, (3,)), q_z=col(q, 3, (3,)), q_cov=col(q, 4, (3, 3)),
        **state_prior)
