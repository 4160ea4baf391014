"""coop-denied (issue #18): the scenario's geometry, contacts from the MuJoCo state, the swarm
flown on the cascade (IMU filters updated by the sliding-window estimator) in the loop, the video's overlays and `reproduce denied`.

Short horizons only (the CI budget): the numbers of the full experiment are in docs/denied.md.
"""
from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from matplotlib.text import Text

from testbed import reference
from testbed.config import from_dict, to_dict
from testbed.plugins.loading import resolve
from testbed.plugins.online import in_the_loop
from testbed.config.estimators import EstimatorSpec
from testbed.outputs.render_overlay import FEEDBACK_FILE, Overlays
from testbed.reproduce import denied
from testbed.runner import run
from testbed.config.scenario import load
from testbed.sim.world import FLOOR, OBSTACLE, build, lever_arms


def test_reference_clears_the_block_and_a_path_into_a_building_is_refused():
    sc = load("coop-denied")
    assert reference.clearance(sc) is None
    into = load("coop-denied", overrides={"trajectory.points": [[-10.0, 20.0, 8.0], [190.0, 20.0, 8.0]]})
    key, reason = reference.clearance(into)
    assert key.startswith("world.obstacles[") and "inside its airframe radius" in reason


def test_gnss_is_lost_under_the_covered_passage():
    """A vehicle placed under the roof slab sees no satellite; in the open street it has a fix."""
    from testbed.rng import stream_rng
    from testbed.sensors.sky import Sky

    sc = load("coop-denied")
    physics = build(sc)
    sky = Sky(sc.sensors.gnss.sky, physics, stream_rng(sc.seed, "constellation"), physics.body_ids[:2])
    _, vis = sky.visible(physics, 0.0, np.array([[135.0, 0.0, 8.0], [-30.0, 0.0, 8.0]]))
    assert vis[0].sum() == 0 and vis[1].sum() >= 4


def test_the_scenario_flies_on_the_distributed_filter_and_on_truth_by_one_key():
    """coop-denied flies on coop.ins_distributed over the scenario's own [network] (the file says
    it twice: the estimator's params and [network], and they agree), as reproduce denied's
    coop_distributed variant; --set control.feedback=truth is the one key to fly on the state."""
    sc = load("coop-denied")
    (est,) = sc.estimators
    assert (est.entry, est.name, sc.control.feedback) == ("coop.ins_distributed", denied.COOP, f"estimate:{denied.COOP}")
    assert sc.control.release_sigmas == 1.0 and sc.control.max_tilt_deg > 0
    net = to_dict(sc.network)
    assert {k: net[k] for k in est.params["network"]} == est.params["network"]
    assert to_dict(from_dict(type(sc.network), dict(est.params["network"]), "params")) == net
    v = denied.variant(sc, "coop_distributed")
    assert (v.control, v.estimators[0].entry) == (sc.control, est.entry)
    assert load("coop-denied", overrides={"control.feedback": "truth"}).control.feedback == "truth"
    played = load("coop-denied", motion="prescribed")  # nothing flown: the estimator runs on the log
    assert in_the_loop(played, build(played), resolve(played.estimators)) is None


def test_contacts_are_classified_from_the_mujoco_state():
    physics = build(load("coop-denied"))
    q = physics.data.qpos.copy()
    assert physics.contacts_at(q).shape == (0, 2)
    a, b = physics.qpos_adr[0], physics.qpos_adr[1]
    q2 = q.copy()
    q2[b:b + 3] = q[a:a + 3] + [0.3, 0.0, 0.0]  # vehicle 2 inside vehicle 1
    assert {tuple(r) for r in physics.contacts_at(q2)} == {(0, 1)}
    q3 = q.copy()
    q3[a:a + 3] = [30.0, 15.2, 8.0]  # vehicle 1 into the north building's face
    assert {tuple(r) for r in physics.contacts_at(q3)} == {(0, OBSTACLE)}
    q4 = q.copy()
    q4[a + 2] = 0.05  # on the floor
    assert {tuple(r) for r in physics.contacts_at(q4)} == {(0, FLOOR)}


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """coop-denied for 1.2 s flown on the cascade coop.window_ins ("coop"), with coop.window
    scored beside it on the same log ("w": the same measurements its inner window gets in the loop)."""
    sc = load("coop-denied", duration=1.2)
    sc = replace(sc, estimators=(EstimatorSpec(entry="coop.window_ins", name="coop"), EstimatorSpec(entry="coop.window", name="w")),
                 control=replace(sc.control, feedback="estimate:coop"))
    out = tmp_path_factory.mktemp("denied") / "run"
    return out, run(sc, out, plots=False)


def test_window_estimator_estimates_the_swarm(flown):
    _, metrics = flown
    est = metrics["estimators"]["w"]
    assert est["health"]["epochs"] == 7 and est["health"]["skipped_epochs"] == 0  # 5 Hz over 1.2 s
    # every vehicle's estimate is scored; the GNSS-level accuracy bound of a 1.2 s start
    assert all(f"uav{i}" in est["targets"] for i in range(1, 19))
    assert est["rmse_position_mean_m"] < 3.0


def test_cascade_flies_on_imu_rate_estimates_updated_by_the_window(flown):
    out, metrics = flown
    ins, w = metrics["estimators"]["coop"], metrics["estimators"]["w"]
    h = ins["health"]
    # its window solved the same epochs as the window alone; every vehicle's filter started at the
    # first epoch and took the position of each later epoch closed by an IMU sample (not the last,
    # closed at the end of the run with no sample left to fly on)
    assert h["epochs"] == w["health"]["epochs"] == 7
    assert h["window_updates"] == 18 * 5 and h["rejected_measurements"] == 0
    with np.load(out / FEEDBACK_FILE) as z:
        t = z["uav7/time"]
    np.testing.assert_allclose(np.diff(t), 0.01, atol=1e-9)  # the IMU's 100 Hz, not the 5 Hz epochs
    assert t[0] < 0.2  # from the first epoch (t = 0, closed by the IMU sample at 0.01 s)
    assert all(f"uav{i}" in ins["targets"] for i in range(1, 19))
    assert ins["rmse_position_mean_m"] < 3.0
    # the IMU between epochs: a better velocity than the window's (measured 0.74 vs 1.97 m/s)
    assert ins["rmse_velocity_mean_m_s"] < w["rmse_velocity_mean_m_s"]


def test_video_overlays_read_the_run(flown):
    out, _ = flown
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(out / "scene.xml"))
    ov = Overlays(out, lambda s: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, s), 18)
    assert (out / FEEDBACK_FILE).is_file() and ov.estimator == "coop"
    src, dst, nlos = ov.links(1.0)
    with np.load(out / "log.npz") as z:
        at = np.isclose(z["uwb/time"], 1.0)
        assert len(src) == int(at.sum()) > 0 and nlos.sum() == int(z["uwb/nlos"][at].sum())
    err, cov = ov.estimate(1.0)  # the estimator flown on, from estimates.npz: its errors at the estimates' times
    assert err.shape == (18, 3) and cov.shape == (18, 3, 3) and np.isfinite(err).all()
    with np.load(out / FEEDBACK_FILE) as z:  # the positions the controller flew on
        k = np.searchsorted(z["uav7/time"], 1.0 + 1e-9) - 1
        t7, flown_on = z["uav7/time"][k], z["uav7/pos"][k]
    with np.load(out / "log.npz") as z:
        truth = np.array([np.interp(t7, z["time"], z["truth/pos"][:, 6, j]) for j in range(3)])
    np.testing.assert_allclose(err[6] + truth, flown_on, rtol=0, atol=1e-9)
    assert np.isnan(ov.estimate(-1.0)[0]).all()
    assert ov.fixed(1.0).shape == (18,)


@pytest.mark.slow  # six flights with their estimators and figures, ~15 s (no run's figures)
def test_reproduce_denied_end_to_end(tmp_path, monkeypatch):
    from testbed.reproduce import reproduce

    from testbed.outputs import plots

    drawn = {}  # the texts of every figure (testbed.outputs.plots.save), read after the save laid them out
    save = plots.save

    def record(fig, path):
        saved = save(fig, path)
        drawn[Path(path).name] = {t.get_text() for t in fig.findobj(Text) if t.get_text()}
        return saved

    monkeypatch.setattr(plots, "save", record)
    out = tmp_path / "rep"
    # 1.2 s: the distributed window cascade's filters start once its window holds 5 epochs (0.8 s);
    # the example plugin runs offline on every variant's flown log (it does not fly)
    plugin = EstimatorSpec(entry=f"{Path(__file__).resolve().parents[1]}/examples/uwb_ekf.py:UwbEkf")
    result = reproduce("denied", out, runs=1, duration=1.2, workers=1, estimators=(plugin,), run_plots=False)
    ids = {c["id"] for c in result["claims"]}
    assert ids == {f"{v}_{c}" for v in ("coop", "coop_distributed", "coop_onboard", "window", "window_distributed")
                   for c in ("flight_without_contact", "beats_gnss_only")}
    doc = json.loads((out / "claims.json").read_text())
    assert set(doc["flights"]) == set(denied.VARIANTS)
    for v, flights in doc["flights"].items():
        f = flights[0]
        assert f["min_separation_m"] > 0 and f["tracking_max_m"] >= f["tracking_rms_m"] >= 0
        assert len(f["no_fix_s"]) == 18
    assert doc["flights"]["truth"][0]["tracking_max_m"] < 0.05  # flown on the state itself
    text = (out / "report.md").read_text()
    assert "cooperative, centralized" in text and "--motion flown" in text
    # 1.2 s in the open street: no vehicle lost its fix, so the claims about the denied street say so
    undecided = [c for c in result["claims"] if c["id"].endswith("beats_gnss_only")]
    assert all(c["holds"] is None and c["not_decidable"].startswith("no vehicle lost GNSS") for c in undecided)
    assert all(isinstance(c["holds"], bool) for c in result["claims"] if c not in undecided)
    assert "5 not decidable" in text and "**not decidable: no vehicle lost GNSS" in text
    # written for its reader: the scenario and its page, no tracker number
    assert text.startswith("# GNSS-denied cooperative flight (coop-denied") and "issue" not in text.lower()
    assert "(no paper: docs/denied.md)" in text
    # the plugin: scored on every variant's flights, in the table, the RMSE figure and the paired tests
    head = (out / "table.csv").read_text().splitlines()[0].split(",")
    assert head[-1] == "estimation_rmse_UwbEkf_m" and all(doc["plugins"]["UwbEkf"][v] for v in denied.VARIANTS)
    assert {"flying", "UwbEkf"} <= drawn["estimation_rmse_m.png"] and "UwbEkf" not in drawn["tracking_rms_m.png"]
    _, *paired = (out / "table_plugins_paired.csv").read_text().strip().splitlines()
    assert {r.split(",")[0] for r in paired if r.split(",")[1:4] == ["UwbEkf", "coop", "1"]} == set(denied.VARIANTS) - {"gnss_ekf"}
    assert any(r.startswith("gnss_ekf,UwbEkf,ekf,1,") for r in paired)


def _results(no_fix_max_s: float, rmse: dict) -> denied.DeniedResults:
    """Six runs per variant (a one-sided signed-rank test can reach p = 1/64) with the given
    estimation RMSE (m) and time without a fix."""
    row = {k: 0.0 for k in denied.METRICS}
    flights = {v: [{**row, "estimation_rmse_m": rmse.get(v, 1.0) + 0.01 * i, "no_fix_max_s": no_fix_max_s}
                   for i in range(6)] for v in denied.VARIANTS}
    return denied.DeniedResults(scenario=load("coop-denied"), runs=6, flights=flights)


def test_denied_street_claims_are_decided_only_when_a_vehicle_lost_gnss():
    better = {v: 0.5 for v in denied.COOPERATIVE}
    for lost, decided in ((0.0, False), (3.2, True)):
        claims = {c.id: c for c in denied.decide(_results(lost, {"gnss_ekf": 2.0, **better}))}
        for v in denied.COOPERATIVE:
            c = claims[f"{v}_beats_gnss_only"]
            assert (c.not_decidable == "") is decided
            assert c.to_json()["holds"] is (True if decided else None)
            assert claims[f"{v}_flight_without_contact"].to_json()["holds"] is True  # always decidable


def test_a_floor_contact_breaks_the_no_contact_claim():
    """A vehicle fallen to the floor in one run is no clean flight: the claim counts every kind of
    contact (vehicle, obstacle, floor), and only in its own variant."""
    res = _results(3.2, {})
    res.flights["coop_onboard"][4]["contacts_floor"] = 2
    claims = {c.id: c for c in denied.decide(res)}
    assert claims["coop_onboard_flight_without_contact"].holds is False
    assert claims["coop_onboard_flight_without_contact"].numbers["contacts"]["coop_onboard"] == 2
    assert all(claims[f"{v}_flight_without_contact"].holds for v in denied.COOPERATIVE if v != "coop_onboard")


def test_cascade_skips_a_bad_window_covariance_and_restarts_a_broken_filter():
    from testbed.plugins.api import Estimate, Measurement
    from testbed.plugins.builtin_window_ins import WindowIns
    from testbed.plugins.context import make_context

    sc = load("coop-denied", duration=1.0)
    ins = WindowIns(make_context(sc, lever_arms(build(sc)), "ins", {}), {})
    level = np.array([0.0, 0.0, 9.81, 0.0, 0.0, 0.0])  # at rest: specific force up, no rate

    def imu(t):
        return ins.process(Measurement(stream="imu", time=t, arrival=t, value=level, src="uav1/imu"))

    assert imu(0.0) == []  # no epoch yet: nothing to fly on
    ins._epoch(Estimate(time=0.0, target="uav1", quantity="position", value=np.zeros(3), cov=-np.eye(3)))
    assert ins.health()["invalid_window_updates"] == 1 and ins.v["uav1"].x is None
    ins._epoch(Estimate(time=0.0, target="uav1", quantity="position", value=np.zeros(3), cov=np.eye(3)))
    assert len(imu(0.01)) == 3  # started: position, velocity, attitude at the IMU sample
    ins.v["uav1"].P[0, 0] = np.nan
    assert imu(0.02) == [] and ins.health()["filter_restarts"] == 1 and ins.v["uav1"].x is None


@pytest.mark.parametrize("attitude", ["truth", "estimate"])
def test_swarm_flies_on_the_distributed_estimate_over_the_network(tmp_path, attitude):
    """coop-denied for 4 s flown on coop.ins_distributed, the broadcasts over the scenario's
    network (the coop_distributed variant of reproduce denied), the attitude loop on the MuJoCo
    attitude or on the filter's (then nothing in the loop is truth): the first seconds hold the
    largest errors (every filter starts at its first SPP fix, 3 m vertical). Stated bound: no
    vehicle farther from its reference than the formation's 6 m spacing, hence no contact; the
    broadcasts went through the network (sent, some dropped at 1 % loss)."""
    sc = denied.variant(load("coop-denied", duration=4.0), "coop_distributed")
    sc = replace(sc, control=replace(sc.control, attitude=attitude))
    metrics = run(sc, tmp_path / "r", plots=False)
    f = denied.flight(tmp_path / "r", metrics, denied.COOP)
    assert f["tracking_max_m"] < 6.0
    assert f["contacts_vehicle"] == f["contacts_obstacle"] == f["contacts_floor"] == 0
    health = f["health"]
    assert health["sent"] > 0 and 0 < health["dropped"] < health["sent"]


def test_cascade_decorrelated_feeds_the_epochs_equivalent_measurement():
    """decorrelate = true: after its start, a filter is updated with the window epoch's equivalent
    measurement (estimators.window.equivalent_measurement of the epoch's tracklet), not its marginal."""
    from estimators import window as sw
    from testbed.plugins.api import Estimate, Measurement
    from testbed.plugins.builtin_window_ins import WindowIns
    from testbed.plugins.context import make_context

    sc = load("coop-denied", duration=1.0)
    ins = WindowIns(make_context(sc, lever_arms(build(sc)), "ins", {"decorrelate": True}), {"decorrelate": True})
    assert ins.window.solver.tracklets
    level = np.array([0.0, 0.0, 9.81, 0.0, 0.0, 0.0])
    ins.process(Measurement(stream="imu", time=0.0, arrival=0.0, value=level, src="uav2/imu"))
    ins._epoch(Estimate(time=0.0, target="uav2", quantity="position", value=np.zeros(3), cov=np.eye(3)))
    rng = np.random.default_rng(0)
    m, mp = rng.normal(size=(18, 3)), rng.normal(size=(18, 3))
    P, Pp = np.tile(0.5 * np.eye(3), (18, 1, 1)), np.tile(2.0 * np.eye(3), (18, 1, 1))
    ins.window.last = sw.WindowEstimate(t=0.2, pos=m, vel=m, pos_cov=P, vel_cov=P, iterations=1, converged=True,
                                        tracklet=(m, P, mp, Pp))
    seen = []
    ins._apply = lambda f, z, model, Rn: seen.append((z, Rn))
    ins._epoch(Estimate(time=0.2, target="uav2", quantity="position", value=m[1] - ins.lever["uav2"], cov=P[1]))
    z, R, _ = sw.equivalent_measurement(m, P, mp, Pp)
    assert len(seen) == 1
    np.testing.assert_allclose(seen[0][0], z[1])
    np.testing.assert_allclose(seen[0][1], R[1])
    np.testing.assert_allclose(R[1], np.eye(3) / (2.0 - 0.5), rtol=1e-12)  # 1 / (1/0.5 - 1/2)


def test_window_range_scale_multiplies_the_range_sigma_and_the_cascade_defaults_to_huber():
    from testbed.plugins.builtin_window import Window
    from testbed.plugins.builtin_window_ins import WindowIns
    from testbed.plugins.context import make_context

    sc = load("coop-denied", duration=1.0)
    ctx = make_context(sc, lever_arms(build(sc)), "w", {})
    row = [(0, 1, 7.0, 0.1)]  # uav1 to uav2, 7 m, declared sigma 0.1 m
    one, three = Window(ctx, {}), Window(ctx, {"range_scale": 3.0})
    assert three._range_sigmas(row) == pytest.approx(3.0 * one._range_sigmas(row)) and one._range_sigmas(row)[0] > 0.1
    assert one.solver.huber is None  # coop.window: least squares (seed 001)
    assert WindowIns(ctx, {}).window.solver.huber == 1.345
    assert WindowIns(ctx, {}).window.p["antenna_delays"] == "white"  # its filters take the tracklets (no consider term)
    assert WindowIns(ctx, {"huber": 0.0}).window.solver.huber is None


def test_window_range_weights_hold_the_antenna_delays_as_white_or_as_consider_parameters():
    """coop.window's range variance (testbed.plugins.builtin_window, "Range weights"): "white"
    adds the two antenna delays as white noise, 2 sigma_ad^2; "consider" (coop.window's default)
    leaves them out of the weights and gives them to the centralized window as consider
    parameters (estimators.window_delays: one per vehicle tag and anchor); the distributed window
    and the cascades keep them white ("consider" is refused there)."""
    from testbed.errors import ConfigError
    from testbed.plugins.api import Context
    from testbed.plugins.builtin_window import Window, WindowDistributed

    uwb = dict(mode="ds-twr", clock_ppm=0.0, reply_time=0.0, antenna_delay_sigma=0.04, link_bias_sigma=0.0)
    vehicles = ("uav1", "uav2", "uav3")
    ctx = Context(vehicles=vehicles, sites={f"{v}/uwb": (v, np.zeros(3)) for v in vehicles},
                  anchors={"anchor1": np.zeros(3)}, sensors={"uwb": uwb}, duration=1.0, seed=0, rng=np.random.default_rng(0))
    rows = [(0, 1, 5.0, 0.1), (0, 2, 6.0, 0.1), (1, 2, 7.0, 0.1), (0, 3, 9.0, 0.2)]  # device 3: the anchor
    noise = np.array([0.1, 0.1, 0.1, 0.2]) ** 2
    consider, white = Window(ctx, {}), Window(ctx, {"antenna_delays": "white"})
    assert consider._range_sigmas(rows) ** 2 == pytest.approx(noise, rel=1e-12)
    assert white._range_sigmas(rows) ** 2 == pytest.approx(noise + 2 * 0.04 ** 2, rel=1e-12)
    assert (consider.solver.delay_sigma, consider.solver.devices) == (0.04, 4) and white.solver.delay_sigma == 0.0
    assert WindowDistributed(ctx, {}).p["antenna_delays"] == "white"
    with pytest.raises(ConfigError, match="antenna_delays"):
        WindowDistributed(ctx, {"antenna_delays": "consider"})


def test_distributed_cascade_gives_its_window_the_imu_motion():
    """coop.window_distributed_ins (imu_motion and start_epochs 5, its defaults; the centralized
    cascade neither): the motion of each vehicle over the window's last interval is its IMU filter's, [displacement beyond constant velocity, velocity
    change]. A filter started level at rest at t = 0 and then held at 0.5 m/s^2 east from 0.01 s
    (zero-order hold) has moved by 0.5 a T^2 and sped up by a T (T = 0.19 s) at the next epoch,
    0.2 s; a vehicle whose filter has not started contributes nothing."""
    from types import SimpleNamespace

    from testbed.plugins.api import Estimate, Measurement
    from testbed.plugins.builtin_window_ins import WindowDistributedIns, WindowIns
    from testbed.plugins.context import make_context

    sc = load("coop-denied", duration=1.0, seed=1000)
    ctx = make_context(sc, lever_arms(build(sc)), "ins", {})
    assert WindowIns(ctx, {}).window.motion is None and WindowIns(ctx, {}).start_epochs == 1  # centralized: off
    default = WindowDistributedIns(ctx, {})
    assert default.window.motion == default._motion and default.start_epochs == 5
    ins = WindowDistributedIns(ctx, {"start_epochs": 1})  # started at the first epoch: here, the one below
    rest, a = ins.v["uav3"].bias0.copy(), 0.5  # uav3's own declared bias
    rest[2] += 9.81  # specific force at rest, level, plus the declared bias the filter removes
    push = rest + [a, 0.0, 0.0, 0.0, 0.0, 0.0]
    ins.process(Measurement(stream="imu", time=0.0, arrival=0.0, value=rest, src="uav3/imu"))
    ins._epoch(Estimate(time=0.0, target="uav3", quantity="position", value=np.zeros(3), cov=np.eye(3)))
    for k in range(1, 20):
        ins.process(Measurement(stream="imu", time=0.01 * k, arrival=0.01 * k, value=push, src="uav3/imu"))
    ins.window.solver.epochs = [SimpleNamespace(t=0.0)]  # the window's previous epoch
    motion = ins._motion(0.2)
    T = 0.19
    np.testing.assert_allclose(motion[2], [0.5 * a * T * T, 0, 0, a * T, 0, 0], atol=1e-9)
    assert not motion[np.arange(18) != 2].any()


def test_swarm_flies_on_the_distributed_window_cascade(tmp_path):
    """coop-denied (calibration seed 1000) for 4 s flown on coop.window_distributed_ins, its
    broadcasts over the scenario's network: the first seconds hold the largest estimate errors
    (every window starts at the first fixes, 3 m vertical). Stated bound: no vehicle farther from
    its reference than half the formation's 6 m spacing, so no two can touch; no contact; the
    broadcasts went through the network. Measured: tracking max 1.64 m (the cascade before the
    window broadcast, the held range directions, the IMU motion and the full-window start: 7.9 m,
    its estimate 3.1 m RMS off)."""
    sc = load("coop-denied", duration=4.0, seed=1000)
    sc = replace(sc, estimators=(EstimatorSpec(entry="coop.window_distributed_ins", name="coop",
                                               params={"network": to_dict(sc.network)}),),
                 control=replace(sc.control, feedback="estimate:coop"))
    metrics = run(sc, tmp_path / "r", plots=False)
    f = denied.flight(tmp_path / "r", metrics, "coop")
    assert f["tracking_max_m"] < 3.0
    assert f["contacts_vehicle"] == f["contacts_obstacle"] == f["contacts_floor"] == 0
    assert f["health"]["sent"] > 0 and f["health"]["bytes_sent"] > 0


@pytest.mark.skipif(not os.environ.get("WINDOW_LONG"), reason="10 coop-denied runs, ~60 s CPU: WINDOW_LONG=1")
def test_window_position_anees_inside_its_run_spread_interval(tmp_path):
    """coop.window (antenna delays as consider parameters, Huber 1.345) on coop-denied, prescribed,
    20 s, judged seeds 18-27 (docs/estimators.md, "The window's antenna delays"): the mean of the
    per-run position ANEES inside the 99 % run-spread interval (testbed.scoring.metrics
    .anees_run_interval: the delays are one draw per run, docs/consistency.md). Measured 2.73 in
    [2.37, 3.63]; with the delays white 3.61."""
    from testbed.log import load_log
    from testbed.plugins.builtin_window import Window
    from testbed.plugins.context import make_context
    from testbed.plugins.feed import measurements
    from testbed.scoring.metrics import anees_run_interval

    per_run = []
    for seed in range(18, 28):
        sc = load("coop-denied", overrides={"control.feedback": "truth", "control.release_sigmas": 0.0}, duration=20.0,
                  seed=seed, motion="prescribed")
        sc = replace(sc, estimators=())
        run(sc, tmp_path / str(seed), plots=False)
        log = load_log(tmp_path / str(seed) / "log.npz")
        params = {"huber": 1.345}
        ctx = make_context(sc, lever_arms(build(sc)), "w", params)
        w, out = Window(ctx, params), []
        for m in measurements(sc, log):
            out += w.process(m)
        nees = []
        for e in out + w.finish():
            if e.quantity == "position":
                k = int(np.argmin(np.abs(log["time"] - e.time)))
                err = e.value - log["truth/pos"][k, ctx.vehicles.index(e.target)]
                nees.append(err @ np.linalg.solve(e.cov, err))
        per_run.append(np.mean(nees))
    lo, hi = anees_run_interval(np.array(per_run), 3)
    assert lo <= np.mean(per_run) <= hi, (np.mean(per_run), lo, hi, per_run)
