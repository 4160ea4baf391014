"""The tables of a recorded dataset read from a ROS 1 or ROS 2 bag through the spec's topic map
(docs/replay.md, "ROS bags"; the spec's [bag], testbed.replay.spec.BagSource).

Each mapped topic's messages become rows of the format's tables, the same columns as the CSV files
(testbed.replay.tables.SCHEMAS), so everything after reading (checks, feed, scoring) is the CSV path:
- uwb, phase, range-rate -> links rows (kind = the stream): testbed_msgs/msg/Link, or any message
  type whose fields the topic names (src, dst, value, optional sigma);
- gnss -> poses rows of kind gnss: nav_msgs/msg/Odometry or geometry_msgs/msg/PoseWithCovarianceStamped,
  position m world ENU, sigma_x, sigma_y, sigma_z the square roots of the pose covariance's diagonal
  (a zero variance: none declared);
- imu -> imu rows: sensor_msgs/msg/Imu (linear_acceleration m/s^2, angular_velocity rad/s, the site
  frame; sigma_accel, sigma_gyro the square roots of the covariances' first element, zero: none);
- truth -> truth rows: Odometry (the twist, in the body frame by the ROS convention, turned into a
  world-frame velocity) or PoseWithCovarianceStamped (no velocity).
Times: header.stamp (time of validity) and the message's log time (arrival), both as integer ns / 1e9.
The site or body measured: the topic's `source`, else the message's frame (Imu header.frame_id,
Odometry child_frame_id). Mistakes (a bag that cannot be read, a topic missing, a message type the
stream cannot read, a field missing) are one ConfigError naming the spec, the key and the value.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from testbed.errors import ConfigError
from testbed.replay.ros import LINK_TYPE, rosbags, seconds, typestore
from testbed.replay.spec import LINK_FIELDS, LINK_STREAMS, BagTopic, ReplaySpec
from testbed.replay.tables import SCHEMAS, Table

ODOMETRY, POSE_COV, IMU = "nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped", "sensor_msgs/msg/Imu"
#: the message types each stream reads (a link stream: any type, through its fields)
TYPES = {"gnss": (ODOMETRY, POSE_COV), "truth": (ODOMETRY, POSE_COV), "imu": (IMU,)}
TABLE = {"uwb": "links", "phase": "links", "range-rate": "links", "gnss": "poses", "imu": "imu", "truth": "truth"}


def _field(msg, path: str):
    for name in path.split("."):
        msg = getattr(msg, name)
    return msg


def _stamp(header) -> float:
    return seconds(int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec))


def _sigma(variance: float) -> float:
    return float(np.sqrt(variance)) if variance > 0 else np.nan


def _xyz(v) -> tuple[float, float, float]:
    return float(v.x), float(v.y), float(v.z)


class _Rows:
    """Rows of one table, as lists per column."""

    def __init__(self, table: str):
        self.table = table
        self.cols: dict[str, list] = {c: [] for c, _, _ in SCHEMAS[table]}

    def add(self, **cells) -> None:
        for c, cell in self.cols.items():
            cell.append(cells.get(c, np.nan))


def _row(topic: BagTopic, msg, arrival: float, rows: _Rows, where: str) -> None:
    """Append the row(s) of one message to rows."""
    s = topic.stream
    if s in LINK_STREAMS:
        f = {c: topic.fields.get(c, c) for c in LINK_FIELDS}
        missing = [c for c in LINK_FIELDS if not _has(msg, f[c]) and (c != "sigma" or "sigma" in topic.fields)]
        if missing:
            raise ConfigError(f"{where}.fields.{missing[0]}: {f[missing[0]]!r}: no such field in {msg.__msgtype__}")
        cells = {c: _field(msg, f[c]) if _has(msg, f[c]) else np.nan for c in LINK_FIELDS}
        for c in ("value", "sigma"):
            if not isinstance(cells[c], (int, float)) or isinstance(cells[c], bool):
                raise ConfigError(f"{where}.fields.{c}: {f[c]!r}: a {type(cells[c]).__name__} in {msg.__msgtype__}, not a number")
        rows.add(time=_stamp(msg.header), src=str(cells["src"]), dst=str(cells["dst"]), kind=s, value=float(cells["value"]),
                 sigma=float(cells["sigma"]), arrival=arrival)
    elif s == "imu":
        rows.add(time=_stamp(msg.header), site=topic.source or str(msg.header.frame_id),
                 **dict(zip(("ax", "ay", "az"), _xyz(msg.linear_acceleration))),
                 **dict(zip(("gx", "gy", "gz"), _xyz(msg.angular_velocity))),
                 sigma_accel=_sigma(msg.linear_acceleration_covariance[0]), sigma_gyro=_sigma(msg.angular_velocity_covariance[0]),
                 arrival=arrival)
    else:
        odometry = msg.__msgtype__ == ODOMETRY
        if not odometry and not topic.source:
            raise ConfigError(f"{where}.source: a {msg.__msgtype__} names no body or site: name it (source = \"BODY/SITE\")")
        name = topic.source or str(msg.child_frame_id)
        pose, cov = msg.pose.pose, msg.pose.covariance
        p = _xyz(pose.position)
        q = (float(pose.orientation.w), *_xyz(pose.orientation))
        if s == "gnss":
            rows.add(time=_stamp(msg.header), body=name, kind="gnss", **dict(zip("xyz", p)),
                     **{f"sigma_{c}": _sigma(cov[7 * k]) for k, c in enumerate("xyz")}, arrival=arrival)
        else:
            vel = {}
            if odometry:
                v = Rotation.from_quat(q, scalar_first=True).apply(_xyz(msg.twist.twist.linear))
                vel = {**dict(zip(("vx", "vy", "vz"), v.tolist())), **dict(zip(("wx", "wy", "wz"), _xyz(msg.twist.twist.angular)))}
            rows.add(time=_stamp(msg.header), body=name, **dict(zip("xyz", p)), **dict(zip(("qw", "qx", "qy", "qz"), q)), **vel)


def _has(msg, path: str) -> bool:
    try:
        _field(msg, path)
    except AttributeError:
        return False
    return True


def _table(rows: _Rows, file: str) -> Table:
    cols = {}
    for c, numeric, required in SCHEMAS[rows.table]:
        if numeric:
            a = np.array(rows.cols[c], float)
            bad = ~np.isfinite(a) if required else np.isinf(a)
            if bad.any():
                i = int(np.argmax(bad))
                raise ConfigError(f"{file}: row {i + 1}, column {c}: must be a finite number, got {a[i]!r}")
        else:
            a = np.array(rows.cols[c], str)
        cols[c] = a
    return Table(file, cols, None)


def bag_tables(spec: ReplaySpec, spec_path: Path) -> dict[str, Table]:
    """The tables {name: Table} of the bag spec.bag names (relative to spec_path's directory)."""
    bag = spec.bag
    path = Path(spec_path).parent / bag.path
    hl = rosbags("highlevel")
    if not path.exists():
        raise ConfigError(f"{spec_path}: bag.path: {bag.path!r}: no such file or directory ({path})")
    try:
        reader = hl.AnyReader([path], default_typestore=typestore())
        reader.open()
    except Exception as e:  # rosbags' errors (AnyReaderError, ReaderError, ...) share no public base class
        raise ConfigError(f"{spec_path}: bag.path: {bag.path!r}: not a readable ROS 1 or ROS 2 bag: {e}".splitlines()[0]) from None
    try:
        by_conn = {}
        for i, topic in enumerate(bag.topics):
            where = f"{spec_path}: bag.topics[{i}]"
            conns = [c for c in reader.connections if c.topic == topic.topic]
            if not conns:
                have = sorted({c.topic for c in reader.connections})
                raise ConfigError(f"{where}.topic: {topic.topic!r}: no such topic in {path} (it has {len(have)}: "
                                  f"{', '.join(have[:8])}{', ...' if len(have) > 8 else ''})")
            for c in conns:
                ok = TYPES.get(topic.stream, (c.msgtype,) if topic.fields else (LINK_TYPE,))
                if c.msgtype not in ok:
                    raise ConfigError(f"{where}.stream: {topic.stream!r}: topic {topic.topic} carries {c.msgtype}; "
                                      f"the stream reads {' or '.join(ok)}"
                                      + ("" if topic.stream not in LINK_STREAMS else " (or name the message's fields)"))
                by_conn[c.id] = (topic, where)
        rows = {name: _Rows(name) for name in dict.fromkeys(TABLE[t.stream] for t in bag.topics)}
        if "links" not in rows:
            raise ConfigError(f"{spec_path}: bag.topics: no topic of a link stream ({', '.join(LINK_STREAMS)}); a dataset needs links")
        conns = [c for c in reader.connections if c.id in by_conn]
        for conn, ns, raw in reader.messages(connections=conns):
            topic, where = by_conn[conn.id]
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as e:  # a corrupt message: rosbags raises whatever its decoder met
                raise ConfigError(f"{path}: topic {conn.topic}: the message logged at {ns} ns cannot be decoded as "
                                  f"{conn.msgtype}: {type(e).__name__}: {e}".splitlines()[0]) from None
            _row(topic, msg, seconds(ns), rows[TABLE[topic.stream]], where)
    finally:
        reader.close()
    return {name: _table(r, f"{path} ({name} rows)") for name, r in rows.items()}
