"""estimators.eskf: every Jacobian against central differences through inject/difference."""
from __future__ import annotations

import numpy as np

from estimators import eskf
from estimators.so3 import quat_exp, quat_to_rotmat, skew

RNG = np.random.default_rng(7)


def _state(extras: int = 2) -> np.ndarray:
    """A random nominal state with `extras` extra states (m)."""
    x = np.zeros(eskf.N_ERR + 1 + extras)
    x[0:3], x[3:6] = RNG.normal(0, 5, 3), RNG.normal(0, 2, 3)
    x[6:10] = quat_exp(RNG.normal(0, 0.6, 3))
    x[10:13], x[13:16] = RNG.normal(0, 0.2, 3), RNG.normal(0, 0.02, 3)
    x[16:34] = RNG.normal(0, 0.01, 18)  # scale factors and misalignments
    x[34:] = RNG.normal(0, 0.05, extras)
    return x


def _numeric(fn, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d fn(x (+) dx) / d dx at dx = 0 by central differences, columns per error component."""
    cols = []
    n = eskf.error_size(x)
    for k in range(n):
        d = np.zeros(n)
        d[k] = h
        cols.append((fn(eskf.inject(x, d)) - fn(eskf.inject(x, -d))) / (2 * h))
    return np.stack(cols, axis=-1)


def test_inject_and_difference_are_inverse():
    x, dx = _state(), RNG.normal(0, 0.1, eskf.N_ERR + 2)
    assert np.allclose(eskf.difference(eskf.inject(x, dx), x), dx, atol=1e-12)


def test_transition_is_the_jacobian_of_propagate():
    for _ in range(5):
        x, f, w = _state(), RNG.normal(0, 3, 3) + [0, 0, 9.81], RNG.normal(0, 1, 3)
        dt = 0.05
        y, F = eskf.step(x, f, w, dt)
        numeric = _numeric(lambda z: eskf.difference(eskf.step(z, f, w, dt)[0], y), x)
        assert np.allclose(F, numeric, atol=1e-7), np.abs(F - numeric).max()


def test_a_batched_step_is_each_vehicles_step():
    """estimators.eskf.step over a batch of vehicles (each its own state, sample and interval)
    gives each vehicle's own step, to round-off."""
    xs = np.stack([_state() for _ in range(4)])
    f, w, dt = RNG.normal(0, 3, (4, 3)) + [0, 0, 9.81], RNG.normal(0, 1, (4, 3)), np.array([0.01, 0.02, 0.05, 0.1])
    y, F = eskf.step(xs, f, w, dt)
    for k in range(4):
        yk, Fk = eskf.step(xs[k], f[k], w[k], dt[k])
        np.testing.assert_allclose(y[k], yk, rtol=0, atol=1e-12)
        np.testing.assert_allclose(F[k], Fk, rtol=0, atol=1e-12)


def test_measurement_jacobians():
    for _ in range(5):
        x, lever, anchor = _state(), RNG.normal(0, 0.3, 3), RNG.normal(0, 20, 3)
        _, H = eskf.site_position(x, lever)
        assert np.allclose(H, _numeric(lambda z: eskf.site_position(z, lever)[0], x), atol=1e-7)
        for extras in ((), (1,), (0, 1)):
            _, Hr = eskf.range_model(x, lever, anchor, extras)
            assert np.allclose(Hr, _numeric(lambda z: np.array([eskf.range_model(z, lever, anchor, extras)[0]]), x), atol=1e-7)
        r0, r1 = eskf.range_model(x, lever, anchor)[0], eskf.range_model(x, lever, anchor, (0, 1))[0]
        assert np.isclose(r1 - r0, x[34] + x[35])


def test_update_gate_rejects_and_accepts():
    x, P = _state(), np.eye(eskf.N_ERR + 2) * 0.01
    s, _ = eskf.site_position(x, np.zeros(3))
    model = lambda z: eskf.site_position(z, np.zeros(3))  # noqa: E731
    gate = 16.27  # chi-square 3 dof, 1e-3
    x1, P1, res = eskf.update(x, P, s + [0.05, 0.0, 0.0], model, np.eye(3) * 0.01, gate)
    assert res.accepted and x1[0] > x[0] and np.trace(P1) < np.trace(P)
    x2, P2, res = eskf.update(x, P, s + [5.0, 0.0, 0.0], model, np.eye(3) * 0.01, gate)
    assert not res.accepted and np.array_equal(x2, x) and res.nis > gate
    H = model(x)[1]
    keep = eskf.screen(P, np.array([0.05, 5.0, 0.0]), H, np.eye(3) * 0.01, 10.83)  # 1 dof, 1e-3
    assert keep.tolist() == [True, False, True]


def test_held_states_keep_their_estimate_and_variance_and_the_joseph_covariance():
    """A held (consider) state correlated with the position: a position fix moves the position and
    shrinks its variance, but leaves the held state's value and its own variance as they were; the
    covariance is the Joseph form of the gain with the held rows zero (the exact covariance of that
    estimator), computed here by hand."""
    rng = np.random.default_rng(3)
    n = eskf.N_ERR + 2
    A = rng.normal(size=(n, n)) * 0.1
    P = A @ A.T + 0.01 * np.eye(n)
    x = _state()
    s, H = eskf.site_position(x, np.zeros(3))
    Rn = np.eye(3) * 0.01
    z = s + [0.1, -0.05, 0.02]
    hold = eskf.ACCEL_BIAS_ACROSS
    x1, P1, res = eskf.update(x, P, z, lambda y: eskf.site_position(y, np.zeros(3)), Rn, np.inf, 1, hold)
    assert res.accepted and abs(P[0, 9]) > 1e-3  # the held state is correlated with the position
    assert np.array_equal(x1[[10, 11]], x[[10, 11]]) and np.allclose(P1[np.ix_(hold, hold)], P[np.ix_(hold, hold)])
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + Rn)
    K[list(hold)] = 0.0
    I_KH = np.eye(n) - K @ H
    G = np.eye(n)
    G[eskf.TH, eskf.TH] -= skew(0.5 * (K @ (z - s))[eskf.TH])
    assert np.allclose(P1, G @ (I_KH @ P @ I_KH.T + K @ Rn @ K.T) @ G.T, atol=1e-12)
    assert np.allclose(eskf.difference(x1, x), K @ (z - s), atol=1e-12)
    assert P1[0, 0] < P[0, 0] and x1[0] != x[0]

def test_iterated_update_reaches_the_map_estimate_of_ranges_with_a_large_prior_error():
    """Four noiseless-prior ranges 30 m away, the prior 5 m off (sigma 3 m): the iterated update
    converges to the minimiser of the MAP cost |dx|_P^2 + |z - h(x (+) dx)|_R^2 (its gradient
    vanishes), the single-linearisation update does not."""
    x = np.zeros(eskf.N_ERR + 1)
    x[6] = 1.0
    truth = x.copy()
    truth[0:3] = [0.0, 0.0, 10.0]
    x[0:3] = truth[0:3] + [2.0, 0.8, -4.8]
    anchors = np.array([[-25.0, -15.0, 3.0], [35.0, -20.0, 9.0], [30.0, 35.0, 3.0], [-20.0, 30.0, 9.0]])
    P = np.diag([1.5 ** 2, 1.5 ** 2, 3.0 ** 2] + [1.0] * (eskf.N_ERR - 3))
    Rn = np.eye(4) * 0.1 ** 2

    def model(z):
        hs = [eskf.range_model(z, np.zeros(3), a) for a in anchors]
        return np.array([h for h, _ in hs]), np.vstack([H for _, H in hs])
    z = model(truth)[0]

    def gradient(y):  # of the MAP cost at y, in the error state around x
        dx = eskf.difference(y, x)
        h, H = model(y)
        return np.linalg.solve(P, dx) - H.T @ np.linalg.solve(Rn, z - h)
    one, _, _ = eskf.update(x, P, z, model, Rn, np.inf, 1)
    it, _, _ = eskf.update(x, P, z, model, Rn, np.inf, 6)
    assert np.linalg.norm(gradient(it)) < 1e-3 * np.linalg.norm(gradient(one))
    assert np.linalg.norm(it[0:3] - truth[0:3]) < 0.1 < np.linalg.norm(one[0:3] - truth[0:3])


def test_level_and_the_tilt_error_an_accelerometer_bias_leaves():
    """A vehicle at rest with attitude R reads f = R^T (0, 0, g) + b; levelling the reading with
    a bias error db gives the tilt error (the part of dtheta across the vertical) J db to first
    order."""
    for _ in range(5):
        q = quat_exp(np.array([*RNG.normal(0, 0.2, 2), RNG.uniform(-3, 3)]))
        R = quat_to_rotmat(q)
        f = R.T @ [0.0, 0.0, 9.81]
        yaw = np.arctan2(R[1, 0], R[0, 0])
        q0, J = eskf.level(f, yaw)
        assert np.allclose(quat_to_rotmat(q0), R, atol=1e-12)
        x0 = np.zeros(eskf.N_ERR + 1)
        x0[6:10] = q0
        for db in (RNG.normal(0, 0.02, 3) for _ in range(3)):
            qb, _ = eskf.level(f + db, yaw)  # levelled with a bias db not removed
            xt, xb = x0.copy(), x0.copy()
            xb[6:10] = qb
            dtheta = eskf.difference(xt, xb)[eskf.TH]  # R_true = R_est Exp(dtheta)
            v = f / np.linalg.norm(f)
            tilt = dtheta - v * (v @ dtheta)  # the ZYX heading held fixed may turn about v: not J's part
            assert np.allclose(tilt, J @ db, atol=2e-5), (tilt, J @ db)
