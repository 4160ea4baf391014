"""The warm start of per-epoch solves (estimators.graph.warmstart) and the batched SO(3) exp/log."""
from __future__ import annotations

import numpy as np

from estimators.graph.warmstart import fit_motion
from estimators.so3 import rotmat_to_quat, skew, so3_exp, so3_log


def test_so3_exp_log_batched_match_one_at_a_time_invert_each_other_and_match_rodrigues():
    rng = np.random.default_rng(0)
    w = rng.normal(size=(60, 3))
    w *= (rng.uniform(0.0, 3.1, 60) / np.linalg.norm(w, axis=1))[:, None]
    w[0] = 0.0
    w[1] = [1e-10, 0.0, 0.0]
    w[2] *= 1e-6 / np.linalg.norm(w[2])
    w[3] *= (np.pi - 1e-6) / np.linalg.norm(w[3])  # near half a turn, where Shepperd's branches switch
    R = so3_exp(w)
    th = np.linalg.norm(w, axis=1)[:, None, None]
    K = skew(w)
    with np.errstate(invalid="ignore", divide="ignore"):  # Rodrigues' formula, the reference away from 0
        rod = np.eye(3) + np.sin(th) / th * K + (1.0 - np.cos(th)) / th ** 2 * (K @ K)
    np.testing.assert_allclose(R[4:], rod[4:], atol=1e-14)
    np.testing.assert_allclose(R[:2], np.eye(3) + K[:2], atol=1e-15)  # I + [w]x to second order
    out = so3_log(R)
    np.testing.assert_allclose(out, w, rtol=1e-12, atol=1e-14)  # also relative at 1e-6 rad
    np.testing.assert_array_equal(out, [so3_log(r) for r in R])
    np.testing.assert_array_equal(rotmat_to_quat(R.reshape(6, 10, 3, 3)).reshape(60, 4), [rotmat_to_quat(r) for r in R])


def test_fit_motion_is_exact_for_constant_velocity_and_body_rate():
    t = np.arange(10) * 0.1
    v, w = np.array([[0.3, -0.2, 0.1], [1.0, 0.0, 0.5]]), np.array([[0.0, 0.0, 0.4], [0.1, -0.2, 0.3]])
    R0 = so3_exp(np.array([[0.1, 0.2, 0.3], [-1.0, 0.5, 2.0]]))
    p = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 1.0]]) + v * t[:, None, None]
    R = R0 @ so3_exp(w * t[:, None, None])
    tp = np.array([1.2, 2.5])
    pp, Rp = fit_motion(t, p, R).predict(tp)
    np.testing.assert_allclose(pp, p[0] + v * tp[:, None, None], atol=1e-12)
    np.testing.assert_allclose(Rp, R0 @ so3_exp(w * tp[:, None, None]), atol=1e-12)


def test_fit_motion_of_one_solution_holds_it():
    p, R = np.array([[[1.0, 2.0, 3.0]]]), so3_exp(np.array([[[0.1, 0.2, 0.3]]]))
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
