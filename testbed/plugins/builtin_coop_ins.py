"""Built-in `coop.ins` and `coop.ins_distributed`: the swarm's IMU error-state EKFs updated by
GNSS, UWB ranges to anchors and UWB ranges between vehicles (estimators.coop_ins), offline or
online in the control loop ([control] feedback). Centralized: one joint covariance over the
swarm. Distributed: per vehicle two filters, the flown one and one of the vehicle's own
measurements only (IMU, GNSS, anchors); at each UWB epoch every vehicle broadcasts the second
one's antenna position, velocity and their covariances (BROADCAST_BYTES) over the network, and
a range to a neighbour enters the flown filter with the neighbour's last broadcast that has
arrived as a known point, its covariance times kappa added to the range variance
(broadcasting the flown filter, which already holds what the neighbours said, made the filters
optimistic until they rejected the fixes; kappa counts the neighbour's slowly changing error
entering every epoch: k at the receiver's k-th epoch ranging to that neighbour, up to
`peer_inflation`, chosen by the rule of testbed.reproduce.peer_inflation; peer_kappa). Each
broadcast is first checked against the sender's flown estimate of the same antenna
(checked_broadcast, chi-square 3 dof at 1 - broadcast_check): an own filter that has gone wrong
(measured: 16 m off with a 1.3 m sigma) is broadcast with the disagreement added to its
covariance. The per-vehicle filters' iterated update is line-searched (estimators.coop_ins
SwarmIns._line_search). A range enters a per-vehicle filter only where it is linear in that
filter's own uncertainty (linear_ranges: the neglected second-order term of the range at most
`linearity` times its noise sd): at a first SPP fix, metres of height sigma straddle the height
of the anchors and of the neighbours, a range cannot tell above from below, and fused there it
made the filter sure of the wrong side; such a range is skipped (counted) until the fixes have
narrowed the prior; a filter whose anchor ranges were all skipped at UNLOCK_EPOCHS epochs in a row
takes them all at the last (counted, `forced_ranges`), so none is skipped for good.

Feeding. IMU samples of one instant (every vehicle's, 100 Hz in coop-denied) are applied
together: the filters are propagated from the previous instant with the previous samples held
(zero-order hold, as nav.eskf), then each vehicle's position and velocity are output every
`output_every`-th instant with its attitude (what [control] attitude = "estimate" flies on), as
EstimateBatches (one per quantity for the swarm). An instant's IMU samples fed as one MeasurementBatch are taken
at once (process_batch), a UWB epoch's ranges too, exactly as row by row. GNSS
fixes and UWB ranges of one time of validity are an epoch; it is applied when a measurement of a
later time arrives (no look-ahead), as one update at the
epoch's time (an epoch older than the filters updates their current state: the delay is not
compensated). Distributed: broadcasts are sent at the epoch's time and used if they have
arrived by the time the epoch is applied (the arrival of the measurement that closed it);
otherwise the sender's previous broadcast, moved on at its broadcast velocity, its covariance
grown by the velocity's over the gap, is used if younger than `stale_s`, else the range is
skipped (counted). The channel's geometry (range limit) is taken from the estimators' own
positions (the estimator cannot see the truth), all links taken as line of sight.

A vehicle's filter starts at its first GNSS fix (position: the fix minus the rotated lever arm;
velocity 0; roll and pitch levelled from its accelerometer less the declared constant bias,
correlated with the bias error as estimators.eskf.level; yaw `yaw0`); until then its rows are
skipped (counted). Or, given a position in `initial_pose`, at its first IMU sample from that pose
(testbed.plugins.builtin_eskf.InitialPose); with neither, at the first epoch at which its anchor
ranges and heights of the last `start_window` s determine its body origin (estimators.range_start,
as nav.eskf); a vehicle that never starts is counted and named (health `unstarted_vehicles`,
stderr). Range noise matched on the anchor ranges' innovations (eq. R1) and the divergence guard
(eq. D1, a vehicle re-initialised from its ranges and heights): as nav.eskf
(estimators.range_innovations; the distributed filter's from the ranges its linearity check
passes). Each vehicle's IMU noise and bias priors come from its own
IMU table (estimators.sensor_models.vehicle_imu).

Sites: every row is taken at the lever arm of the site it measures (a GNSS antenna, any of a
vehicle's UWB tags, a height's site; estimators.coop_ins.Rows.lever). Heights (stream `height`,
the up coordinate of a site or a body's origin, m world) are a fix's third row, with the row's
sigma (a row without one, or before its vehicle started, skipped and counted). The distributed
filter broadcasts each vehicle's reference antenna (its `uwb` site, else the body origin).

Noise: IMU white noise and bias walks from the declared [sensors.imu] (a Gauss-Markov bias of
sigma s, time constant tau as a walk of density s sqrt(2 / tau), as nav.eskf), the white
densities then measured on the samples (`imu_noise_window`, estimators.imu_adapt); initial bias
uncertainty: turn-on and Gauss-Markov sigmas, plus, for the accelerometer, the declared
scale-factor and misalignment sigmas times g (the 15 states have no scale factors: near hover a
scale or misalignment error of the accelerometer is a constant error of the 1 g it reads, which
the bias state takes; the gyro's, times rates of a few deg/s, are left out). GNSS: the row's
declared sigma. UWB: the declared noise plus the two-way-ranging clock term and the link bias
as white noise (estimators.sensor_models.range_variances); the antenna delay of every UWB
device (the vehicles' tags, the anchors) is a state (mean 0, the declared antenna_delay_sigma). Ranges are weighted by Huber's function of their normalized innovation (threshold
`huber`, estimators.coop_ins.SwarmIns.update); an optional gate (gate_prob > 0) rejects a range
whose NIS alone exceeds the chi-square quantile 1 - gate_prob of 1 dof. The default, Huber 1.345
and no gate, was chosen on the calibration seeds of testbed.reproduce.peer_inflation (position
RMSE of coop.ins on seeds 1000 / 1001 / 1002, 30 s on the truth: 0.313 / 0.390 / 0.734 m against
0.324 / 0.390 / 0.894 m with the gate at 1e-3 and no Huber weight, which rejected every range once
the estimate had drifted).

params (defaults): huber (1.345; 0: least squares), gate_prob (0: no gate), iterations (3, of
the iterated update), yaw0 (rad, 0), yaw0_sigma (rad, 0.1), tilt0_sigma (rad, 0.05), vel0_sigma
(m/s, 1.0), output_every (1), initial_pose ({}), imu_noise_window (100), imu_noise_average (1),
start_window (s, 2),
range_window (20), range_noise_adapt (true), divergence_prob (1e-6); distributed only: network (a [network] table, docs/network.md;
absent: ideal), stale_s (s, 1.0), peer_inflation (4), broadcast_check (1e-3; 0: off), linearity
(1.0; 0: off). health(): epochs, rejected_measurements, skipped_updates, stale_ranges,
reinitialisations (with its reason and time, builtin_eskf.Reinitialisations);
distributed also inconsistent_broadcasts (checked_broadcast), nonlinear_ranges (ranges a flown
filter skipped, linear_ranges), forced_ranges (nonlinear ones taken all the same, _unlock) and the network's sent, delivered, dropped, bytes_sent and
latency_p50_us / latency_p95_us.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from estimators import coop_ins as ci
from estimators.range_start import BodyStarts
from estimators.sensor_models import imu_noise, range_variances, vehicle_imu
from estimators.so3 import quat_to_rotmat
from testbed.config import from_dict, key
from testbed.config.network import NetworkConfig
from testbed.plugins.api import Context, Estimate, EstimateBatch, Measurement, MeasurementBatch
from testbed.plugins.builtin_eskf import (Reinitialisations, StartParams, heading, imu_adapter, initial_poses, levelled_start,
                                          note_unstarted, range_guard)
from testbed.plugins.epochs import equal_time_runs
from testbed.plugins.params import fields_of, read


@dataclass(frozen=True, kw_only=True)
class CoopInsParams(StartParams):
    """Parameters of coop.ins ([[estimators]] params; module docstring)."""

    huber: float = key(1.345, lo=0, unit="sigma", doc="Huber weight threshold of the ranges (0: least squares)")
    gate_prob: float = key(0.0, lo=0, hi=1, hi_open=True, doc="NIS gate: false-alarm probability (0: no gate)")
    iterations: int = key(3, lo=1, doc="iterations of the iterated update")


@dataclass(frozen=True, kw_only=True)
class CoopInsDistributedParams(CoopInsParams):
    """Parameters of coop.ins_distributed ([[estimators]] params; module docstring)."""

    network: dict | None = key(None, range="a [network] table (docs/network.md)", doc="the channel of the broadcasts (none: ideal)")
    stale_s: float = key(1.0, lo=0, unit="s", doc="a neighbour's broadcast older than this is not used")
    peer_inflation: float = key(4.0, lo=0, doc="cap on kappa, the factor on a neighbour's broadcast covariance")
    broadcast_check: float = key(1e-3, lo=0, hi=1, hi_open=True, doc="false-alarm probability of the broadcast consistency check (0: off)")
    linearity: float = key(1.0, lo=0, doc="range linearity test factor (0: off)")

    def __post_init__(self) -> None:
        super(CoopInsDistributedParams, self).__post_init__()
        if self.network is not None:
            from_dict(NetworkConfig, self.network, "", "network")


BROADCAST_BYTES = 8 * (3 + 3 + 6 + 6 + 1)  # float64: antenna position, velocity, their 6 covariance entries each, time
NAN3 = np.full(3, np.nan)  # "no other end" in a row (EpochRows.other)
ZERO3 = np.zeros(3)  # a body's origin (EpochRows.lever)


class CoopIns:
    description = "swarm IMU error-state EKF updated by GNSS + UWB anchors + inter-vehicle UWB, centralized; flies in the loop"
    joint = True
    copies = 1  # filters per vehicle in self.ins (the distributed one adds its own-measurement filter)

    Params = CoopInsParams

    def __init__(self, context: Context, params: dict):
        self.p = fields_of(read(self.Params, params, type(self).__name__))
        if "imu" not in context.sensors:
            raise ValueError("needs [sensors.imu]")
        self.vehicles = list(context.vehicles)
        self.n = n = len(self.vehicles)
        imus = [vehicle_imu(context.sensors["imu"], v) for v in self.vehicles]  # each vehicle's own
        noise = [imu_noise(imu) for imu in imus]
        self.adapt = imu_adapter(self.p, noise)
        noise = noise[0] if all(k == noise[0] for k in noise) else noise * self.copies
        self.bias0, self.bias_var = (np.array(a) for a in zip(*(_bias_prior(imu) for imu in imus)))  # (n, 6) each
        self.poses = initial_poses(self.p, self.vehicles, type(self).__name__)
        self._posed = [(i, self.poses[v]) for i, v in enumerate(self.vehicles) if v in self.poses and self.poses[v].position is not None]
        self.sites = dict(context.sites)
        self.anchors = {k: np.asarray(v, float) for k, v in context.anchors.items()}
        self.uwb = context.sensors.get("uwb")
        self.body = {v: i for i, v in enumerate(self.vehicles)}
        self.lever = np.array([self.sites[f"{v}/uwb"][1] if f"{v}/uwb" in self.sites else np.zeros(3)
                               for v in self.vehicles], float)
        # UWB devices whose antenna delays are states: the vehicles' tags, then the anchors
        delay = self.uwb["antenna_delay_sigma"] if self.uwb is not None else 0.0
        self.device = {**{f"{v}/uwb": k for k, v in enumerate(self.vehicles)},
                       **{a: n + k for k, a in enumerate(self.anchors)}} if delay > 0 else {}
        self.ins = ci.SwarmIns(self.copies * n, np.tile(self.lever, (self.copies, 1)), noise, joint=self.joint,
                               devices=len(self.device), delay_var=delay ** 2, damped=not self.joint)
        self.gate = float(chi2.isf(self.p["gate_prob"], 1)) if self.p["gate_prob"] > 0 else np.inf
        self.held = np.full((n, 6), np.nan)  # the IMU sample each vehicle holds
        self.new = np.full((n, 6), np.nan)  # samples of the instant being collected
        self.t_imu = None
        self.instants = 0
        self._targets: tuple[bytes, tuple] = (b"", ())  # (which flown filters are started, their vehicles): _flush's targets
        self.epoch_t = None
        self.rows = EpochRows()
        self._links: dict[tuple[str, str], tuple | None] = {}  # (src, dst): _link's answer
        self._imu_rows: dict[tuple, np.ndarray] = {}  # IMU sites of an instant: their filters
        self.counts = {"epochs": 0, "rejected_measurements": 0, "skipped_updates": 0, "stale_ranges": 0}
        self.starts = BodyStarts(self.p["start_window"], self.p["vel0_sigma"])
        self.innovations = range_guard(self.p, n)
        self.reinit = Reinitialisations(self.counts)
        self.restart: list[dict | None] = [None] * n  # a re-initialised vehicle's params of its next start (its own heading)
        self._network(context)

    def _network(self, context: Context) -> None:
        """Centralized: nothing travels."""

    def _rows(self, t: float, now: float, rows: ci.Rows) -> ci.Rows:
        """The rows of the epoch's update: centralized, the epoch's rows (a range between vehicles
        on both their states)."""
        return rows

    # ------------------------------------------------------------------ the protocol
    def process(self, m: Measurement) -> list[Estimate]:
        out = []
        if self.epoch_t is not None and (m.time > self.epoch_t or (m.stream != "imu" and m.time != self.epoch_t)):
            self._close(m.arrival)
        if m.stream == "imu":
            out = self._imu(m)
        elif m.stream in ("gnss", "uwb", "height"):
            self._take(m)
        return out

    def process_batch(self, b: MeasurementBatch) -> list[EstimateBatch]:
        """process() of each row of b, in order (the protocol); an IMU batch is taken an instant
        (rows of one time) at a time, its samples stored together when that is what the rows one
        by one would do (distinct vehicles, the instant completed by its last row)."""
        if b.stream == "uwb":
            self._take_ranges(b)
            return []
        if b.stream != "imu":
            return [e for m in b.rows() for e in self.process(m)]
        out = []
        for lo, hi in equal_time_runs(b.time):
            t = float(b.time[lo])
            if self.epoch_t is not None and t > self.epoch_t:
                self._close(float(b.arrival[lo]))
            i = self._imu_vehicles(b.src[lo:hi])
            # the vehicles with a sample once all but the last row are in (a later t flushes first)
            before_last = ~np.isnan(self.new[:, 0]) & (self.t_imu is not None and t <= self.t_imu)
            before_last[i[:-1]] = True
            if np.unique(i).size < i.size or before_last.all():  # row by row would flush within the run
                for m in b.rows()[lo:hi]:
                    out += self.process(m)
                continue
            out += self._store_imu(t, i, b.value[lo:hi])
        return out

    def _imu_vehicles(self, src: np.ndarray) -> np.ndarray:
        """(k,) the filters of IMU sites src (k,) (cached: an instant's sites come again and again)."""
        key = tuple(src.tolist())
        if key not in self._imu_rows:
            self._imu_rows[key] = np.array([self.body[self.sites[s][0]] for s in key], int)
        return self._imu_rows[key]

    def finish(self) -> list[Estimate]:
        out = self._flush() if self.t_imu is not None else []
        if self.epoch_t is not None:
            self._close(self.epoch_t)
        note_unstarted(type(self).__name__, [v for i, v in enumerate(self.vehicles) if not self.ins.active[i]], self.counts)
        self.reinit.note(type(self).__name__)
        return out

    def health(self) -> dict[str, int]:
        return dict(self.counts)

    # ------------------------------------------------------------------ IMU
    def _imu(self, m: Measurement) -> list[EstimateBatch]:
        return self._store_imu(m.time, self.body[self.sites[m.src][0]], m.value)

    def _store_imu(self, t: float, i, value: np.ndarray) -> list[EstimateBatch]:
        """IMU samples value (k, 6) of vehicles i (k,) (or one) at t (s): a later instant flushes
        the one collected, and the instant is flushed once every vehicle's sample is in."""
        out = self._flush() if self.t_imu is not None and t > self.t_imu else []
        self.t_imu = t
        self.new[i] = value
        if not np.isnan(self.new[:, 0]).any():
            out += self._flush()
        return out

    def _flush(self) -> list[Estimate]:
        """Propagate to the collected instant, hold its samples, output (module docstring)."""
        t, got = self.t_imu, ~np.isnan(self.new[:, 0])
        self._advance(t)
        self.held[got] = self.new[got]
        if self.adapt is not None:
            done = self.adapt.add(np.flatnonzero(got), t, self.new[got])
            if done.size:  # both filters of each vehicle (the distributed one's copies)
                k = np.concatenate([done + c * self.n for c in range(self.copies)])
                density = np.tile(self.adapt.density[done], (self.copies, 1))
                self.ins.set_white_noise(k, density[:, 0], density[:, 1])
        self.new[:] = np.nan
        for i, pose in self._posed:  # started from its initial pose at its first sample
            if got[i] and not self.ins.active[i] and self.restart[i] is None:
                self._start(i, t, np.array(pose.position, float), np.diag(np.full(3, pose.position_sigma ** 2)), np.zeros(3))
        self.t_imu = None
        self.instants += 1
        if self.instants % int(self.p["output_every"]) or not self.ins.active[:self.n].any():
            return []
        ins = self.ins
        C = ins.marginals(slice(self.n))  # the flown filters'
        i = np.flatnonzero(ins.active[:self.n])
        started = ins.active[:self.n].tobytes()
        if self._targets[0] != started:  # which vehicles are started (a re-initialised one stops until it restarts)
            self._targets = (started, tuple(self.vehicles[k] for k in i.tolist()))
        target, time = self._targets[1], np.full(i.size, t)
        # each block copied out: a view would keep the whole (n, 15, 15) array alive with the estimate
        return [EstimateBatch(time=time, target=target, quantity=q, value=x[i], cov=C[i][:, s, s].copy())
                for q, x, s in (("position", ins.p, ci.P_), ("velocity", ins.v, ci.V_), ("attitude", ins.q, ci.TH))]

    def _advance(self, t: float) -> None:
        """Propagate the filters to t (s) with the held samples (nothing if t is not later)."""
        ins = self.ins
        if ins.t is not None and t > ins.t:
            held = np.tile(np.where(np.isnan(self.held), 0.0, self.held), (self.copies, 1))
            ins.propagate(held[:, :3], held[:, 3:], t - ins.t)
        ins.t = t if ins.t is None else max(ins.t, t)

    # ------------------------------------------------------------------ GNSS and UWB epochs
    def _take(self, m: Measurement) -> None:
        self.epoch_t = m.time
        if m.stream == "uwb":
            link = self._link(m.src, m.dst)
            if link is not None:
                self.rows.add([float(m.value[0])], [float(m.sigma[0])], *([x] for x in link))
            return
        i, lever = self._vehicle(m.src)
        if i is None:
            return
        if m.stream == "height":  # the up coordinate of a site: a fix's third row
            if m.sigma is not None:
                self.starts.height(i, m.time, float(m.value[0]), float(m.sigma[0]), lever)
            if not self.ins.active[i] or m.sigma is None:
                self.counts["skipped_updates"] += 1
                return
            self.rows.add([float(m.value[0])], [float(m.sigma[0])], [i], [-1], [2], [NAN3], [(-1, -1)], [lever], [ZERO3])
            return
        if not self.ins.active[i]:
            self._start(i, m.time, np.asarray(m.value, float), np.diag(np.asarray(m.sigma, float) ** 2), lever)
            return
        self.rows.add([float(x) for x in m.value[:3]], [float(x) for x in m.sigma[:3]], [i] * 3, [-1] * 3, [0, 1, 2],
                      [NAN3] * 3, [(-1, -1)] * 3, [lever] * 3, [ZERO3] * 3)

    def _take_ranges(self, b: MeasurementBatch) -> None:
        """_take of every row of a UWB batch, in order, an epoch (rows of one time) at a time."""
        for lo, hi in equal_time_runs(b.time):
            t = float(b.time[lo])
            if self.epoch_t is not None and t != self.epoch_t:
                self._close(float(b.arrival[lo]))
            self.epoch_t = t
            links = [self._link(src, dst) for src, dst in zip(b.src[lo:hi].tolist(), b.dst[lo:hi].tolist())]
            k = [r for r, link in enumerate(links) if link is not None]
            if k:
                self.rows.add(b.value[lo:hi, 0][k].tolist(), b.sigma[lo:hi, 0][k].tolist(), *zip(*(links[r] for r in k)))

    def _vehicle(self, src: str) -> tuple[int | None, np.ndarray]:
        """(the filter of the vehicle of site src (None: not a vehicle's), the site's lever arm (3,)
        m body frame); "uavI/base" or an unknown site of a vehicle is its body origin."""
        v, lever = self.sites[src] if src in self.sites else (src.partition("/")[0], ZERO3)
        return self.body.get(v), np.asarray(lever, float)

    def _link(self, src: str, dst: str) -> tuple | None:
        """The row template of a range src -> dst: (i, j (-1: an anchor), component 3, the
        anchor's position (3,) (NaN between vehicles), the two devices' delay states (-1: none),
        the lever arms (3,) m of the tags src and dst (zero at an anchor)); None for a range the
        filters do not use. Cached per link."""
        if (src, dst) not in self._links:
            (i, lever), link = self._vehicle(src), None
            dev = (self.device.get(src, -1), self.device.get(dst, -1))
            if i is not None and dst in self.anchors:
                link = (i, -1, 3, self.anchors[dst], dev, lever, ZERO3)
            elif i is not None and dst.partition("/")[0] in self.body:
                j, lever_j = self._vehicle(dst)
                link = (i, j, 3, NAN3, dev, lever, lever_j)
            self._links[(src, dst)] = link
        return self._links[(src, dst)]

    def _start(self, i: int, t: float, z: np.ndarray, z_cov: np.ndarray, lever: np.ndarray) -> None:
        """Vehicle i's filter at t (s) from position z (3,) m world of its site at lever (3,) m, with
        covariance z_cov (3, 3) m^2: its first fix, its initial pose, or the fix of its first ranges
        and heights (module docstring); after a re-initialisation with its own heading."""
        if np.isnan(self.held[i, 0]):
            self.counts["skipped_updates"] += 1
            return
        self._advance(t)
        p = heading(self.p, self.poses.get(self.vehicles[i])) if self.restart[i] is None else self.restart[i]
        b0, bv = self.bias0[i], self.bias_var[i]
        q, R, P_th, P_thba = levelled_start(self.held[i, :3] - b0[:3], bv[:3], p)
        P0 = np.diag(np.concatenate([np.zeros(3), [p["vel0_sigma"] ** 2] * 3, np.zeros(3), bv]))
        P0[ci.P_, ci.P_] = z_cov
        P0[ci.TH, ci.TH] = P_th
        P0[ci.TH, ci.BA] = P_thba
        P0[ci.BA, ci.TH] = P_thba.T
        for c in range(self.copies):
            self.ins.start(i + c * self.n, z - R @ lever, q, b0[:3], b0[3:], P0)

    def _close(self, now: float) -> None:
        """Apply the open epoch (module docstring); now (s): the clock when it is applied."""
        t, rows = self.epoch_t, self.rows
        self.epoch_t, self.rows = None, EpochRows()
        if not rows.z:
            return
        self._advance(t)
        z, sigma = np.array(rows.z, float), np.array(rows.sigma, float)
        comp = np.array(rows.component, int)
        rng = comp == 3
        var = sigma ** 2
        var[rng] = range_variances(self.uwb, sigma[rng], z[rng], antenna_delays=not self.device)
        rows = ci.Rows(z=z, var=var, i=np.array(rows.i, int), j=np.array(rows.j, int), component=comp,
                       other=np.array(rows.other, float), dev=np.array(rows.dev, int), lever=np.array(rows.lever, float),
                       lever_j=np.array(rows.lever_j, float))
        self.counts["epochs"] += 1
        anchor = np.flatnonzero(rng & (rows.j < 0))
        if anchor.size:  # the windows of a start from ranges (and of a re-initialisation): the whole declared variance
            whole = range_variances(self.uwb, sigma[anchor], z[anchor], antenna_delays=True)
            for k, v in zip(anchor.tolist(), np.sqrt(whole).tolist()):
                self.starts.range(int(rows.i[k]), t, rows.other[k], float(z[k]), v, rows.lever[k])
        ranged = np.unique(rows.i[anchor]).tolist()  # the vehicles with anchor ranges in the epoch
        rows, guarded = self._guard(rows, anchor)
        rows = self._rows(t, now, rows)
        status = self.ins.update(rows, self.gate, int(self.p["iterations"]), float(self.p["huber"]) or None)
        mine = rows.i < self.n  # the flown filters' rows (not their own-measurement copies')
        self.counts["rejected_measurements"] += int((status[mine] == 0).sum())
        self.counts["skipped_updates"] += int((status[mine] < 0).sum())
        if self.p["divergence_prob"]:
            for i in guarded:
                if self.innovations.diverged(i):
                    self._reinitialise(i, t)
        for i in ranged:
            if not self.ins.active[i]:
                self._range_start(i, t)

    def _guard(self, rows: ci.Rows, anchor: np.ndarray) -> tuple[ci.Rows, list[int]]:
        """(rows with the range variances times eq. R1's lambda: of the vehicle, or the larger of the
        two between vehicles; the vehicles whose anchor ranges entered eqs. R1 and D1): the prior
        innovations of the anchor ranges (rows anchor (k,)) of started vehicles recorded."""
        guard = self.innovations
        if guard is None:
            return rows, []
        k = anchor[self.ins.active[rows.i[anchor]]]
        k = k[self._fusable(rows.subset(k))]
        declared = rows.var[k]
        lam = guard.scale[rows.i]
        pair = rows.j >= 0
        lam[pair] = np.maximum(lam[pair], guard.scale[rows.j[pair]])
        rows = rows.replace(var=np.where(rows.component == 3, rows.var * lam, rows.var))
        if not k.size:
            return rows, []
        nu, hph = self.ins.innovations(rows.subset(k))
        guard.add(rows.i[k], nu, hph, declared)
        return rows, np.unique(rows.i[k]).tolist()

    def _fusable(self, rows: ci.Rows) -> np.ndarray:
        """(m,) bool: the anchor ranges rows (m,) the flown filters fuse as they are (centralized: all)."""
        return np.ones(rows.z.size, bool)

    def _range_start(self, i: int, t: float) -> None:
        """Start vehicle i (no fix, no initial position; or re-initialised) at t (s) from its window of
        ranges and heights (estimators.range_start) when they determine its origin."""
        fix = self.starts.fix(i, t)
        if fix is not None:
            self._start(i, t, fix[0], fix[1], ZERO3)

    def _reinitialise(self, i: int, t: float) -> None:
        """The divergence guard (eq. D1 failed at t, s), counted: vehicle i's filters started again
        from its window of ranges and heights, with its flown filter's heading and yaw variance (at
        least yaw0_sigma); kept running when the window does not determine a position
        (Reinitialisations)."""
        guard = self.innovations
        nis = guard.nis(i)
        above = int((nis > guard.c).sum())
        guard.reset(i)
        fix = self.starts.fix(i, t)
        if not self.reinit.add(self.vehicles[i], t, above, nis.size, guard.c, fix is not None):
            return
        R = quat_to_rotmat(self.ins.q[i])
        v = R.T @ [0.0, 0.0, 1.0]
        P_th = self.ins.marginals(slice(i, i + 1))[0][ci.TH, ci.TH]
        self.restart[i] = {**self.p, "yaw0": float(np.arctan2(R[1, 0], R[0, 0])),
                           "yaw0_sigma": max(float(np.sqrt(max(v @ P_th @ v, 0.0))), self.p["yaw0_sigma"])}
        for c in range(self.copies):
            self.ins.stop(i + c * self.n)
        self._start(i, t, fix[0], fix[1], ZERO3)


def _bias_prior(imu: dict) -> tuple[np.ndarray, np.ndarray]:
    """(6,) mean and (6,) variances of one vehicle's accel and gyro biases from its declared IMU
    table: turn-on and Gauss-Markov sigmas, and the accelerometer's scale factor and misalignment
    errors at 1 g folded into its bias (this filter has no scale-factor states)."""
    acc, gyr = imu["accel"], imu["gyro"]
    g2 = 9.81 ** 2 * (acc["scale_sigma"] ** 2 + acc["misalign_sigma"] ** 2)
    return (np.array([acc["bias"]] * 3 + [gyr["bias"]] * 3, float),
            np.array([acc["bias_sigma"] ** 2 + acc["gm_sigma"] ** 2 + g2] * 3 + [gyr["bias_sigma"] ** 2 + gyr["gm_sigma"] ** 2] * 3))


@dataclass(slots=True)
class EpochRows:
    """The rows of the open epoch as growing columns: value z and declared sigma (m), filter i,
    other vehicle j (-1: none), component (0-2: a GNSS axis, 2 also a height, 3: a range), other
    end's position (3,) m world (NaN: none), delay states of the two devices (2,) (-1: none), lever
    arms (3,) m body frame of the measured site on i and of the tag on j (zero: none)."""

    z: list = field(default_factory=list)
    sigma: list = field(default_factory=list)
    i: list = field(default_factory=list)
    j: list = field(default_factory=list)
    component: list = field(default_factory=list)
    other: list = field(default_factory=list)
    dev: list = field(default_factory=list)
    lever: list = field(default_factory=list)
    lever_j: list = field(default_factory=list)

    def add(self, z, sigma, i, j, component, other, dev, lever, lever_j) -> None:
        """Append rows: sequences of one length, one per column."""
        for column, rows in zip((self.z, self.sigma, self.i, self.j, self.component, self.other, self.dev, self.lever,
                                 self.lever_j), (z, sigma, i, j, component, other, dev, lever, lever_j)):
            column.extend(rows)


class CoopInsDistributed(CoopIns):
    description = "per-vehicle IMU error-state EKFs, GNSS + UWB anchors + neighbours' broadcasts over [network]; flies in the loop"
    joint = False
    Params = CoopInsDistributedParams
    # per vehicle i: the flown filter (index i) and the filter of its own measurements (IMU, GNSS,
    # anchors; index n + i) whose state it broadcasts, propagated and updated together
    copies = 2

    def _network(self, context: Context) -> None:
        check = float(self.p["broadcast_check"])
        self.threshold = float(chi2.isf(check, 3)) if check > 0 else np.inf
        self.counts["inconsistent_broadcasts"] = 0
        self.counts["nonlinear_ranges"] = 0
        self.counts["forced_ranges"] = 0
        self.locked = np.zeros(2 * self.n, int)  # per filter: epochs in a row with every anchor range nonlinear
        net = self.p["network"]
        self.network = context.links(None if net is None else from_dict(NetworkConfig, dict(net), "estimator params network"),
                                     self.n)
        n = self.n
        self.heard_t = np.full((n, n), -np.inf)  # receiver, sender: time of the broadcast held
        self.heard_s = np.zeros((n, n, 3))
        self.heard_v = np.zeros((n, n, 3))
        self.heard_cs = np.zeros((n, n, 3, 3))
        self.heard_cv = np.zeros((n, n, 3, 3))
        self.uses = np.zeros((n, n), int)  # receiver, sender: epochs a range to its broadcasts entered

    def health(self) -> dict[str, int]:
        st = self.network.stats()
        out = {**self.counts, **{k: int(st[k]) for k in ("sent", "delivered", "dropped", "bytes_sent")}}
        for k in ("latency_p50_s", "latency_p95_s"):  # as integer microseconds (health counts are integers)
            if np.isfinite(st[k]):
                out[k.replace("_s", "_us")] = int(round(st[k] * 1e6))
        return out

    def _rows(self, t: float, now: float, rows: ci.Rows) -> ci.Rows:
        """Broadcast every started vehicle's own-measurement antenna state at t, receive what has
        arrived by `now`, and make the epoch's rows (module docstring): the fixes and anchor ranges
        for both filters of their vehicle, each range between vehicles for both ends' flown
        filters, the other end's broadcast as a known point."""
        ins, net, n = self.ins, self.network, self.n
        ins.fold()
        s_all, dS = ins.antennas()
        own = slice(n, 2 * n)
        C_all = antenna_covariances(ins.blocks(), dS)
        Cs, Cv = C_all[own], ins.blocks()[own][:, ci.V_, ci.V_]
        s, v = s_all[own], ins.v[own]
        Cs, bad = checked_broadcast(s, Cs, s_all[:n], C_all[:n], self.threshold)
        self.counts["inconsistent_broadcasts"] += int((bad & ins.active[own]).sum())
        net.set_geometry(t, s)
        senders = np.flatnonzero(ins.active[own])
        sent = [x[senders] for x in (s, v, Cs, Cv)]  # copies (Cv is a view of the filters' P): as sent
        net.broadcast_all(t, senders, BROADCAST_BYTES, [(t, *(x[k] for x in sent)) for k in range(senders.size)])
        self._hear([msg for r in range(n) for msg in net.receive(now, r)])
        pair = rows.j >= 0
        mine = rows.subset(~pair)
        linearity = float(self.p["linearity"])
        parts = []
        for copy in (mine, mine.replace(i=mine.i + n)):
            if linearity > 0:  # a fix always; an anchor range where it is linear in the filter's uncertainty
                rng = np.flatnonzero(copy.component == 3)
                lin = linear_ranges(s_all[copy.i[rng]], C_all[copy.i[rng]], copy.other[rng], copy.var[rng], linearity)
                lin = self._unlock(copy.i[rng], lin)
                self.counts["nonlinear_ranges"] += int((~lin & (copy.i[rng] < n)).sum())
                keep = np.ones(copy.z.size, bool)
                keep[rng[~lin]] = False
                copy = copy.subset(keep)
            parts.append(copy)
        ranged = rows.subset(pair)
        for me, you, l_me, l_you in ((ranged.i, ranged.j, ranged.lever, ranged.lever_j),
                                     (ranged.j, ranged.i, ranged.lever_j, ranged.lever)):
            age = t - self.heard_t[me, you]
            ok = np.flatnonzero(age <= self.p["stale_s"])
            self.counts["stale_ranges"] += me.size - ok.size
            me, you, age, l_me, l_you = me[ok], you[ok], age[ok], l_me[ok], l_you[ok]
            point = self.heard_s[me, you] + self.heard_v[me, you] * age[:, None]
            if linearity > 0:
                lin = linear_ranges(s_all[me], C_all[me], point, ranged.var[ok], linearity)
                self.counts["nonlinear_ranges"] += int((~lin).sum())
                ok, me, you, age, point, l_me, l_you = ok[lin], me[lin], you[lin], age[lin], point[lin], l_me[lin], l_you[lin]
            cov = self.heard_cs[me, you] + age[:, None, None] ** 2 * self.heard_cv[me, you]
            # the neighbour broadcasts its reference antenna; a range from another of its tags is
            # taken to end there, the tags' offset (rotated by an attitude the receiver does not
            # know) as variance: |l - l_ref|^2 along the range, its largest projection
            offset = ((l_you - self.lever[you]) ** 2).sum(axis=1)
            u = s_all[me] - point  # the range's direction from the flown filter's antenna
            u /= np.maximum(np.linalg.norm(u, axis=1), 1e-9)[:, None]
            kappa = peer_kappa(float(self.p["peer_inflation"]), self.uses[me, you])
            np.add.at(self.uses, (me, you), 1)
            var = ranged.var[ok] + kappa * np.einsum("mi,mij,mj->m", u, cov, u) + offset
            parts.append(ci.Rows(z=ranged.z[ok], var=var, i=me, j=np.full(me.size, -1), component=ranged.component[ok],
                                 other=point, dev=ranged.dev[ok], lever=l_me, lever_j=np.zeros_like(l_me)))
        return ci.Rows(**{f: np.concatenate([getattr(r, f) for r in parts]) for f in ci.Rows.__dataclass_fields__})

    def _fusable(self, rows: ci.Rows) -> np.ndarray:
        """(m,) bool: the anchor ranges rows (m,) the flown filters find linear (linear_ranges): the
        others' innovations at a linearisation they fail say nothing of the filter's consistency."""
        linearity = float(self.p["linearity"])
        if linearity <= 0 or not rows.z.size:
            return np.ones(rows.z.size, bool)
        self.ins.fold()
        s_all, dS = self.ins.antennas()
        C_all = antenna_covariances(self.ins.blocks(), dS)
        return linear_ranges(s_all[rows.i], C_all[rows.i], rows.other, rows.var, linearity)

    def _unlock(self, i: np.ndarray, lin: np.ndarray) -> np.ndarray:
        """lin (m,) of anchor ranges of filters i (m,), with every range of a filter taken (counted in
        `forced_ranges`) at its UNLOCK_EPOCHS-th epoch in a row whose anchor ranges were all nonlinear:
        a filter whose covariance has grown past what one range can linearly correct would otherwise
        skip every anchor range for good (its line-searched update keeps the step from overshooting)."""
        f = np.unique(i)
        skipped = np.bincount(i, lin, minlength=self.locked.size)[f] == 0  # no linear range this epoch
        self.locked[f] = np.where(skipped, self.locked[f] + 1, 0)
        due = f[self.locked[f] >= UNLOCK_EPOCHS]
        if due.size:
            force = np.isin(i, due)
            self.counts["forced_ranges"] += int((force & ~lin & (i < self.n)).sum())
            lin = lin | force
            self.locked[due] = 0
        return lin

    def _hear(self, messages: list) -> None:
        """Hold each sender's newest broadcast (by its time; of equal times the last to arrive) at
        each receiver: the messages received, in arrival order per receiver."""
        if not messages:
            return
        r = np.array([m.dst for m in messages])
        k = np.array([m.src for m in messages])
        tb = np.array([m.payload[0] for m in messages])
        last = np.lexsort((np.arange(len(messages)), tb, k, r))  # by receiver, sender, time, arrival
        last = last[np.r_[(r[last][1:] != r[last][:-1]) | (k[last][1:] != k[last][:-1]), True]]
        last = last[tb[last] >= self.heard_t[r[last], k[last]]]
        r, k = r[last], k[last]
        self.heard_t[r, k] = tb[last]
        for held, f in ((self.heard_s, 1), (self.heard_v, 2), (self.heard_cs, 3), (self.heard_cv, 4)):
            held[r, k] = np.array([messages[i].payload[f] for i in last.tolist()]).reshape(len(last), *held.shape[2:])


# After this many epochs in a row with every anchor range of a filter skipped as nonlinear, its
# anchor ranges are taken all the same (CoopInsDistributed._unlock): at 5 Hz ranging, 1 s.
UNLOCK_EPOCHS = 5


def linear_ranges(s: np.ndarray, C: np.ndarray, other: np.ndarray, var: np.ndarray, factor: float) -> np.ndarray:
    """(m,) bool: the range rows that a filter can fuse linearly. A row: the filter's antenna s
    (m, 3) m with covariance C (m, 3, 3) m^2, the other end's point other (m, 3) m, the range's
    measurement variance var (m,) m^2. The range |s + e - other| of an antenna error e ~ N(0, C) is
    d + u^T e + e_perp^T e_perp / (2 d) + ... (u the unit direction, d the distance, e_perp the
    part of e across u); the EKF keeps the first-order term, the second is neglected. A row is
    linear where that term's mean, tr(C_perp) / (2 d) (C_perp = (I - u u^T) C (I - u u^T)), is at
    most factor times the range's own noise sd. A prior of metres across the range fails it: a
    first SPP fix, 3-14 m of vertical sigma, straddles the height of the anchors and of the
    neighbours, the range cannot tell above from below (the mirror image), and fused at such a
    prior it made the filter sure of the wrong side (docs/denied.md)."""
    d = s - other
    dist = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    u = d / dist[:, None]
    perp = np.trace(C, axis1=1, axis2=2) - np.einsum("mi,mij,mj->m", u, C, u)
    return perp <= factor * 2.0 * dist * np.sqrt(var)


def peer_kappa(cap: float, uses: np.ndarray) -> np.ndarray:
    """(m,) the factor on a neighbour's broadcast covariance in a range's variance, given how many
    epochs (m,) the receiver has already ranged to that neighbour's broadcasts: the broadcast error
    changes slowly, so the k-th epoch counts the same error a k-th time; its share is multiplied
    by k (the first range, whose error nothing has counted yet, by 1), up to cap = peer_inflation
    (beyond which the error is taken to have changed)."""
    return np.minimum(cap, 1.0 + np.asarray(uses, float))


def antenna_covariances(blocks: np.ndarray, dS: np.ndarray) -> np.ndarray:
    """(k, 3, 3) m^2 the antenna position covariance of each filter: ds = dp + dS dtheta, from its
    core covariance blocks (k, 15, 15) and dS = ds/ddtheta (k, 3, 3)."""
    A = np.concatenate([np.tile(np.eye(3), (len(blocks), 1, 1)), dS], axis=2)  # (k, 3, 6)
    idx = np.r_[0:3, 6:9]
    return A @ blocks[:, idx][:, :, idx] @ np.swapaxes(A, 1, 2)


def checked_broadcast(s_own: np.ndarray, C_own: np.ndarray, s_flown: np.ndarray, C_flown: np.ndarray,
                      threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(covariance (k, 3, 3) m^2, failed (k,) bool): the covariance each vehicle broadcasts with its own-measurement antenna estimate
    s_own (k, 3) m, C_own (k, 3, 3): a chi-square test of the vehicle's two estimates of one antenna,
    d = s_own - s_flown against C_own + C_flown (3 dof; the two filters share the vehicle's own
    measurements, so the covariance of d is smaller than that sum and the test errs towards
    passing); where d^T (C_own + C_flown)^-1 d > threshold the own filter is inconsistent (its error
    far beyond its covariance: measured, one vehicle's own filter 16 m off with a 1.3 m sigma) and
    the broadcast covariance is C_own + d d^T, which covers the disagreement in its direction."""
    d = s_own - s_flown
    nis = np.einsum("ki,ki->k", d, np.linalg.solve(C_own + C_flown, d[..., None])[..., 0])
    bad = nis > threshold
    return np.where(bad[:, None, None], C_own + d[:, :, None] * d[:, None, :], C_own), bad
