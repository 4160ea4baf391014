"""The shared estimator core: linear Kalman steps, consistency helpers, the driver and its health counts."""
import numpy as np
import pytest

from estimators.core import (
    Epoch,
    Gaussian,
    Stepper,
    chi2_interval,
    cho_inverse_upper,
    cho_solve_upper,
    cholesky_upper,
    counting,
    drive,
    is_spd,
    joseph_update,
    kf_predict,
    kf_update,
    nees,
    tally,
)


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


# ------------------------------------------------------------------------------------------------
# The driver (core.drive / core.Stepper) and the health counts
# ------------------------------------------------------------------------------------------------
class _CountingFilter:
    """x' = x + u dt (u defaults to 1); update replaces the mean and tallies one rejection per
    negative entry; every predict tallies one covariance repair."""

    def predict(self, belief, dt, u=None):
        tally(covariance_repairs=1)
        return Gaussian(belief.mean + dt * (1.0 if u is None else u), belief.cov)

    def update(self, belief, z):
        tally(rejected_measurements=int((z < 0).sum()))
        return Gaussian(np.asarray(z, float), belief.cov)


def test_drive_predicts_to_each_epoch_then_updates_and_records_health():
    prior = Gaussian(np.zeros(1), np.eye(1))
    epochs = [Epoch(0.0, np.array([5.0])),                    # at the prior's time: no predict
              Epoch(0.5, None),                               # predict over 0.5 s only
              Epoch(2.0, np.array([-1.0])),                   # predict over 1.5 s, then update
              Epoch(3.0, None, [(0.25, 2.0), (0.75, 4.0)])]   # explicit controls
    tr = drive(_CountingFilter(), prior, epochs)
    assert tr.t.tolist() == [0.0, 0.5, 2.0, 3.0]
    assert tr.mean[:, 0].tolist() == [5.0, 5.5, -1.0, -1.0 + 0.5 + 3.0]
    assert tr.covariance_repairs.tolist() == [0, 1, 1, 2]
    assert tr.rejected_measurements.tolist() == [0, 0, 1, 0]
    assert tr.nonconverged_iterations.tolist() == [0, 0, 0, 0]
    assert tr.cov.shape == (4, 1, 1) and np.all(tr.predict_s >= 0) and np.all(tr.update_s >= 0)


def test_stepper_is_incremental_and_refuses_an_epoch_from_the_past():
    prior = Gaussian(np.zeros(1), np.eye(1))
    st = Stepper(_CountingFilter(), prior, t0=1.0)
    st.step(Epoch(2.0, None))
    assert st.t == 2.0 and st.belief.mean[0] == 1.0
    with pytest.raises(ValueError, match="earlier"):
        st.step(Epoch(1.5, None))
    assert len(st.track().beliefs) == 1


def test_tally_outside_the_driver_does_nothing_and_counting_isolates_steps():
    tally(covariance_repairs=3)  # no step in progress: ignored, no error
    with counting() as outer:
        tally(rejected_measurements=2)
        with counting() as inner:
            tally(rejected_measurements=5)
        assert inner.rejected_measurements == 5
    assert outer.rejected_measurements == 2


def test_lapack_cholesky_helpers_solve_like_scipy():
    rng = np.random.default_rng(4)
    A = rng.normal(size=(6, 6))
    S = A @ A.T + 6 * np.eye(6)
    b = rng.normal(size=(6, 2))
    U = cholesky_upper(S)
    np.testing.assert_allclose(U.T @ U, S, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(cho_solve_upper(U, b), np.linalg.solve(S, b), rtol=1e-10)
    np.testing.assert_allclose(np.triu(cho_inverse_upper(U)), np.triu(np.linalg.inv(S)), rtol=1e-10, atol=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        cholesky_upper(-S)
