"""[disturbance]: the white-noise-acceleration motion model realized in the physics.

Statistical checks use chi-square intervals from the sample size (estimators.core.chi2_interval).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from estimators.core import chi2_interval
from testbed.config import scenario
from testbed.sim.disturbance import perturb, realize
from testbed.reference import evaluate
from testbed.sim.simulate import simulate, schedule
from testbed.sensors.suite import make_sensors
from testbed.sim.world import build

from physics_checks import assert_imu_reads_played_state  # tests/ helper

Q_T, Q_R = 2e-3, 5e-5  # m^2/s^3, rad^2/s^3


def _hovering_master(motion="prescribed", duration=60.0, vehicles="[1]", q_t=Q_T, q_r=Q_R):
    """phase-cross-h000 with master 1 (hovering level, yaw 0) disturbed: its truth velocity and
    body rate ARE the disturbance's random walks."""
    return scenario.load("phase-cross-h000", motion=motion, duration=duration, overrides={
        "disturbance.accel_density": str(q_t), "disturbance.angular_accel_density": str(q_r),
        "disturbance.vehicles": vehicles, "sensors.phase.rate_hz": "10.0"})


def _increments(log, dt):
    """Rows every dt s: times (n,), pos, vel (n, 3), rotation (n, 3, 3), omega (n, 3) of uav1."""
    t = log["time"]
    rows = np.flatnonzero(np.isclose(np.mod(t + 1e-9, dt), 0.0, atol=1e-6))
    R = Rotation.from_quat(log["truth/quat"][rows, 0], scalar_first=True)
    return t[rows], log["truth/pos"][rows, 0], log["truth/vel"][rows, 0], R, log["truth/omega"][rows, 0]


def test_prescribed_disturbance_is_the_constant_velocity_model():
    """Over dt = 0.1 s the translation (dp - v dt, dv) of the disturbed master has the covariance
    q [[dt^3/3 - h^2 dt/12, dt^2/2], [dt^2/2, dt]] per axis (h = 5 ms tick), independent across
    intervals: the sum of the 6-dof NEES over n intervals is inside the 99 % chi-square interval
    of 6 n dof; likewise the rotation (rotation vector over dt, body-rate increment) with q_r."""
    sc = _hovering_master()
    log, physics = simulate(sc)
    assert physics.warnings() == {}
    dt, h = 0.1, 1.0 / sc.world.control_rate
    t, p, v, R, w = _increments(log, dt)
    n = t.size - 1
    C = Q_T * np.array([[dt**3 / 3 - h * h * dt / 12, dt**2 / 2], [dt**2 / 2, dt]])
    Ci = np.linalg.inv(C)
    x = np.stack([p[1:] - p[:-1] - v[:-1] * dt, v[1:] - v[:-1]], axis=-1)  # (n, 3, 2)
    nees_t = np.einsum("nai,ij,naj->", x, Ci, x)
    lo, hi = chi2_interval(6 * n, 1)
    print(f"translation: {nees_t / n:.3f} per interval, 6 expected, n = {n}")
    assert lo < nees_t < hi
    # rotation: the same with the rotation vector of R_k^T R_k+1 in place of dp (body frame;
    # the non-commuting part is ~|w| |dw| dt / 2 ~ 6e-6 rad, 5 % of its 1.3e-4 rad sigma)
    rv = (R[:-1].inv() * R[1:]).as_rotvec()
    x = np.stack([rv - w[:-1] * dt, w[1:] - w[:-1]], axis=-1)
    nees_r = np.einsum("nai,ij,naj->", x, Ci * (Q_T / Q_R), x)
    print(f"rotation: {nees_r / n:.3f} per interval, 6 expected")
    assert lo < nees_r < hi


def test_prescribed_disturbance_reaches_accelerometer_and_gyro():
    """The IMU physics sees the disturbed motion: at logged instants MuJoCo's accelerometer reads
    R^T (a_ref + a_d - g) and the gyro the disturbed body rate (ideal sensors, straight from
    mj_inverse, to 1e-6 m/s^2 and 1e-9 rad/s)."""
    sc = scenario.load("visnav", duration=2.0, overrides={
        "disturbance.accel_density": "0.01", "disturbance.angular_accel_density": "1e-3"})
    physics = build(sc)
    sched = schedule(sc, make_sensors(sc, physics))
    ticks = np.array([37, 211, 399])
    real = realize(sc, ticks)
    ref = perturb(evaluate(sc.trajectory, ticks * sched.tick), real, slice(None))
    assert np.abs(real.accel).max() > 0.5  # the disturbance is there to be seen
    for k in range(ticks.size):
        assert_imu_reads_played_state(physics, ref, k)
    # the angular acceleration of a tick is the rate of change of the body rate over that tick
    # (alpha_d is held over the tick; the smooth reference part changes by ~h d(alpha)/dt)
    ticks2 = np.array([200, 201])
    ref2 = perturb(evaluate(sc.trajectory, ticks2 * sched.tick), realize(sc, ticks2), slice(None))
    fd = (ref2.omega[1] - ref2.omega[0]) / sched.tick
    print(f"alpha vs forward difference of omega: {np.abs(fd - ref2.alpha[0]).max():.2e} rad/s^2 "
          f"(alpha_d sigma {np.sqrt(1e-3 / sched.tick):.2f})")
    assert np.abs(fd - ref2.alpha[0]).max() < 1e-3


def test_disturbance_only_moves_the_disturbed_vehicles_and_is_reproducible():
    """prescribed and flown: other vehicles' truth is bit-identical to the undisturbed run, the
    disturbed one differs, and the same seed gives the same realization bit for bit."""
    for motion in ("prescribed", "flown"):
        base, _ = simulate(scenario.load("phase-cross-h000", motion=motion, duration=3.0))
        a, _ = simulate(_hovering_master(motion, 3.0, "[6]", q_t=0.05, q_r=1e-3))
        b, _ = simulate(_hovering_master(motion, 3.0, "[6]", q_t=0.05, q_r=1e-3))
        assert np.array_equal(a["qpos"], b["qpos"]) and np.array_equal(a["qvel"], b["qvel"])
        rows = np.isin(base["time"], a["time"])
        assert np.array_equal(a["truth/pos"][:, :5], base["truth/pos"][rows][:, :5])
        moved = np.abs(a["truth/pos"][-1, 5] - base["truth/pos"][rows][-1, 5]).max()
        print(f"{motion}: follower moved {moved:.4f} m by the disturbance")
        assert moved > 1e-3


def test_flown_disturbance_is_a_force_the_controller_rejects():
    """flown: the disturbance is an external wrench; the hovering master is pushed off its
    reference but the controller keeps it within a metre (it is a gust, not a prescribed walk),
    while prescribed mode with the same draws lets it wander freely."""
    flown, _ = simulate(_hovering_master("flown", 30.0, q_t=0.05, q_r=0.0))
    free, _ = simulate(_hovering_master("prescribed", 30.0, q_t=0.05, q_r=0.0))
    dev_f = np.linalg.norm(flown["truth/pos"][:, 0] - flown["reference/pos"][:, 0], axis=1)
    dev_p = np.linalg.norm(free["truth/pos"][:, 0] - free["reference/pos"][:, 0], axis=1)
    print(f"max deviation flown {dev_f.max():.3f} m, prescribed {dev_p.max():.3f} m")
    assert 1e-3 < dev_f.max() < 1.0
    assert dev_p.max() > 3 * dev_f.max()
