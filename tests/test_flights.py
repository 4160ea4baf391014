"""The IMU filters on a simulated real flight: three flown quadrotors with rotor vibration on (the
bmi088 preset's default), exported (testbed export) and replayed with sparse ranging, as a real
recording has it (docs/estimators.md, "Flights: sparse ranging without GNSS"):

- anchors at 1 Hz per vehicle (one anchor at a time, in turn), each pair of vehicles at 0.5 Hz,
  heights at 30 Hz (each body's true up coordinate, linearly interpolated from the 50 Hz truth,
  plus N(0, 0.05^2) m, declared sigma 0.05 m), no GNSS;
- each filter starts without a GNSS fix and without an initial position: from its first anchor
  ranges and heights over a 2-s window (estimators.range_start); its heading is its own
  (`initial_pose.BODY.yaw_deg`, as a compass gives it): the truth's first yaw plus N(0, 5^2) deg
  (declared 5 deg), drawn once (the truth's first position plus N(0, 0.5^2) m per axis is drawn
  too, the `initial_pose` position the other option, and kept out of the start);
- it is consistent (position ANEES inside its 99 % interval for the correlated samples,
  testbed.scoring.metrics.anees_interval_at from its metrics.json keys), tracks (an estimate at every
  truth instant from 3 s on: three anchor ranges at 1 Hz take 2 s, and a position RMSE under 1 m,
  ten times the range noise) and never re-initialises (eq. D1 at 1e-6 on a consistent filter).

The suite flies HORIZON_S = 20 s; the same test over the issue's 60 s is
`FLIGHTS_HORIZON_S=60 python -m pytest tests/test_flights.py` (docs/estimators.md gives its figures).
Also the noise measured from the IMU samples (estimators.imu_adapt) on white noise of known sigma.
"""
from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from estimators.imu_adapt import DifferenceNoise
from testbed.cli import main
from testbed.config import scenario
from testbed.runner import run
from testbed.scoring.metrics import anees_interval_at

HORIZON_S = float(os.environ.get("FLIGHTS_HORIZON_S", "20"))
SCENARIO = f"""
name = "flights-sparse"
description = "three flown quadrotors, rotor vibration on, sparse UWB, exported and replayed"
seed = 7
duration = {HORIZON_S}
motion = "flown"

[world]
truth_rate = 50.0
anchors = [[-25.0, -15.0, 3.0], [35.0, -20.0, 9.0], [30.0, 35.0, 3.0], [-20.0, 30.0, 9.0]]

[trajectory]
kind = "waypoints"
points = [[0.0, 0.0, 5.0], [15.0, -8.0, 8.0], [0.0, 10.0, 6.0], [0.0, 0.0, 5.0]]
times = [0.0, 20.0, 40.0, 60.0]
offsets = [[0.0, 0.0, 0.0], [0.0, 6.0, 0.0], [6.0, 0.0, 0.0]]

[sensors.imu]
preset = "bmi088"
rate_hz = 100.0

[sensors.uwb]
preset = "dw1000"
rate_hz = 10.0
"""
BODIES = ("uav1", "uav2", "uav3")
HEIGHT_SIGMA = 0.05  # m
POSE_SIGMA, YAW_SIGMA_DEG = 0.5, 5.0


def _sparse(links: list[dict]) -> list[dict]:
    """The rows of a 10 Hz links table kept: vehicle v ranges anchor a at the epochs k (of 0.1 s)
    with k % 10 == 3 (v - 1) and (k // 10) % 4 == a - 1 (1 Hz, the anchors in turn, the vehicles
    staggered); the pair (v, w) at k % 20 == 5 (v + w - 3) (0.5 Hz each)."""
    keep = []
    for r in links:
        k, v = round(float(r["time"]) * 10), int(r["src"].split("/")[0][3:])
        if r["dst"].startswith("anchor"):
            if k % 10 == 3 * (v - 1) and (k // 10) % 4 == int(r["dst"][6:]) - 1:
                keep.append(r)
        elif k % 20 == 5 * (v + int(r["dst"].split("/")[0][3:]) - 3):
            keep.append(r)
    return keep


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> tuple[Path, str]:
    """(the sparse dataset's spec.toml, the --param giving every vehicle its own heading (no position))."""
    d = tmp_path_factory.mktemp("flights")
    (d / "s.toml").write_text(SCENARIO)
    run(scenario.load(str(d / "s.toml")), d / "run", plots=False)
    assert main(["export", str(d / "run"), "--out", str(d / "data")]) == 0
    data = d / "data"
    with open(data / "links.csv") as f:
        links = list(csv.DictReader(f))
    with open(data / "links.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(links[0]))
        w.writeheader()
        w.writerows(_sparse(links))
    with open(data / "truth.csv") as f:
        truth = list(csv.DictReader(f))
    rng = np.random.default_rng(11)
    heights, poses = [], []
    for body in BODIES:
        rows = [r for r in truth if r["body"] == body]
        t, z = (np.array([float(r[k]) for r in rows]) for k in ("time", "z"))
        for th in np.arange(0.0, HORIZON_S + 1e-9, 1.0 / 30.0):
            heights.append((float(th), body, float(np.interp(th, t, z)) + rng.normal(0, HEIGHT_SIGMA)))
        w, x, y, zq = (float(rows[0][k]) for k in ("qw", "qx", "qy", "qz"))
        yaw = math.degrees(math.atan2(2 * (w * zq + x * y), 1 - 2 * (y * y + zq * zq))) + rng.normal(0, YAW_SIGMA_DEG)
        p = [float(rows[0][k]) + rng.normal(0, POSE_SIGMA) for k in ("x", "y", "z")]
        assert len(p) == 3  # drawn (the initial_pose position of the other option), not given
        poses.append(f"{body} = {{ yaw_deg = {yaw!r}, yaw_sigma_deg = {YAW_SIGMA_DEG} }}")
    heights.sort(key=lambda h: h[0])
    (data / "height.csv").write_text("time,site,value,sigma\n" + "".join(f"{t!r},{b},{v!r},{HEIGHT_SIGMA}\n" for t, b, v in heights))
    return data / "spec.toml", "initial_pose={ " + ", ".join(poses) + " }"


@pytest.mark.parametrize("entry", ["nav.eskf", "coop.ins_distributed", "coop.ins"])
def test_an_imu_filter_started_from_ranges_without_gnss_or_a_position_tracks_a_vibrating_flight_consistently(flight, tmp_path, entry):
    spec, poses = flight
    assert main(["replay", str(spec), "--out", str(tmp_path / "r"), "--estimator", entry, "--param", poses,
                 "--no-plots"]) == 0
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())["estimators"][entry]
    lo, hi = anees_interval_at(m, "anees_position", 0.99) or (float("nan"),) * 2
    print(f"{entry}: position RMSE {m['rmse_position_m']:.3f} m, ANEES {m['anees_position']:.3f} [{lo:.3f}, {hi:.3f}] "
          f"(n_eff {m['n_eff_position']:.1f}) {m.get('anees_position_null_reason', '')}, health {m['health']}")
    assert m["coverage_position"] >= (HORIZON_S - 3.0) / HORIZON_S, m
    assert m["rmse_position_m"] < 1.0, (entry, m["rmse_position_m"])
    assert m["health"]["reinitialisations"] == 0, m["health"]
    if "anees_position_null_reason" in m:  # one run cannot decide (docs/consistency.md, "Decidable from one run")
        pytest.xfail(f"{entry}: {m['anees_position_null_reason']}")
    assert lo <= m["anees_position"] <= hi, (entry, m["anees_position"], lo, hi)


def test_the_imu_noise_measured_on_white_samples_is_their_sigma_and_never_below_the_declared():
    """Eq. A1 on one block of W = 100 samples of white noise (accel sigma 0.2 m/s^2, gyro 0.02 rad/s
    per sample at 100 Hz): the mean of 297 terms |dy|^2 / 2 (adjacent ones correlated 1/4), relative
    sd of sigma^2 sqrt(3 / 297) = 0.10, of sigma 0.05: within 4 of them (20 %). A vehicle whose
    samples are quieter than declared keeps the declared densities (eq. A2's floor)."""
    rng = np.random.default_rng(4)
    dt, sd = 0.01, np.array([0.2, 0.2, 0.2, 0.02, 0.02, 0.02])
    floor = np.array([[1e-3, 1e-4], [1.0, 1.0]])  # vehicle 1 declared far noisier than its samples
    adapt = DifferenceNoise(floor, window=100)
    for k in range(100):
        done = adapt.add(np.array([0, 1]), k * dt, rng.normal(0, 1, (2, 6)) * sd)
    assert done.tolist() == [0, 1]
    np.testing.assert_allclose(adapt.density[0] / np.sqrt(dt), [0.2, 0.02], rtol=0.2)
    np.testing.assert_array_equal(adapt.density[1], [1.0, 1.0])


def test_the_imu_noise_measured_on_means_of_white_samples_is_the_same_density():
    """Eqs. A1-A2 on W = 100 means of M = 10 white samples (the sigmas above, 100 Hz): the means
    have sigma / sqrt(10) over 0.1 s, the same density sigma sqrt(dt); 297 terms as above, so
    within 20 %. The block closes at the 1000th sample, not before."""
    rng = np.random.default_rng(6)
    dt, sd = 0.01, np.array([0.2, 0.2, 0.2, 0.02, 0.02, 0.02])
    adapt = DifferenceNoise(np.array([[1e-3, 1e-4]]), window=100, average=10)
    closed = [k for k in range(1000) if adapt.add(np.array([0]), k * dt, rng.normal(0, 1, (1, 6)) * sd).size]
    assert closed == [999]
    np.testing.assert_allclose(adapt.density[0] / np.sqrt(dt), [0.2, 0.02], rtol=0.2)


ANCHORS = {f"anchor{k + 1}": np.array(a) for k, a in enumerate([[-20.0, -15.0, 3.0], [25.0, -20.0, 9.0], [20.0, 25.0, 3.0],
                                                                 [-20.0, 20.0, 9.0]])}


def _drifted(entry: str, params: dict, preset: str) -> tuple[object, np.ndarray]:
    """(filter `entry` of one vehicle at rest at TRUE, started 4 m away with a 0.1 m sigma (a filter
    that has drifted and is sure of it), the true position). IMU at 100 Hz reading exactly rest
    (declared: the IMU preset `preset`), ranges of 0.1 m declared noise to four anchors once a second, exact."""
    from testbed.config import to_dict
    from testbed.plugins.api import Context
    from testbed.plugins.loading import load_class
    from testbed.sensors.config import ImuConfig, UwbConfig
    from testbed.sim.network import Network

    true = np.array([0.0, 0.0, 5.0])
    ctx = Context(vehicles=("uav1",), sites={"uav1/imu": ("uav1", np.zeros(3)), "uav1/uwb": ("uav1", np.zeros(3))},
                  anchors=ANCHORS, duration=20.0, seed=0, rng=np.random.default_rng(0), open_network=Network,
                  sensors={"imu": to_dict(ImuConfig(preset=preset, rate_hz=100.0)), "uwb": to_dict(UwbConfig(preset="ideal"))})
    start = {"uav1": {"position": list(true + [4.0, 0.0, 0.0]), "position_sigma": 0.1, "yaw_deg": 0.0, "yaw_sigma_deg": 1.0}}
    return load_class(entry)(ctx, {"initial_pose": start, **params}), true


def _fly(f, true: np.ndarray, seconds: int) -> np.ndarray:
    """Feed `seconds` s of rest and ranges; the last position estimate (3,)."""
    from testbed.plugins.api import Measurement

    last = None
    for k in range(100 * seconds + 1):
        t = k / 100.0
        out = f.process(Measurement(stream="imu", time=t, arrival=t, value=np.array([0.0, 0.0, 9.81, 0.0, 0.0, 0.0]),
                                    src="uav1/imu"))
        last = next((e.value for e in out if e.quantity == "position"), last) if out else last
        if k % 100 == 50:
            for name, a in ANCHORS.items():
                f.process(Measurement(stream="uwb", time=t, arrival=t, value=np.array([np.linalg.norm(true - a)]),
                                      src="uav1/uwb", dst=name, sigma=np.array([0.1])))
    return np.asarray(last if last is not None else f.ins.p[0])


def test_nav_eskfs_gate_cannot_lock_the_ranges_out_for_good():
    """A filter at rest 1 m off, sure of its position (0.05 m), its velocity (0.01 m/s) and its
    attitude (no tilt or yaw uncertainty), an ideal IMU: nothing but the ranges moves its covariance,
    and its gate rejects every range (before: for ever). The fifth epoch in a row opens the position's covariance until every range passes;
    the filter comes back within 0.1 m of the truth and takes the ranges from then on. (Far off,
    16 m, the released update jumped to the mirror solution below the anchors: the divergence
    guard's case, the next test; off here, as it would act first.)"""
    f, true = _drifted("nav.eskf", {"vel0_sigma": 0.01, "tilt0_sigma": 0.0, "divergence_prob": 0.0, "initial_pose": {"uav1": {
        "position": [1.0, 0.0, 5.0], "position_sigma": 0.05, "yaw_deg": 0.0, "yaw_sigma_deg": 0.0}}}, "ideal")
    p = _fly(f, true, 8)
    h = f.health()
    assert h["gate_inflations"] == 1 and h["rejected_measurements"] == 4 * len(ANCHORS), h
    assert np.linalg.norm(p - true) < 0.1, (p, h)


def test_the_distributed_filter_never_skips_every_anchor_range_for_good():
    """The distributed filter started 4 m off with a 5 m sigma: every anchor range fails the
    linearity check (skipped, counted). At the fifth epoch in a row they are taken; the filter
    comes back within 0.5 m of the truth. Before: skipped for good (issue's 'ANEES 0.001')."""
    f, true = _drifted("coop.ins_distributed", {"initial_pose": {"uav1": {
        "position": [4.0, 0.0, 5.0], "position_sigma": 5.0, "yaw_deg": 0.0, "yaw_sigma_deg": 1.0}}}, "bmi088")
    p = _fly(f, true, 12)
    h = f.health()
    assert h["forced_ranges"] >= 1 and h["nonlinear_ranges"] >= 4 * len(ANCHORS), h
    assert np.linalg.norm(p - true) < 0.5, (p, h)


@pytest.mark.parametrize("entry", ["nav.eskf", "coop.ins", "coop.ins_distributed"])
def test_a_filter_gone_far_off_is_reinitialised_from_its_ranges_and_says_so(entry, capsys):
    """A filter at rest started 16 m off and sure of it (0.1 m): the sum of its last W = 20 ranges'
    NIS (eq. D1) passes the chi-square bound at its fifth epoch of four ranges (4.5 s); it is
    dropped and started again from its window of ranges (2 s: two epochs, eight ranges) and is
    within 0.3 m of the truth (three times the range noise) 1.5 s later; health and stderr say when
    and why."""
    f, true = _drifted(entry, {"initial_pose": {"uav1": {"position": [16.0, 0.0, 5.0], "position_sigma": 0.1,
                                                          "yaw_deg": 0.0, "yaw_sigma_deg": 1.0}}}, "bmi088")
    p = _fly(f, true, 6)
    f.finish()
    h = f.health()
    assert h["reinitialisations"] == 1 and h["reinitialised_diverged_nis"] == 1 and h["reinitialisation_last_ms"] == 4500, h
    assert np.linalg.norm(p - true) < 0.3, (p, h)
    assert "re-initialised from ranges and heights: uav1 at 4.50 s" in capsys.readouterr().err


def test_the_range_noise_matched_on_the_innovations_is_the_data_s_and_never_below_the_declared():
    """Eq. R1 on W = 20 innovations of variance H P H^T + 9 R (R = 0.01 m^2, H P H^T = 0.002 m^2)
    with two 3-m outliers: lambda puts the median NIS at the chi-square median; the sample median of
    20 (two moved to the top) lies between the 6th and 15th order statistics with probability
    0.96, so lambda within [0.27, 2.9] x 9 allowing the outliers. Innovations quieter than
    declared (R / 4) leave lambda = 1 (the floor). A filter 2 m off (each innovation 2 m, 0.11 m
    sd) is capped at 25 and fails eq. D1; the outliers alone do not."""
    from estimators.range_innovations import RangeInnovations

    rng = np.random.default_rng(5)
    g = RangeInnovations(3)
    hph, R = np.full(20, 0.002), np.full(20, 0.01)
    noisy = rng.normal(0, np.sqrt(0.002 + 9 * 0.01), 20)
    noisy[[3, 11]] = 3.0
    g.add(np.zeros(20, int), noisy, hph, R)
    g.add(np.ones(20, int), rng.normal(0, np.sqrt(0.002 + 0.25 * 0.01), 20), hph, R)
    g.add(np.full(20, 2), 2.0 + rng.normal(0, np.sqrt(0.002 + 0.01), 20), hph, R)
    assert 0.27 * 9 <= g.scale[0] <= 2.9 * 9 and g.scale[1] == 1.0 and g.scale[2] == 25.0, g.scale
    assert not g.diverged(0) and not g.diverged(1) and g.diverged(2)


def test_a_start_from_sparse_ranges_and_heights_covers_the_body():
    """Three anchor ranges, one a second (the body moving at 0.5 m/s), and a height: the fix of
    eqs. S1-S2 at the last range holds the true position within its covariance (NEES under the
    chi-square 3-dof 0.999 quantile, 16.3); with two ranges there is no fix."""
    from estimators.range_start import BodyStarts

    rng = np.random.default_rng(3)
    starts = BodyStarts(2.0, 1.0)
    v, p0, lever = np.array([0.3, -0.4, 0.0]), np.array([1.0, 2.0, 5.0]), np.array([0.1, 0.0, 0.05])
    names = list(ANCHORS)
    for k in range(3):
        p = p0 + v * k
        starts.height("b", float(k), p[2] + rng.normal(0, 0.05), 0.05, np.zeros(3))
        starts.range("b", float(k), ANCHORS[names[k]], np.linalg.norm(p - ANCHORS[names[k]]) + rng.normal(0, 0.1), 0.1, lever)
        fix = starts.fix("b", float(k))
        assert (fix is None) == (k < 2), (k, fix)
    e = fix[0] - (p0 + 2 * v)
    assert e @ np.linalg.solve(fix[1], e) < 16.3, (fix, e)
