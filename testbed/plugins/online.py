"""The estimator of `[control] feedback = "estimate:NAME"` run online, inside the flown loop.

testbed.sim.simulate hands `measured` the rows each sensor has just recorded (the values the log
will hold, noise included) and calls `advance(t)` at the end of every tick: every measurement
whose arrival (time + latency) is at or before t is turned into a `Measurement` exactly as the
offline feed builds it from the log (testbed.plugins.feed.measurement_columns) and processed in
the offline feed's order (arrival, time of validity, stream name, row of the stream); rows of
one sensor sample that come next to each other in that order (the IMUs of a swarm at one
instant) go as one MeasurementBatch, as offline (testbed.plugins.feed.batched). The
estimates returned are checked and collected as offline (testbed.plugins.collect), so the run
scores these very estimates; the latest world position and velocity of each fed-back vehicle
("uavI" targets) are what `state` gives the controller from the next tick on, and its latest
world attitude what `rotation` gives (with [control] attitude = "estimate"). A vehicle with no
estimate yet is controlled on its reference (zero position and velocity error); without a
velocity estimate, its velocity error is taken as zero. With [control] release_sigmas = n > 0 a
vehicle is also held on its reference until its estimate is released: the first time the
covariances of its latest position and velocity estimates satisfy
n (kx sigma_p + kv sigma_v) <= g tan(max_tilt_deg), sigma = sqrt(trace), or, flying on the
estimated attitude, once sigma_p is no larger than the drift of the open-loop hold dead-reckoned
from the attitude's declared tilt (docs/control.md, the initialization phase); an estimate without
a covariance never releases it. With [control] release_blend_s = tau > 0 the release is
bumpless: the estimate's difference from the reference at the first tick a vehicle is flown on
its estimate (position and velocity) is subtracted from what the controller gets, faded out as
exp(-(t - t_release) / tau), so the error the controller answers starts at zero and the
difference is flown out over a few tau instead of at once.

Target check: at the first tick from TARGET_CHECK_S (1 s) on at which the estimator has given any
estimate, every fed-back vehicle must have a world position estimate of its body "uavI", unless
the estimates name only flown bodies (a vehicle may still be waiting for its first fix); otherwise
the run stops there with a PluginError naming what arrived (e.g. the site "uav1/uwb") and what is
needed, instead of flying the whole run on the reference.

Order check: batches are cut at tick times and sorted inside, and a measurement arrives no
earlier than it was taken, so the concatenated batches are the offline feed's order.
"""
from __future__ import annotations

import heapq
import time as wallclock

import numpy as np

from estimators.eskf import GRAVITY
from estimators.so3 import quat_to_rotmat
from testbed.errors import PluginError
from testbed.plugins.api import Context, EstimateBatch
from testbed.plugins.collect import Track
from testbed.plugins.feed import finish_plugin, measurement_columns, process, process_batch, start_plugin
from testbed.plugins.loading import Plugin
from testbed.plugins.context import make_context
from testbed.config.scenario import Scenario
from testbed.sim.world import Physics, lever_arms

ARRIVAL_TOLERANCE = 1e-9  # s: an arrival this close after a tick time counts as at the tick
TARGET_CHECK_S = 1.0  # s: by then (or at the first estimates after it) the estimates must name the flown bodies
HELD = {"position": 0, "velocity": 1, "attitude": 2}  # the quantities held for the controller


class OnlineEstimator:
    """One plugin estimator run in the loop; `vehicles` (N,) bool: which are fed back."""

    def __init__(self, scenario: Scenario, plugin: Plugin, context: Context):
        self.scenario, self.plugin, self.context = scenario, plugin, context
        t0 = wallclock.perf_counter()
        self.est, self.col = start_plugin(plugin, context)
        self.wall = wallclock.perf_counter() - t0
        N = scenario.vehicles
        chosen = scenario.control.feedback_vehicles or range(1, N + 1)
        self.vehicles = np.zeros(N, bool)
        self.vehicles[np.array(chosen) - 1] = True
        self.index = {f"uav{i}": i - 1 for i in range(1, N + 1)}
        self.pos, self.vel, self.att = np.zeros((N, 3)), np.zeros((N, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (N, 1))
        self.times = np.full((3, N), -np.inf)  # time of validity of the held position, velocity, attitude
        self.has = np.zeros((3, N), bool)  # whether held: position, velocity, attitude
        c = scenario.control
        # the initialization phase ([control] release_sigmas): released vehicles fly on their estimate
        self.released = np.full(N, not c.release_sigmas)
        self.sigma = np.full((2, N), np.inf)  # m, m/s: RMS error of the held position, velocity estimate
        self.gains = np.array([c.kx, c.kv])  # 1/s^2, 1/s
        self.release_at = np.tan(np.radians(c.max_tilt_deg)) * -GRAVITY[2] / max(c.release_sigmas, 1e-300)  # m/s^2
        # attitude "estimate": a held vehicle flies its reference open-loop on the estimated attitude, and
        # drifts; RMS velocity (m/s) and position (m) of that drift, dead-reckoned from the declared tilt
        self.drift = np.zeros((2, N)) if c.attitude == "estimate" else None
        # the bumpless release ([control] release_blend_s): per vehicle the (position, velocity) offset
        # (2, N, 3) m, m/s estimate - reference at its release and the time t_release (s; NaN: not yet)
        self.blend = c.release_blend_s
        self.offset = np.zeros((2, N, 3)) if self.blend and c.release_sigmas else None
        self.t_release = np.full(N, np.nan)
        self.t = -np.inf  # s: the latest tick advanced to
        self._vehicle_rows: dict[tuple, tuple | None] = {}  # _hold_batch's per target tuple
        self._pending: list = []  # heap of (arrival, time, stream, row, columns, index)
        self._rows: dict[str, int] = {}
        self.fed = 0
        self.arrived: set[tuple] | None = set()  # (target, quantity, frame) of the estimates until the target check

    def measured(self, name: str, rows: dict[str, np.ndarray]) -> None:
        """The rows a sensor just recorded (Recorder.new_rows), queued by arrival."""
        n = len(rows["time"])
        if n == 0:
            return
        cols = measurement_columns(name, rows, self.scenario)
        first = self._rows.get(name, 0)
        self._rows[name] = first + n
        for r in range(n):
            heapq.heappush(self._pending, (float(rows["arrival"][r]), float(rows["time"][r]), name, first + r, cols, r))

    def advance(self, t: float) -> None:
        """Process every queued measurement arrived by time t (s), in feeding order."""
        self.t = t
        pending = self._pending
        if not pending or pending[0][0] > t + ARRIVAL_TOLERANCE:
            return
        t0 = wallclock.perf_counter()
        while pending and pending[0][0] <= t + ARRIVAL_TOLERANCE:
            *_, cols, r = heapq.heappop(pending)
            end = r + 1  # the run of this sample's next rows, next in the feeding order too
            while end < len(cols.time) and pending and pending[0][0] <= t + ARRIVAL_TOLERANCE and pending[0][4] is cols and pending[0][5] == end:
                heapq.heappop(pending)
                end += 1
            if end - r > 1 and cols.batchable:
                self._hold(process_batch(self.plugin, self.est, self.col, cols.batch(r, end)))
            else:
                for k in range(r, end):
                    self._hold(process(self.plugin, self.est, self.col, cols.measurement(k)))
            self.fed += end - r
        self.wall += wallclock.perf_counter() - t0
        if self.arrived is not None and t >= TARGET_CHECK_S and self.arrived:
            self._check_targets(t)

    def _check_targets(self, t: float) -> None:
        """The target check, once, at the first tick t (s) from TARGET_CHECK_S on at which the
        estimator has given estimates: a fed-back vehicle without a world position estimate, while
        the estimates name other targets (a site such as "uav1/uwb", another frame) or none of the
        flown bodies, is a mistake of the estimator's targets; PluginError naming what arrived and
        what is needed. (Before any estimate the vehicles fly on their reference: an estimator may
        wait for its first fix.)"""
        arrived, self.arrived = self.arrived, None
        missing = [f"uav{i + 1}" for i in np.flatnonzero(self.vehicles & ~self.has[0])]
        flown = {f"uav{i + 1}" for i in np.flatnonzero(self.vehicles)}
        other = sorted(a for a in arrived if not (a[0] in flown and a[1] in HELD and a[2] == "world"))
        if not missing or not (other or len(missing) == len(flown)):
            return
        seen = ", ".join(f"{q} of {tg!r}" + ("" if f == "world" else f" in frame {f!r}") for tg, q, f in other[:6])
        more = f" and {len(other) - 6} more" if len(other) > 6 else ""
        raise PluginError(f"estimator {self.plugin.key!r} ({self.plugin.entry}) in the control loop (control.feedback): "
                          f"by {t:.3g} s it estimated {seen or 'no position of a flown body'}{more}; the controller needs "
                          f"a world position of each flown body: no position estimate of {', '.join(missing)} "
                          f"(targets 'uavI', not sites such as 'uav1/uwb'; {self.fed} measurements fed)")

    def _hold(self, estimates: list) -> None:
        """Keep the latest (by time of validity) world position, velocity and attitude of each vehicle."""
        for e in estimates:
            if isinstance(e, EstimateBatch) and not isinstance(e.quantity, str):  # several quantities
                self._hold(e.parts())
                continue
            if self.arrived is not None:  # until the target check (_check_targets)
                self.arrived.update((tg, e.quantity, e.frame) for tg in ((e.target,) if isinstance(e.target, str) else set(e.target)))
            if isinstance(e, EstimateBatch):
                self._hold_batch(e)
                continue
            i = self.index.get(e.target)
            if i is None or e.frame != "world" or e.quantity not in HELD:
                continue
            k = HELD[e.quantity]
            if e.time >= self.times[k, i]:
                dt = np.array([e.time - self.times[k, i]])
                self.times[k, i] = e.time
                self._held(k)[i] = e.value
                self.has[k, i] = True
                self._release(k, np.array([i]), None if e.cov is None else np.asarray(e.cov, float)[None], dt)

    def _held(self, k: int) -> np.ndarray:
        """The held values of quantity k (HELD): (N, 3) position or velocity, (N, 4) attitude."""
        return (self.pos, self.vel, self.att)[k]

    def _hold_batch(self, b: EstimateBatch) -> None:
        """_hold of the rows of b, at once (row by row when a vehicle has several rows)."""
        if b.frame != "world" or b.quantity not in HELD:
            return
        targets = tuple(b.target)
        if targets not in self._vehicle_rows:  # (rows of fed-back vehicles, their vehicles), or None
            i = np.array([self.index.get(k, -1) for k in targets], int)
            keep = np.flatnonzero(i >= 0)
            self._vehicle_rows[targets] = (keep, i[keep]) if np.unique(i[keep]).size == keep.size else None
        if self._vehicle_rows[targets] is None:  # a vehicle twice: row by row
            self._hold(b.rows())
            return
        keep, i = self._vehicle_rows[targets]
        k = HELD[b.quantity]
        t, value = np.asarray(b.time, float)[keep], np.asarray(b.value, float)[keep]
        newer = t >= self.times[k, i]
        if not newer.all():
            i, t, value, keep = i[newer], t[newer], value[newer], keep[newer]
        dt = t - self.times[k, i]
        self.times[k, i] = t
        self._held(k)[i] = value
        self.has[k, i] = True
        if not self.released.all():
            self._release(k, i, None if b.cov is None else np.asarray(b.cov, float)[keep], dt)

    def _release(self, k: int, i: np.ndarray, cov: np.ndarray | None, dt: np.ndarray) -> None:
        """The initialization phase (module docstring), latched: newly held estimates of quantity k
        (HELD) of vehicles i (m,), covariances cov (m, 3, 3) (None: unknown), dt (m,) s since the
        previous one (inf: the first). Position, velocity: their RMS error sqrt(trace). Attitude,
        flown on (attitude "estimate"): the open-loop drift of a held vehicle grows by g sigma_tilt dt
        in velocity and by that velocity times dt in position (sigma_tilt: the declared tilt, the
        body x and y rotations); a vehicle is also released once its position estimate is no worse
        than that drift."""
        held = ~self.released[i]  # released is latched: only the vehicles still held matter
        if not held.any():
            return
        i, dt, cov = i[held], dt[held], None if cov is None else cov[held]
        if k < 2:
            self.sigma[k, i] = np.inf if cov is None else np.sqrt(np.trace(cov, axis1=1, axis2=2))
        elif self.drift is not None and cov is not None:
            dt = np.where(np.isfinite(dt), dt, 0.0)
            self.drift[0, i] += -GRAVITY[2] * np.sqrt(cov[:, 0, 0] + cov[:, 1, 1]) * dt
            self.drift[1, i] += self.drift[0, i] * dt
        self.released |= self.gains @ self.sigma <= self.release_at
        if self.drift is not None:
            self.released |= self.sigma[0] <= self.drift[1]

    def state(self, pos: np.ndarray, vel: np.ndarray, ref_pos: np.ndarray, ref_vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity (N, 3) world the controller uses: the held estimate of each
        fed-back vehicle (its reference before a first estimate and until released), the truth of
        the others."""
        fb = self.vehicles
        flown = fb & self.has[0] & self.released
        p = np.where(flown[:, None], self.pos, np.where(fb[:, None], ref_pos, pos))
        v = np.where((fb & self.has[1] & self.released)[:, None], self.vel, np.where(fb[:, None], ref_vel, vel))
        if self.offset is not None:
            p, v = self._blend(flown, p, v, ref_pos, ref_vel)
        return p, v

    def _blend(self, flown: np.ndarray, p: np.ndarray, v: np.ndarray, ref_pos: np.ndarray,
               ref_vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bumpless release (module docstring): flown (N,) bool, the vehicles flown on their
        estimate this tick; p, v (N, 3) world m, m/s what the controller would get; returns them
        less each released vehicle's offset times exp(-(t - t_release) / tau). Once every fed-back
        vehicle has been flown on its estimate for 30 tau (the offset then below 1e-13 of itself)
        the offsets are dropped and this is no longer called."""
        new = flown & np.isnan(self.t_release)
        if new.any():
            self.offset[0, new] = p[new] - ref_pos[new]
            self.offset[1, new] = v[new] - ref_vel[new]
            self.t_release[new] = self.t
        age = self.t - self.t_release  # s; NaN: not released yet
        w = np.exp(-np.where(np.isnan(age), np.inf, age) / self.blend)[:, None]  # (N, 1)
        p, v = p - w * self.offset[0], v - w * self.offset[1]
        if not np.isnan(age[self.vehicles]).any() and age[self.vehicles].min() > 30.0 * self.blend:
            self.offset = None
        return p, v

    def rotation(self, R: np.ndarray, R_start: np.ndarray) -> np.ndarray:
        """Attitude (N, 3, 3) body-to-world the controller uses ([control] attitude = "estimate"):
        the held attitude estimate of each fed-back vehicle (R_start (N, 3, 3) before a first
        one), the truth R (N, 3, 3) of the others."""
        fb = self.vehicles[:, None, None]
        return np.where(fb & self.has[2][:, None, None], quat_to_rotmat(self.att), np.where(fb, R_start, R))

    def finish(self) -> tuple[Track, dict, float]:
        """The rows still queued, then finish() and health() of the plugin; (estimates, health,
        wall ms) as run_plugin gives.
        A fed-back vehicle that never got a position estimate is a PluginError."""
        self.advance(np.inf)  # rows arriving after the last tick: fed as offline, too late to steer
        t0 = wallclock.perf_counter()
        health = finish_plugin(self.plugin, self.est, self.col)
        self.wall += wallclock.perf_counter() - t0
        missing = [f"uav{i + 1}" for i in np.flatnonzero(self.vehicles & ~self.has[0])]
        if missing:
            raise PluginError(f"estimator {self.plugin.key!r} ({self.plugin.entry}) in the control loop "
                              f"(control.feedback): no position estimate of {', '.join(missing)} in the whole run "
                              f"({self.fed} measurements fed)")
        return self.col.track(), health, self.wall * 1e3


def in_the_loop(scenario: Scenario, physics: Physics, plugins: list[Plugin]) -> OnlineEstimator | None:
    """The estimator [control] feedback names, constructed for this run (None: truth feedback or a
    prescribed motion).
    Its Context is the one the offline feed gives, without a prior (priors come from the log)."""
    name = scenario.control.feedback_estimator
    if not name or scenario.motion != "flown":  # prescribed: no controller, the estimator runs on the log
        return None
    plugin = next(p for p in plugins if p.key == name)  # the scenario checked the name
    return OnlineEstimator(scenario, plugin, make_context(scenario, lever_arms(physics), plugin.key, plugin.params))
