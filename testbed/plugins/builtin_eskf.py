"""Built-in `nav.eskf`: one loosely coupled IMU + GNSS + UWB error-state EKF per vehicle
(estimators.eskf), offline on a log or online in the control loop ([control] feedback).

Per vehicle "uavI" with an IMU: each IMU sample propagates the filter from its last time with
the previous sample held (zero-order hold) and then emits the position, velocity and attitude of
the body (the IMU site is the body origin) with their covariances, every `output_every`-th
sample. A GNSS fix or a UWB range first propagates the filter to its time of validity, then
updates it (a measurement older than the filter, possible with a latency, updates the current
state: the delay is not compensated). The filter starts at the vehicle's first GNSS fix: position
the fix minus the rotated antenna lever arm, velocity 0, roll and pitch levelled from the last
accelerometer sample (less the declared constant bias; its tilt error correlated with the
accelerometer bias error, estimators.eskf.level), yaw `yaw0`; before that its GNSS and UWB rows are skipped (counted).
A vehicle given a position in `initial_pose` (no GNSS needed) starts instead at its first IMU sample
from that position of the body origin with its sigma; its `yaw_deg`, `yaw_sigma_deg` replace yaw0,
yaw0_sigma. A vehicle with neither starts at the first anchor range at which its ranges and heights
of the last `start_window` s determine its body origin (estimators.range_start, eqs. S1-S2: that
fix and its covariance; heading yaw0 or its initial_pose yaw). One that never starts is counted
(health `unstarted_vehicles`) and named on stderr.
Each vehicle's noise and bias priors come from its own IMU table (estimators.sensor_models.vehicle_imu).

Noise: IMU white noise and bias walks from the declared [sensors.imu] table (a Gauss-Markov
bias of sigma s, time constant tau enters as a walk of density s sqrt(2 / tau)); turn-on and
Gauss-Markov bias sigmas as the initial bias uncertainty, the constant `bias` as its mean; the
accelerometer's and the gyro's scale factors and misalignments (declared scale_sigma,
misalign_sigma) are states too (estimators.eskf, mean 0, those sigmas): untreated, a gyro
misalignment of 1 % alone drove the attitude ANEES to 13.6 (95 % interval [1.55, 4.92]). The
accelerometer bias's body x and y are held (Schmidt's consider states, estimators.eskf
ACCEL_BIAS_ACROSS): across the thrust axis they cannot be told from the tilt error.
GNSS: the row's declared sigma. UWB ranges to anchors: the declared noise plus, as white
variance, the clock term of the two-way ranging (estimators.sensor_models.twr_range_variance) and
the per-link bias sigma; the antenna delays of the vehicle's tag and of each anchor (constant
per device, declared `antenna_delay_sigma`) are extra states of the vehicle's filter (mean 0,
that sigma), because a constant bias treated as white noise would make the filter overconfident
on long stretches without GNSS. Ranges between tags are not used (a filter per vehicle cannot
use another's broadcast estimate without counting shared information twice).
Heights (a recorded dataset's `height` stream: the up coordinate of a site or of a body's origin,
m world): each updates its vehicle's filter as a position's third row, with the row's sigma.
Innovation gate: NIS above the chi-square quantile 1 - gate_prob (rejections counted); after
GATE_LOCK_EPOCHS range epochs in a row with every range rejected, the position's covariance is
opened until every range of the epoch passes (health `gate_inflations`; docs/estimators.md). The white
IMU densities are measured on the samples (`imu_noise_window`, estimators.imu_adapt), floored at the
declared ones. The range variances are scaled by the median covariance match of each vehicle's last
`range_window` range innovations (eq. R1), and a vehicle whose innovations fail the sign test of
eq. D1 (`divergence_prob`) is re-initialised from its ranges and heights (health
`reinitialisations`, stderr; estimators.range_innovations, docs/estimators.md).

params: yaw0 (rad, 0), yaw0_sigma (rad, 0.1), tilt0_sigma (rad, 0.05), vel0_sigma (m/s, 1.0),
initial_pose ({}: per vehicle, InitialPose), imu_noise_window (100), imu_noise_average (1),
start_window (s, 2), range_window (20),
range_noise_adapt (true), divergence_prob (1e-6), gate_prob (1e-4), output_every (1), iterations (1: the plain EKF; more: Gauss-Newton iterations of
each update, estimators.eskf.update. Measured: no better with four anchors, worse with one; the
ranges of one epoch in one update is what matters, see `_ranges`).
"""
from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from estimators import eskf
from estimators.core import symmetrize
from estimators.imu_adapt import WINDOW, DifferenceNoise
from estimators.range_innovations import ALPHA as DIVERGENCE_ALPHA
from estimators.range_innovations import WINDOW as RANGE_WINDOW
from estimators.range_innovations import RangeInnovations
from estimators.range_start import BodyStarts
from estimators.sensor_models import imu_noise, range_variances, vehicle_imu
from estimators.so3 import quat_to_rotmat
from testbed.config import check_fields, from_dict, key
from testbed.plugins.api import Context, Estimate, EstimateBatch, Measurement, MeasurementBatch
from testbed.plugins.epochs import equal_time_runs
from testbed.plugins.params import fields_of, read


@dataclass(frozen=True, kw_only=True)
class InitialPose:
    """One vehicle's own start (StartParams.initial_pose.BODY): position (3,) m world ENU of the body
    origin with position_sigma (m, 1 sigma per axis), to start at the vehicle's first IMU sample
    without a GNSS fix (None: at its first fix); yaw_deg, yaw_sigma_deg its own heading and its
    1 sigma (deg; None: yaw0, yaw0_sigma)."""

    position: tuple[float, float, float] | None = key(None, unit="m")
    position_sigma: float = key(1.0, lo=0, lo_open=True, unit="m")
    yaw_deg: float | None = key(None, unit="deg")
    yaw_sigma_deg: float | None = key(None, lo=0, unit="deg")

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True, kw_only=True)
class StartParams:
    """How an IMU filter of the swarm starts (at its vehicle's first GNSS fix, or from an initial pose), and how often it outputs."""

    yaw0: float = key(0.0, unit="rad", doc="initial heading")
    yaw0_sigma: float = key(0.1, lo=0, unit="rad", doc="initial heading uncertainty, 1 sigma")
    tilt0_sigma: float = key(0.05, lo=0, unit="rad", doc="initial tilt uncertainty beyond the levelling error, 1 sigma")
    vel0_sigma: float = key(1.0, lo=0, unit="m/s", doc="initial velocity uncertainty per axis, 1 sigma")
    output_every: int = key(1, lo=1, doc="estimates at every n-th IMU sample")
    imu_noise_window: int = key(WINDOW, lo=0, doc="IMU white densities measured from the samples' first differences over "
                                "blocks of this many samples, floored at the declared ones (estimators.imu_adapt; 0: the declared)")
    imu_noise_average: int = key(1, lo=1, doc="eqs. A1-A2 on the means of this many successive samples, each block "
                                 "imu_noise_window means: the Allan variance at that span (estimators.imu_adapt; 1: the samples)")
    initial_pose: dict = key(factory=dict, doc="per vehicle {BODY = {position = [x, y, z] (m, world), position_sigma (m, 1), "
                             "yaw_deg (deg), yaw_sigma_deg (deg)}}: with a position, the vehicle starts at its first IMU "
                             "sample without a GNSS fix; its yaw replaces yaw0, yaw0_sigma")
    start_window: float = key(2.0, lo=0, unit="s", doc="span of the anchor ranges and heights that start (and re-initialise) a "
                              "vehicle without a fix or an initial position (estimators.range_start)")
    range_window: int = key(RANGE_WINDOW, lo=0, doc="ranges per vehicle of the range-noise match (eq. R1) and the divergence "
                            "test (eq. D1) (estimators.range_innovations; 0: neither)")
    range_noise_adapt: bool = key(True, doc="range variances scaled by the covariance match of the innovations (eq. R1)")
    divergence_prob: float = key(DIVERGENCE_ALPHA, lo=0, hi=1, hi_open=True,
                                 doc="false-alarm probability of the divergence test (eq. D1; 0: no guard)")

    def __post_init__(self) -> None:
        check_fields(self)
        for body, table in self.initial_pose.items():
            from_dict(InitialPose, table, "", f"initial_pose.{body}")


# The gate's release (NavEskf._ranges): after this many range epochs in a row with every range
# rejected, the position's covariance is opened until every range of the epoch passes. A
# consistent filter rejects a whole epoch with probability at most gate_prob (1e-4) x its ranges:
# five in a row do not happen to it; a filter that has drifted away from its ranges gets back.
GATE_LOCK_EPOCHS = 5


def imu_adapter(p: dict, noise: list) -> DifferenceNoise | None:
    """The IMU noise measured from the data (estimators.imu_adapt) of vehicles with declared noise
    (estimators.eskf.ImuNoise, one each), by params p (StartParams); None when off."""
    if not p["imu_noise_window"]:
        return None
    return DifferenceNoise(np.array([[k.accel_density, k.gyro_density] for k in noise]), int(p["imu_noise_window"]),
                           int(p["imu_noise_average"]))


def initial_poses(p: dict, vehicles, entry: str) -> dict[str, InitialPose]:
    """{body: InitialPose} of the params p (fields_of a StartParams); a body not among vehicles is a
    ValueError naming it."""
    out = {body: from_dict(InitialPose, table, "", f"initial_pose.{body}") for body, table in p["initial_pose"].items()}
    unknown = [b for b in out if b not in vehicles]
    if unknown:
        raise ValueError(f"{entry} params initial_pose: {', '.join(unknown)} not a vehicle (vehicles: {', '.join(vehicles)})")
    return out


def heading(p: dict, pose: InitialPose | None) -> dict:
    """p with one vehicle's yaw0, yaw0_sigma (rad): its InitialPose's when it gives them."""
    if pose is None or (pose.yaw_deg is None and pose.yaw_sigma_deg is None):
        return p
    return {**p, "yaw0": p["yaw0"] if pose.yaw_deg is None else math.radians(pose.yaw_deg),
            "yaw0_sigma": p["yaw0_sigma"] if pose.yaw_sigma_deg is None else math.radians(pose.yaw_sigma_deg)}


def range_guard(p: dict, n: int) -> RangeInnovations | None:
    """The range-noise match (eq. R1) and divergence test (eq. D1) of n vehicles
    (estimators.range_innovations) by params p (StartParams); None when range_window is 0."""
    if not p["range_window"]:
        return None
    return RangeInnovations(n, int(p["range_window"]), p["divergence_prob"] or DIVERGENCE_ALPHA, bool(p["range_noise_adapt"]))


class Reinitialisations:
    """The divergence guard's record (eq. D1): health counts `reinitialisations`,
    `reinitialised_diverged_nis` (by reason: the only one, eq. D1) and `reinitialisation_last_ms`
    (the time of the last, ms); a divergence whose window of ranges and heights does not determine
    a position cannot re-initialise: the filter runs on, counted in `divergences_without_fix`
    (and `divergence_last_ms`). One stderr line per event at finish()."""

    def __init__(self, counts: dict):
        self.counts, self.events = counts, []
        counts["reinitialisations"] = 0

    def add(self, body: str, t: float, above: int, window: int, c: float, fixed: bool) -> bool:
        """body failed eq. D1 at t (s): `above` of its last `window` ranges had a NIS above c;
        fixed: its window gives a position. Returns fixed (re-initialise)."""
        what = f"{body} at {t:.2f} s: {above} of its last {window} ranges with NIS above {c:.2f} (eq. D1)"
        c = self.counts
        if fixed:
            c["reinitialisations"] += 1
            c["reinitialised_diverged_nis"] = c.get("reinitialised_diverged_nis", 0) + 1
            c["reinitialisation_last_ms"] = int(round(t * 1e3))
            self.events.append(f"re-initialised from ranges and heights: {what}")
        else:
            c["divergences_without_fix"] = c.get("divergences_without_fix", 0) + 1
            c["divergence_last_ms"] = int(round(t * 1e3))
            self.events.append(f"diverged, not re-initialised (its ranges and heights give no position): {what}")
        return fixed

    def note(self, entry: str) -> None:
        for e in self.events:
            print(f"testbed: note: {entry}: {e}", file=sys.stderr)


def note_unstarted(entry: str, bodies: list[str], counts: dict) -> None:
    """Say in health (`unstarted_vehicles`) and in one stderr line which vehicles never started
    (no GNSS fix and no initial_pose position), so no filter is silent about estimating nothing."""
    if bodies:
        counts["unstarted_vehicles"] = len(bodies)
        print(f"testbed: note: {entry}: {', '.join(bodies)} never started: no position fix (GNSS) and no initial_pose position "
              "(params initial_pose.BODY.position)", file=sys.stderr)


@dataclass(frozen=True, kw_only=True)
class NavEskfParams(StartParams):
    """Parameters of nav.eskf ([[estimators]] params)."""

    gate_prob: float = key(1e-4, lo=0, hi=1, hi_open=True, doc="NIS gate: false-alarm probability (0: no gate)")
    iterations: int = key(1, lo=1, doc="Gauss-Newton iterations of each update (1: the plain EKF)")


def levelled_start(f: np.ndarray, accel_bias_var: np.ndarray, p: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A vehicle's first attitude and its covariance (NavEskf._start): q (4,) wxyz and R (3, 3) levelled
    from the bias-corrected specific force f (3,) m/s^2 with heading p["yaw0"], and the blocks
    P[TH, TH], P[TH, BA] (3, 3) given the accelerometer bias variances accel_bias_var (3,) m^2/s^4:
    the levelling error dtheta = J db_a (estimators.eskf.level), plus p["tilt0_sigma"] across the
    vertical and p["yaw0_sigma"] about it (rad)."""
    q, J = eskf.level(f, p["yaw0"])
    R = quat_to_rotmat(q)
    v = R.T @ [0.0, 0.0, 1.0]  # the vertical in the body frame
    Pb = np.diag(accel_bias_var)
    P_th = J @ Pb @ J.T + p["tilt0_sigma"] ** 2 * (np.eye(3) - np.outer(v, v)) + p["yaw0_sigma"] ** 2 * np.outer(v, v)
    return q, R, P_th, J @ Pb


def _matrix_var(errors: dict) -> np.ndarray:
    """(9,) prior variances of a triad's K = scale factors (diagonal) + misalignments (off it),
    row-major, as testbed.sensors.noise.TriadErrors draws them."""
    return np.where(np.eye(3).ravel() > 0, errors["scale_sigma"] ** 2, errors["misalign_sigma"] ** 2)


class _Vehicle:
    """One vehicle's filter: nominal x (34 + E,), covariance P (33 + E, 33 + E), time t (s), held
    IMU sample."""

    __slots__ = ("x", "P", "t", "imu", "samples", "ranges", "noise", "bias0", "bias_var", "k_var", "locked", "k", "restart")

    def __init__(self, imu: dict, k: int):
        self.x, self.P, self.t, self.imu, self.samples = None, None, None, None, 0
        self.k = k  # its index among the vehicles
        self.restart = None  # the params of its next start after a re-initialisation (its own heading)
        self.locked = 0  # range epochs in a row whose every range the gate rejected
        # its own declared IMU (estimators.sensor_models.vehicle_imu): noise, bias mean and variances
        acc, gyr = imu["accel"], imu["gyro"]
        self.noise = imu_noise(imu)
        self.bias0 = np.array([acc["bias"]] * 3 + [gyr["bias"]] * 3, float)
        self.bias_var = np.array([acc["bias_sigma"] ** 2 + acc["gm_sigma"] ** 2] * 3 + [gyr["bias_sigma"] ** 2 + gyr["gm_sigma"] ** 2] * 3)
        self.k_var = np.concatenate([_matrix_var(acc), _matrix_var(gyr)])
        self.ranges = []  # (time, z, lever, anchor, extras, variance) of the UWB epoch not yet applied


class NavEskf:
    description = "per-vehicle loosely coupled IMU + GNSS + UWB error-state EKF (estimators.eskf); flies in the loop"

    Params = NavEskfParams

    def __init__(self, context: Context, params: dict):
        self.p = fields_of(read(NavEskfParams, params, "nav.eskf"))
        if "imu" not in context.sensors:
            raise ValueError("needs [sensors.imu]")
        imu = context.sensors["imu"]
        self.poses = initial_poses(self.p, list(context.vehicles), type(self).__name__)
        self.uwb = context.sensors.get("uwb")
        self.sites, self.anchors = context.sites, context.anchors
        # extra states: antenna delays of the own tag (0) and of each anchor (1..A), m
        delay = self.uwb["antenna_delay_sigma"] if self.uwb is not None else 0.0
        self.delay_var = np.full(1 + len(self.anchors), delay ** 2) if delay > 0 else np.zeros(0)
        self.delay_index = {name: k for k, name in enumerate(self.anchors, start=1)}
        self.gate = {m: float(chi2.isf(self.p["gate_prob"], m)) for m in (1, 3)}
        self.v = {name: _Vehicle(vehicle_imu(imu, name), k) for k, name in enumerate(context.vehicles)}
        self.adapt = imu_adapter(self.p, [f.noise for f in self.v.values()])
        self.vehicles = list(self.v)  # index -> vehicle
        self.counts = {"rejected_measurements": 0, "skipped_updates": 0, "gate_inflations": 0}
        self.starts = BodyStarts(self.p["start_window"], self.p["vel0_sigma"])
        self.innovations = range_guard(self.p, len(self.v))
        self.reinit = Reinitialisations(self.counts)

    # ------------------------------------------------------------------ the protocol
    def process(self, m: Measurement):
        body = self.sites[m.src][0] if m.stream == "imu" else self._site(m.src)[0]
        f = self.v.get(body)
        if f is not None and f.ranges and not (m.stream == "uwb" and m.time == f.ranges[0][0]):
            self._ranges(f)
        if m.stream == "imu":
            return self._imu(m)
        if m.stream == "gnss":
            self._gnss(m)
        elif m.stream == "uwb":
            self._uwb(m)
        elif m.stream == "height":
            self._height(m)
        return []

    def finish(self) -> list[Estimate]:
        note_unstarted(type(self).__name__, [b for b, f in self.v.items() if f.x is None], self.counts)
        self.reinit.note(type(self).__name__)
        return []

    def health(self) -> dict[str, int]:
        return dict(self.counts)

    # ------------------------------------------------------------------ per stream
    def _to(self, f: _Vehicle, t: float) -> None:
        """Propagate filter f to time t (s) with its held IMU sample (nothing if t is not later)."""
        self._propagate([f], t)

    def _propagate(self, fs: list[_Vehicle], t: float) -> None:
        """Propagate the started filters fs to time t (s), each with its held IMU sample (one not
        earlier than t unchanged), batched over them (estimators.eskf.step)."""
        fs = [f for f in fs if t > f.t]
        if not fs:
            return
        dt = np.array([t - f.t for f in fs])
        x, F = eskf.step(np.stack([f.x for f in fs]), np.stack([f.imu[0] for f in fs]), np.stack([f.imu[1] for f in fs]), dt)
        P = symmetrize(F @ np.stack([f.P for f in fs]) @ np.swapaxes(F, 1, 2) + eskf.process_noise([f.noise for f in fs], dt, F.shape[-1]))
        for k, f in enumerate(fs):
            f.x, f.P, f.t = x[k], P[k], t

    def process_batch(self, b: MeasurementBatch) -> list[Estimate]:
        """process() of each row of b, in order (the protocol); an IMU batch an instant (rows of
        one time, distinct vehicles) at a time: `_instant` first, then its filters propagated
        together (`_imu_rows`)."""
        if b.stream != "imu":
            return [e for m in b.rows() for e in self.process(m)]
        out = []
        for lo, hi in equal_time_runs(b.time):
            bodies = [self.sites[s][0] for s in b.src[lo:hi].tolist()]
            if len(set(bodies)) < len(bodies):  # a vehicle twice in an instant: row by row
                out += [e for m in b.rows()[lo:hi] for e in self.process(m)]
                continue
            self._instant(b, lo, bodies)
            out += self._imu_rows(float(b.time[lo]), bodies, np.asarray(b.value[lo:hi], float))
        return out

    def _instant(self, b: MeasurementBatch, lo: int, bodies: list[str]) -> None:
        """What process() does for each IMU row of an instant before its sample (b's rows from lo,
        of vehicles bodies): the vehicle's pending UWB ranges."""
        for body in bodies:
            f = self.v.get(body)
            if f is not None and f.ranges:
                self._ranges(f)

    def _imu(self, m: Measurement) -> list[EstimateBatch]:
        return self._imu_rows(m.time, [self.sites[m.src][0]], np.asarray(m.value, float)[None])

    def _imu_rows(self, t: float, bodies: list[str], values: np.ndarray) -> list[EstimateBatch]:
        """IMU samples values (k, 6) [accel m/s^2, gyro rad/s] of the distinct vehicles bodies
        (k,) at t (s): each started filter propagated to t with its held sample (together), the
        new samples held, the measured white noise updated, unstarted filters started where they
        have an initial pose, and every `output_every`-th sample's estimates (`_estimates`)."""
        fs = [self.v[b] for b in bodies]
        self._propagate([f for f in fs if f.x is not None], t)
        for f, value in zip(fs, values):
            f.imu = (value[:3], value[3:])
        if self.adapt is not None:
            done = self.adapt.add([self.v[b].k for b in bodies], t, values)
            for k in done.tolist():
                acc, gyr = self.adapt.density[k]
                f = self.v[self.vehicles[k]]
                f.noise = dataclasses.replace(f.noise, accel_density=float(acc), gyro_density=float(gyr))
        shown = []  # the vehicles whose estimates this sample gives
        for body, f in zip(bodies, fs):
            if f.x is None:
                f.t = t
                pose = self.poses.get(body)
                if pose is None or pose.position is None or f.restart is not None:
                    continue
                self._start(f, body, t, np.array(pose.position, float), np.diag(np.full(3, pose.position_sigma ** 2)), np.zeros(3))
            f.samples += 1
            if not f.samples % self.p["output_every"]:
                shown.append(body)
        return self._estimates(t, shown)

    def _estimates(self, t: float, bodies: list[str]) -> list[EstimateBatch]:
        """The position, velocity and attitude of the filters of `bodies` (k,) at t (s), with their
        covariances: one EstimateBatch per quantity (no object per vehicle); [] for none."""
        if not bodies:
            return []
        x = np.stack([self.v[b].x[0:10] for b in bodies])  # (k, 10): p, v, q
        P = np.stack([self.v[b].P[0:9, 0:9] for b in bodies])  # (k, 9, 9): p, v, theta
        time, target = np.full(len(bodies), t), tuple(bodies)
        return [EstimateBatch(time=time, target=target, quantity=q, value=x[:, s], cov=P[:, e, e].copy())
                for q, s, e in (("position", eskf.P, eskf.P), ("velocity", eskf.V, eskf.V), ("attitude", slice(6, 10), eskf.TH))]

    def _start(self, f: _Vehicle, body: str, t: float, z: np.ndarray, z_cov: np.ndarray, lever: np.ndarray,
               p: dict | None = None) -> None:
        """Start at time t (s) from position z (3,) m world of the site at lever (3,) m body frame
        with covariance z_cov (3, 3) m^2 (the first fix, the initial pose of the body origin, or the
        fix of its first ranges and heights), the heading of p (params; None: heading()): the
        initial state and covariance (module docstring). The levelling error
        is the accelerometer bias error seen across the vertical (estimators.eskf.level): the
        initial tilt and accelerometer bias errors are correlated, dtheta = J db_a, plus
        tilt0_sigma across the vertical (the vehicle not at rest: a drag-free quadrotor's
        accelerometer reads its thrust axis, so an acceleration a tilts the levelled vertical
        by a / g, 0.05 rad at 0.5 m/s^2) and yaw0_sigma about it."""
        p = heading(self.p, self.poses.get(body)) if p is None else p
        q, R, P_th, P_thba = levelled_start(f.imu[0] - f.bias0[:3], f.bias_var[:3], p)
        x = np.zeros(eskf.N_ERR + 1 + len(self.delay_var))
        x[0:3] = z - R @ lever
        x[6:10] = q
        x[10:16] = f.bias0
        P = np.diag(np.concatenate([np.zeros(3), [p["vel0_sigma"] ** 2] * 3, np.zeros(3),
                                    f.bias_var, f.k_var, self.delay_var]))
        P[eskf.P, eskf.P] = z_cov
        P[eskf.TH, eskf.TH] = P_th
        P[eskf.TH, eskf.BA] = P_thba
        P[eskf.BA, eskf.TH] = P_thba.T
        f.x, f.P, f.t = x, P, max(f.t, t)

    def _gnss(self, m: Measurement) -> None:
        body, lever = self._site(m.src)
        f = self.v[body]
        if f.imu is None:
            self.counts["skipped_updates"] += 1
            return
        if f.x is None:
            self._start(f, body, m.time, np.asarray(m.value, float), np.diag(np.asarray(m.sigma, float) ** 2), lever)
            return
        self._to(f, m.time)
        self._apply(f, np.asarray(m.value, float), lambda x: eskf.site_position(x, lever), np.diag(np.asarray(m.sigma, float) ** 2))

    def _height(self, m: Measurement) -> None:
        """A height: the up coordinate (m, world) of a site, or of a body's origin (docs/replay.md),
        with its row's sigma; a row without a sigma, or before the filter started, is skipped (counted)."""
        body, lever = self._site(m.src)
        f = self.v.get(body)
        if f is None:
            return
        if m.sigma is not None:
            self.starts.height(body, m.time, float(m.value[0]), float(np.asarray(m.sigma, float)[0]), lever)
        if f.x is None or m.sigma is None:
            self.counts["skipped_updates"] += 1
            return
        self._to(f, m.time)

        def up(x):  # z = e_3^T (p + R l), the third row of the site's position and its Jacobian
            s, H = eskf.site_position(x, lever)
            return s[2:], H[2:]
        self._apply(f, np.asarray(m.value, float)[:1], up, np.diag(np.asarray(m.sigma, float)[:1] ** 2))

    def _uwb(self, m: Measurement) -> None:
        if m.dst not in self.anchors:
            return  # between tags: not used (module docstring)
        body, lever = self._site(m.src)
        f = self.v[body]
        anchor = self.anchors[m.dst]
        sigma = np.asarray(m.sigma, float)[:1]
        # the window of a start from ranges (and of a re-initialisation): the range's whole declared variance
        var = float(range_variances(self.uwb, sigma, np.asarray(m.value, float)[:1], antenna_delays=True)[0])
        self.starts.range(body, m.time, anchor, float(m.value[0]), float(np.sqrt(var)), lever)
        if f.x is None:  # this range starts it (it is in the fix), or is skipped
            self._range_start(f, body, m.time)
            if f.x is None:
                self.counts["skipped_updates"] += 1
            return
        self._to(f, m.time)
        extras = (0, self.delay_index[m.dst]) if len(self.delay_var) else ()
        r, _ = eskf.range_model(f.x, lever, anchor, extras)
        # the antenna delays are states here: the rest as white noise, at the predicted range r
        var = float(range_variances(self.uwb, sigma, np.array([r]), antenna_delays=False)[0])
        f.ranges.append((m.time, float(m.value[0]), lever, anchor, extras, var))

    def _ranges(self, f: _Vehicle) -> None:
        """Apply the pending ranges of one UWB epoch (same time of validity) as one update: each
        range gated alone at the prior (scalar NIS), the accepted ones together, all linearised at
        the prior. One range at a time relinearises each at the state the previous one moved: with
        an SPP first fix 5 m off, that walked the vertical away (seed 103 of tests/test_loop.py's
        scenario: 12 m error, the gate then locking the ranges out, position NEES > 10^4)."""
        epoch, f.ranges = f.ranges, []
        z = np.array([e[1] for e in epoch])
        declared = np.array([e[5] for e in epoch])
        k, guard = f.k, self.innovations
        Rn = np.diag(declared * (guard.scale[k] if guard is not None else 1.0))  # eq. R1's lambda

        def model(x, rows=range(len(epoch))):
            hs = [eskf.range_model(x, epoch[k][2], epoch[k][3], epoch[k][4]) for k in rows]
            return np.array([h for h, _ in hs]), np.vstack([H for _, H in hs])
        h, H = model(f.x)
        if guard is not None:
            guard.add(np.full(z.size, k), z - h, np.einsum("ij,jk,ik->i", H, f.P, H), declared)
            if self.p["divergence_prob"] and guard.diverged(k) and self._reinitialise(f, k, epoch[0][0]):
                return
        keep = eskf.screen(f.P, z - h, H, Rn, self.gate[1])
        f.locked = 0 if keep.any() else f.locked + 1
        if f.locked >= GATE_LOCK_EPOCHS:
            # the gate's release: the position re-opened, P[p, p] += delta I, with
            # delta = max_k (r_k^2 / g - S_k): a range's H has a unit vector on the position, so
            # S_k grows by delta and every range of the epoch then passes
            S = np.einsum("ij,jk,ik->i", H, f.P, H) + np.diag(Rn)
            delta = float(np.max((z - h) ** 2 / self.gate[1] - S)) * (1.0 + 1e-9)
            f.P[eskf.P, eskf.P] += max(delta, 0.0) * np.eye(3)
            keep = eskf.screen(f.P, z - h, H, Rn, self.gate[1])
            f.locked = 0
            self.counts["gate_inflations"] += 1
        self.counts["rejected_measurements"] += int(np.sum(~keep))
        if keep.any():
            rows = np.flatnonzero(keep)
            f.x, f.P, _ = eskf.update(f.x, f.P, z[rows], lambda x: model(x, rows), Rn[np.ix_(rows, rows)], np.inf,
                                      self.p["iterations"], eskf.ACCEL_BIAS_ACROSS)

    def _range_start(self, f: _Vehicle, body: str, t: float) -> None:
        """Start a vehicle with no fix or initial position, or re-initialise one, at t (s) from its
        window of ranges and heights (estimators.range_start) when they determine its origin."""
        if f.imu is None:
            return
        fix = self.starts.fix(body, t)
        if fix is not None:
            self._start(f, body, t, fix[0], fix[1], np.zeros(3), f.restart)

    def _reinitialise(self, f: _Vehicle, k: int, t: float) -> bool:
        """The divergence guard (eq. D1 failed at t, s), counted: the filter started again from its
        window of ranges and heights, with its own heading and yaw variance (at least yaw0_sigma)
        and the other start priors; True if so, False (kept running) when the window does not
        determine a position (Reinitialisations)."""
        body, guard = self.vehicles[k], self.innovations
        nis = guard.nis(k)
        above = int((nis > guard.c).sum())
        guard.reset(k)
        if not self.reinit.add(body, t, above, nis.size, guard.c, self.starts.fix(body, t) is not None):
            return False
        R = quat_to_rotmat(f.x[6:10])
        v = R.T @ [0.0, 0.0, 1.0]
        yaw_sd = float(np.sqrt(max(v @ f.P[eskf.TH, eskf.TH] @ v, 0.0)))
        f.restart = {**self.p, "yaw0": math.atan2(R[1, 0], R[0, 0]), "yaw0_sigma": max(yaw_sd, self.p["yaw0_sigma"])}
        f.x, f.P, f.locked = None, None, 0
        self._range_start(f, body, t)
        return True

    # ------------------------------------------------------------------ helpers
    def _site(self, site: str) -> tuple[str, np.ndarray]:
        """(vehicle, lever arm (3,) m) of a site; "uavI/base" is the body origin."""
        if site in self.sites:
            return self.sites[site]
        return site.partition("/")[0], np.zeros(3)

    def _apply(self, f: _Vehicle, z: np.ndarray, model, Rn: np.ndarray) -> None:
        """Iterated update of filter f with measurement z (m,) and model(x) -> (h (m,), H (m, n))."""
        f.x, f.P, res = eskf.update(f.x, f.P, z, model, Rn, self.gate[len(z)], self.p["iterations"], eskf.ACCEL_BIAS_ACROSS)
        if not res.accepted:
            self.counts["rejected_measurements"] += 1
