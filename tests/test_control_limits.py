"""The controller's tilt limit ([control] max_tilt_deg, docs/control.md): the commanded thrust
axis never leans more than the limit, keeps the direction of the horizontal correction, leaves
small corrections untouched, and is off (bit-identical commands) at its default 0."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from testbed.sim.control import GeometricController, heading
from testbed.config.scenario import load
from testbed.sim.world import build


def _commands(max_tilt: float, pos_error: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rotor thrusts (N, 4), desired thrust axis b3d (N, 3)) of a level hovering swarm whose
    position is off its reference by pos_error (N, 3) m."""
    sc = load("coop-denied", duration=1.0, overrides={"control.feedback": "truth"})
    physics = build(sc)
    n = physics.n
    ctl = GeometricController(physics, replace(sc.control, max_tilt_deg=max_tilt))
    R = np.repeat(np.eye(3)[None], n, 0)
    zero = np.zeros((n, 3))
    ref = np.tile([0.0, 0.0, 10.0], (n, 1))
    thrust = ctl(ref + pos_error, zero, R, zero, ref, zero, zero, heading(np.zeros(n)))
    return thrust.copy(), ctl._b3.copy()


def test_tilt_is_limited_and_the_direction_kept():
    n = 18
    rng = np.random.default_rng(3)
    err = rng.normal(0.0, 20.0, (n, 3))  # large errors: kx |e| up to ~10 g
    err[0] = [0.1, -0.2, 0.05]  # a small one: under the limit
    _, b3 = _commands(35.0, err)
    tilt = np.degrees(np.arccos(b3[:, 2]))
    assert (tilt <= 35.0 + 1e-9).all()
    _, free = _commands(0.0, err)
    free_tilt = np.degrees(np.arccos(free[:, 2]))
    over = free_tilt > 35.0
    assert over.sum() >= n // 2  # the draw does exceed the limit
    np.testing.assert_allclose(tilt[over], 35.0, atol=1e-9)  # saturated at the limit, not below
    # the horizontal direction of the correction is kept
    h, hf = b3[:, :2], free[:, :2]
    np.testing.assert_allclose(h / np.linalg.norm(h, axis=1)[:, None], hf / np.linalg.norm(hf, axis=1)[:, None], atol=1e-12)
    np.testing.assert_array_equal(b3[~over], free[~over])  # under the limit: the same command
    assert not over[0]


def test_a_commanded_dive_keeps_lift():
    """A position far above the reference asks F/m < 0; with the limit on the vertical part is
    kept at half gravity, so the thrust axis stays defined and up."""
    err = np.tile([3.0, 0.0, 30.0], (18, 1))  # kx 30 m = 120 m/s^2 down
    thrust, b3 = _commands(35.0, err)
    assert (b3[:, 2] >= np.cos(np.radians(35.0)) - 1e-12).all() and np.isfinite(thrust).all()
