"""The IMU filters (nav.eskf, coop.ins, coop.ins_distributed) on recorded data:
a simulated 3 s run of three vehicles with IMUs, exported (testbed export) and replayed.

- `[sensors.imu] preset = "..."` in a replay is resolved as in a scenario (it was a KeyError);
- `[sensors.imu.BODY]` overrides the shared IMU table for one body, and each filter uses its
  vehicle's own table;
- without GNSS, the filters start from the `initial_pose` parameter (per vehicle position, yaw and
  their sigmas); a vehicle with neither a fix nor an initial pose is named in health and on stderr.
"""
from __future__ import annotations

import csv
import json
import math
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from testbed.config import scenario
from testbed.cli import main
from testbed.config import to_dict
from testbed.plugins.collect import ESTIMATES_FILE, load_tracks
from testbed.replay.spec import load_spec
from testbed.runner import run
from testbed.sensors.config import ImuConfig

SCENARIO = """
name = "imu-replay"
description = "three vehicles with IMUs, exported and replayed"
seed = 5
duration = 3.0
motion = "prescribed"

[world]
anchors = [[-25.0, -15.0, 3.0], [35.0, -20.0, 9.0], [30.0, 35.0, 3.0], [-20.0, 30.0, 9.0]]

[trajectory]
kind = "waypoints"
points = [[0.0, 0.0, 10.0], [15.0, -8.0, 13.0]]
times = [0.0, 12.0]
offsets = [[0.0, 0.0, 0.0], [0.0, 6.0, 0.0], [6.0, 0.0, 0.0]]

[sensors.imu]
preset = "bmi088"
rate_hz = 100.0

[sensors.uwb]
preset = "dw1000"
rate_hz = 10.0

[sensors.gnss]
rate_hz = 5.0
"""
FILTERS = ("nav.eskf", "coop.ins", "coop.ins_distributed")
BODIES = ("uav1", "uav2", "uav3")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """The exported dataset of the 3 s run (its spec lists no estimator: each test names its own)."""
    d = tmp_path_factory.mktemp("imu")
    (d / "s.toml").write_text(SCENARIO)
    run(scenario.load(str(d / "s.toml")), d / "run", plots=False)
    assert main(["export", str(d / "run"), "--out", str(d / "data")]) == 0
    return d / "data"


def _variant(dataset: Path, out: Path, edit=None, drop: tuple[str, ...] = ()) -> Path:
    """A copy of the dataset at out with its spec edited by edit(spec dict) and the tables drop left out."""
    shutil.copytree(dataset, out)
    for name in drop:
        (out / name).unlink()
    spec = tomllib.loads((out / "spec.toml").read_text())
    if edit is not None:
        edit(spec)
    (out / "spec.toml").write_text(tomli_w.dumps(spec))
    return out / "spec.toml"


def _one(tracks: dict) -> dict:
    """The tracks of the only estimator of a replay."""
    (track,) = tracks.values()
    return track


def test_a_preset_in_a_replays_imu_table_is_resolved_as_in_a_scenario(dataset, tmp_path):
    """Before: `KeyError: 'accel'` in every IMU filter."""
    spec = _variant(dataset, tmp_path / "d", lambda s: s["sensors"].update(imu={"preset": "mpu9250", "rate_hz": 100.0}))
    assert load_spec(spec).sensors["imu"] == to_dict(ImuConfig(preset="mpu9250", rate_hz=100.0))
    for entry in FILTERS:
        assert main(["replay", str(spec), "--out", str(tmp_path / entry), "--estimator", entry, "--no-plots"]) == 0
        track = _one(load_tracks(tmp_path / entry / ESTIMATES_FILE))
        assert {t for t, q in track if q == "position"} == set(BODIES), entry


def _uav2_noisier(spec: dict) -> None:
    spec["sensors"]["imu"]["uav2"] = {"preset": "mpu9250", "accel": {"noise_density": 3 * spec["sensors"]["imu"]["accel"]["noise_density"]}}


def test_a_bodys_own_imu_table_overrides_the_shared_one(dataset, tmp_path):
    spec = load_spec(_variant(dataset, tmp_path / "d", _uav2_noisier))
    imu = spec.sensors["imu"]
    shared = imu["accel"]["noise_density"]
    assert imu["uav2"]["accel"]["noise_density"] == 3 * shared
    # the keys uav2's table leaves out: the shared table's where it gives them (all of accel but
    # noise_density here), else uav2's preset (vibration is given by the export: shared)
    assert imu["uav2"]["accel"]["bias_sigma"] == imu["accel"]["bias_sigma"]
    assert imu["uav2"]["preset"] == "mpu9250" and imu["preset"] == "bmi088"
    assert "uav1" not in imu and "uav3" not in imu


@pytest.mark.parametrize("entry", FILTERS)
def test_each_filter_uses_its_vehicles_own_imu_table(dataset, tmp_path, entry):
    """uav2's accelerometer declared 3x noisier: its position covariance grows faster; the
    per-vehicle nav.eskf leaves uav1 and uav3 bit-identical."""
    plain = _variant(dataset, tmp_path / "a")
    own = _variant(dataset, tmp_path / "b", _uav2_noisier)
    for spec, out in ((plain, "ra"), (own, "rb")):
        assert main(["replay", str(spec), "--out", str(tmp_path / out), "--estimator", entry, "--no-plots"]) == 0
    a, b = (_one(load_tracks(tmp_path / k / ESTIMATES_FILE)) for k in ("ra", "rb"))
    ca, cb = a[("uav2", "position")].cov, b[("uav2", "position")].cov
    # right after the first GNSS fix's update and before the next (0.2 s later): pure propagation
    # in between, where a larger white accel noise only adds covariance
    assert np.trace(cb[-1]) > np.trace(ca[-1])
    if entry == "nav.eskf":
        for body in ("uav1", "uav3"):
            np.testing.assert_array_equal(a[(body, "position")].value, b[(body, "position")].value)
            np.testing.assert_array_equal(a[(body, "position")].cov, b[(body, "position")].cov)


def _first_truth(dataset: Path) -> dict[str, tuple[list[float], float]]:
    """{body: (position (3,) m, yaw deg)} of the truth table's first row of each body."""
    out = {}
    with open(dataset / "truth.csv") as f:
        for row in csv.DictReader(f):
            if row["body"] not in out:
                w, x, y, z = (float(row[k]) for k in ("qw", "qx", "qy", "qz"))
                yaw = math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
                out[row["body"]] = ([float(row[k]) for k in ("x", "y", "z")], yaw)
    return out


def _yaw(q: np.ndarray) -> float:
    w, x, y, z = q
    return math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


@pytest.mark.parametrize("entry", FILTERS)
def test_without_gnss_a_filter_starts_from_its_initial_pose(dataset, tmp_path, entry, capsys):
    """No poses.csv (no GNSS) and no rows in links.csv (no ranges to start from, estimators.range_start):
    uav1 and uav2 start at their first IMU sample from their own initial pose (position, sigma;
    their own yaw: 30 and -60 deg, not yaw0); uav3, with none, never starts, and says so in health
    and in one stderr line."""
    spec = _variant(dataset, tmp_path / "d", drop=("poses.csv",))
    links = spec.parent / "links.csv"
    links.write_text(links.read_text().splitlines()[0] + "\n")
    truth = _first_truth(dataset)
    yaws = {"uav1": 30.0, "uav2": -60.0}
    poses = ", ".join(f"{b} = {{ position = {truth[b][0]}, position_sigma = 0.5, yaw_deg = {yaws[b]}, yaw_sigma_deg = 5.0 }}"
                      for b in yaws)
    assert main(["replay", str(spec), "--out", str(tmp_path / "r"), "--estimator", entry,
                 "--param", f"initial_pose={{ {poses} }}", "--no-plots"]) == 0
    err = capsys.readouterr().err
    track = _one(load_tracks(tmp_path / "r" / ESTIMATES_FILE))
    assert {t for t, q in track if q == "position"} == {"uav1", "uav2"}
    for body, yaw in yaws.items():
        p, q = track[(body, "position")], track[(body, "attitude")]
        assert p.time[0] == 0.0  # the first IMU sample
        np.testing.assert_array_equal(p.value[0], truth[body][0])
        np.testing.assert_array_equal(p.cov[0], 0.25 * np.eye(3))
        assert abs(_yaw(q.value[0]) - yaw) < 1e-9, (body, _yaw(q.value[0]))
    health = json.loads((tmp_path / "r" / "metrics.json").read_text())["estimators"][entry]["health"]
    assert health["unstarted_vehicles"] == 1
    lines = [ln for ln in err.splitlines() if "never started" in ln]
    assert len(lines) == 1 and "uav3" in lines[0] and "uav1" not in lines[0] and "initial_pose" in lines[0], err


@pytest.mark.parametrize("entry", FILTERS)
def test_an_imu_filter_updates_on_the_height_stream(dataset, tmp_path, entry):
    """A height.csv (each body's true up coordinate at 10 Hz from 0.5 s plus N(0, 0.05^2) noise, declared
    sigma 0.05 m): the filter's vertical variance at the end falls below that of the same replay
    without it, and every height row is used (nothing skipped). Before: the stream was ignored
    (the two replays were identical; coop.ins and coop.ins_distributed until this stop). The range
    noise is the declared in both (range_noise_adapt off: eq. R1's lambda, matched on each run's
    own innovations, would differ between them by chance)."""
    rng = np.random.default_rng(3)
    rows = ["time,site,value,sigma"]
    with open(dataset / "truth.csv") as f:
        for row in csv.DictReader(f):
            t = float(row["time"])
            if t >= 0.5 and abs(t * 10 - round(t * 10)) < 1e-9:  # 10 Hz, once every filter has started
                rows.append(f"{t!r},{row['body']},{float(row['z']) + rng.normal(0, 0.05)!r},0.05")
    plain = _variant(dataset, tmp_path / "a")
    heights = _variant(dataset, tmp_path / "b")
    (heights.parent / "height.csv").write_text("\n".join(rows) + "\n")
    for spec, out in ((plain, "ra"), (heights, "rb")):
        assert main(["replay", str(spec), "--out", str(tmp_path / out), "--estimator", entry, "--param",
                     "range_noise_adapt=false", "--no-plots"]) == 0
    a, b = (_one(load_tracks(tmp_path / k / ESTIMATES_FILE)) for k in ("ra", "rb"))
    for body in BODIES:
        assert b[(body, "position")].cov[-1][2, 2] < a[(body, "position")].cov[-1][2, 2], body
    ha, hb = (json.loads((tmp_path / k / "metrics.json").read_text())["estimators"][entry]["health"] for k in ("ra", "rb"))
    assert hb["skipped_updates"] == ha["skipped_updates"]


@pytest.mark.parametrize("imu, key", [
    ({"preset": "mpu9250", "uav9": {"preset": "bmi088"}}, "sensors.imu.uav9"),  # not a body
    ({"preset": "mpu9250", "uav2": {"accel": {"noise_density": -1.0}}}, "sensors.imu.uav2.accel.noise_density"),
    ({"preset": "adxl"}, "sensors.imu.preset"),
])
def test_a_bad_imu_table_in_a_replay_is_one_line_naming_its_key(dataset, tmp_path, capsys, imu, key):
    spec = _variant(dataset, tmp_path / "d", lambda s: s["sensors"].update(imu=imu))
    assert main(["replay", str(spec), "--out", str(tmp_path / "o"), "--estimator", "nav.eskf"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"testbed: error: {spec}: {key}"), err
    assert not (tmp_path / "o").exists()
