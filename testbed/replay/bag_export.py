"""`testbed export RUN --format mcap --out DIR`: a run as a ROS 2 bag (MCAP storage) and the
spec.toml that replays it (docs/replay.md, "ROS bags").

DIR/bag/ is the bag (metadata.yaml and bag.mcap, rosbag2 format 9, CDR messages with their
definitions embedded); DIR/spec.toml is the spec of the CSV export (testbed.replay.export) plus a
[bag] table naming the bag and mapping its topics to the format's streams. The messages carry
exactly the rows of the CSV export (testbed.replay.export.tables) but the camera's (no topic: the
estimators that read it are left out of the spec, a note says so), times rounded to the ns of a ROS
stamp; the bag's clock is the run's (0 s at its start). Topics (N vehicles uavI):

  /links/uwb, /links/phase, /links/range_rate  testbed_msgs/msg/Link (testbed.replay.ros.LINK_MSG)
  /uavI/imu     sensor_msgs/msg/Imu: frame_id the IMU site; covariances diag(sigma^2), orientation
                unknown (orientation_covariance[0] = -1)
  /uavI/gnss    nav_msgs/msg/Odometry: a GNSS fix as a position in the world frame (local ENU, m),
                child_frame_id the antenna site, pose covariance diag(sigma_x^2, sigma_y^2, sigma_z^2)
  /uavI/truth   nav_msgs/msg/Odometry: the true pose; twist in the body frame (ROS convention)
  /estimates/EST/TARGET  nav_msgs/msg/Odometry: each position estimate of a plugin estimator
                (estimates.npz; EST its key with '.' and '-' as '_'), in the world frame (or the
                vehicle's body frame, frame_id uavJ, for an estimate relative to it); the pose
                covariance's position block is the estimate's covariance (zero where it gave none)
  /tf           tf2_msgs/msg/TFMessage: world -> uavI, the true poses at every log instant
Orientation is not part of a GNSS fix or a position estimate: (1, 0, 0, 0), covariance block zero.
Odometry and tf are in the frame "world" (local ENU, m); a Link's frame_id is empty. A message's
log time is the row's arrival (when it reached the estimator), its header.stamp the time of
validity; estimates and truth are logged at their own time.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import tomli_w
from scipy.spatial.transform import Rotation

from testbed.api import load_run
from testbed.outdir import Output
from testbed.plugins.collect import ESTIMATES_FILE, load_tracks
from testbed.replay.export import run_spec, tables
from testbed.replay.ros import LINK_TYPE, nanoseconds, rosbags, typestore

WORLD = "world"
BAG = "bag"  # the bag's directory inside the dataset
LINK_TOPICS = {"uwb": "/links/uwb", "phase": "/links/phase", "range-rate": "/links/range_rate"}


class _Messages:
    """Messages built with one typestore, kept serialized (CDR): (topic, msgtype, log time ns, bytes)
    in the order added."""

    def __init__(self, store):
        self.ts = store
        self.items: list[tuple[str, str, int, bytes]] = []
        self.streams: dict[str, str] = {}  # {topic: the stream a replay reads from it}

    def header(self, t: float, frame: str):
        T = self.ts.types
        ns = nanoseconds(t)
        stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def vec(self, v):
        return self.ts.types["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quat(self, q):
        """geometry_msgs/Quaternion of q (4,) wxyz."""
        return self.ts.types["geometry_msgs/msg/Quaternion"](w=float(q[0]), x=float(q[1]), y=float(q[2]), z=float(q[3]))

    def odometry(self, t: float, child: str, p, q, cov: np.ndarray, v_body=(0.0, 0.0, 0.0), w_body=(0.0, 0.0, 0.0),
                 frame: str = WORLD):
        """nav_msgs/Odometry of child in `frame`: position p (3,) m, attitude q (4,) wxyz, pose
        covariance cov (6, 6) (m, rad), twist in the child's frame (m/s, rad/s)."""
        T = self.ts.types
        pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                                           orientation=self.quat(q))
        twist = T["geometry_msgs/msg/Twist"](linear=self.vec(v_body), angular=self.vec(w_body))
        return T["nav_msgs/msg/Odometry"](
            header=self.header(t, frame), child_frame_id=child,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.ascontiguousarray(cov, float).ravel()),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))

    def add(self, topic: str, msg, arrival: float, stream: str | None = None) -> None:
        """Queue msg on topic at log time `arrival` (s); stream: what a replay reads it as (None: not read)."""
        self.items.append((topic, msg.__msgtype__, nanoseconds(arrival), bytes(self.ts.serialize_cdr(msg, msg.__msgtype__))))
        if stream is not None:
            self.streams[topic] = stream


def _position_cov(cov3: np.ndarray) -> np.ndarray:
    """(6, 6) pose covariance with cov3 (3, 3) m^2 as its position block (NaN -> 0), the rest 0."""
    out = np.zeros((6, 6))
    out[:3, :3] = np.nan_to_num(cov3, nan=0.0)
    return out


def _links(m: _Messages, links: dict) -> None:
    Link = m.ts.types[LINK_TYPE]
    for i in range(links["time"].size):
        msg = Link(header=m.header(float(links["time"][i]), ""), src=str(links["src"][i]), dst=str(links["dst"][i]),
                   value=float(links["value"][i]), sigma=float(links["sigma"][i]))
        kind = str(links["kind"][i])
        m.add(LINK_TOPICS[kind], msg, float(links["arrival"][i]), kind)


def _imu(m: _Messages, imu: dict) -> None:
    T = m.ts.types
    ident = m.quat((1.0, 0.0, 0.0, 0.0))
    unknown = np.zeros(9)
    unknown[0] = -1.0  # sensor_msgs/Imu: no orientation estimate
    for i in range(imu["time"].size):
        site = str(imu["site"][i])
        sa, sg = (np.nan_to_num(float(imu[c][i]) ** 2, nan=0.0) for c in ("sigma_accel", "sigma_gyro"))
        msg = T["sensor_msgs/msg/Imu"](
            header=m.header(float(imu["time"][i]), site), orientation=ident, orientation_covariance=unknown,
            angular_velocity=m.vec([imu[c][i] for c in ("gx", "gy", "gz")]), angular_velocity_covariance=np.eye(3).ravel() * sg,
            linear_acceleration=m.vec([imu[c][i] for c in ("ax", "ay", "az")]), linear_acceleration_covariance=np.eye(3).ravel() * sa)
        m.add(f"/{site.partition('/')[0]}/imu", msg, float(imu["arrival"][i]), "imu")


def _gnss(m: _Messages, poses: dict) -> None:
    for i in range(poses["time"].size):
        site = str(poses["body"][i])
        cov = np.diag([float(poses[f"sigma_{c}"][i]) ** 2 for c in "xyz"])
        msg = m.odometry(float(poses["time"][i]), site, [poses[c][i] for c in "xyz"], (1.0, 0.0, 0.0, 0.0), _position_cov(cov))
        m.add(f"/{site.partition('/')[0]}/gnss", msg, float(poses["arrival"][i]), "gnss")


def _truth(m: _Messages, truth: dict) -> None:
    T = m.ts.types
    q = np.stack([truth[c] for c in ("qw", "qx", "qy", "qz")], axis=1)
    v_body = Rotation.from_quat(q, scalar_first=True).inv().apply(np.stack([truth[c] for c in ("vx", "vy", "vz")], axis=1))
    frames: dict[float, list] = {}
    for i in range(truth["time"].size):
        t, body = float(truth["time"][i]), str(truth["body"][i])
        p = [truth[c][i] for c in "xyz"]
        m.add(f"/{body}/truth", m.odometry(t, body, p, q[i], np.zeros((6, 6)), v_body[i], [truth[c][i] for c in ("wx", "wy", "wz")]), t,
              "truth")
        tr = T["geometry_msgs/msg/Transform"](translation=m.vec(p), rotation=m.quat(q[i]))
        frames.setdefault(t, []).append(T["geometry_msgs/msg/TransformStamped"](header=m.header(t, WORLD), child_frame_id=body,
                                                                               transform=tr))
    for t, transforms in frames.items():
        m.add("/tf", T["tf2_msgs/msg/TFMessage"](transforms=transforms), t)


def _topic_token(key: str) -> str:
    """An estimator key as a ROS topic name token: '.' and '-' become '_'."""
    return key.replace(".", "_").replace("-", "_")


def _estimates(m: _Messages, run_dir: Path) -> None:
    tracks = load_tracks(run_dir / ESTIMATES_FILE)
    for key, track in tracks.items():
        for (target, q), s in track.items():
            if q != "position":
                continue
            for k in range(s.time.size):
                t = float(s.time[k])
                msg = m.odometry(t, target, s.value[k], (1.0, 0.0, 0.0, 0.0), _position_cov(s.cov[k]),
                                 frame=WORLD if s.frame == "world" else s.frame)
                m.add(f"/estimates/{_topic_token(key)}/{target}", msg, t)


def write_bag(path: Path, m: _Messages) -> int:
    """The messages as a ROS 2 bag directory (MCAP) at path, in order of log time (ties: in the
    order added); returns the number of topics."""
    r2 = rosbags("rosbag2")
    with r2.Writer(path, version=9, storage_plugin=r2.StoragePlugin.MCAP) as w:
        conns = {}
        for topic, msgtype, _, _ in m.items:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=m.ts)
        for topic, _, ns, data in sorted(m.items, key=lambda item: item[2]):
            w.write(conns[topic], ns, data)
    return len(conns)


def export_bag(run_dir: Path, out: Path, *, force: bool = False) -> list[str]:
    """Write the run at run_dir as DIR/bag (ROS 2, MCAP) and DIR/spec.toml; returns the files written."""
    run_dir = Path(run_dir)
    run = load_run(run_dir)
    sc, log = run.scenario, run.log
    m = _Messages(typestore())
    spec = run_spec(run_dir, sc, log, bag=True)
    rows = tables(sc, log, bag=True)
    for name, add in (("links", _links), ("poses", _gnss), ("imu", _imu), ("truth", _truth)):
        if name in rows:
            add(m, rows[name])
    _estimates(m, run_dir)
    with Output(Path(out), kind="dataset", force=force) as o:
        topics = write_bag(o.path / BAG, m)
        bag = {"path": BAG, "topics": [{"topic": t, "stream": s} for t, s in m.streams.items()]}
        (o.path / "spec.toml").write_text(spec + "\n" + tomli_w.dumps({"bag": bag}))
        o.commit()
    return ["spec.toml", f"{BAG}/ ({len(m.items)} messages on {topics} topics)"]
