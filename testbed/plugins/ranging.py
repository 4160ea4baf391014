"""The generalized ranging EKF (estimators.ranging) as a protocol estimator, for recorded data.

Each follower body is tracked by its own filter from ranges between its antennas and KNOWN
points: the world's anchors (Context.anchors) and the antennas of known bodies, whose poses
arrive on a pose stream (from any source: motion capture, another navigation solution) and whose
lever arms come from Context.sites. Optional: range rates, a height of the follower (altimeter /
barometer). Followers: params follower (one body), else every vehicle that is not known and has
an antenna (known: params known, else every vehicle but the named follower, else none).
Antennas: params antennas, else each follower's sites that [sensors.uwb] declares as tags
(`tags`), else all its sites.

Streams (names configurable in params):
- ranges: the streams of `range_streams` {stream: column of value holding the range, m}
  (default {"uwb": 0, "phase": 1}: the simulator's phase value is [phase, range, rate]);
  src and dst are site (or anchor) names, one end a follower antenna, the other a known point;
- range rates (only with use_rates = true): `rate_streams` {stream: column} (default
  {"range-rate": 0, "phase": 2}), m/s, same src/dst;
- known poses: `pose_stream` (default "mocap", the recorded-data format's stream of known poses,
  docs/replay.md), src = body, value (7,) = position m, quaternion
  wxyz body to world; the latest pose at or before an epoch is used, and the velocity of a known
  antenna (for the rates) is the difference of its last two positions;
- height: `height_stream` (default "height"), value (1,) m: the up coordinate of its src, as
  everywhere (docs/replay.md): src = one of the follower's antennas, that antenna; src = the
  follower, its body origin, the affine combination sum_j c_j x_j of the antennas with
  sum_j c_j l_j = 0 (least norm; where the origin lies off the antennas' affine hull, e.g. above
  a flat array, the nearest such point, its height offset from the origin taken as for a level
  body). height_weights in params replaces the c_j for heights of the follower.
The sigma of each row is the measurement's declared sigma at that column when given, else
range_sigma / range_rate_sigma / height_sigma from params. Correlated range errors
(range_correlation tau_c > 0, s: docs/calibration.md, cal. 8): the filter averages ranges over
time as if independent, so a range's variance is multiplied by max(1, tau_c / dt_l), dt_l the time
since its link's (stream, antenna, known end) previous range (1 for the link's first): the rows
the link makes within the time its errors stay correlated, which carry the information of one.

Epochs: measurements of one time of validity form an epoch, processed when a later one arrives
(or at finish), never looking ahead; an epoch may hold a single range, or a height alone
(sparse, asynchronous ranging: docs/replay.md, "Sparse ranging"). Between epochs the antennas
move at constant velocity with white acceleration (estimators.ranging.RangingNoise: q per
antenna, q_translation common, q_rotation about the centroid). q is the antennas' motion relative
to each other (an array's flex): a follower tracked at a single antenna has none, and its white
acceleration is q_translation alone (q would add to it the acceleration q_translation already
holds: a calibration's q_translation measures all of it, docs/calibration.md cal. 6). Initialisation: the follower's
ranges of the last init_window seconds build the prior at the epoch being solved
(estimators.ranging.initial_belief: a rigid pose fix from the lever arms, or a fix per antenna),
each range of age a with its sigma grown to hypot(sigma, v_sigma a) (the follower moved by at
most that, at the velocity prior's 1 sigma), the latest height likewise; epochs before the first
that determines the follower, and epochs that cannot be used (ranges none of which ends at a
known point), are counted (health: skipped_epochs; ranges whose other end is neither an anchor
nor a site of a known body with a pose yet: unknown_end_rows; ranges of a follower site that is
not one of its antennas: untracked_rows). Estimates: each antenna site's position and velocity,
and the follower body's position, velocity and attitude when its lever arms determine an
attitude.

Range bias (bias_states = true; docs/replay.md, "Range bias"): one bias state b per link (a
range stream, a follower antenna and a known end), added to its ranges, r = |x_j - X| + b, from the link's first
range on: a random constant (bias_walk = 0) or a random walk of density bias_walk (m^2/s); prior
mean 0 (what the dataset's calibration table left), sigma the link's bias_sigma of
Context.sensors[stream] (testbed.replay.calibration: "uwb") when it has one, else params bias_sigma, else
the link's range sigma (its first range's declared sigma, or range_sigma). bias_estimates() gives
them.

Time offsets (docs/calibration.md, cal. 10): a link (stream, antenna, known end) whose
Context.sensors[stream]["time_offset"] (testbed.replay.calibration: "uwb") gives it an offset c s
measures the distance at t + c: its range row is r = |x_j - X| + c u^T (v_j - V) (+ b), the rate
from the filter's own velocity state (estimators.ranging.ranging_model, RangingEpoch.offset).

params: RangingParams (`testbed estimators ranging.ekf`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from estimators.core import Gate, Gaussian, counting
from estimators.geometry import DegenerateGeometryError
from estimators.range_start import StartWindow
from estimators.ranging import RangingEkf, RangingEpoch, RangingNoise, body_pose, initial_belief
from estimators.sensor_models import correlated_sigma
from estimators.so3 import quat_to_rotmat
from testbed.config import check_fields, key, require
from testbed.errors import ConfigError
from testbed.plugins.api import Context, Estimate, Measurement
from testbed.plugins.params import fields_of, read


@dataclass(frozen=True, kw_only=True)
class RangingParams:
    """Parameters of ranging.ekf ([[estimators]] params; module docstring)."""

    follower: str | None = key(None, doc="the one tracked body (none: every vehicle that is not known, each its own filter)")
    antennas: tuple[str, ...] | None = key(None, doc="the followers' antenna sites (none: each follower's sites named by [sensors.uwb] tags, else all)")
    known: tuple[str, ...] | None = key(None, doc="bodies on the pose stream (none: every vehicle but the follower; no vehicle when no follower is named)")
    q: float = key(1e-3, lo=0, unit="m^2/s^3",
                   doc="white-acceleration density per antenna axis, independent between the antennas of an array (unused for one antenna)")
    q_translation: float = key(1e-2, lo=0, unit="m^2/s^3", doc="rigid-body white acceleration")
    q_rotation: float = key(1e-2, lo=0, unit="rad^2/s^3", doc="rigid-body white angular acceleration")
    gate_alpha: float = key(1e-3, lo=0, hi=1, lo_open=True, hi_open=True, doc="false-alarm rate of the innovation gate")
    iterations: int = key(1, lo=1, doc="1: EKF; > 1: iterated EKF")
    range_sigma: float = key(0.1, lo=0, lo_open=True, unit="m", doc="sigma of the ranges that declare none")
    range_correlation: float = key(0.0, lo=0, unit="s",
                                   doc="correlation time of the range errors (0: independent; docs/calibration.md)")
    range_rate_sigma: float = key(0.1, lo=0, lo_open=True, unit="m/s", doc="sigma of the range rates that declare none")
    height_sigma: float = key(0.1, lo=0, lo_open=True, unit="m", doc="sigma of the heights that declare none")
    use_rates: bool = key(False, doc="use the range rates")
    rate_window: float | None = key(None, lo=0, lo_open=True, unit="s", doc="window of the range rates (none: instantaneous)")
    v_sigma: float = key(1.0, lo=0, lo_open=True, unit="m/s", doc="prior velocity per axis, 1 sigma")
    init_window: float = key(2.0, lo=0, unit="s", doc="span of the first ranges that initialise the filter together (0: one epoch)")
    shape_sigma: float = key(0.01, lo=0, lo_open=True, unit="m", doc="rigidity of the antenna array in the prior, 1 sigma")
    level_sigma: float | None = key(None, lo=0, lo_open=True, unit="rad", doc="prior levelling, 1 sigma (none: no level prior)")
    range_streams: dict = key(factory=lambda: {"uwb": 0, "phase": 1}, range="{stream: column >= 0}", doc="range streams and the value column of the range")
    rate_streams: dict = key(factory=lambda: {"range-rate": 0, "phase": 2}, range="{stream: column >= 0}", doc="range-rate streams and their column")
    pose_stream: str = key("mocap", doc="stream of the known bodies' poses")
    height_stream: str = key("height", doc="stream of the follower's heights")
    height_weights: tuple[float, ...] | None = key(None, doc="weights of the antennas for a height of the follower (none: least norm)")
    bias_states: bool = key(False, doc="a range-bias state per link (docs/replay.md, Range bias)")
    bias_sigma: float | None = key(None, lo=0, lo_open=True, unit="m",
                                   doc="prior sigma of a link's bias without a calibrated one (none: the link's range sigma)")
    bias_walk: float = key(0.0, lo=0, unit="m^2/s", doc="random-walk density of the bias states (0: random constants)")

    def __post_init__(self) -> None:
        check_fields(self)
        for name in ("range_streams", "rate_streams"):
            for stream, col in getattr(self, name).items():
                require(isinstance(col, int) and not isinstance(col, bool) and col >= 0, f"{name}.{stream}", col,
                        "expected a column number >= 0")


def _body(site: str) -> str:
    return site.split("/", 1)[0]


class RangingEkfEstimator:
    """Generalized ranging EKF: any antennas and lever arms, known poses from any source, height aid;
    one filter per follower body (`followers`)."""

    description = "ranging EKF per follower, any antennas/lever arms, known poses from a pose stream, optional rates and height"

    Params = RangingParams

    def __init__(self, context: Context, params: dict):
        p = self.p = fields_of(read(RangingParams, params, "ranging.ekf"))
        vehicles = list(context.vehicles)
        if p["follower"] is not None and p["follower"] not in vehicles:
            raise ConfigError(f"estimator ranging.ekf params: follower {p['follower']!r} must name one of {vehicles}")
        if p["known"] is not None:
            known = set(p["known"])
        else:
            known = {v for v in vehicles if v != p["follower"]} if p["follower"] is not None else set()
        followers = [p["follower"]] if p["follower"] is not None else [v for v in vehicles if v not in known]
        if not followers:
            raise ConfigError(f"estimator ranging.ekf params: no follower: every vehicle {vehicles} is known")
        if p["antennas"] is not None:
            bad = [a for a in p["antennas"] if a not in context.sites or _body(a) not in followers]
            if bad:
                raise ConfigError(f"estimator ranging.ekf params: antennas {bad!r} are not sites of a follower {followers}")
        self.known = known
        self.sites = context.sites
        self.anchors = {k: np.asarray(v, float) for k, v in context.anchors.items()}
        # {stream: {antenna: {known end: m}}}: a calibration table's sigmas (testbed.replay.calibration)
        self.calibrated = {k: v["bias_sigma"] for k, v in context.sensors.items()
                           if isinstance(v, dict) and isinstance(v.get("bias_sigma"), dict)}
        self.offsets = {k: v["time_offset"] for k, v in context.sensors.items()
                        if isinstance(v, dict) and isinstance(v.get("time_offset"), dict)}
        self.poses: dict[str, list[tuple[float, np.ndarray, np.ndarray]]] = {}
        self.t = None
        self.last_range: dict[tuple[str, str, str], float] = {}  # (stream, antenna, known end) -> time of its last range
        self.counts = {"skipped_epochs": 0, "skipped_rows": 0, "unknown_end_rows": 0, "untracked_rows": 0,
                       "rejected_measurements": 0, "covariance_repairs": 0}
        # a range sensor's declared tags ([sensors.uwb] tags), else every site of the follower
        tags = {t for stream in p["range_streams"] for t in (context.sensors.get(stream) or {}).get("tags", ())}
        self.followers = {}
        for f in followers:
            mine = sorted(s for s, (b, _) in context.sites.items() if b == f)
            ants = [a for a in p["antennas"] if _body(a) == f] if p["antennas"] is not None else \
                [a for a in mine if not tags or a.split("/", 1)[1] in tags]
            if ants:
                self.followers[f] = _Follower(self, f, ants)
            elif p["follower"] is not None:  # a vehicle without sites is no follower unless named
                raise ConfigError(f"estimator ranging.ekf params: the follower {f} has no antenna site (sites {mine})")
        if not self.followers:
            raise ConfigError(f"estimator ranging.ekf params: none of the followers {followers} has an antenna site")

    # -------------------------------------------------------------- one follower (the tests' and scripts' view)
    def _only(self) -> "_Follower":
        if len(self.followers) != 1:
            raise AttributeError(f"ranging.ekf tracks {sorted(self.followers)}: ask .followers[body]")
        return next(iter(self.followers.values()))

    def __getattr__(self, name: str):
        """The attributes of the one follower (follower, antennas, n, belief, bias_index) when there is one."""
        if name in ("follower", "antennas", "n", "belief", "bias_index"):
            f = self._only()
            return f.body if name == "follower" else getattr(f, name)
        raise AttributeError(name)

    def bias_estimates(self) -> dict[tuple[str, str, str], tuple[float, float]]:
        """{(stream, antenna site, known end): (bias m, its sigma m)} of every follower's bias states."""
        return {k: v for f in self.followers.values() for k, v in f.bias_estimates().items()}

    # -------------------------------------------------------------- bookkeeping
    def known_point(self, name: str) -> tuple[np.ndarray, np.ndarray] | None:
        """Position and velocity (3,) of a known end at the latest pose, or None if unknown yet."""
        if name in self.anchors:
            return self.anchors[name], np.zeros(3)
        body = _body(name)
        if body not in self.known or name not in self.sites or not self.poses.get(body):
            return None
        arm = np.asarray(self.sites[name][1], float)
        hist = self.poses[body]
        X = [p + R @ arm for _, p, R in hist[-2:]]
        V = (X[-1] - X[0]) / (hist[-1][0] - hist[0][0]) if len(hist) == 2 and hist[-1][0] > hist[0][0] else np.zeros(3)
        return X[-1], V

    def sigma(self, m: Measurement, col: int, default: float) -> float:
        if m.sigma is not None and np.size(m.sigma) > col and np.isfinite(m.sigma[col]) and m.sigma[col] > 0:
            return float(m.sigma[col])
        return float(default)

    def _correlated(self, link: tuple, t: float, sigma: float) -> float:
        """sigma (m) of a range of link (stream, antenna, known end) at time t (s), times
        sqrt(max(1, range_correlation / dt)), dt the time since the link's previous range (module
        docstring; 1 for its first)."""
        last = self.last_range.get(link)
        self.last_range[link] = t
        return correlated_sigma(sigma, self.p["range_correlation"], None if last is None else t - last)

    def _advance(self, t: float | None) -> list[Estimate]:
        """Solve the buffered epoch once time moves past it (t None: at finish); then buffer at t."""
        out = []
        if self.t is not None and (t is None or t > self.t):
            for f in self.followers.values():
                out += f.solve(self.t)
        self.t = self.t if t is None else t
        return out

    def process(self, m: Measurement) -> list[Estimate]:
        out = self._advance(m.time)
        p = self.p
        if m.stream == p["pose_stream"]:
            if m.src in self.known:
                v = np.asarray(m.value, float)
                hist = self.poses.setdefault(m.src, [])
                hist.append((m.time, v[:3].copy(), quat_to_rotmat(v[3:7] / np.linalg.norm(v[3:7]))))
                del hist[:-2]
        elif m.stream == p["height_stream"]:
            f = self.followers.get(_body(m.src))
            if f is not None:
                f.height = (m.src, float(m.value[0]), self.sigma(m, 0, p["height_sigma"]))
        else:
            for mine, other in ((m.src, m.dst), (m.dst, m.src)):
                f = self.followers.get(_body(mine))
                if f is None or mine not in self.sites or _body(other) == f.body:
                    continue
                if m.stream in p["range_streams"]:
                    col = int(p["range_streams"][m.stream])
                    sigma = self._correlated((m.stream, mine, other), m.time, self.sigma(m, col, p["range_sigma"]))
                    f.links.append((mine, other, float(m.value[col]), sigma, m.stream))
                if p["use_rates"] and m.stream in p["rate_streams"] and np.size(m.value) > int(p["rate_streams"][m.stream]):
                    col = int(p["rate_streams"][m.stream])
                    f.rates[(mine, other)] = (float(m.value[col]), self.sigma(m, col, p["range_rate_sigma"]))
        return out

    def finish(self) -> list[Estimate]:
        return self._advance(None)

    def health(self) -> dict[str, int]:
        return dict(self.counts)


class _Follower:
    """The filter of one follower body: its antennas, the epoch being collected, the prior's window,
    the belief and its bias states."""

    def __init__(self, owner: RangingEkfEstimator, body: str, antennas: list[str]):
        o = self.o = owner
        self.body = body
        self.belief = None
        self.t_belief = None
        self.bias_index: dict[tuple[str, int, str], int] = {}  # (stream, antenna, known end) -> bias state
        self.antennas = list(antennas)
        self.index = {a: k for k, a in enumerate(self.antennas)}
        self.arms = np.stack([np.asarray(o.sites[a][1], float) for a in self.antennas])
        self.n = len(self.antennas)
        # the body origin as an affine combination of the antennas: c = 1/n + N w (sum c = 1, N a basis
        # of the vectors summing to 0), w the least-norm minimizer of |arms^T c| (the hull's nearest point)
        N = np.linalg.svd(np.ones((1, self.n)))[2][1:].T
        c0 = np.full(self.n, 1.0 / self.n)
        self.origin_weights = c0 + N @ np.linalg.lstsq(self.arms.T @ N, -self.arms.T @ c0, rcond=None)[0]
        self.origin_offset = float((self.origin_weights @ self.arms)[2])  # m, up, of that point from the origin
        p = o.p
        self.window = StartWindow(p["init_window"], p["v_sigma"])  # the ranges before the prior
        # q is the antennas' motion relative to each other (an array's flex): a follower tracked at one
        # antenna has none, its acceleration is q_translation's alone (docs/replay.md, "Sparse ranging")
        self.ekf = RangingEkf(n=self.n, q=RangingNoise(antenna=p["q"] if self.n > 1 else 0.0, translation=p["q_translation"],
                                                       rotation=p["q_rotation"]),
                              gate=Gate(alpha=p["gate_alpha"]), iterations=int(p["iterations"]), bias_walk=p["bias_walk"])
        self._reset()

    def _reset(self) -> None:
        self.links: list[tuple[str, str, float, float, str]] = []  # (antenna site, known end, range, sigma, stream)
        self.rates: dict[tuple[str, str], tuple[float, float]] = {}
        self.height: tuple[str, float, float] | None = None  # (site or body, z m, sigma m)

    def _height_row(self, h: tuple[str, float, float] | None) -> tuple[float, float, np.ndarray] | None:
        """(z, sigma, c) of a height as the up coordinate of sum_j c_j x_j (module docstring), None if
        it is of a site that is not an antenna."""
        if h is None:
            return None
        src, z, s = h
        if src in self.index:
            return z, s, np.eye(self.n)[self.index[src]]
        if src != self.body:
            return None
        if self.o.p["height_weights"] is not None:
            return z, s, np.asarray(self.o.p["height_weights"], float)
        return z + self.origin_offset, s, self.origin_weights

    # -------------------------------------------------------------- one epoch
    def _rows(self) -> list[tuple[str, np.ndarray, np.ndarray, float, float, str, str]]:
        """The epoch's ranges to known points: (antenna site, X, V, r, sigma, stream, known end);
        the others counted."""
        rows = []
        for site, other, r, s, stream in self.links:
            known = self.o.known_point(other)
            if known is None:
                self.o.counts["unknown_end_rows"] += 1
            elif site not in self.index:
                self.o.counts["untracked_rows"] += 1
            else:
                rows.append((site, known[0], known[1], r, s, stream, other))
        return rows

    def _epoch(self, rows: list) -> RangingEpoch | None:
        self.epoch_links = [(stream, self.index[site], other, s) for site, _, _, _, s, stream, other in rows]
        h = self._height_row(self.height)
        if not rows:
            return None
        j = np.array([self.index[r[0]] for r in rows], int)
        X, V, r, s = (np.array([row[k] for row in rows]) for k in (1, 2, 3, 4))
        rates = [self.rates.get((row[0], row[6]), (np.nan, 1.0)) for row in rows]
        rd, sd = np.array([x[0] for x in rates]), np.array([x[1] for x in rates])
        use_rates = bool(self.o.p["use_rates"]) and np.isfinite(rd).any()
        c = np.array([self.o.offsets.get(row[5], {}).get(row[0], {}).get(row[6], 0.0) for row in rows])
        timed = bool(np.any(c != 0.0))
        return RangingEpoch(antenna=j, known_pos=X, ranges=r, sigma_range=s, offset=c if timed else None,
                            range_rates=rd if use_rates else None, known_vel=V if use_rates or timed else None,
                            sigma_range_rate=sd, rate_window=self.o.p["rate_window"],
                            height=None if h is None else h[0], sigma_height=1.0 if h is None else h[1],
                            height_weights=None if h is None else h[2])

    def solve(self, t: float) -> list[Estimate]:
        """The estimates of the epoch at t: the prior's window before the follower initialises, else
        predict and update (a height alone too)."""
        try:
            rows = self._rows()
            if self.belief is None:
                return self._estimates(t) if self._initialise(t, rows) else []
            if not rows and self._height_row(self.height) is None:
                if self.links:  # ranges, none to a known point: this epoch cannot be used
                    self.o.counts["skipped_epochs"] += 1
                return []
            epoch = self._epoch(rows)
            if epoch is None:  # a height alone
                h = self._height_row(self.height)
                epoch = RangingEpoch(antenna=np.zeros(0, int), known_pos=np.zeros((0, 3)), ranges=np.zeros(0),
                                     height=h[0], sigma_height=h[1], height_weights=h[2])
            elif self.o.p["bias_states"]:
                epoch = dataclasses.replace(epoch, bias=self._bias_states())
            with counting() as h:
                b = self.belief if t == self.t_belief else self.ekf.predict(self.belief, t - self.t_belief)
                b = self.ekf.update(b, epoch)
            self.belief, self.t_belief = b, t
            counts = self.o.counts
            counts["skipped_rows"] += h.skipped_updates
            counts["rejected_measurements"] += h.rejected_measurements
            counts["covariance_repairs"] += h.covariance_repairs
            return self._estimates(t)
        finally:
            self._reset()

    def _initialise(self, t: float, rows: list) -> bool:
        """Try to build the prior at t from the epochs of the last init_window s (docs/replay.md,
        "Sparse ranging"; estimators.range_start, eq. S1: each buffered range of age a = t - t_k
        counts as a range at t of sigma hypot(sigma_k, v_sigma a), the latest height likewise); the
        velocity prior is v_sigma per axis; True when built. An epoch with ranges that leaves the
        follower undetermined is counted in skipped_epochs."""
        p = self.o.p
        h = self._height_row(self.height)
        self.window.add(t, [self.index[site] for site, *_ in rows], [row[1] for row in rows], [row[3] for row in rows],
                        [row[4] for row in rows], None if h is None else (h[0], h[1], h[2]))
        if not rows:
            if self.links:
                self.o.counts["skipped_epochs"] += 1
            return False
        try:
            self.belief = initial_belief(self.window.epoch(t), self.n, self.arms, v_cov=p["v_sigma"] ** 2,
                                         shape_sigma=p["shape_sigma"], level_sigma=p["level_sigma"])
        except DegenerateGeometryError:
            self.o.counts["skipped_epochs"] += 1
            return False
        self.t_belief = t
        self.window.clear()
        return True

    def _bias_states(self) -> np.ndarray:
        """(L,) the bias state of each link of the epoch, a new one appended to the belief (mean 0,
        variance its prior sigma^2: module docstring) for a link seen the first time."""
        out = []
        for stream, j, other, s in self.epoch_links:
            k = self.bias_index.get((stream, j, other))
            if k is None:
                k = self.bias_index[(stream, j, other)] = len(self.bias_index)
                sigma = self.o.calibrated.get(stream, {}).get(self.antennas[j], {}).get(other, self.o.p["bias_sigma"] or s)
                b = self.belief
                cov = np.zeros((b.mean.size + 1, b.mean.size + 1))
                cov[:-1, :-1], cov[-1, -1] = b.cov, sigma ** 2
                self.belief = Gaussian(np.append(b.mean, 0.0), cov)
            out.append(k)
        return np.array(out, int)

    def bias_estimates(self) -> dict[tuple[str, str, str], tuple[float, float]]:
        """{(stream, antenna site, known end): (bias m, its sigma m)} of the bias states (bias_states)."""
        if self.belief is None:
            return {}
        o = 6 * self.n
        return {(stream, self.antennas[j], other): (float(self.belief.mean[o + k]), float(np.sqrt(self.belief.cov[o + k, o + k])))
                for (stream, j, other), k in self.bias_index.items()}

    def _estimates(self, t: float) -> list[Estimate]:
        b, n = self.belief, self.n
        out = []
        for a, j in self.index.items():
            for qty, off in (("position", 0), ("velocity", 3 * n)):
                sl = slice(off + 3 * j, off + 3 * j + 3)
                out.append(Estimate(time=t, target=a, quantity=qty, value=b.mean[sl], cov=b.cov[sl, sl]))
        pose = body_pose(b, self.arms)
        if pose is not None:
            f = self.body
            out += [Estimate(time=t, target=f, quantity="position", value=pose.position, cov=pose.cov[:3, :3]),
                    Estimate(time=t, target=f, quantity="attitude", value=pose.quat,
                             cov=pose.cov[3:6, 3:6]),
                    Estimate(time=t, target=f, quantity="velocity", value=pose.velocity, cov=pose.cov[6:9, 6:9])]
        return out
