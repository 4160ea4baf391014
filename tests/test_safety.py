"""The safety of a flown run (testbed.scoring.safety): contact events by kind and their first time, the
minimum separation, the crash rules (tilt past 90 deg, floor impact above 2 m/s), the time
without a GNSS fix, on logged states made by hand in the coop-denied scene."""
from __future__ import annotations

import numpy as np

from testbed.scoring import safety
from testbed.config.scenario import load
from testbed.sim.world import build


def _log(physics, states: list[np.ndarray], vel: list[np.ndarray], fix: np.ndarray) -> dict:
    """A log of the logged states qpos (K, nq), the vehicles' linear velocities (K, N, 3), gnss/fix."""
    qpos = np.array(states)
    idx = physics.qpos_adr[:, None] + np.arange(7)
    qvel = np.zeros((len(states), physics.model.nv))
    qvel[:, physics.dof_adr[:, None] + np.arange(3)] = np.array(vel)
    return {"time": 0.1 * np.arange(len(states)), "qpos": qpos, "qvel": qvel, "truth/pos": qpos[:, idx[:, :3]],
            "truth/quat": qpos[:, idx[:, 3:]], "truth/vel": np.array(vel), "gnss/fix": fix}


def test_contacts_separation_crashes_and_gnss_outages():
    physics = build(load("coop-denied"))
    n = physics.n
    q = physics.data.qpos.copy()
    a, b, c, d = physics.qpos_adr[:4]
    q1 = q.copy()
    q1[b:b + 3] = q[a:a + 3] + [0.3, 0.0, 0.0]  # vehicle 2 inside vehicle 1: a violent collision
    q1[c + 3:c + 7] = [0.0, 1.0, 0.0, 0.0]  # vehicle 3 upside down (tilt 180 deg)
    q2 = q1.copy()
    q2[d + 2] = 0.05  # vehicle 4 on the floor
    still = np.zeros((n, 3))
    falling = still.copy()
    falling[3] = [0.0, 0.0, -3.0]  # 3 m/s down: above the 2 m/s impact limit
    fix = np.ones((4, n), bool)
    fix[2:, 4] = False  # vehicle 5 loses its fix from the third instant: 0.2 s without
    log = _log(physics, [q, q1, q2, q2], [still, still, falling, still], fix)
    f = safety.flight(log, physics)
    assert f["contacts"] == {"vehicle": {"events": 1, "first_s": 0.1}, "obstacle": {"events": 0, "first_s": None},
                             "floor": {"events": 1, "first_s": 0.2}}
    assert abs(f["min_separation_m"] - 0.3) < 1e-12 and f["min_separation_s"] == 0.1
    crashes = {c["vehicle"]: (c["time_s"], c["cause"]) for c in f["crash"]["vehicles"]}
    assert crashes == {1: (0.1, "contact force"), 2: (0.1, "contact force"), 3: (0.1, "tilt"), 4: (0.2, "impact")}
    assert f["crash"]["crashed"]
    assert np.allclose(f["no_fix_s"], np.where(np.arange(n) == 4, 0.2, 0.0))
    line = safety.summary_line(f)
    assert line.startswith("safety: contacts vehicle 1, obstacle 0, floor 1 (first at 0.1 s)") and "4 crashed" in line
    assert safety.crash_warning(f).startswith("crash: uav1 at 0.1 s (contact force), uav2 at")
    # the network statistics of the estimator flown on (or, on the truth, of every one that has them)
    ests = {"a": {"health": {"sent": 10, "dropped": 2, "bytes_sent": 1520, "latency_p50_us": 5000}},
            "w": {"health": {"sent": 8, "dropped_range": 1, "dropped_loss": 2, "bytes_sent": 64}}, "x": {}}
    assert safety.summary_line(f, ests, "a").endswith("; network (a): 10 sent, 2 dropped, 1520 bytes, latency p50 5 ms")
    assert safety.summary_line(f, ests).endswith("; network (a): 10 sent, 2 dropped, 1520 bytes, latency p50 5 ms; "
                                                 "network (w): 8 sent, 3 dropped, 64 bytes")
    assert "network" not in safety.summary_line(f, ests, "x")


def test_a_slow_touchdown_is_a_contact_not_a_crash():
    """Touching the floor at 0.5 m/s, upright: one floor contact, no crash (the contact force of
    that touchdown, 461 N, is below 20 weights, 1354 N)."""
    physics = build(load("coop-denied"))
    q = physics.data.qpos.copy()
    a = physics.qpos_adr[0]
    q1 = q.copy()
    q1[a + 2] = 0.098  # 2 mm into the floor
    slow = np.zeros((physics.n, 3))
    slow[0] = [0.0, 0.0, -0.5]
    f = safety.flight(_log(physics, [q, q1], [slow * 0, slow], np.ones((2, physics.n), bool)), physics)
    assert f["contacts"]["floor"]["events"] == 1 and not f["crash"]["crashed"], f
    assert safety.crash_warning(f) is None
