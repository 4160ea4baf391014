"""The replay spec (`spec.toml` of a recorded dataset, docs/replay.md): bodies, sites, anchors,
declared sensor models, the estimators to run and the time window.

Built only through testbed.config.from_dict, so an unknown key, a wrong type or a bad value is a
FieldError naming the file, the dotted key and the value (exit 2).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from testbed.config import from_dict, in_range, read_toml_file, require
from testbed.config.network import NetworkConfig
from testbed.config.estimators import EstimatorSpec
from testbed.sensors.config import declared_imu

FORMAT = 1
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
_FIELD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
LINK_STREAMS = ("uwb", "phase", "range-rate")
LINK_FIELDS = ("src", "dst", "value", "sigma")


@dataclass(frozen=True, kw_only=True, slots=True)
class Window:
    """The replayed time window, in the clock of the files (s): rows with start <= time <= end are
    fed; estimators see time - start, so the replay runs over [0, end - start] like a simulation."""

    start: float = 0.0
    end: float

    def __post_init__(self) -> None:
        in_range(self, "start", unit="s")
        in_range(self, "end", unit="s")
        require(self.end > self.start, "end", self.end, f"must be after window.start = {self.start:g} s")


@dataclass(frozen=True, kw_only=True, slots=True)
class BagTopic:
    """One topic of a bag and the stream its messages are read as (docs/replay.md, "ROS bags").

    topic: its name in the bag. stream: uwb, phase, range-rate (links rows), gnss (poses rows of
    kind gnss), imu or truth. source: the site (imu, gnss) or body (truth) measured; "" takes it
    from each message (Imu: header.frame_id; Odometry: child_frame_id); link streams name theirs
    in the message. fields (link streams only): {column: field path} for the columns src, dst,
    value, sigma of a message type other than testbed_msgs/msg/Link (a dotted path such as
    "header.frame_id"); a column not named takes the Link message's field of its name.
    """

    topic: str
    stream: Literal["uwb", "phase", "range-rate", "gnss", "imu", "truth"]
    source: str = ""
    fields: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        require(self.topic.startswith("/"), "topic", self.topic, f"{self.topic!r}: a ROS topic name starts with '/'")
        link = self.stream in LINK_STREAMS
        require(not (link and self.source), "source", self.source,
                f"{self.source!r}: a {self.stream} message names its own src and dst (map them with fields)")
        require(not self.fields or link, "fields", self.fields,
                f"{self.fields}: only a link stream (uwb, phase, range-rate) takes fields")
        for column, path in self.fields.items():
            require(column in LINK_FIELDS, f"fields.{column}", column,
                    f"{column!r}: not a column of links (one of {', '.join(LINK_FIELDS)})")
            require(isinstance(path, str) and _FIELD.fullmatch(path) is not None, f"fields.{column}", path,
                    f"{path!r}: expected a message field path such as \"range\" or \"header.frame_id\"")


@dataclass(frozen=True, kw_only=True, slots=True)
class BagSource:
    """The dataset as a ROS bag. path: relative to the spec's directory, a ROS 2 bag directory (or
    its .mcap file) or a ROS 1 .bag file; topics: the topics read, each with its stream (topics not
    listed are skipped)."""

    path: str
    topics: tuple[BagTopic, ...]

    def __post_init__(self) -> None:
        require(bool(self.path), "path", self.path,
                "empty: name the bag (a ROS 2 bag directory or .mcap file, or a ROS 1 .bag file)")
        require(bool(self.topics), "topics", self.topics, "empty: map at least one topic ([[bag.topics]] topic, stream)")
        names = [t.topic for t in self.topics]
        for i, name in enumerate(names):
            require(name not in names[:i], f"topics[{i}].topic", name, f"{name!r} is mapped twice")


def _finite(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _point(value: object) -> bool:
    return isinstance(value, (list, tuple)) and len(value) == 3 and all(_finite(v) for v in value)


def _check_prior(prior: dict) -> None:
    for target, table in prior.items():
        key = f"prior.{target}"
        require(isinstance(table, dict) and set(table) == {"mean", "cov"}, key, table,
                "expected a table with two keys, mean = [n numbers] and cov = [k rows of k numbers], k <= n")
        mean, cov = table["mean"], table["cov"]
        require(isinstance(mean, list) and bool(mean) and all(_finite(v) for v in mean), f"{key}.mean", mean,
                "expected a non-empty array of finite numbers")
        k = len(cov) if isinstance(cov, list) else 0
        require(0 < k <= len(mean) and all(isinstance(r, list) and len(r) == k and all(_finite(v) for v in r) for r in cov),
                f"{key}.cov", cov, f"expected a square array of finite numbers, at most {len(mean)} rows "
                "(the covariance of mean, or of its tangent space on a manifold)")


def _check_bodies(bodies: dict) -> None:
    for body, table in bodies.items():
        require(_NAME.fullmatch(body) is not None, f"bodies.{body}", body, "letters, digits, '_', '-' and '.' only")
        require(isinstance(table, dict) and set(table) <= {"sites"}, f"bodies.{body}", table,
                "expected a table with one key, sites = {NAME = [x, y, z]} (m, body frame)")
        sites = table.get("sites", {})
        require(isinstance(sites, dict), f"bodies.{body}.sites", sites, "expected a table {NAME = [x, y, z]}")
        for site, arm in sites.items():
            require(_NAME.fullmatch(site) is not None, f"bodies.{body}.sites.{site}", site, "letters, digits, '_', '-' and '.' only")
            require(_point(arm), f"bodies.{body}.sites.{site}", arm, "expected a lever arm [x, y, z] of finite numbers (m, body frame)")


@dataclass(frozen=True, kw_only=True, slots=True)
class ReplaySpec:
    """One `spec.toml` (docs/replay.md).

    format: the format version (1). description: one line. seed: seeds each estimator's
    Context.rng (stream "estimator/NAME"). window: the time window. bodies: {body: {sites: {site:
    [x, y, z] m, body frame FLU}}}, in order (the vehicles of the Context); the site's full name is
    "body/site". anchors: {name: [x, y, z] m, world ENU}, fixed. sensors: {stream: table} the declared
    sensor models handed to estimators as Context.sensors (free tables, but `imu` resolved as a
    scenario's, with its per-body tables: testbed.sensors.config.declared_imu). motion: Context.motion,
    "prescribed" (kinematic) or "flown" (closed loop). prior: {target: {mean: (n,), cov: (k, k)}}
    the prior the built-in estimators start from, in their own state (Context.prior; an exported
    run's, testbed.plugins.priors.priors; k = n, or k < n for the tangent space where the state
    lives on a manifold, as visnav's (22,) state with a (21, 21) covariance). estimators: [[estimators]]
    tables as in a scenario (entry, name, params). network: the [network] the recorded vehicles'
    messages travel through, as a scenario's (testbed.config.network; an exported run's): each
    estimator gets its own (Context.channel, testbed.plugins.channel), its geometry the truth
    table's and the links rows' nlos flags; None: ideal (no channel). bag: the measurements and truth are read from
    this ROS bag instead of the CSV tables beside the spec (None: from the tables).
    """

    format: int = FORMAT
    description: str = ""
    seed: int = 0
    window: Window
    bodies: dict
    anchors: dict = field(default_factory=dict)
    sensors: dict = field(default_factory=dict)
    motion: Literal["prescribed", "flown"] = "prescribed"
    prior: dict = field(default_factory=dict)
    estimators: tuple[EstimatorSpec, ...] = ()
    network: NetworkConfig | None = None
    bag: BagSource | None = None

    def __post_init__(self) -> None:
        require(self.format == FORMAT, "format", self.format, f"this testbed reads format {FORMAT}")
        in_range(self, "seed", 0, 10**9)
        require(bool(self.bodies), "bodies", self.bodies, "name at least one body ([bodies.NAME.sites])")
        _check_bodies(self.bodies)
        for name, p in self.anchors.items():
            require(_NAME.fullmatch(name) is not None, f"anchors.{name}", name, "letters, digits, '_', '-' and '.' only")
            require(name not in self.bodies, f"anchors.{name}", name, "is also a body name")
            require(_point(p), f"anchors.{name}", p, "expected a position [x, y, z] of finite numbers (m, world ENU)")
        for name, table in self.sensors.items():
            require(isinstance(table, dict), f"sensors.{name}", table, "expected a table (the declared sensor model)")
        if "imu" in self.sensors:  # resolved as a scenario's: its preset fills the keys left out
            resolved = declared_imu(self.sensors["imu"], tuple(self.bodies), "sensors.imu")
            object.__setattr__(self, "sensors", {**self.sensors, "imu": resolved})
        _check_prior(self.prior)

    @property
    def sites(self) -> dict[str, tuple[str, np.ndarray]]:
        """{"body/site": (body, lever arm (3,) m body frame)}, arrays read-only."""
        out = {}
        for body, table in self.bodies.items():
            for site, arm in table.get("sites", {}).items():
                a = np.array(arm, float)
                a.flags.writeable = False
                out[f"{body}/{site}"] = (body, a)
        return out

    @property
    def priors(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """{target: (mean (n,), cov (k, k))} as Context.prior."""
        return {t: (np.array(p["mean"], float), np.array(p["cov"], float)) for t, p in self.prior.items()}

    @property
    def anchor_points(self) -> dict[str, np.ndarray]:
        """{anchor: (3,) m world}."""
        return {name: np.array(p, float) for name, p in self.anchors.items()}


def load_spec(path: Path) -> ReplaySpec:
    """Read and check a spec.toml; ConfigError (exit 2) naming the file and key on any mistake."""
    path = Path(path)
    return from_dict(ReplaySpec, read_toml_file(path, "spec", "name its spec.toml"), str(path))
