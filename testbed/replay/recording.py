"""A recorded dataset (docs/replay.md) read whole and checked: its spec, its measurements in feeding
order as the plugin protocol's Measurements, the Context of each estimator, and its truth.

Streams fed (Measurement.stream, value, sigma; src, dst site or body names):
- links.csv kind uwb / phase: stream "uwb" / "phase", value (1,) range m; kind range-rate: stream
  "range-rate", value (1,) m/s; sigma (1,) from the row, None where the row has none.
- poses.csv kind gnss: stream "gnss", value (3,) antenna (or body) position m world ENU, sigma
  (3,) m (sigma_x, sigma_y, sigma_z); kind mocap: stream "mocap", value (7,) position m and
  quaternion wxyz (body to world), sigma (3,) m or None.
- imu.csv: stream "imu", value (6,) specific force m/s^2 then angular rate rad/s (site frame),
  sigma (6,) or None. height.csv: stream "height", value (1,) up coordinate m, sigma (1,) or None.
- phase.csv: stream "phase" as a simulated run feeds it (testbed.sensors.phase): value (3,)
  [carrier phase rad, range m, range rate m/s (NaN: none)], sigma (3,) or None, extra master_pos
  (3,) m and master_vel (3,) m/s (the src antenna by its master's navigation solution, world),
  rate_periods (int), wavelength (m), slip (bool); one Measurement per row (a batch has no extra).
  A dataset takes the phase stream from phase.csv or from links rows of kind phase, not both.
- camera.csv: stream "camera", src the camera site, dst the seen site, value (5,) [alpha, beta]
  focal-plane coordinates (units of the focal length) and [bx, by, bz] the unit line of sight
  (camera frame), sigma None (testbed.sensors.camera).
Times: the files' clock minus window.start; arrival: the row's arrival (default its time).
Order: as a simulated run's (testbed.plugins.feed): arrival, time, stream name, row of the stream.
calibration.csv (testbed.replay.calibration), when present: its known bias and scale are removed
from the uwb ranges at load, and the sigma of each link's remaining bias is
Context.sensors["uwb"]["bias_sigma"] {src: {dst: m}}.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from testbed.errors import ConfigError
from testbed.plugins.api import Context, Measurement, MeasurementBatch
from testbed.plugins.channel import Channel
from testbed.sim.network import Network
from testbed.plugins.truth import Truth, relative
from testbed.replay.bag_read import bag_tables
from testbed.replay.calibration import Calibration, CalibrationFile, read_calibration, read_calibration_file
from testbed.replay.spec import ReplaySpec, Window, load_spec
from testbed.replay.tables import CAMERA_COLUMNS, PHASE_MASTER_COLUMNS, REQUIRED_TABLES, SCHEMAS, Table, find, read_table
from testbed.rng import stream_rng

LINK_KINDS = ("uwb", "phase", "range-rate")
#: m: the longest range a link may report. Radio ranging between robots (UWB: tens to a few hundred
#: metres; carrier phase between antennas of one swarm) never spans 100 km; a value beyond is a
#: corrupt row, refused at load so that no residual, square or covariance of it can overflow.
MAX_RANGE_M = 1e5
#: m/s: the largest range rate a link may report (ten times the speed of sound), for the same reason.
MAX_RANGE_RATE_M_S = 3.4e3
#: the smallest 1-sigma a row may declare (m, m/s, m/s^2, rad/s): below any sensor's, and its inverse
#: square (a weight) times a squared residual of table numbers stays far from overflow
MIN_SIGMA = 1e-9
POSE_KINDS = ("gnss", "mocap")
#: (table, column of the per-row sigma(s), value columns) of the per-site/body tables
QUAT = ("qw", "qx", "qy", "qz")


@dataclass(frozen=True, slots=True)
class Recording:
    """spec; directory; tables {name: Table} (rows within the window, times in the files' clock);
    feed: every measurement in feeding order, runs of one stream as MeasurementBatches (the rows
    one by one: measurements()); bias_sigma: {src: {dst: m}} the sigma of each calibrated uwb
    link's remaining bias (testbed.replay.calibration), {} without calibration.csv; time_offset:
    {src: {dst: s}} each calibrated link's nonzero time offset (cal. 10), {} without; calibration:
    the calibration file applied (`testbed replay --calibration`), else None."""

    spec: ReplaySpec
    directory: Path
    tables: dict[str, Table]
    feed: list[Measurement]
    bias_sigma: dict = field(default_factory=dict)
    calibration: CalibrationFile | None = None
    time_offset: dict = field(default_factory=dict)

    @property
    def duration(self) -> float:
        return self.spec.window.end - self.spec.window.start

    def context(self, key: str, params: dict) -> Context:
        """The Context of estimator `key` (its rng: stream "estimator/KEY" of the spec's seed; its
        channel: with a [network], its own network, stream "network/KEY", as in a simulated run;
        open_network: testbed.sim.network.Network, as in a simulated run);
        of an exported run, the Context the estimator had in the simulation (Context.pipeline
        aside: {}, the exported built-ins carry their resolved params; testbed.replay.export)."""
        sensors = {k: dict(v) for k, v in self.spec.sensors.items()}
        if self.bias_sigma:
            sensors.setdefault("uwb", {})["bias_sigma"] = {k: dict(v) for k, v in self.bias_sigma.items()}
        if self.time_offset:
            sensors.setdefault("uwb", {})["time_offset"] = {k: dict(v) for k, v in self.time_offset.items()}
        return Context(
            vehicles=tuple(self.spec.bodies), sites=self.spec.sites, anchors=self.spec.anchor_points,
            sensors=sensors, prior=self.spec.priors, params=dict(params),
            duration=self.duration, motion=self.spec.motion, seed=self.spec.seed,
            rng=stream_rng(self.spec.seed, f"estimator/{key}"), channel=self._channel(key),
            open_network=Network,
        )

    def _channel(self, key: str) -> Channel | None:
        """Estimator `key`'s network (testbed.plugins.channel) under the spec's [network]: the
        truth table's geometry, the NLOS flags of the links rows of kind uwb (empty: line of
        sight); None without a [network]."""
        if self.spec.network is None:
            return None
        t = self.tables["links"]
        rows = t["kind"] == "uwb"
        nlos = t["nlos"][rows] if "nlos" in t.columns else np.zeros(rows.sum())
        uwb = {"time": t["time"][rows] - self.spec.window.start, "src": t["src"][rows], "dst": t["dst"][rows],
               "nlos": np.nan_to_num(nlos) > 0}
        return Channel(self.spec.network, RecordedTruth(self), uwb, tuple(self.spec.bodies), self.spec.seed, key)

    def measurements(self) -> list[Measurement]:
        """The feed one Measurement per row."""
        return [m for item in self.feed for m in (item.rows() if isinstance(item, MeasurementBatch) else (item,))]

    def counts(self) -> dict[str, int]:
        """Measurements fed, per stream."""
        out: dict[str, int] = {}
        for item in self.feed:
            out[item.stream] = out.get(item.stream, 0) + (len(item) if isinstance(item, MeasurementBatch) else 1)
        return dict(sorted(out.items()))


def _unit_quaternions(t: Table, rows: np.ndarray) -> None:
    q = np.stack([t[c] for c in QUAT], axis=1)[rows]
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(~np.isfinite(norm) | (np.abs(norm - 1.0) > 1e-6))
    if bad.size:
        i = int(np.flatnonzero(rows)[bad[0]])
        raise t.error(i, "qw", f"a unit quaternion wxyz is needed here (norm {norm[bad[0]]:.9g})")


def _check_names(t: Table, column: str, allowed: set[str], what: str) -> None:
    bad = ~np.isin(t[column], sorted(allowed))
    if bad.any():
        i = int(np.argmax(bad))
        raise t.error(i, column, f"{str(t[column][i])!r} is not {what} of the spec")


def _check(spec: ReplaySpec, tables: dict[str, Table]) -> None:
    """Meaning of the rows: names known, kinds known, ranges in [0, MAX_RANGE_M] and range rates within
    MAX_RANGE_RATE_M_S, sigmas >= MIN_SIGMA, arrival >= time, quaternions unit."""
    sites, bodies = set(spec.sites), set(spec.bodies)
    for name, t in tables.items():
        for c in ("sigma", "sigma_x", "sigma_y", "sigma_z", "sigma_accel", "sigma_gyro", "sigma_phase", "sigma_range", "sigma_rate"):
            if c in t.columns and np.any(t[c] < MIN_SIGMA):
                i = int(np.argmax(t[c] < MIN_SIGMA))
                want = "positive" if t[c][i] <= 0 else f"at least {MIN_SIGMA:g}"
                raise t.error(i, c, f"must be {want} (or empty), got {float(t[c][i]):g}")
        if "arrival" in t.columns and np.any(t["arrival"] < t["time"]):
            raise t.error(int(np.argmax(t["arrival"] < t["time"])), "arrival", "is before the row's time")
    if "links" in tables:
        t = tables["links"]
        _check_names(t, "kind", set(LINK_KINDS), "a link kind (uwb, phase, range-rate) ")
        _check_names(t, "src", sites | set(spec.anchors), "a site (body/site) or an anchor")
        _check_names(t, "dst", sites | set(spec.anchors), "a site (body/site) or an anchor")
        same = t["src"] == t["dst"]
        if same.any():
            raise t.error(int(np.argmax(same)), "dst", "a link from a site to itself")
        flag = t["nlos"] if "nlos" in t.columns else np.zeros(len(t))
        bad = ~np.isin(flag, (0.0, 1.0)) & ~np.isnan(flag)
        if bad.any():
            i = int(np.argmax(bad))
            raise t.error(i, "nlos", f"a flag is 0 or 1 (or empty: line of sight), got {float(flag[i]):g}")
        rate = t["kind"] == "range-rate"
        bad = np.where(rate, np.abs(t["value"]) > MAX_RANGE_RATE_M_S, (t["value"] < 0) | (t["value"] > MAX_RANGE_M))
        if bad.any():
            i = int(np.argmax(bad))
            want = (f"a range rate is at most {MAX_RANGE_RATE_M_S:g} m/s in magnitude" if rate[i]
                    else f"a range is in [0, {MAX_RANGE_M:g}] m")
            raise t.error(i, "value", f"{want} (docs/replay.md), got {float(t['value'][i]):g}")
    if "poses" in tables:
        t = tables["poses"]
        _check_names(t, "kind", set(POSE_KINDS), "a pose kind (gnss, mocap) ")
        _check_names(t, "body", sites | bodies, "a body or a site")
        gnss = t["kind"] == "gnss"
        for c in ("sigma_x", "sigma_y", "sigma_z"):
            if np.any(gnss & np.isnan(t[c])):
                raise t.error(int(np.argmax(gnss & np.isnan(t[c]))), c, "a GNSS fix needs its 1-sigma (m)")
        mocap = t["kind"] == "mocap"
        if np.any(mocap & ~np.isin(t["body"], sorted(bodies))):
            raise t.error(int(np.argmax(mocap & ~np.isin(t["body"], sorted(bodies)))), "body", "a mocap pose is of a body, not a site")
        _unit_quaternions(t, mocap)
    for name, column in (("imu", "site"), ("height", "site")):
        if name in tables:
            _check_names(tables[name], column, sites | bodies, "a body or a site")
    if "camera" in tables:
        t = tables["camera"]
        _check_names(t, "src", sites, "a site (body/site)")
        _check_names(t, "dst", sites, "a site (body/site)")
    if "phase" in tables:
        t = tables["phase"]
        if "links" in tables and np.any(tables["links"]["kind"] == "phase"):
            raise t.error(0, "phase", f"the phase stream comes from here and from the links rows of kind phase "
                                      f"({tables['links'].file}): keep one")
        _check_names(t, "src", sites, "a site (body/site)")
        _check_names(t, "dst", sites, "a site (body/site)")
        for c, ok, want in (("rate_periods", (t["rate_periods"] >= 0) & (t["rate_periods"] == np.round(t["rate_periods"])),
                             "a whole number of periods, 0 or more"), ("slip", np.isin(t["slip"], (0.0, 1.0)), "0 or 1"),
                            ("wavelength", t["wavelength"] > 0, "a positive wavelength (m)")):
            if not ok.all():
                raise t.error(int(np.argmin(ok)), c, f"must be {want}, got {float(t[c][np.argmin(ok)]):g}")
    if "truth" in tables:
        t = tables["truth"]
        _check_names(t, "body", bodies, "a body")
        _unit_quaternions(t, np.ones(len(t), bool))
        for body in bodies:
            rows = np.flatnonzero(t["body"] == body)
            back = np.flatnonzero(np.diff(t["time"][rows]) <= 0)
            if back.size:
                raise t.error(int(rows[back[0] + 1]), "time", f"the truth of {body} must be in increasing time")


def _stream(name: str, t: Table, rows: np.ndarray, value: np.ndarray, sigma: np.ndarray | None, src: np.ndarray,
            dst: np.ndarray | None, start: float, extra: dict | None = None) -> tuple:
    """(name, time, arrival, value, src, dst, sigma, extra) of one stream's rows (read-only arrays;
    extra: {column: (n, ...) array} of a stream whose rows carry Measurement.extra, else None)."""
    time = t["time"][rows] - start
    arrival = (np.where(np.isnan(t["arrival"][rows]), t["time"][rows], t["arrival"][rows]) - start
               if "arrival" in t.columns else time)
    value = np.ascontiguousarray(value[rows], dtype=float)
    value.flags.writeable = False
    if sigma is not None:
        sigma = np.ascontiguousarray(sigma[rows], dtype=float)
        sigma.flags.writeable = False
    extra = None if extra is None else {k: _frozen(v[rows]) for k, v in extra.items()}
    return (name, time, arrival, value, src[rows], np.full(rows.sum(), "") if dst is None else dst[rows], sigma, extra)


def _streams(tables: dict[str, Table], start: float) -> list[tuple]:
    out = []
    if "links" in tables:
        t = tables["links"]
        for kind in LINK_KINDS:
            rows = t["kind"] == kind
            if rows.any():
                sig = t["sigma"][:, None]
                out.append(_stream(kind, t, rows, t["value"][:, None], sig, t["src"], t["dst"], start))
    if "poses" in tables:
        t = tables["poses"]
        xyz = np.stack([t[c] for c in ("x", "y", "z")], axis=1)
        sig = np.stack([t[c] for c in ("sigma_x", "sigma_y", "sigma_z")], axis=1)
        for kind, value in (("gnss", xyz), ("mocap", np.concatenate([xyz, np.stack([t[c] for c in QUAT], axis=1)], axis=1))):
            rows = t["kind"] == kind
            if rows.any():
                out.append(_stream(kind, t, rows, value, sig, t["body"], None, start))
    if "imu" in tables:
        t = tables["imu"]
        value = np.stack([t[c] for c in ("ax", "ay", "az", "gx", "gy", "gz")], axis=1)
        sig = np.repeat(np.stack([t["sigma_accel"], t["sigma_gyro"]], axis=1), 3, axis=1)
        out.append(_stream("imu", t, np.ones(len(t), bool), value, sig, t["site"], None, start))
    if "height" in tables:
        t = tables["height"]
        out.append(_stream("height", t, np.ones(len(t), bool), t["value"][:, None], t["sigma"][:, None], t["site"], None, start))
    if "phase" in tables:
        t = tables["phase"]
        value = np.stack([t["phase"], t["range"], t["rate"]], axis=1)
        sig = np.stack([t[f"sigma_{c}"] for c in ("phase", "range", "rate")], axis=1)
        pv = np.stack([t[c] for c in PHASE_MASTER_COLUMNS], axis=1)
        extra = {"master_pos": pv[:, :3], "master_vel": pv[:, 3:], "rate_periods": t["rate_periods"].astype(np.int64),
                 "wavelength": t["wavelength"], "slip": t["slip"].astype(bool)}
        out.append(_stream("phase", t, np.ones(len(t), bool), value, sig, t["src"], t["dst"], start, extra))
    if "camera" in tables:
        t = tables["camera"]
        value = np.stack([t[c] for c in CAMERA_COLUMNS], axis=1)
        out.append(_stream("camera", t, np.ones(len(t), bool), value, None, t["src"], t["dst"], start))
    return sorted(out, key=lambda s: s[0])


def _measurements(streams: list[tuple]) -> list[Measurement | MeasurementBatch]:
    """Every row in the order of testbed.plugins.feed.measurements (arrival, time, stream, row): a
    run of consecutive rows of one stream as one MeasurementBatch, a lone row or a row of a stream
    with extra columns as a Measurement; a row whose sigma is (partly) missing has sigma None (NaN
    in a batch)."""
    if not streams:
        return []
    arrival = np.concatenate([s[2] for s in streams])
    tov = np.concatenate([s[1] for s in streams])
    sid = np.concatenate([np.full(s[1].shape[0], i) for i, s in enumerate(streams)])
    row = np.concatenate([np.arange(s[1].shape[0]) for s in streams])
    order = np.lexsort((row, sid, tov, arrival))
    sid, row = sid[order], row[order]
    cuts = np.concatenate([[0], np.flatnonzero(np.diff(sid)) + 1, [sid.size]]).tolist()
    out: list[Measurement | MeasurementBatch] = []
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        name, t, a, value, src, dst, sigma, extra = streams[sid[lo]]
        rows = row[lo:hi]
        b = MeasurementBatch(stream=name, time=_frozen(t[rows]), arrival=_frozen(a[rows]), value=_frozen(value[rows]),
                             src=_frozen(src[rows]), dst=_frozen(dst[rows]), sigma=None if sigma is None else _frozen(sigma[rows]))
        if extra is not None:
            out += [dataclasses.replace(m, extra={k: v[r] for k, v in extra.items()}) for m, r in zip(b.rows(), rows.tolist())]
        else:
            out += b.rows() if hi - lo == 1 else [b]
    return out


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


def dataset_files(spec_path: Path) -> list[Path]:
    """The files a replay of spec_path reads: the spec, the tables beside it and the bag its [bag]
    names (what an output must never overlap: testbed.outdir.apart). ConfigError on a bad spec."""
    spec_path = Path(spec_path)
    spec = load_spec(spec_path)
    files = [spec_path, *filter(None, (find(spec_path.parent, name) for name in (*SCHEMAS, "calibration")))]
    return files + ([spec_path.parent / spec.bag.path] if spec.bag is not None else [])


def load_recording(spec_path: Path, *, window: Window | None = None, window_key: str = "window",
                   calibration: Path | None = None) -> Recording:
    """Read spec.toml and the tables beside it (or the ROS bag its [bag] names:
    testbed.replay.bag_read), check everything, build the feed; ConfigError on a mistake.
    window: replaces the spec's (named window_key in messages: `testbed calibrate`'s --window);
    calibration: a calibration file (testbed.replay.calibration) applied instead of calibration.csv."""
    spec_path = Path(spec_path)
    spec = load_spec(spec_path)
    if window is not None:
        spec = dataclasses.replace(spec, window=window)
    directory = spec_path.parent
    if spec.bag is not None:
        beside = [path.name for name in SCHEMAS if (path := find(directory, name)) is not None]
        if beside:
            raise ConfigError(f"{spec_path}: bag: the spec reads a bag, but {beside[0]} lies beside it: keep one source")
        tables = bag_tables(spec, spec_path)
    else:
        tables = {}
        for name in SCHEMAS:
            path = find(directory, name)
            if path is None:
                if name in REQUIRED_TABLES:
                    raise ConfigError(f"{directory}: no {name}.csv (or {name}.parquet) beside {spec_path.name}")
                continue
            tables[name] = read_table(path, name)
    _check(spec, tables)
    if spec.network is not None and "truth" not in tables:
        raise ConfigError(f"{spec_path}: network: the network's geometry is the true one, so it needs the truth "
                          "table (truth.csv): add it or remove [network]")
    cal_file = None
    if calibration is not None:
        if find(directory, "calibration") is not None:
            raise ConfigError(f"{calibration}: the dataset has its own {find(directory, 'calibration').name} beside "
                              f"{spec_path.name}: keep one calibration")
        cal_file = read_calibration_file(calibration, set(spec.sites) | set(spec.anchors))
        bias_sigma, time_offset = _apply(spec, cal_file.table, tables, calibration)
    else:
        bias_sigma, time_offset = _calibrate(spec, tables, find(directory, "calibration"))
    w = spec.window
    if window is not None:  # a window the caller chose must lie within the measurements' span
        times = np.concatenate([t["time"] for name, t in tables.items() if name != "truth"])
        if times.size and (w.start < times.min() or w.end > times.max()):
            raise ConfigError(f"{window_key} {w.start:g},{w.end:g}: outside the data of {spec_path} (its measurements "
                              f"span {times.min():g} to {times.max():g} s)")
    for name, t in tables.items():
        if name != "truth":  # truth is kept whole: interpolation at the window's edges needs its neighbours
            tables[name] = t.select((t["time"] >= w.start) & (t["time"] <= w.end))
    feed = _measurements(_streams(tables, w.start))
    if not feed:
        raise ConfigError(f"{spec_path}: window [{w.start:g}, {w.end:g}] s holds no measurement of the dataset")
    return Recording(spec, directory, tables, feed, bias_sigma, cal_file, time_offset)


def _calibrate(spec: ReplaySpec, tables: dict[str, Table], path: Path | None) -> tuple[dict, dict]:
    """Remove calibration.csv's known bias and scale from the uwb ranges of tables["links"] (in
    place); return the remaining bias sigmas {src: {dst: m}} and the time offsets {src: {dst: s}}
    ({}, {} without the file)."""
    if path is None:
        return {}, {}
    return _apply(spec, read_calibration(path, set(spec.sites) | set(spec.anchors)), tables, path)


def _apply(spec: ReplaySpec, cal: Calibration, tables: dict[str, Table], path: Path) -> tuple[dict, dict]:
    """Remove cal's (read from path) known bias and scale from the uwb ranges of tables["links"] (in
    place); return the remaining bias sigmas {src: {dst: m}} and the links' time offsets {src: {dst: s}}."""
    for k, what in (("bias_sigma", "bias sigmas"), ("time_offset", "time offsets")):
        if k in spec.sensors.get("uwb", {}):
            raise ConfigError(f"{path}: the spec's [sensors.uwb] {k} and this calibration both give the {what}: keep one")
    if "links" not in tables:
        return {}, {}
    t = tables["links"]
    uwb = t["kind"] == "uwb"
    value, sigma = t["value"].copy(), t["sigma"].copy()
    value[uwb], sigma[uwb] = cal.apply(t["src"][uwb], t["dst"][uwb], value[uwb], sigma[uwb])
    tables["links"] = Table(t.file, {**t.columns, "value": value, "sigma": sigma}, t.lines)
    pairs = set(zip(t["src"][uwb].tolist(), t["dst"][uwb].tolist()))
    return cal.bias_sigma(pairs), cal.time_offsets(pairs)


class RecordedTruth:
    """Truth of bodies and sites at any time within each body's truth rows (scoring only), by
    testbed.plugins.truth.Truth per body (linear position/velocity, slerp attitude).

    span: {body: (first, last) time, window clock}; has_velocity: {body: vel and omega given}."""

    def __init__(self, rec: Recording):
        t = rec.tables["truth"]
        start = rec.spec.window.start
        self.by_body: dict[str, Truth] = {}
        self.span: dict[str, tuple[float, float]] = {}
        self.has_velocity: dict[str, bool] = {}
        sites = rec.spec.sites
        for body in rec.spec.bodies:
            rows = t["body"] == body
            if not rows.any():
                continue
            col = lambda names: np.stack([t[c][rows] for c in names], axis=1)[:, None, :]  # noqa: E731
            vel, omega = col(("vx", "vy", "vz")), col(("wx", "wy", "wz"))
            log = {"time": t["time"][rows] - start, "truth/pos": col(("x", "y", "z")), "truth/quat": col(QUAT),
                   "truth/vel": vel, "truth/omega": omega}
            ctx = SimpleNamespace(vehicles=(body,), sites={s: v for s, v in sites.items() if v[0] == body})
            self.by_body[body] = Truth(log, ctx)
            self.span[body] = (float(log["time"][0]), float(log["time"][-1]))
            self.has_velocity[body] = bool(np.all(np.isfinite(vel)) and np.all(np.isfinite(omega)))
        self.sites = sites
        self.anchors = rec.spec.anchor_points

    def body_of(self, target: str) -> str:
        return self.sites[target][0] if target in self.sites else target

    def times(self, target: str) -> np.ndarray:
        """The instants (K,) s of the truth rows of `target`'s body (window clock)."""
        return self.by_body[self.body_of(target)].t

    def known(self, target: str, quantity: str) -> bool:
        """Is there truth for this target and quantity (velocity needs vel and omega rows)?"""
        body = self.body_of(target)
        return body in self.by_body and (quantity != "velocity" or self.has_velocity[body])

    def at(self, target: str, quantity: str, t: np.ndarray, frame: str = "world") -> np.ndarray:
        """As testbed.plugins.truth.Truth.at; an anchor's position is its fixed point."""
        t = np.asarray(t, float)
        x = self._world(target, quantity, t)
        if frame == "world":
            return x
        R = Rotation.from_quat(self._world(frame, "attitude", t), scalar_first=True)
        return relative(x, quantity, R, lambda: self._world(frame, quantity, t))

    def _world(self, target: str, quantity: str, t: np.ndarray) -> np.ndarray:
        if target in self.anchors:
            return np.tile(self.anchors[target], (np.size(t), 1)) if quantity == "position" else np.zeros((np.size(t), 3))
        return self.by_body[self.body_of(target)].at(target, quantity, np.asarray(t, float))
