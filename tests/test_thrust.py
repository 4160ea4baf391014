"""Rotor routes: the joint route (free-joint moment gear + thrust in xfrc_applied, testbed.sim.thrust)
flies exactly as the site transmission, for the same controls and in closed loop."""
from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from testbed.bench.swarm import swarm_scenario
from testbed.config.scenario import Disturbance
from testbed.sim.simulate import simulate
from testbed.sim.thrust import BodyForces
from testbed.sim.world import build, rotor_route

TOL = 1e-9  # m, m/s, rad/s, m/s^2: the two routes differ only in floating-point rounding


def _open_loop(physics, controls: np.ndarray, substeps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fly `controls` (T, N, 4) N, one row per tick of `substeps` steps; returns qpos (T, nq),
    qvel (T, nv) and IMU readings (T, N, 6) at the start of each tick (acceleration stage)."""
    m, d = physics.model, physics.data
    forces = BodyForces(physics)
    ctrl = physics.views().ctrl
    qpos, qvel, imu = [], [], []
    for u in controls:
        mujoco.mj_step1(m, d)
        ctrl[:] = u
        forces.apply()
        mujoco.mj_step2(m, d)
        qpos.append(d.qpos.copy()), qvel.append(d.qvel.copy()), imu.append(d.sensordata[physics.imu_idx])
        forces.step(m, d, substeps - 1)
    return np.array(qpos), np.array(qvel), np.array(imu)


def _aggressive_controls(n: int, ticks: int, dt: float, hover: float) -> np.ndarray:
    """(ticks, n, 4) N: hover thrust plus per-rotor sinusoids of +-6 N at 1.5-3 Hz (body rates of
    several rad/s within a second), phase-shifted per vehicle and rotor, within 0..40 N."""
    t = np.arange(ticks)[:, None, None] * dt
    freq = 1.5 + 1.5 * np.arange(4) / 3
    phase = np.arange(n)[None, :, None] * 0.7 + np.arange(4) * 1.3
    return hover + 6.0 * np.sin(2 * np.pi * freq * t + phase) + 2.0 * np.sin(2 * np.pi * 0.5 * t)


@pytest.mark.parametrize("n", [1, 6, 50])
def test_joint_route_flies_the_same_controls_as_the_site_route(n):
    sc = swarm_scenario(n, 1.0)
    site, joint = build(sc, rotors="site"), build(sc, rotors="joint")
    assert (site.rotor_route, joint.rotor_route) == ("site", "joint")
    substeps = int(round(1 / (sc.world.control_rate * sc.world.timestep)))
    controls = _aggressive_controls(n, int(sc.duration * sc.world.control_rate), 1 / sc.world.control_rate, site.vehicle_mass * 9.81 / 4)
    a, b = _open_loop(site, controls, substeps), _open_loop(joint, controls, substeps)
    omega = a[1][:, site._qvel_idx[:, 3:]]
    assert np.abs(omega).max() > 1.5  # aggressive: body rates beyond 1.5 rad/s
    for x, y in zip(a, b):
        np.testing.assert_allclose(y, x, rtol=0, atol=TOL)
    # controls move the vehicles: the routes are not trivially equal
    assert np.abs(a[0][-1] - a[0][0]).max() > 0.1


def test_joint_route_closed_loop_with_disturbance_matches_site_route():
    """Controller in the loop and a disturbance wrench held over each tick (added to the thrust)."""
    sc = swarm_scenario(12, 1.0)
    sc = replace(sc, disturbance=Disturbance(accel_density=2.0, angular_accel_density=0.5, vehicles=(2, 5)))
    assert rotor_route(sc) == "joint"
    a, _ = simulate(sc, build(sc, rotors="site"))
    b, _ = simulate(sc, build(sc, rotors="joint"))
    assert np.abs(a["truth/pos"][-1, 1] - a["reference/pos"][-1, 1]).max() > 1e-4  # the disturbance acts
    for key in ("truth/pos", "truth/vel", "truth/quat", "truth/omega", "ctrl"):
        np.testing.assert_allclose(b[key], a[key], rtol=0, atol=TOL, err_msg=key)


def test_joint_route_scene_xml_reloads_and_explains_itself():
    """The saved scene of a joint-route swarm loads back with the same rotor transmissions, and
    carries the note on where the thrust force comes from."""
    physics = build(swarm_scenario(12, 1.0))
    assert physics.rotor_route == "joint"
    m = physics.model
    reloaded = mujoco.MjModel.from_xml_string(physics.to_xml())
    ids = physics.actuator_idx.ravel()
    assert (m.actuator_trntype[ids] == mujoco.mjtTrn.mjTRN_JOINT).all()
    np.testing.assert_array_equal(reloaded.actuator_trnid[ids], m.actuator_trnid[ids])
    np.testing.assert_allclose(reloaded.actuator_gear[ids], m.actuator_gear[ids], rtol=0, atol=1e-6)
    # gear = (0, 0, 0, y, -x, k_m) for a rotor at (x, y) (body frame)
    xy = m.site_pos[physics.rotor_site_idx[0], :2]
    np.testing.assert_allclose(m.actuator_gear[ids[:4], 3:5], np.stack([xy[:, 1], -xy[:, 0]], axis=1), rtol=0, atol=1e-15)
    t = mujoco.mj_name2id(reloaded, mujoco.mjtObj.mjOBJ_TEXT, "rotor_route")
    note = reloaded.text_data[reloaded.text_adr[t] : reloaded.text_adr[t] + reloaded.text_size[t]].decode()
    assert t >= 0 and "xfrc_applied" in note
