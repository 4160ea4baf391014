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


def _mixed(ctl: GeometricController, omega: np.ndarray, limits: bool) -> tuple[np.ndarray, np.ndarray]:
    """(rotor thrusts (N, 4), [collective, moments per unit inertia] (N, 4) they produce) of a level
    swarm on its reference turning at body rate omega (N, 3) rad/s; limits False: the rotor
    limits lifted (the controller's command before any allocation)."""
    n = len(omega)
    lo, hi = ctl.lo, ctl.hi
    if not limits:
        ctl.lo, ctl.hi = np.full(4, -np.inf), np.full(4, np.inf)
    R = np.repeat(np.eye(3)[None], n, 0)
    zero = np.zeros((n, 3))
    ref = np.tile([0.0, 0.0, 10.0], (n, 1))
    thrust = ctl(ref, zero, R, omega, ref, zero, zero, heading(np.zeros(n))).copy()
    ctl.lo, ctl.hi = lo, hi
    mix = np.vstack([ctl.mix_f, ctl.mix_m])  # thrust = [f, m] @ mix
    return thrust, thrust @ np.linalg.inv(mix)


def test_rotor_limits_keep_roll_and_pitch_before_yaw():
    """A command past the rotor limits (docs/control.md, "Rotor limits"): every rotor within its
    limits, the roll and pitch moments exactly as commanded where they fit, the yaw moment scaled
    down with its sign kept; a command within the limits is the plain mix. 1 N m of yaw asks 15.6 N
    more on one diagonal pair of rotors and 15.6 N less on the other: a yaw rate of 0.5-1 rad/s
    asks more than the rotors' drag can give, and clipped rotor by rotor it took the roll and
    pitch authority with it (coop-denied seed 18: a vehicle tipped over on the MuJoCo attitude)."""
    sc = load("coop-denied", duration=1.0, overrides={"control.feedback": "truth"})
    physics = build(sc)
    ctl = GeometricController(physics, sc.control)
    omega = np.zeros((physics.n, 3))  # the controller is built for the scenario's 18; the first 4 matter
    omega[0] = [0.02, -0.01, 0.01]  # small: within the limits
    omega[1] = [0.3, 0.0, 0.8]  # roll damping and a yaw rate past the rotors' drag
    omega[2] = [-0.2, 0.25, -1.0]
    omega[3] = [0.0, 0.0, 3.0]  # yaw alone, far past
    thrust, produced = (a[:4] for a in _mixed(ctl, omega, limits=True))
    free, asked = (a[:4] for a in _mixed(ctl, omega, limits=False))
    assert ((free < ctl.lo) | (free > ctl.hi))[1:].any(axis=1).all()  # the three saturate
    assert (thrust >= ctl.lo).all() and (thrust <= ctl.hi).all()
    np.testing.assert_array_equal(thrust[0], free[0])  # within the limits: the plain mix
    np.testing.assert_allclose(produced[:, :3], asked[:, :3], rtol=1e-9, atol=1e-9)  # collective, roll, pitch
    assert (np.sign(produced[1:, 3]) == np.sign(asked[1:, 3])).all()
    assert (np.abs(produced[1:, 3]) < np.abs(asked[1:, 3])).all()
    # what the rotor-by-rotor clip gave: the roll and pitch moments lost
    clipped = np.clip(free, ctl.lo, ctl.hi) @ np.linalg.inv(np.vstack([ctl.mix_f, ctl.mix_m]))
    assert np.abs(clipped[1:3, 1:3] - asked[1:3, 1:3]).max() > 0.1 * np.abs(asked[1:3, 1:3]).max()
