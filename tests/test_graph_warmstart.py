"""The warm start of per-epoch solves (estimators.graph.warmstart) and the batched SO(3) log."""
from __future__ import annotations

import numpy as np

from estimators.graph.batch import so3_exp_batch, so3_log_batch
from estimators.graph.model import so3_log
from estimators.graph.warmstart import fit_motion


def test_so3_log_batch_matches_the_single_log_and_inverts_exp():
    rng = np.random.default_rng(0)
    w = rng.normal(size=(50, 3))
    w *= (rng.uniform(0.0, 3.0, 50) / np.linalg.norm(w, axis=1))[:, None]
    w[0] = 0.0
    w[1] = [1e-10, 0.0, 0.0]
    R = so3_exp_batch(w)
    out = so3_log_batch(R)
    np.testing.assert_allclose(out, w, atol=1e-9)
    np.testing.assert_allclose(out, [so3_log(r) for r in R], atol=1e-12)


def test_fit_motion_is_exact_for_constant_velocity_and_body_rate():
    t = np.arange(10) * 0.1
    v, w = np.array([[0.3, -0.2, 0.1], [1.0, 0.0, 0.5]]), np.array([[0.0, 0.0, 0.4], [0.1, -0.2, 0.3]])
    R0 = so3_exp_batch(np.array([[0.1, 0.2, 0.3], [-1.0, 0.5, 2.0]]))
    p = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 1.0]]) + v * t[:, None, None]
    R = R0 @ so3_exp_batch(w * t[:, None, None])
    tp = np.array([1.2, 2.5])
    pp, Rp = fit_motion(t, p, R).predict(tp)
    np.testing.assert_allclose(pp, p[0] + v * tp[:, None, None], atol=1e-12)
    np.testing.assert_allclose(Rp, R0 @ so3_exp_batch(w * tp[:, None, None]), atol=1e-12)


def test_fit_motion_of_one_solution_holds_it():
    p, R = np.array([[[1.0, 2.0, 3.0]]]), so3_exp_batch(np.array([[[0.1, 0.2, 0.3]]]))
    pp, Rp = fit_motion(np.array([5.0]), p, R).predict(np.array([5.0, 7.0]))
    np.testing.assert_array_equal(pp, np.broadcast_to(p[0], (2, 1, 3)))
    np.testing.assert_allclose(Rp, np.broadcast_to(R[0], (2, 1, 3, 3)), atol=1e-15)


def test_fit_motion_averages_the_noise_of_the_solutions():
    """Predicting 1 s past a window of 10 noisy positions (sigma 0.1 m, 0.1 s apart): the velocity of
    the least-squares line has sigma 0.1 / sqrt(sum (t - mean)^2) = 0.110 m/s, the prediction
    sigma sqrt(0.1^2 / 10 + (1.45 * 0.110)^2) = 0.163 m per axis; a two-point difference would have
    0.1 sqrt(11^2 + 10^2) = 1.49 m. Over 2000 trials (3 axes), the RMS error is within 10 % of
    0.163 (the RMS of 6000 normals has a relative sigma of 1 / sqrt(2 * 6000) = 0.9 %)."""
    rng = np.random.default_rng(1)
    t = np.arange(10) * 0.1
    errs = []
    for _ in range(2000):
        p = 0.1 * rng.standard_normal((10, 1, 3))
        pp, _ = fit_motion(t, p, np.tile(np.eye(3), (10, 1, 1, 1))).predict(np.array([1.9]))
        errs.append(pp[0, 0])
    rms = float(np.sqrt(np.mean(np.square(errs))))
    sxx = float(np.sum((t - t.mean()) ** 2))
    expected = float(np.sqrt(0.01 / 10 + (1.9 - t.mean()) ** 2 * 0.01 / sxx))
    assert abs(rms / expected - 1.0) < 0.1
