"""The shared estimator core: linear Kalman steps and consistency helpers."""
import numpy as np

from estimators.core import Gaussian, chi2_interval, is_spd, joseph_update, kf_predict, kf_update, nees


def test_kf_update_matches_textbook_on_scalar():
    b = Gaussian(np.array([1.0]), np.array([[4.0]]))
    post = kf_update(b, np.array([3.0]), np.array([[1.0]]), np.array([[1.0]]))
    # K = 4/5, x = 1 + 0.8*2, P = (1-0.8)^2*4 + 0.64*1 = 0.8
    assert np.isclose(post.mean[0], 2.6)
    assert np.isclose(post.cov[0, 0], 0.8)


def test_joseph_equals_simple_form_for_optimal_gain():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + np.eye(4)
    H = rng.normal(size=(2, 4))
    R = np.diag([0.5, 0.2])
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    assert np.allclose(joseph_update(P, K, H, R), (np.eye(4) - K @ H) @ P, atol=1e-12)


def test_predict_and_nees():
    b = kf_predict(Gaussian(np.zeros(2), np.eye(2)), np.array([[1, 1], [0, 1.0]]), 0.1 * np.eye(2))
    assert is_spd(b.cov)
    assert np.isclose(nees(np.array([1.0, 0.0]), np.eye(2) * 2), 0.5)
    lo, hi = chi2_interval(3, 30)
    assert lo < 3 < hi
