"""GNSS sky visibility (issue 18 part 3): rays towards a seeded constellation, DOP of the visible
set, no fix under cover, the DOP-scaled sigma declared per row. Short horizons."""
from __future__ import annotations

import math

import mujoco
import numpy as np

from testbed.config import from_dict
from testbed.rng import stream_rng
from testbed.config.scenario import Scenario
from testbed.sensors.config import SkyConfig
from testbed.sensors.sky import Constellation, Sky, dop
from testbed.sim.simulate import simulate
from testbed.stream import make_stream
from testbed.sim.world import build

HOVER = {"kind": "waypoints", "points": [[0.0, 0.0, 5.0], [0.0, 0.0, 5.0]], "times": [0.0, 10.0]}
TALL_BOX = {"type": "box", "pos": [3.0, 0.0, 10.0], "size": [1.0, 1.0, 10.0]}  # east of the vehicle, 20 m high
ROOF = {"type": "box", "pos": [0.0, 0.0, 20.0], "size": [200.0, 200.0, 1.0]}  # a covered passage over it


def scenario(obstacles: list, sky: dict | None = None, duration: float = 1.0) -> Scenario:
    return from_dict(Scenario, {
        "name": "sky-test", "description": "test", "seed": 5, "duration": duration, "trajectory": HOVER,
        "world": {"obstacles": obstacles},
        "sensors": {"gnss": {"rate_hz": 5.0, "sky": {"enabled": True, **(sky or {})}}},
    }, "test")


def unit(az_deg: float, el_deg: float) -> np.ndarray:
    az, el = math.radians(az_deg), math.radians(el_deg)
    return np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])


def test_satellite_behind_a_box_is_not_used():
    sc = scenario([TALL_BOX])
    physics = build(sc)
    mujoco.mj_forward(physics.model, physics.data)
    sky = Sky(sc.sensors.gnss.sky, physics, stream_rng(0, "constellation"), physics.body_ids)
    # east at 30 deg elevation: through the box (the ray reaches x = 2 m at z ~ 6.3 m < 20 m);
    # west and north at 30 deg, and the zenith: open sky
    dirs = np.stack([unit(90, 30), unit(270, 30), unit(0, 30), unit(0, 90)])
    sky.constellation.u0, sky.constellation.v = dirs, np.zeros_like(dirs)
    p = physics.site_pos("uav1/uwb")[None]
    u, vis = sky.visible(physics, 0.0, p)
    assert np.allclose(u, dirs)
    assert vis.tolist() == [[False, True, True, True]]
    # the same satellites seen from 25 m up (above the box): all visible
    u, vis = sky.visible(physics, 0.0, p + [0.0, 0.0, 20.0])
    assert vis.all()


def test_dop_matches_a_hand_computation():
    # zenith + four on the horizon E, W, N, S: G^T G = diag(2, 2) (E, N) and [[1, -1], [-1, 5]]
    # (up, clock), whose inverse is [[5, 1], [1, 1]] / 4: HDOP = sqrt(1/2 + 1/2) = 1,
    # VDOP = sqrt(5/4), PDOP = sqrt(1 + 5/4) = 1.5
    u = np.stack([unit(0, 90), unit(90, 0), unit(270, 0), unit(0, 0), unit(180, 0)])
    h, v, p = dop(u, np.ones((1, 5), bool))
    assert np.allclose([h[0], v[0], p[0]], [1.0, math.sqrt(5) / 2, 1.5], rtol=1e-12)
    # and against (G^T G)^-1 for a random geometry
    rng = np.random.default_rng(1)
    w = rng.standard_normal((7, 3))
    w[:, 2] = np.abs(w[:, 2])
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    G = np.concatenate([-w, np.ones((7, 1))], axis=1)
    Q = np.linalg.inv(G.T @ G)
    h, v, p = dop(w, np.ones((1, 7), bool))
    assert np.allclose([h[0], v[0], p[0]], [math.sqrt(Q[0, 0] + Q[1, 1]), math.sqrt(Q[2, 2]), math.sqrt(np.trace(Q[:3, :3]))])


def test_fewer_than_four_visible_or_degenerate_is_no_fix():
    u = np.stack([unit(0, 90), unit(90, 20), unit(270, 20), unit(0, 20), unit(180, 20)])
    vis = np.array([[True, True, True, False, False], [True, True, True, True, False], [True] * 5])
    h, v, p = dop(u, vis)
    assert np.isinf(p[0]) and np.isinf(h[0]) and np.all(np.isfinite(p[1:]))
    same = np.stack([unit(0, 45)] * 5)  # every satellite in one direction: rank 2
    assert np.isinf(dop(same, np.ones((1, 5), bool))[2][0])


def test_constellation_above_the_mask_and_moving_at_the_stated_rate():
    cfg = SkyConfig(enabled=True, satellites=12, elevation_mask_deg=15.0, rate_deg_s=0.01)
    c = Constellation(cfg, stream_rng(3, "constellation"))
    u0, u1 = c.directions(0.0), c.directions(100.0)
    assert c.above_mask(u0).all() and np.allclose(np.linalg.norm(u1, axis=1), 1.0)
    angle = np.degrees(np.arccos(np.clip((u0 * u1).sum(1), -1, 1)))
    assert np.allclose(angle, 1.0, atol=1e-9)  # 0.01 deg/s x 100 s along a great circle


def test_no_fix_under_a_roof_and_the_declared_sigma_is_dop_scaled():
    open_sky = scenario([])
    log, _ = simulate(open_sky)
    K = len(log["time"])
    assert log["gnss/fix"].shape == (K, 1) and log["gnss/fix"].all()
    assert (log["gnss/sats"] == 10).all() and np.isfinite(log["gnss/dop"]).all()
    rows = len(log["gnss/time"])
    assert rows == 6  # 1 s at 5 Hz, one vehicle
    s = make_stream("gnss", log, open_sky)
    assert np.array_equal(s.sigma, log["gnss/sigma"])
    g = open_sky.sensors.gnss
    sky = g.sky
    base = np.array([g.receiver.noise_h, g.receiver.noise_h, g.receiver.noise_v])
    f = s.sigma / base
    assert np.allclose(f[:, 0], f[:, 1]) and np.all(f > 0)
    # PDOP^2 = HDOP^2 + VDOP^2 with HDOP = f_h hdop_ref, VDOP = f_v vdop_ref
    pdop = np.hypot(f[:, 0] * sky.hdop_ref, f[:, 2] * sky.vdop_ref)
    assert np.allclose(pdop, log["gnss/dop"][log["gnss/state_index"], 0])
    covered, _ = simulate(scenario([ROOF]))
    assert len(covered["gnss/time"]) == 0 and not covered["gnss/fix"].any()
    assert (covered["gnss/sats"] == 0).all() and np.isinf(covered["gnss/dop"]).all()
    assert make_stream("gnss", covered, open_sky).sigma.shape == (0, 3)
