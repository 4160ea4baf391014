"""Built-in `coop.window_ins` and `coop.window_distributed_ins`: the cascade that makes the
cooperative estimate flyable. Per vehicle an IMU-propagated error-state EKF (nav.eskf's filter,
estimators.eskf, driven exactly as `nav.eskf` drives it) whose only position updates are the
cooperative solution: the sliding-window factor graph's (`coop.window`, or
`coop.window_distributed`) per-vehicle antenna position at each epoch, with its marginal
covariance. GNSS fixes and UWB ranges go to the window graph, not to the filters; IMU samples go
to both (to the window they only close epochs).

Why: the window solves 5 Hz epochs of position and velocity without an IMU; held between
epochs, its velocity is off by metres per second at the start (docs/denied.md), and the
controller answers each epoch's step. The filter integrates the IMU at 100 Hz between epochs,
so the controller gets a smooth state (position, velocity, attitude, every `output_every`-th IMU
sample) and the epoch's information enters as a correction weighted against the IMU prediction.

Position update per epoch and vehicle: z = the window's antenna position (its body output plus
the lever arm of the `uwb` site, undoing the window's level-attitude conversion), h(x) = the
antenna position of the filter's state (estimators.eskf.site_position, attitude of the filter),
R = the window's marginal position covariance. The window's epoch closes when the next sample
of a later time arrives (the IMU's, 10 ms later in coop-denied) and the filter is then at the
epoch's time (the closing sample is handed to the window before the filter); an epoch older than
the filter updates its current state, as nav.eskf does with late measurements. The filter
starts at the vehicle's first window position (roll and pitch levelled from the IMU, velocity
0 with vel0_sigma), as nav.eskf starts at its first fix.

The approximation (stated): the window's newest-epoch marginal already holds the measurements
of the earlier epochs (through the window and its marginalized prior), which the filter has
received before; feeding each epoch's marginal as an independent measurement counts that shared
information again, so the filter's position covariance is optimistic and the filter follows the
window more closely than an exact fusion would. The IMU information is what the cascade adds
between epochs; the UWB and GNSS information is the window's alone.

decorrelate (default true) feeds instead each epoch's new information only, the standard
equivalent measurement (tracklet decorrelation, estimators.window.equivalent_measurement):
Lambda = P^-1 - P_pred^-1 between the newest epoch's position marginal and the window's own
prediction of that epoch without its fixes and ranges. It needs a window whose covariance is
right: measured on coop-denied (docs/denied.md, 60 s, calibration seeds 1000-1009), with the
window's ranges in least squares (position ANEES 19 on 3 dof on a flight on the truth: the
outlier ranges) it flew worse than the marginal (contacts on 8 of 10 seeds, against 4);
with the Huber window (ANEES 4.0) it flies every seed without a contact, 0.36-0.58 m tracking
RMS (the marginal: 9 of 10, 0.8-2.1 m).

imu_motion (default true for the distributed cascade, false for the centralized one) gives the
window each vehicle's motion between two epochs as its filter propagated it on the IMU
(`_motion`: the displacement beyond constant velocity and the velocity change, Epoch.motion),
the known input of the window's motion factor instead of a zero-mean acceleration: flown on the
estimate, the swarm accelerates together, which the window's white-acceleration model lags and
the distributed cascade followed (docs/denied.md: the swarm swung 2 m north and south on seed
1000). start_epochs (default 5 for the distributed cascade, 1 for the centralized one): a
vehicle's filter starts once the window holds that many epochs; the distributed window's first
epoch rested on each vehicle's fix and its neighbours' (measured up to 5.6 m off vertically on
1000-1009, and a vehicle rolled over answering it on seed 1006; chosen before the window's start
exchange, estimators.window, which now gives that epoch); until it starts, the vehicle is flown
on its reference. Both stay off for the centralized cascade: its outputs are unchanged.

params: those of the window (testbed.plugins.builtin_window: window, q, range_scale, huber
(here 1.345 by default, WINDOW_DEFAULTS: flown with least squares the swarm fell on 4 of 10
calibration seeds, with Huber on none, docs/denied.md), max_iter, max_rounds, tol, init_sigma_v,
network), decorrelate (true, above), imu_motion, start_epochs (above) and of the filter (testbed.plugins.builtin_eskf: yaw0,
yaw0_sigma, tilt0_sigma, vel0_sigma, gate_prob, output_every), in one table. gate_prob defaults
to 0 here (no innovation gate): the window's position is the filters' only position information,
and a filter that rejects it runs on its IMU alone; measured on a 6 s diagnostic of coop-denied
flown on this estimate (seed 18), the nav.eskf gate (1e-4) rejected 204 of 522 window updates
and the estimates drifted to 10-22 m of error.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np

from estimators import eskf
from estimators.window import equivalent_measurement
from testbed.config import key
from testbed.plugins import builtin_eskf, builtin_window
from testbed.plugins.api import Context, Estimate, EstimateBatch, Measurement, MeasurementBatch
from testbed.plugins.collect import cov_problem, cov_problems
from testbed.plugins.params import fields_of, read


@dataclass(frozen=True, kw_only=True)
class WindowInsParams(builtin_eskf.NavEskfParams, builtin_window.WindowParams):
    """Parameters of coop.window_ins: the window's, the filter's and the cascade's, in one table."""

    # no innovation gate: the window's position is the filters' only position information (module docstring)
    gate_prob: float = key(0.0, lo=0, hi=1, hi_open=True, doc="NIS gate: false-alarm probability (0: no gate)")
    # the cascade's window: Huber range loss (docs/denied.md: least squares let the DW1000's 1 % of
    # 3 m outlier ranges throw single vehicles metres off vertically, and the swarm fell on 4 of 10
    # calibration seeds)
    huber: float = key(1.345, lo=0, unit="sigma", doc="Huber range loss threshold (0: least squares)")
    # the filters take the window's tracklets, which hold no consider term (builtin_window, "Range weights")
    antenna_delays: Literal["white"] = key("white", doc="the radios' constant antenna delays: white noise in each range's variance (the filters take the window's tracklets)")
    decorrelate: bool = key(True, doc="feed each epoch's new information only (equivalent measurement), not the marginal")
    imu_motion: bool = key(False, doc="the filters' IMU motion between epochs as the known input of the window's motion factor")
    start_epochs: int = key(1, lo=1, doc="a vehicle's filter starts once the window holds this many epochs")

    def __post_init__(self) -> None:
        builtin_window.WindowParams.__post_init__(self)  # every field's interval, and the network table


@dataclass(frozen=True, kw_only=True)
class WindowDistributedInsParams(WindowInsParams):
    """Parameters of coop.window_distributed_ins: as coop.window_ins, other cascade defaults."""

    imu_motion: bool = key(True, doc="the filters' IMU motion between epochs as the known input of the window's motion factor")
    start_epochs: int = key(5, lo=1, doc="a vehicle's filter starts once the window holds this many epochs")


def _part(p: dict, Params: type) -> dict:
    """The keys of params p that are Params' fields (the filter's, the window's)."""
    names = {f.name for f in dataclasses.fields(Params)}
    return {k: v for k, v in p.items() if k in names}


class _WindowIns(builtin_eskf.NavEskf):
    """nav.eskf's per-vehicle filters, position-updated by a window estimator (module docstring)."""

    window_class: type = builtin_window.Window
    Params = WindowInsParams

    def __init__(self, context: Context, params: dict):
        p = fields_of(read(self.Params, params, type(self).__name__))
        self.decorrelate = bool(p["decorrelate"])
        self.start_epochs = int(p["start_epochs"])
        super().__init__(context, _part(p, builtin_eskf.NavEskfParams))
        self.window = self.window_class(context, _part(p, self.window_class.Params))
        self.window.solver.tracklets = self.decorrelate
        if p["imu_motion"]:
            self.window.motion = self._motion
        self.delay_var = np.zeros(0)  # no UWB range reaches the filters: no antenna-delay states
        self.lever = {v: context.sites[f"{v}/uwb"][1] for v in context.vehicles}  # (3,) m body
        self.index = {v: i for i, v in enumerate(context.vehicles)}
        self.counts.update(window_updates=0, invalid_window_updates=0, filter_restarts=0, projected_updates=0)
        self._eq = None  # (time, z (n, 3), R (n, 3, 3), full (n,)): the newest epoch's equivalent measurements
        self._after: dict[str, tuple] = {}  # vehicle: (t s, antenna (3,) m, velocity (3,) m/s) of its filter after the last epoch

    def process(self, m: Measurement) -> list[Estimate]:
        for e in self.window.process(m):
            if e.quantity == "position":
                self._epoch(e)
        return self._imu(m) if m.stream == "imu" else []

    def _instant(self, b: MeasurementBatch, lo: int, bodies: list[str]) -> None:
        """What process() does for an instant's IMU rows before the filters take them: the first
        row closes the window's epoch (an IMU row does nothing else to the window: its site is
        none the window indexes, and the rows after the first are of the same time)."""
        first = Measurement(stream=b.stream, time=float(b.time[lo]), arrival=float(b.arrival[lo]),
                            value=np.asarray(b.value[lo], float), src=str(b.src[lo]))
        for e in self.window.process(first):
            if e.quantity == "position":
                self._epoch(e)

    def _imu_rows(self, t: float, bodies: list[str], values: np.ndarray) -> list[EstimateBatch]:
        """nav.eskf's propagation and output (its `_imu_rows`); a filter whose covariance is no
        longer finite and positive definite (after a vehicle tumbled: measured at 48 s of a 60 s
        flight of seed 18 on the distributed cascade) is dropped and restarts at the next epoch
        (counted)."""
        out = super()._imu_rows(t, bodies, values)
        if not out:
            return out
        bad = np.zeros(len(out[0]), bool)  # the vehicles (rows of every batch) with a bad covariance
        for b in out:
            bad |= np.array([r is not None for r in cov_problems(b.cov)])
        if not bad.any():
            return out
        for body in np.asarray(out[0].target)[bad].tolist():
            self.v[body].x = None
            self.counts["filter_restarts"] += 1
        shown = [body for body, ok in zip(out[0].target, ~bad) if ok]
        return self._estimates(t, shown)

    def finish(self) -> list[Estimate]:
        self.window.finish()  # the last epoch: no IMU sample follows to fly on it
        return super().finish()

    def health(self) -> dict[str, int]:
        return {**self.window.health(), **self.counts}

    def _epoch(self, e: Estimate) -> None:
        """The window's body position e of one vehicle: start or update its filter."""
        f, lever = self.v[e.target], self.lever[e.target]
        z = np.asarray(e.value, float) + lever  # the antenna (the window's level conversion undone)
        if f.imu is None:
            self.counts["skipped_updates"] += 1
            return
        if cov_problem(np.asarray(e.cov, float).tolist()):
            self.counts["invalid_window_updates"] += 1
            return
        if f.x is None:
            if self.start_epochs > 1 and len(self.window.solver.epochs) < self.start_epochs:
                return  # the window is not yet what the filter should start from (start_epochs)
            self._start(f, e.target, e.time, z, np.diag(np.diag(np.asarray(e.cov, float))), lever)  # its variances
        else:
            Rn = np.asarray(e.cov, float)
            if self.decorrelate:
                z, Rn = self._equivalent(e)
            if z is not None:
                self._to(f, e.time)
                self._apply(f, z, lambda x: eskf.site_position(x, lever), Rn)
                self.counts["window_updates"] += 1
        if f.t == e.time:  # the filter at the epoch: where the next interval's motion starts
            self._after[e.target] = (e.time, eskf.site_position(f.x, lever)[0], f.x[3:6].copy())

    def _motion(self, t: float) -> np.ndarray:
        """(n, 6) each vehicle's motion over the window's last interval (Epoch.motion; imu_motion):
        its filter propagated on the IMU from its state after the window's previous epoch to t
        (s): [antenna displacement beyond constant velocity (m), velocity change (m/s)], world.
        Zero for a vehicle whose filter was not at the previous epoch (not started yet).
        The velocity is the body's (the antenna's differs by the lever arm's rotation, w x R l:
        under 0.1 m/s at 0.5 rad/s and the 0.17 m mast)."""
        out = np.zeros((len(self.index), 6))
        t0 = self.window.solver.epochs[-1].t
        for v, i in self.index.items():
            after, f = self._after.get(v), self.v[v]
            if after is None or after[0] != t0 or f.x is None:
                continue
            self._to(f, t)
            s0, v0 = after[1], after[2]
            out[i, :3] = eskf.site_position(f.x, self.lever[v])[0] - s0 - v0 * (t - t0)
            out[i, 3:] = f.x[3:6] - v0
        return out

    def _equivalent(self, e: Estimate) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The new information of the window's epoch for vehicle e.target (module docstring):
        its antenna position z (3,) m and covariance R (3, 3); (None, None) at the window's first
        epoch (nothing predicted it: the filters start there)."""
        if self._eq is None or self._eq[0] != e.time:
            est = self.window.last
            if est.tracklet is None:
                self._eq = (e.time, None, None, None)
            else:
                self._eq = (e.time, *equivalent_measurement(*est.tracklet))
                self.counts["projected_updates"] += int((~self._eq[3]).sum())
        _, z, R, _ = self._eq
        i = self.index[e.target]
        return (None, None) if z is None else (z[i], R[i])


class WindowIns(_WindowIns):
    description = "IMU error-state EKF per vehicle, position-updated by coop.window (cascade); flies in the loop"


class WindowDistributedIns(_WindowIns):
    description = "IMU error-state EKF per vehicle, position-updated by coop.window_distributed (cascade); flies in the loop"
    window_class = builtin_window.WindowDistributed
    Params = WindowDistributedInsParams
