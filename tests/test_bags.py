"""ROS bags (docs/replay.md, "ROS bags"): `testbed export --format mcap` writes a ROS 2 bag whose
replay gives the estimates of the CSV export's replay; the same data as a ROS 1 bag (another link
message type, read through the topic map's fields) replays to the same estimates; the bad inputs."""
import dataclasses
import json
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from testbed.config import scenario
from testbed.cli import main
from testbed.plugins import EstimatorSpec
from testbed.plugins.collect import read_tracks
from testbed.plugins.feed import run_plugin
from testbed.plugins.loading import resolve
from testbed.replay.recording import load_recording
from testbed.replay.ros import LINK_TYPE, typestore
from testbed.runner import ESTIMATES_FILE, run

highlevel = pytest.importorskip("rosbags.highlevel")
rosbag1 = pytest.importorskip("rosbags.rosbag1")

NS = 0.5e-9  # s: a ROS stamp holds integer ns, so a time moves by at most half of one


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """coop-denied for 2 s (18 UAVs: UWB, GNSS, IMU) with coop.window_ins and coop.window, exported
    as CSV and as MCAP; the CSV export replayed."""
    d = tmp_path_factory.mktemp("bags")
    sc = scenario.load("coop-denied", duration=2.0)
    sc = dataclasses.replace(sc, estimators=(EstimatorSpec(entry="coop.window_ins", name="coop"),
                                             EstimatorSpec(entry="coop.window", name="w")))
    run(sc, d / "run", plots=False)
    assert main(["export", str(d / "run"), "--out", str(d / "csv")]) == 0
    assert main(["export", str(d / "run"), "--out", str(d / "mcap"), "--format", "mcap"]) == 0
    assert main(["replay", str(d / "csv" / "spec.toml"), "--out", str(d / "rep_csv"), "--no-plots"]) == 0
    return d


def _same_estimates(a: Path, b: Path) -> None:
    """Two replay directories hold the same estimates (values to 1e-9 m, times to a ns) and scores."""
    with np.load(a / "estimates.npz") as ea, np.load(b / "estimates.npz") as eb:
        assert sorted(ea.files) == sorted(eb.files)
        ta, tb = read_tracks(ea), read_tracks(eb)
    assert set(ta) == {"coop", "w"} and set(ta) == set(tb)
    for key in ta:
        assert set(ta[key]) == set(tb[key]) and len(ta[key]) >= 18
        for k, s in ta[key].items():
            r = tb[key][k]
            assert s.time.size == r.time.size > 0
            np.testing.assert_allclose(r.time, s.time, rtol=0, atol=NS)
            np.testing.assert_allclose(r.value, s.value, rtol=0, atol=1e-9)
            np.testing.assert_allclose(r.cov, s.cov, rtol=1e-9, atol=1e-15)
    ma, mb = (json.loads((p / "metrics.json").read_text()) for p in (a, b))
    assert ma["measurements"] == mb["measurements"] and sum(ma["measurements"].values()) > 5000
    for key in ma["estimators"]:
        np.testing.assert_allclose(mb["estimators"][key]["rmse_position_m"], ma["estimators"][key]["rmse_position_m"], rtol=1e-9)


@pytest.mark.slow  # the shared run, its exports and two replays of coop-denied, ~20 s
def test_bag_replay_gives_the_estimates_of_the_csv_replay(exported, capsys):
    d = exported
    assert sorted(p.name for p in (d / "mcap").iterdir() if not p.name.startswith(".")) == ["bag", "provenance.json", "spec.toml"]
    assert main(["replay", str(d / "mcap" / "spec.toml"), "--out", str(d / "rep_bag"), "--no-plots"]) == 0
    _same_estimates(d / "rep_csv", d / "rep_bag")
    # the rows themselves: every value bit for bit, times to the ns of a stamp
    a, b = load_recording(d / "csv" / "spec.toml"), load_recording(d / "mcap" / "spec.toml")
    assert a.tables.keys() == b.tables.keys() == {"links", "poses", "imu", "truth"}
    for name, ta in a.tables.items():
        tb = b.tables[name]
        for c, x in ta.columns.items():
            if c in ("time", "arrival"):
                np.testing.assert_allclose(tb[c], x, rtol=0, atol=NS)
            elif c == "nlos":  # a bag's Link message has no NLOS flag (the export's note says so)
                assert np.isnan(tb[c]).all()
            elif c in ("vx", "vy", "vz"):  # the twist goes to the body frame and back
                np.testing.assert_allclose(tb[c], x, rtol=0, atol=1e-12)
            else:
                np.testing.assert_array_equal(tb[c], x, err_msg=f"{name}.{c}")


def test_the_bag_is_ros2_mcap_with_the_topics_types_and_counts(exported):
    d = exported
    bag = d / "mcap" / "bag"
    raw = (bag / "bag.mcap").read_bytes()
    assert raw[:8] == b"\x89MCAP0\r\n" and raw[8] == 1 and raw[17:25] == b"\x04\x00\x00\x00ros2"  # header: profile ros2
    meta = (bag / "metadata.yaml").read_text()
    assert "storage_identifier: mcap" in meta and "serialization_format: cdr" in meta
    from testbed.api import load_run

    log = load_run(d / "run").log
    with np.load(d / "run" / ESTIMATES_FILE) as f:
        tracks = read_tracks(f)
    T = log["time"].size
    want = {"/links/uwb": (LINK_TYPE, log["uwb/time"].size), "/tf": ("tf2_msgs/msg/TFMessage", T)}
    for i in range(1, 19):
        want[f"/uav{i}/imu"] = ("sensor_msgs/msg/Imu", int((log["imu/src"] == f"uav{i}/imu").sum()))
        want[f"/uav{i}/gnss"] = ("nav_msgs/msg/Odometry", int(np.char.startswith(log["gnss/src"], f"uav{i}/").sum()))
        want[f"/uav{i}/truth"] = ("nav_msgs/msg/Odometry", T)
    for key, track in tracks.items():
        for (target, q), s in track.items():
            if q == "position":
                want[f"/estimates/{key}/{target}"] = ("nav_msgs/msg/Odometry", s.time.size)
    with highlevel.AnyReader([bag]) as r:  # no typestore given: every definition comes from the bag
        got = {c.topic: (c.msgtype, c.msgcount) for c in r.connections}
        assert got == want
        imu = next(c for c in r.connections if c.topic == "/uav1/imu")
        _, ns, raw = next(r.messages(connections=[imu]))
        m = r.deserialize(raw, imu.msgtype)
        row = np.flatnonzero(log["imu/src"] == "uav1/imu")[0]
        assert m.header.frame_id == "uav1/imu" and ns == round(log["imu/arrival"][row] * 1e9)
        assert [m.linear_acceleration.x, m.angular_velocity.z] == [log["imu/value"][row, 0], log["imu/value"][row, 5]]
        assert m.orientation_covariance[0] == -1 and m.linear_acceleration_covariance[0] > 0
        link = next(c for c in r.connections if c.topic == "/links/uwb")
        m = r.deserialize(next(r.messages(connections=[link]))[2], LINK_TYPE)
        assert (m.src, m.dst, m.value) == (log["uwb/src"][0], log["uwb/dst"][0], log["uwb/value"][0, 0])
        est = next(c for c in r.connections if c.topic.startswith("/estimates/w/"))
        m = r.deserialize(next(r.messages(connections=[est]))[2], est.msgtype)
        s = tracks["w"][(est.topic.rpartition("/")[2], "position")]
        assert [m.pose.pose.position.x, m.pose.covariance[0]] == [s.value[0, 0], s.cov[0, 0, 0]]


VENDOR = "vendor_msgs/msg/Distance"
VENDOR_MSG = "std_msgs/Header header\nstring tag\nstring anchor\nfloat64 distance\nfloat64 std\n"


def _ros1(obj, store):
    """A ROS 2 message object as the same message of the ROS 1 store (Header gets seq 0)."""
    if hasattr(obj, "__msgtype__"):
        cls = store.types[obj.__msgtype__]
        return cls(**{f: _ros1(getattr(obj, f, 0), store) for f in cls.__dataclass_fields__ if f != "__msgtype__"})
    if isinstance(obj, list):
        return [_ros1(x, store) for x in obj]
    return obj


def test_the_same_data_as_a_ros1_bag_with_another_link_type_replays_to_the_same_estimates(exported, tmp_path):
    """The mapped topics copied into a ROS 1 bag by rosbags' rosbag1 Writer (ROS 1 Noetic types, the
    links as a vendor's message type read through `fields`) replay to the CSV path's estimates."""
    from rosbags.typesys import get_types_from_msg

    d = exported
    spec = tomllib.loads((d / "mcap" / "spec.toml").read_text())
    topics = {t["topic"] for t in spec["bag"]["topics"]}
    store1 = typestore(ros1=True)
    store1.register(get_types_from_msg(VENDOR_MSG, VENDOR))
    with highlevel.AnyReader([d / "mcap" / "bag"]) as r, rosbag1.Writer(tmp_path / "data.bag") as w:
        conns = {}
        for c in r.connections:
            if c.topic in topics:
                conns[c.id] = w.add_connection(c.topic, VENDOR if c.msgtype == LINK_TYPE else c.msgtype, typestore=store1)
        for c, ns, raw in r.messages(connections=[c for c in r.connections if c.topic in topics]):
            m = r.deserialize(raw, c.msgtype)
            if c.msgtype == LINK_TYPE:
                H = store1.types["std_msgs/msg/Header"]
                m = store1.types[VENDOR](header=H(seq=0, stamp=m.header.stamp, frame_id=""), tag=m.src, anchor=m.dst,
                                         distance=m.value, std=m.sigma)
            else:
                m = _ros1(m, store1)
            w.write(conns[c.id], ns, store1.serialize_ros1(m, m.__msgtype__))
    for t in spec["bag"]["topics"]:
        if t["stream"] == "uwb":
            t["fields"] = {"src": "tag", "dst": "anchor", "value": "distance", "sigma": "std"}
    spec["bag"]["path"] = "data.bag"
    (tmp_path / "spec.toml").write_text(tomli_w.dumps(spec))
    assert main(["replay", str(tmp_path / "spec.toml"), "--out", str(tmp_path / "rep"), "--no-plots"]) == 0
    _same_estimates(d / "rep_csv", tmp_path / "rep")


def _spec_with(exported: Path, tmp: Path, edit) -> Path:
    """The MCAP export's spec, its bag named by absolute path, changed by edit(spec dict), in tmp."""
    spec = tomllib.loads((exported / "mcap" / "spec.toml").read_text())
    spec["bag"]["path"] = str(exported / "mcap" / "bag")
    edit(spec)
    (tmp / "spec.toml").write_text(tomli_w.dumps(spec))
    return tmp / "spec.toml"


def _topic(spec: dict, topic: str) -> dict:
    return next(t for t in spec["bag"]["topics"] if t["topic"] == topic)


@pytest.mark.parametrize("edit, message", [
    (lambda s: _topic(s, "/links/uwb").update(topic="/links/none"), "bag.topics[0].topic: '/links/none': no such topic in"),
    (lambda s: _topic(s, "/uav1/imu").update(stream="gnss"),
     "].stream: 'gnss': topic /uav1/imu carries sensor_msgs/msg/Imu; the stream reads nav_msgs/msg/Odometry or"),
    (lambda s: _topic(s, "/uav1/gnss").update(stream="uwb"), "the stream reads testbed_msgs/msg/Link (or name the message's fields)"),
    (lambda s: _topic(s, "/links/uwb").update(rate=10), "bag.topics[0].rate: unknown key"),
    (lambda s: _topic(s, "/links/uwb").update(fields={"value": "distance"}),
     "bag.topics[0].fields.value: 'distance': no such field in testbed_msgs/msg/Link"),
    (lambda s: _topic(s, "/links/uwb").update(fields={"range": "value"}), "bag.topics[0].fields.range: 'range': not a column of links"),
    (lambda s: _topic(s, "/links/uwb").update(fields={"value": "src"}),
     "bag.topics[0].fields.value: 'src': a str in testbed_msgs/msg/Link, not a number"),
    (lambda s: _topic(s, "/uav1/gnss").update(fields={"value": "x"}), "].fields: {'value': 'x'}: only a link stream"),
    (lambda s: _topic(s, "/uav1/imu").update(stream="lidar"), "bag.topics[", ),
    (lambda s: s["bag"].update(path="nowhere"), "bag.path: 'nowhere': no such file or directory"),
    (lambda s: s["bag"].update(path=str(Path(s["bag"]["path"]).parent / "spec.toml")), "bag.path: "),
    (lambda s: s["bag"].update(topics=[t for t in s["bag"]["topics"] if t["stream"] != "uwb"]), "bag.topics: no topic of a link stream"),
])
def test_a_bad_bag_or_topic_map_is_one_line_naming_spec_key_and_value(exported, tmp_path, capsys, edit, message):
    spec = _spec_with(exported, tmp_path, edit)
    assert main(["replay", str(spec), "--out", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"testbed: error: {spec}: ") and message in err, err
    assert not (tmp_path / "rep").exists()


def test_a_bad_row_names_the_bag_table_row_and_column(exported, tmp_path, capsys):
    spec = _spec_with(exported, tmp_path, lambda s: s["bodies"].pop("uav18"))
    assert main(["replay", str(spec), "--out", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and not (tmp_path / "rep").exists()
    assert err.startswith(f"testbed: error: {exported / 'mcap' / 'bag'} (links rows): row ") and "'uav18/uwb' is not a site" in err, err


def test_the_bag_is_the_only_source_and_rosbags_is_needed(exported, tmp_path, capsys, monkeypatch):
    spec = _spec_with(exported, tmp_path, lambda s: None)
    (tmp_path / "links.csv").write_text((exported / "csv" / "links.csv").read_text())
    assert main(["replay", str(spec), "--out", str(tmp_path / "rep")]) == 2
    assert "bag: the spec reads a bag, but links.csv lies beside it" in capsys.readouterr().err
    # without the bags extra: one line naming it, nothing written
    monkeypatch.setitem(sys.modules, "rosbags.typesys", None)
    assert main(["export", str(exported / "run"), "--out", str(tmp_path / "m"), "--format", "mcap"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "testbed: error: ROS bags need the rosbags package: install the bags extra: pip install '.[bags]'"
    assert not (tmp_path / "m").exists()
