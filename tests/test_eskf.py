"""estimators.eskf: every Jacobian against central differences through inject/difference."""
from __future__ import annotations

import numpy as np

from estimators import eskf
from estimators.so3 import quat_exp

RNG = np.random.default_rng(7)


def _state() -> np.ndarray:
    x = np.zeros(16)
    x[0:3], x[3:6] = RNG.normal(0, 5, 3), RNG.normal(0, 2, 3)
    x[6:10] = quat_exp(RNG.normal(0, 0.6, 3))
    x[10:13], x[13:16] = RNG.normal(0, 0.2, 3), RNG.normal(0, 0.02, 3)
    return x


def _numeric(fn, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d fn(x (+) dx) / d dx at dx = 0 by central differences, columns per error component."""
    cols = []
    for k in range(eskf.N_ERR):
        d = np.zeros(eskf.N_ERR)
        d[k] = h
        cols.append((fn(eskf.inject(x, d)) - fn(eskf.inject(x, -d))) / (2 * h))
    return np.stack(cols, axis=-1)


def test_inject_and_difference_are_inverse():
    x, dx = _state(), RNG.normal(0, 0.1, 15)
    assert np.allclose(eskf.difference(eskf.inject(x, dx), x), dx, atol=1e-12)


def test_transition_is_the_jacobian_of_propagate():
    for _ in range(5):
        x, f, w = _state(), RNG.normal(0, 3, 3) + [0, 0, 9.81], RNG.normal(0, 1, 3)
        dt = 0.05
        y = eskf.propagate(x, f, w, dt)
        numeric = _numeric(lambda z: eskf.difference(eskf.propagate(z, f, w, dt), y), x)
        F = eskf.transition(x, f, w, dt)
        assert np.allclose(F, numeric, atol=1e-7), np.abs(F - numeric).max()


def test_measurement_jacobians():
    for _ in range(5):
        x, lever, anchor = _state(), RNG.normal(0, 0.3, 3), RNG.normal(0, 20, 3)
        _, H = eskf.site_position(x, lever)
        assert np.allclose(H, _numeric(lambda z: eskf.site_position(z, lever)[0], x), atol=1e-7)
        _, Hr = eskf.range_model(x, lever, anchor)
        assert np.allclose(Hr, _numeric(lambda z: np.array([eskf.range_model(z, lever, anchor)[0]]), x), atol=1e-7)


def test_update_gate_rejects_and_accepts():
    x, P = _state(), np.eye(15) * 0.01
    s, H = eskf.site_position(x, np.zeros(3))
    gate = 16.27  # chi-square 3 dof, 1e-3
    x1, P1, res = eskf.update(x, P, np.array([0.05, 0.0, 0.0]), H, np.eye(3) * 0.01, gate)
    assert res.accepted and x1[0] > x[0] and np.trace(P1) < np.trace(P)
    x2, P2, res = eskf.update(x, P, np.array([5.0, 0.0, 0.0]), H, np.eye(3) * 0.01, gate)
    assert not res.accepted and np.array_equal(x2, x) and res.nis > gate
