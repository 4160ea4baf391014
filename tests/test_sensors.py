"""Sensor streams computed from the physics (issue 3): truth recomputation, phase, IMU, UWB,
camera, seeding. Scenarios are built in the tests from dicts; durations are short.

Every statistical tolerance is derived from the sample size (k standard errors, k stated)."""
from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from testbed.config import from_dict, to_dict
from testbed.errors import ConfigError
from testbed.config.scenario import Scenario
from testbed.sensors.config import InertialErrors
from testbed.sensors.noise import TriadErrors, allan_deviation
from testbed.sim.simulate import simulate

K_SIGMA = 5.0  # standard errors allowed in statistical checks


def scenario(sensors: dict, trajectory: dict | None = None, world: dict | None = None, duration: float = 0.5, motion: str = "prescribed", seed: int = 3) -> Scenario:
    data = {
        "name": "sensor-test", "description": "test", "seed": seed, "duration": duration, "motion": motion,
        "world": world or {}, "trajectory": trajectory or {"kind": "leader-follower", "follower_offset": [-8.0, 0.0, 0.0]},
        "sensors": sensors,
    }
    return from_dict(Scenario, data, "test")


def replay(physics, log):
    """A fresh model from the exact scene XML, and a function setting logged state k + mj_forward."""
    model = mujoco.MjModel.from_xml_string(physics.to_xml())
    data = mujoco.MjData(model)

    def at(k: int) -> mujoco.MjData:
        data.qpos[:] = log["qpos"][k]
        data.qvel[:] = log["qvel"][k]
        mujoco.mj_forward(model, data)
        return data

    return model, at


def site(model, name):
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)


IDEAL_ALL = {
    "uwb": {"preset": "ideal"},
    "phase": {"preset": "ideal", "masters": [1], "follower": 2},
    "gnss": {"receiver": {"preset": "ideal"}, "rtk": {"preset": "ideal"}},
    "camera": {"preset": "ideal"},
}
WORLD = {"anchors": [[0.0, 0.0, 1.0], [20.0, 5.0, 10.0], [-30.0, -5.0, 5.0]]}


# ------------------------------------------------------------------ noise-free = recomputed truth
@pytest.mark.parametrize("motion", ["prescribed", "flown"])
def test_ideal_streams_equal_recomputed_physics(motion):
    sc = scenario(IDEAL_ALL, world=WORLD, duration=0.6, motion=motion)
    log, physics = simulate(sc)
    model, at = replay(physics, log)
    rel = 1e-9
    # UWB: distance between the two sites
    for k, s, d, v in zip(log["uwb/state_index"], log["uwb/src"], log["uwb/dst"], log["uwb/value"][:, 0]):
        data = at(k)
        r = np.linalg.norm(data.site_xpos[site(model, d)] - data.site_xpos[site(model, s)])
        assert v == pytest.approx(r, rel=rel)
    assert len(log["uwb/value"]) == 7 * (3 * 2 + 1)
    assert not log["uwb/nlos"].any()
    # GNSS: the uwb-site antenna position
    for k, s, v in zip(log["gnss/state_index"], log["gnss/src"], log["gnss/value"]):
        np.testing.assert_allclose(v, at(k).site_xpos[site(model, s)], rtol=rel, atol=1e-12)
    # Phase: wrapped phase, resolved range, eq. 7 rate from the logged states of the window
    T = 1.0 / sc.sensors.phase.phase_rate_hz
    times = log["time"]
    for row in range(len(log["phase/time"])):
        k, s, d, lam = log["phase/state_index"][row], log["phase/src"][row], log["phase/dst"][row], log["phase/wavelength"][row]
        theta, rng_, rate = log["phase/value"][row]
        P = log["phase/rate_periods"][row]
        rs = []
        for j in range(P + 1):
            kj = int(np.argmin(np.abs(times - (times[k] - j * T))))
            data = at(kj)
            rs.append(np.linalg.norm(data.site_xpos[site(model, d)] - data.site_xpos[site(model, s)]))
        r = rs[0]
        assert rng_ == pytest.approx(r, rel=rel)
        dphi = (theta - 2 * math.pi * r / lam + math.pi) % (2 * math.pi) - math.pi
        assert abs(dphi) < 1e-9 and 0 <= theta < 2 * math.pi
        if P >= 1:
            assert rate == pytest.approx((rs[0] - rs[-1]) / (P * T), rel=1e-7, abs=1e-9)
        else:
            assert np.isnan(rate)
    # Camera: focal-plane coordinates and unit LOS from cam pose and LED site
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "uav1/cam")
    assert len(log["camera/value"]) > 0
    for k, d, v in zip(log["camera/state_index"], log["camera/dst"], log["camera/value"]):
        data = at(k)
        pc = data.cam_xmat[cam].reshape(3, 3).T @ (data.site_xpos[site(model, d)] - data.cam_xpos[cam])
        expected = [-pc[0] / pc[2], -pc[1] / pc[2], *(pc / np.linalg.norm(pc))]
        np.testing.assert_allclose(v, expected, rtol=rel, atol=1e-12)
    for key in ("uwb", "gnss", "phase", "camera"):
        np.testing.assert_allclose(log[f"{key}/value"], log[f"{key}/clean"], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(log[f"{key}/time"], times[log[f"{key}/state_index"]])


# ------------------------------------------------------------------------------------- phase
PHASE_TRAJ = {"kind": "phase-formation", "formation": "cross"}


def test_phase_ideal_ambiguity_and_wrapping():
    sc = scenario({"phase": {"preset": "ideal"}}, trajectory=PHASE_TRAJ, duration=1.0)
    log, _ = simulate(sc)
    theta, r_hat, _ = log["phase/value"].T
    r = log["phase/clean"][:, 1]
    lam = log["phase/wavelength"]
    np.testing.assert_allclose(np.mod(theta - 2 * np.pi * r / lam + np.pi, 2 * np.pi) - np.pi, 0, atol=1e-9)
    np.testing.assert_allclose(r_hat, r, rtol=1e-12)
    np.testing.assert_array_equal(log["phase/ambiguity"], np.floor(r / lam))
    assert len(np.unique(log["phase/src"])) == 15 and len(np.unique(log["phase/dst"])) == 3
    np.testing.assert_array_equal(log["phase/master_pos"], log["phase/master_pos"])  # finite
    assert not log["phase/slip"].any()


def test_phase_noisy_ranges_rates_and_cycle_slips():
    sc = scenario({"phase": {"slip_prob": 0.002}}, trajectory=PHASE_TRAJ, duration=4.0)
    cfg = sc.sensors.phase
    log, _ = simulate(sc)
    val, cl = log["phase/value"], log["phase/clean"]
    lam = log["phase/wavelength"]
    # every reported range carries the right integer: error far below half a wavelength
    err = val[:, 1] - cl[:, 1]
    assert np.all(np.abs(err) < lam / 2)
    # range noise 1 sigma = phase_noise; std of n samples has relative std 1/sqrt(2(n-1))
    n = err.size
    assert abs(err.std() / cfg.phase_noise - 1) < K_SIGMA / math.sqrt(2 * (n - 1))
    # range rate (eq. 7) vs the derivative of the true range, within noise and window lag
    full = log["phase/rate_periods"] == cfg.rate_periods
    T = 1 / cfg.phase_rate_hz
    W = cfg.rate_periods * T
    sigma_rate = math.sqrt(2) * cfg.phase_noise / W
    resid = (val[full, 2] - cl[full, 2]) / sigma_rate
    # outputs 0.1 s apart share their 0.7 s windows: count independent samples per window length
    n_eff = full.sum() * (1 / cfg.rate_hz) / W
    assert abs(resid.mean()) < K_SIGMA / math.sqrt(n_eff)
    assert abs(resid.std() - 1) < K_SIGMA / math.sqrt(2 * n_eff)
    rt = log["phase/rate_true"]
    # lag of the window mean vs the instantaneous derivative: |r_ddot| W / 2
    t = log["phase/time"]
    links = log["phase/src"].astype(object) + log["phase/dst"].astype(object)
    rdd = 0.0
    for l in np.unique(links):
        sel = links == l
        rdd = max(rdd, np.abs(np.diff(rt[sel]) / np.diff(t[sel])).max())
    lag = rdd * W / 2 * 1.5
    assert np.all(np.abs(cl[full, 2] - rt[full]) <= lag + 1e-9)
    assert np.all(np.abs(val[full, 2] - rt[full]) <= K_SIGMA * sigma_rate + lag)
    # injected slips: all flagged, never a false alarm at this noise (5 sigma < lambda/2)
    inj, slip = log["phase/slip_injected"], log["phase/slip"]
    assert inj.sum() >= 5
    np.testing.assert_array_equal(slip, inj)


def test_phase_master_navigation_stream_has_its_error_model():
    for noise in (0.0, 0.5):
        sc = scenario({"phase": {"preset": "ideal", "master_pos_noise": noise}}, trajectory=PHASE_TRAJ, duration=1.0)
        log, physics = simulate(sc)
        model, at = replay(physics, log)
        truth = np.array([at(k).site_xpos[site(model, s)] for k, s in zip(log["phase/state_index"], log["phase/src"])])
        err = log["phase/master_pos"] - truth
        if noise == 0.0:
            np.testing.assert_allclose(err, 0.0, atol=1e-12)  # the paper's "known masters"
        else:
            n = err.size
            assert abs(err.std() / noise - 1) < K_SIGMA / math.sqrt(2 * (n - 1))
        np.testing.assert_allclose(log["phase/value"][:, 1], log["phase/clean"][:, 1], rtol=1e-12)


# --------------------------------------------------------------------------------------- IMU
def test_ideal_imu_strapdown_reproduces_motion():
    traj = {"kind": "leader-follower", "weave_amp": 3.0, "weave_period": 8.0, "heave_amp": 1.0, "yaw_amp_deg": 20.0, "yaw_period": 6.0}
    sc = scenario({"imu": {"preset": "ideal", "vehicles": [2]}}, trajectory=traj, duration=10.0)
    log, physics = simulate(sc)
    t = log["imu/time"]
    f, w = log["imu/value"][:, :3], log["imu/value"][:, 3:]
    g = physics.model.opt.gravity.copy()
    k0 = log["imu/state_index"][0]
    p = log["truth/pos"][k0, 1].copy()
    v = log["truth/vel"][k0, 1].copy()
    q = log["truth/quat"][k0, 1]
    R = Rotation.from_quat(q[[1, 2, 3, 0]])
    pos, att = [p.copy()], [R]
    for k in range(len(t) - 1):
        dt = t[k + 1] - t[k]
        # attitude: rotation vector of the trapezoidal rate over the step
        R1 = R * Rotation.from_rotvec(0.5 * (w[k] + w[k + 1]) * dt)
        a0 = R.apply(f[k]) + g
        a1 = R1.apply(f[k + 1]) + g
        p = p + v * dt + dt**2 / 6 * (2 * a0 + a1)
        v = v + 0.5 * dt * (a0 + a1)
        R = R1
        pos.append(p.copy()), att.append(R)
    idx = log["imu/state_index"]
    true_p = log["truth/pos"][idx, 1]
    true_q = log["truth/quat"][idx, 1]
    perr = np.linalg.norm(np.array(pos) - true_p, axis=1).max()
    aerr = max(np.degrees((Rotation.from_quat(qq[[1, 2, 3, 0]]).inv() * Ri).magnitude()) for qq, Ri in zip(true_q, att))
    assert t[-1] == pytest.approx(10.0)
    print(f"strapdown: max position error {perr:.2e} m, attitude {aerr:.2e} deg")
    assert perr < 0.01, perr
    assert aerr < 0.01, aerr


def _triad(**kw) -> InertialErrors:
    base = dict(noise_density=0.0, bias=0.0, bias_sigma=0.0, bias_walk=0.0, gm_sigma=0.0, gm_tau=0.0, scale_sigma=0.0, misalign_sigma=0.0)
    return InertialErrors(**{**base, **kw})


def _stream(errors: InertialErrors, n: int, dt: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tri = TriadErrors(errors, 1, dt, rng)
    return tri.apply(np.zeros((n, 1, 3)), rng.standard_normal((n, 3, 1, 3)))[:, 0, :]


def test_white_noise_discretisation_and_allan_slope():
    N, dt, n = 2e-3, 0.005, 2**17
    y = _stream(_triad(noise_density=N), n, dt, 1)
    # sample std = N / sqrt(dt); relative standard error 1/sqrt(2(n-1)) per axis, 3n samples
    s = y.std()
    assert abs(s / (N / math.sqrt(dt)) - 1) < K_SIGMA / math.sqrt(2 * (3 * n - 1))
    m = np.array([1, 64])
    ad = np.array([allan_deviation(y[:, a], dt, m) for a in range(3)])
    slope = np.log(ad[:, 1] / ad[:, 0]) / np.log(m[1] / m[0])
    # var(ln avar) ~ 1.5/(K-1) for white noise (lag-1 correlation of block differences = -1/2)
    K = n // m
    se = math.sqrt(sum(0.25 * 1.5 / (k - 1) for k in K)) / math.log(m[1] / m[0]) / math.sqrt(3)
    assert abs(slope.mean() + 0.5) < K_SIGMA * se, (slope, se)


def test_bias_random_walk_allan_slope():
    Kd, dt, n = 1e-3, 0.005, 2**17
    y = _stream(_triad(bias_walk=Kd), n, dt, 2)
    m = np.array([32, 512])
    ad = np.array([allan_deviation(y[:, a], dt, m) for a in range(3)])
    slope = np.log(ad[:, 1] / ad[:, 0]) / np.log(m[1] / m[0])
    # exact expected slope of the discrete process: Var(block-mean difference) = q^2 sum c_j^2,
    # c_j the triangular weights of the increments
    def expected_avar(mm):
        i = np.arange(1, mm + 1)
        c = np.concatenate([i / mm, (mm - i) / mm])
        return 0.5 * (Kd**2 * dt) * np.sum(c**2)

    exp_slope = math.log(math.sqrt(expected_avar(m[1]) / expected_avar(m[0]))) / math.log(m[1] / m[0])
    assert abs(exp_slope - 0.5) < 0.01
    # var(ln avar) ~ 1.125/(K-1) for a random walk (lag-1 correlation of differences = 1/4)
    K = n // m
    se = math.sqrt(sum(0.25 * 1.125 / (k - 1) for k in K)) / math.log(m[1] / m[0]) / math.sqrt(3)
    assert abs(slope.mean() - exp_slope) < K_SIGMA * se, (slope, exp_slope, se)


def test_gauss_markov_stationary_and_scale_misalignment():
    sig, tau, dt, n = 0.3, 0.5, 0.01, 2**16
    y = _stream(_triad(gm_sigma=sig, gm_tau=tau), n, dt, 3)
    # correlated samples: effective count n dt / (2 tau) for the variance
    n_eff = n * dt / (2 * tau)
    assert abs(y.std() / sig - 1) < K_SIGMA / math.sqrt(2 * 3 * n_eff)
    lag = int(tau / dt)
    rho = np.mean([np.corrcoef(y[:-lag, a], y[lag:, a])[0, 1] for a in range(3)])
    assert abs(rho - math.exp(-1)) < K_SIGMA / math.sqrt(3 * n_eff)
    # scale factor and misalignment act as (I + K) on the clean signal
    rng = np.random.default_rng(4)
    tri = TriadErrors(_triad(scale_sigma=0.01, misalign_sigma=0.002), 2, dt, rng)
    x = np.random.default_rng(5).normal(size=(10, 2, 3))
    out = tri.apply(x, np.zeros((10, 3, 2, 3)))
    np.testing.assert_allclose(out, x + np.einsum("vij,nvj->nvi", tri.K, x))
    assert np.all(np.abs(np.diagonal(tri.K, axis1=1, axis2=2)) > 0)


def test_imu_sensor_noise_matches_density_in_simulation():
    # the leader flies straight and level: gyro clean = 0, accel clean = constant (0, 0, g)
    sc = scenario({"imu": {"preset": "mpu9250", "vehicles": [1]}}, duration=2.0)
    log, physics = simulate(sc)
    cfg = sc.sensors.imu
    dt = 1 / cfg.rate_hz
    clean = log["imu/clean"]
    np.testing.assert_allclose(clean[:, 3:], 0.0, atol=1e-9)
    np.testing.assert_allclose(clean[:, :3], np.broadcast_to([0, 0, -physics.model.opt.gravity[2]], clean[:, :3].shape), atol=1e-6)
    e = log["imu/value"] - clean - log["imu/bias"]
    gyro_e = e[:, 3:]  # (I + K) 0 = 0: pure white noise
    n = gyro_e.size
    assert abs(gyro_e.std() / (cfg.gyro.noise_density / math.sqrt(dt)) - 1) < K_SIGMA / math.sqrt(2 * (n - 1))
    acc_e = e[:, :3] - e[:, :3].mean(axis=0)  # K a is constant: remove it with the mean (n - 1 dof per axis)
    m = acc_e.shape[0]
    s = np.sqrt((acc_e**2).sum() / (3 * (m - 1)))
    assert abs(s / (cfg.accel.noise_density / math.sqrt(dt)) - 1) < K_SIGMA / math.sqrt(2 * 3 * (m - 1))
    assert np.abs(e[:, 2].mean()) > 0  # the scale factor of z acts on g
    assert set(np.unique(log["imu/src"])) == {"uav1/imu"}


# --------------------------------------------------------------------------------------- UWB
def _uwb_world():
    # uav1 and uav2 separated by a 2 m thick wall (x from 4 to 6); uav3 beside with a clear path
    return {"anchors": [[5.0, 30.0, 10.0]], "obstacles": [{"type": "box", "pos": [5.0, 0.0, 10.0], "size": [1.0, 3.0, 10.0]}]}


def _uwb_traj():
    return {"kind": "straight-line", "start": [0.0, 0.0, 10.0], "velocity": [0.0, 0.0, 0.0],
            "offsets": [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 20.0, 0.0]]}


def test_uwb_wall_gives_nlos_and_positive_bias_clear_path_los():
    sens = {"uwb": {"preset": "ideal", "nlos": "bias", "nlos_bias_mean": 0.3, "nlos_bias_per_m": 1.0}}
    log, _ = simulate(scenario(sens, trajectory=_uwb_traj(), world=_uwb_world(), duration=0.3))
    src, dst = log["uwb/src"], log["uwb/dst"]
    wall = (src == "uav1/uwb") & (dst == "uav2/uwb")
    assert wall.sum() == 4 and log["uwb/nlos"][wall].all()
    bias = (log["uwb/value"] - log["uwb/clean"])[wall, 0]
    assert np.all(bias > 0)
    np.testing.assert_allclose(log["uwb/span"][wall], 2.0, atol=1e-6)  # wall thickness along the ray
    assert np.all(bias >= 2.0)
    clear = ~wall
    assert not log["uwb/nlos"][clear].any()
    np.testing.assert_array_equal(log["uwb/value"][clear], log["uwb/clean"][clear])
    # drop mode: the blocked link is not reported
    sens["uwb"]["nlos"] = "drop"
    log2, _ = simulate(scenario(sens, trajectory=_uwb_traj(), world=_uwb_world(), duration=0.3))
    assert not ((log2["uwb/src"] == "uav1/uwb") & (log2["uwb/dst"] == "uav2/uwb")).any()
    assert len(log2["uwb/value"]) == len(log["uwb/value"]) - 4


def test_uwb_blocked_by_another_airframe():
    """A vehicle between two tags blocks their link (its collision box, group 3); the links to
    the vehicle in the middle stay clear (a hit on the destination's own airframe does not block)."""
    traj = {"kind": "straight-line", "start": [0.0, 0.0, 10.0], "velocity": [0.0, 0.0, 0.0],
            "offsets": [[0.0, 0.0, 0.0], [5.0, 0.0, 0.1], [10.0, 0.0, 0.0]]}
    log, _ = simulate(scenario({"uwb": {"preset": "ideal", "nlos": "ignore"}}, trajectory=traj, duration=0.2))
    through = (log["uwb/src"] == "uav1/uwb") & (log["uwb/dst"] == "uav3/uwb")
    assert through.sum() == 3 and log["uwb/nlos"][through].all()
    assert not log["uwb/nlos"][~through].any()


def test_uwb_clock_scale_factor_scales_range():
    sens = {"uwb": {"preset": "ideal", "clock_ppm": 500.0}}
    log, _ = simulate(scenario(sens, trajectory=_uwb_traj(), world={"anchors": [[5.0, 30.0, 10.0]]}, duration=0.2))
    ppm = dict(zip(log["uwb/devices"], log["uwb/clock_ppm"]))
    expected = np.array([1 + 1e-6 * (ppm[s] + ppm[d]) / 2 for s, d in zip(log["uwb/src"], log["uwb/dst"])])
    np.testing.assert_allclose(log["uwb/value"][:, 0] / log["uwb/clean"][:, 0], expected, rtol=1e-13)
    assert np.abs(expected - 1).max() > 1e-5


def test_uwb_range_limit_loss_and_noise():
    traj = {"kind": "straight-line", "start": [0.0, 0.0, 10.0], "velocity": [0.0, 0.0, 0.0],
            "offsets": [[0.0, 0.0, 0.0], [50.0, 0.0, 0.0], [150.0, 0.0, 0.0]]}
    sens = {"uwb": {"preset": "ideal", "noise": 0.1, "loss_prob": 0.3, "rate_hz": 100.0}}
    log, _ = simulate(scenario(sens, trajectory=traj, duration=5.0))
    pairs = set(zip(log["uwb/src"], log["uwb/dst"]))
    assert pairs == {("uav1/uwb", "uav2/uwb"), ("uav2/uwb", "uav3/uwb")}  # 150 m pair out of range
    n_try = 2 * 501
    kept = len(log["uwb/value"]) / n_try
    assert abs(kept - 0.7) < K_SIGMA * math.sqrt(0.21 / n_try)
    e = (log["uwb/value"] - log["uwb/clean"])[:, 0]
    assert abs(e.std() / 0.1 - 1) < K_SIGMA / math.sqrt(2 * (e.size - 1))


# ------------------------------------------------------------------------------------ camera
def _camera_traj(lateral: float = 0.0):
    return {"kind": "leader-follower", "leader_start": [0.0, 0.0, 30.0], "leader_velocity": [0.5, 0.0, 0.0],
            "follower_offset": [-6.0, lateral, 0.0], "weave_amp": 0.0, "heave_amp": 0.0, "yaw_amp_deg": 0.0}


def _camera_runs(traj, world=None):
    out = {}
    for mode in ("geometric", "pixels"):
        sc = scenario({"camera": {"preset": "ideal", "mode": mode}}, trajectory=traj, world=world, duration=0.2)
        out[mode] = simulate(sc)[0]
    return out


def test_camera_pixels_match_geometry_when_unoccluded():
    runs = _camera_runs(_camera_traj())
    geo, pix = runs["geometric"], runs["pixels"]
    assert len(pix["camera/led"]) == 3 * 4
    np.testing.assert_array_equal(geo["camera/dst"], pix["camera/dst"])
    err = np.linalg.norm(pix["camera/pixel"] - pix["camera/pixel_clean"], axis=1)
    assert err.max() < 0.5, err
    np.testing.assert_allclose(pix["camera/pixel_clean"], geo["camera/pixel"], atol=1e-9)
    # the LOS from centroids is consistent with the pixel error: < 0.5 px / fx rad
    ang = np.arccos(np.clip(np.einsum("ij,ij->i", pix["camera/value"][:, 2:], pix["camera/clean"][:, 2:]), -1, 1))
    assert ang.max() < 0.5 / (240 / math.tan(math.radians(30)))


def test_camera_occluded_led_not_reported():
    wall = {"obstacles": [{"type": "box", "pos": [-5.0, 0.0, 29.5], "size": [0.2, 2.0, 0.67]}]}
    runs = _camera_runs(_camera_traj(), wall)
    for log in runs.values():
        assert set(log["camera/dst"]) == {"uav2/led3"}, set(log["camera/dst"])
    err = np.linalg.norm(runs["pixels"]["camera/pixel"] - runs["pixels"]["camera/pixel_clean"], axis=1)
    assert err.max() < 0.5


def _edge_lateral() -> float:
    """Follower lateral offset (m) that puts the right image edge midway between LED1 and LED2.

    From the MJCF: camera and LED positions in the body frame; the follower sits 6 m behind.
    LED2 (and LED3, deeper) then project inside the image, LED1 (and LED4, shallower) outside.
    """
    from testbed.sim.world import build

    physics = build(scenario({}, trajectory=_camera_traj()))
    m = physics.model
    cam_x = m.camera("uav1/cam").pos[0]
    led_x = m.site("uav2/led1").pos[0]
    depth = cam_x - (-6.0 + led_x)
    tan_half_x = (m.cam_resolution[0][0] / 2) / (m.cam_resolution[0][1] / 2 / math.tan(math.radians(m.cam_fovy[0]) / 2))
    return tan_half_x * depth


def test_camera_out_of_view_led_not_reported():
    runs = _camera_runs(_camera_traj(lateral=_edge_lateral()))
    geo, pix = runs["geometric"], runs["pixels"]
    seen = set(pix["camera/dst"])
    assert seen == set(geo["camera/dst"]) == {"uav2/led2", "uav2/led3"}, seen
    err = np.linalg.norm(pix["camera/pixel"] - pix["camera/pixel_clean"], axis=1)
    assert err.max() < 0.5


def test_camera_noise_models():
    sc = scenario({"camera": {"preset": "gaussian", "rate_hz": 200.0}}, duration=2.0)
    log, _ = simulate(sc)
    sigma = sc.sensors.camera.sigma
    b, bc = log["camera/value"][:, 2:], log["camera/clean"][:, 2:]
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, rtol=1e-12)
    # eq. 13: two tangent components of variance sigma^2 each -> E|b - b_clean|^2 = 2 sigma^2
    n = len(b)
    ms = np.mean(np.sum((b - bc) ** 2, axis=1)) / (2 * sigma**2)
    assert abs(ms - 1) < K_SIGMA * math.sqrt(1 / n)
    # eq. 8: alpha/f has variance sigma^2 (1 + d a^2)^2 / (1 + d (a^2 + b^2)), standardised
    d = sc.sensors.camera.d
    a, bb = log["camera/clean"][:, 0], log["camera/clean"][:, 1]
    var = sigma**2 * (1 + d * a**2) ** 2 / (1 + d * (a**2 + bb**2))
    z = (log["camera/value"][:, 0] - a) / np.sqrt(var)
    assert abs(z.std() - 1) < K_SIGMA / math.sqrt(2 * (n - 1))
    assert abs(z.mean()) < K_SIGMA / math.sqrt(n)
    assert not log["camera/glint"].any()


# ------------------------------------------------------------------------------ seeds, config
def test_streams_are_seeded_by_name():
    base = {"gnss": {}, "imu": {"preset": "bmi088"}}
    more = {**base, "uwb": {"preset": "dw1000"}, "phase": {"masters": [1], "follower": 2}, "camera": {}}
    a, _ = simulate(scenario(base, world=WORLD, duration=0.5))
    b, _ = simulate(scenario(more, world=WORLD, duration=0.5))
    for key in ("gnss/value", "imu/value", "gnss/time", "imu/time"):
        np.testing.assert_array_equal(a[key], b[key])
    c, _ = simulate(scenario(base, world=WORLD, duration=0.5, seed=4))
    assert not np.array_equal(a["gnss/value"], c["gnss/value"])


def test_rates_must_divide_control_rate():
    with pytest.raises(ConfigError, match=r"sensors\.imu\.rate_hz: 7 Hz does not divide the control rate 200 Hz"):
        scenario({"imu": {"rate_hz": 7.0}})
    with pytest.raises(ConfigError, match="phase_rate_hz"):
        scenario({"phase": {"rate_hz": 10.0, "phase_rate_hz": 25.0, "masters": [1], "follower": 2}})
    with pytest.raises(ConfigError, match="sensors.uwb.noize: unknown key"):
        scenario({"uwb": {"noize": 0.1}})
    with pytest.raises(ConfigError, match="sensors.camera"):
        scenario({"camera": {"follower": 3}})


def test_presets_fill_and_resolve():
    sc = scenario({"imu": {"preset": "paper004", "gyro": {"noise_density": 1e-4}}, "gnss": {"rtk_vehicles": [2]}})
    imu = sc.sensors.imu
    assert imu.gyro.noise_density == 1e-4  # explicit key wins
    assert imu.gyro.bias_sigma == pytest.approx(0.1 * math.pi / 180 / 3600)  # 0.1 deg/h, drawn per vehicle
    assert imu.accel.bias_sigma == pytest.approx(250e-6 * 9.80665)
    assert imu.accel.noise_density == pytest.approx(50e-6 * 9.80665)
    assert imu.gyro.noise_density != pytest.approx(0.08 * math.pi / 180 / 60)
    resolved = to_dict(sc)
    assert "uwb" not in resolved["sensors"]  # a stream that is off stays off
    again = from_dict(Scenario, resolved, "resolved")
    assert again == sc
    assert resolved["sensors"]["gnss"]["rtk"]["noise_h"] == 0.02


def test_gnss_rtk_per_vehicle():
    sc = scenario({"gnss": {"rtk_vehicles": [2]}}, duration=20.0)
    log, _ = simulate(sc)
    e = log["gnss/value"] - log["gnss/clean"]
    for veh, (sh, sv) in {1: (1.5, 3.0), 2: (0.02, 0.03)}.items():
        sel = log["gnss/vehicle"] == veh
        assert log["gnss/rtk"][sel].all() == (veh == 2)
        n = sel.sum()
        tol = K_SIGMA / math.sqrt(2 * (n - 1))
        assert abs(e[sel, :2].std() / sh - 1) < K_SIGMA / math.sqrt(2 * (2 * n - 1))
        assert abs(e[sel, 2].std() / sv - 1) < tol


def test_site_vels_matches_object_velocity():
    sc = scenario({}, trajectory=PHASE_TRAJ, duration=0.1)
    from testbed.sim.world import build

    physics = build(sc)
    ids = physics.site_ids(["uav6/ant1", "uav6/ant2", "uav3/uwb", "uav6/led1"])
    np.testing.assert_allclose(physics.site_vels(ids), physics.site_vel(ids), atol=1e-12)


def test_no_segment_at_an_instant_is_no_hit():
    """An instant with no UWB link sampled (all lost or out of range) asks about zero segments:
    the answer is an empty mask, not an error (a 3600 s bandwidth run stopped on it)."""
    import numpy as np

    from testbed.config.scenario import load
    from testbed.sim.world import build

    physics = build(load("bandwidth"))
    targets = physics.ray_targets(np.ones(6, int))
    hit = physics.segments_may_hit(targets, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 2), int))
    assert hit.shape == (0,) and hit.dtype == bool
