"""Seed 004 filter family (EKF, CKF, HCKF, MCKF, RHCF) and the INS + vision relative-navigation model.

Statistical tolerances come from the sample sizes (see each test's docstring); nothing is tuned.
"""
import warnings

import numpy as np
import pytest
from scipy.stats import chi2

from estimators.core import Epoch, Gaussian, chi2_interval, counting, drive, is_spd, kf_predict, kf_update, nees
from estimators.cubature import fifth_degree_rule
from estimators.sigma_filters import (
    CubaturePredict, LinearGaussianModel, LinearMeasurement, ManifoldGaussian, SpdRepairWarning,
    correntropy_solve, ensure_spd, make_ekf, make_filter, make_mckf, make_rhcf,
)
from estimators.so3 import quat_exp, quat_to_rotmat
from estimators.visnav import CameraFilter, CameraFrame, ImuNoise, RelNavModel, VisNavConfig, make_state
from testbed.synthetic import visnav as syn

FILTERS = ("ekf", "ckf", "hckf", "mckf", "rhcf")
WIDE = 1e8      # kernel width (whitened units) for which the correntropy weights are 1 - O(1e-15)


# --------------------------------------------------------------------------------------------
# Linear-Gaussian model: every filter is the Kalman filter
# --------------------------------------------------------------------------------------------
def _random_linear(rng, n=6, m=3):
    A = np.eye(n) + 0.3 * rng.normal(size=(n, n))
    Lq = 0.2 * rng.normal(size=(n, n))
    Q = Lq @ Lq.T + 0.01 * np.eye(n)
    H = rng.normal(size=(m, n))
    Lr = 0.3 * rng.normal(size=(m, m))
    R = Lr @ Lr.T + 0.05 * np.eye(m)
    return A, Q, H, R


@pytest.mark.parametrize("name", FILTERS)
def test_every_filter_equals_the_kalman_filter_on_a_linear_gaussian_model(name):
    """n = 6 > 4, so the fifth-degree rule has negative weights: still exact for a linear model."""
    rng = np.random.default_rng(4)
    A, Q, H, R = _random_linear(rng)
    B = rng.normal(size=(6, 2))
    model = LinearGaussianModel(A, Q, B)
    opts = {"kernel_sigma": WIDE} if name in ("mckf", "rhcf") else {}
    filt = make_filter(name, model, **opts)
    P0 = np.diag(rng.uniform(0.5, 2.0, 6))
    kf = Gaussian(rng.normal(size=6), P0)
    b = Gaussian(kf.mean.copy(), P0.copy())
    with warnings.catch_warnings():
        warnings.simplefilter("error", SpdRepairWarning)
        for _ in range(12):
            u = rng.normal(size=2)
            kf = kf_predict(kf, A, Q, B @ u)
            b = filt.predict(b, 0.1, u)
            np.testing.assert_allclose(b.mean, kf.mean, rtol=0, atol=1e-9)
            np.testing.assert_allclose(b.cov, kf.cov, rtol=0, atol=1e-9)
            z = rng.normal(size=3) * 3
            kf = kf_update(kf, z, H, R)
            b = filt.update(b, LinearMeasurement(z, H, R))
            np.testing.assert_allclose(b.mean, kf.mean, rtol=0, atol=1e-9)
            np.testing.assert_allclose(b.cov, kf.cov, rtol=0, atol=1e-9)
            assert is_spd(b.cov)


# --------------------------------------------------------------------------------------------
# Maximum correntropy update
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("covariance", ["joseph", "information"])
def test_correntropy_with_a_wide_kernel_is_the_kalman_update(covariance):
    rng = np.random.default_rng(7)
    _, _, H, R = _random_linear(rng)
    P = np.diag(rng.uniform(0.5, 2.0, 6))
    x = rng.normal(size=6)
    z = H @ x + 5 * rng.normal(size=3)
    kf = kf_update(Gaussian(x, P), z, H, R)
    sol = correntropy_solve(P, H, R, z - H @ x, kernel_sigma=WIDE, covariance=covariance)
    assert sol.converged and sol.iterations <= 2
    np.testing.assert_allclose(x + sol.dx, kf.mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sol.P, kf.cov, rtol=0, atol=1e-12)


def test_correntropy_fixed_point_maximizes_the_criterion():
    """At the converged dx, dJ/ddx = 0 for J(dx) = sum_i exp(-e_i^2 / 2 s^2), e = z - M dx (eq. 38-45).

    Checked by central differences of J itself, independently of the psi derivation. The residual
    gradient is bounded by the stop (whitened step <= tol) times the curvature of J."""
    rng = np.random.default_rng(11)
    H = rng.normal(size=(3, 6))
    R = np.diag([0.1, 0.2, 0.15]) ** 2
    P = np.diag(rng.uniform(0.5, 2.0, 6)) * 0.01       # prior std ~ 0.1: the outlier cannot be explained
    dx_true = np.linalg.cholesky(P) @ rng.normal(size=6)
    r = H @ dx_true + np.sqrt(np.diag(R)) * rng.normal(size=3) + np.array([0.0, 6.0, 0.0])   # gross outlier on row 1
    s = 2.0
    sol = correntropy_solve(P, H, R, r, kernel_sigma=s, tol=1e-12, max_iter=500)
    assert sol.converged
    Lp, Lr = np.linalg.cholesky(P), np.linalg.cholesky(R)

    def J(dx):
        e = np.concatenate([np.linalg.solve(Lr, r - H @ dx), -np.linalg.solve(Lp, dx)])
        return np.exp(-0.5 * (e / s) ** 2).sum()

    eps = 1e-6
    grad = np.array([(J(sol.dx + eps * e) - J(sol.dx - eps * e)) / (2 * eps) for e in np.eye(6)])
    assert np.abs(grad).max() < 1e-7
    # the outlier row was down-weighted, the others were not
    assert sol.psi[1] < 1e-3 and sol.psi[0] > 0.5 and sol.psi[2] > 0.5


def _cv_model(dt=0.1, q=0.05):
    A = np.block([[np.eye(2), dt * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
    Q = q * np.block([[dt ** 3 / 3 * np.eye(2), dt ** 2 / 2 * np.eye(2)],
                      [dt ** 2 / 2 * np.eye(2), dt * np.eye(2)]])
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    return A, Q, H


def test_mckf_beats_the_kalman_filter_with_outliers():
    """Constant-velocity target, position measurements, 10 % of samples drawn with 10 x the std.

    Same data for both filters; d_k = |e_KF,k|^2 - |e_MCKF,k|^2. Errors are autocorrelated, so the
    mean of d is judged by batch means: 40 batches of 100 steps (batches much longer than the
    filter's memory are nearly independent), t = mean / (std / sqrt(40)); MCKF must win with
    t > 4 (one-sided p < 1e-4 under the null 'no difference')."""
    rng = np.random.default_rng(2017)
    A, Q, H = _cv_model()
    r = 0.5
    R = r ** 2 * np.eye(2)
    T = 4000
    Lq = np.linalg.cholesky(Q)
    x = np.zeros(4)
    model = LinearGaussianModel(A, Q)
    mckf = make_mckf(model, kernel_sigma=3.0)
    P0 = np.diag([1.0, 1.0, 0.1, 0.1])
    kf = Gaussian(x + rng.multivariate_normal(np.zeros(4), P0), P0)
    mc = Gaussian(kf.mean.copy(), P0.copy())
    d = np.empty(T)
    for k in range(T):
        x = A @ x + Lq @ rng.normal(size=4)
        scale = np.where(rng.random(2) < 0.1, 10.0, 1.0)
        z = H @ x + r * scale * rng.normal(size=2)
        kf = kf_update(kf_predict(kf, A, Q), z, H, R)
        mc = mckf.update(mckf.predict(mc, 0.1), LinearMeasurement(z, H, R))
        d[k] = np.sum((kf.mean - x)[:2] ** 2) - np.sum((mc.mean - x)[:2] ** 2)
    batches = d.reshape(40, 100).mean(axis=1)
    t = batches.mean() / (batches.std(ddof=1) / np.sqrt(batches.size))
    assert t > 4.0, f"t = {t:.2f}"


# --------------------------------------------------------------------------------------------
# HCKF: keeping the covariance SPD with negative weights
# --------------------------------------------------------------------------------------------
class _QuarticModel(LinearGaussianModel):
    """x' = x + c e_0 x_0^4: the fifth-degree rule's negative axis weights make sum w D D^T
    indefinite for n = 10 (its E[x0^8] estimate is far off)."""

    def f(self, X, u, dt):
        out = X.copy()
        out[:, 0] = X[:, 0] + 0.5 * X[:, 0] ** 4
        return out


def test_hckf_predicted_covariance_is_repaired_to_spd():
    n = 10
    model = _QuarticModel(np.eye(n), 1e-6 * np.eye(n))
    b = Gaussian(np.zeros(n), np.eye(n))
    rule = fifth_degree_rule(n)
    X = b.mean + (np.linalg.cholesky(b.cov) @ rule.points).T
    Y = model.f(X, None, 0.0)
    D = Y - rule.weights @ Y
    raw = D.T @ (rule.weights[:, None] * D) + model.Qd
    assert np.linalg.eigvalsh(raw).min() < -1.0          # the raw fifth-degree covariance is indefinite
    with pytest.warns(SpdRepairWarning):
        out = CubaturePredict(fifth_degree_rule)(model, b, None, 0.0)
    assert is_spd(out.cov)
    # the repair keeps the untouched states' variances
    np.testing.assert_allclose(np.diag(out.cov)[1:], np.diag(raw)[1:], rtol=1e-9)


def test_ensure_spd_leaves_spd_matrices_alone():
    rng = np.random.default_rng(3)
    L = rng.normal(size=(5, 5))
    P = L @ L.T + np.diag([1e-13, 1e-12, 1.0, 10.0, 1e3])     # mixed scales, as in visnav
    with warnings.catch_warnings():
        warnings.simplefilter("error", SpdRepairWarning)
        np.testing.assert_array_equal(ensure_spd(P), 0.5 * (P + P.T))


# --------------------------------------------------------------------------------------------
# Relative-navigation model: Jacobians and dynamics
# --------------------------------------------------------------------------------------------
def _random_visnav(rng):
    cfg = VisNavConfig(
        cam_pos=[0.2, -0.1, 0.05], cam_rot=quat_to_rotmat(quat_exp(np.array([0.1, -1.5, 0.2]))),
        led_pos=rng.normal(size=(5, 3)),
        imu_leader=ImuNoise(Kg=0.01 * rng.normal(size=(3, 3)), Ka=0.01 * rng.normal(size=(3, 3))),
        imu_follower=ImuNoise(Kg=0.01 * rng.normal(size=(3, 3)), Ka=0.01 * rng.normal(size=(3, 3))))
    model = RelNavModel(cfg)
    x = make_state(rng.normal(size=3) * 3 + [0, 0, -6], rng.normal(size=3), quat_exp(rng.normal(size=3)),
                   *(0.05 * rng.normal(size=3) for _ in range(4)))
    return model, x


def _numeric_jacobian(fun, model, x, eps=1e-6):
    """Central differences through the retraction: column j = fun(x (+) eps e_j, x (+) -eps e_j) / 2 eps,
    fun taking the difference (with (-) where the output is on the manifold)."""
    cols = []
    for e in np.eye(model.dim):
        cols.append(fun(model.boxplus(x[None], eps * e[None]), model.boxplus(x[None], -eps * e[None])) / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_process_jacobian_matches_central_differences(seed):
    """Truncation error ~ eps^2 |f'''| ~ 1e-11, round-off ~ 1e-16 |x| / eps ~ 1e-9: tolerance 1e-7."""
    rng = np.random.default_rng(seed)
    model, x = _random_visnav(rng)
    u, dt = rng.normal(size=12), 0.3           # a long step so that every term is visible
    Fn = _numeric_jacobian(lambda a, b: model.boxminus(model.f(a, u, dt), model.f(b, u, dt))[0], model, x)
    np.testing.assert_allclose(model.F(x, u, dt), Fn, rtol=0, atol=1e-7)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_measurement_jacobians_match_central_differences(seed):
    rng = np.random.default_rng(seed)
    model, x = _random_visnav(rng)
    leds = np.array([0, 2, 3])
    for meas in (model.los_measurement(x, model.los(x[None], leds)[0], leds),
                 model.focal_measurement(x, model.focal(x[None], leds)[0], leds)):
        H = meas.jacobian(x)
        Hn = _numeric_jacobian(lambda a, b: (meas.h(a) - meas.h(b))[0], model, x)
        assert H.shape == (6, 21)
        np.testing.assert_allclose(H, Hn, rtol=0, atol=1e-7 * max(1.0, np.abs(H).max()))


def test_manifold_retraction_and_process_noise():
    rng = np.random.default_rng(5)
    model, x = _random_visnav(rng)
    dX = 0.4 * rng.normal(size=(7, 21))
    X = model.boxplus(np.tile(x, (7, 1)), dX)
    np.testing.assert_allclose(model.boxminus(X, np.tile(x, (7, 1))), dX, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(X[:, 6:10], axis=1), 1.0, atol=1e-14)
    Qm = model.Q(x, rng.normal(size=12), 0.02)
    assert np.allclose(Qm, Qm.T) and np.linalg.eigvalsh(Qm).min() >= -1e-30
    # tangent-plane LOS noise is sigma^2 I_2 per LED, QUEST's sigma^2 (I - b b^T) projected
    meas = model.los_measurement(x, model.los(x[None])[0])
    np.testing.assert_allclose(meas.R, model.config.los_sigma ** 2 * np.eye(10))
    np.testing.assert_allclose(meas.y, meas.h(x[None])[0], atol=1e-15)
    np.testing.assert_allclose(meas.y, 0.0, atol=1e-15)


def test_dead_reckoning_with_a_perfect_imu_converges_at_second_order():
    """Propagate the exact initial state with error-free IMU readings of both vehicles over 10 s.

    Checks the relative dynamics (gravity cancels, leader rotation terms) against the world-frame
    truth of the synthetic generator: the error is the discretization error, O(dt^2) globally, so
    halving dt must divide it by about 4 (accepted 3..5)."""
    def final_error(dt):
        config = _noiseless_config()
        run = syn.simulate(0, duration=10.0, dt=dt, config=config)
        model = RelNavModel(config)
        x = run.truth[0].copy()
        for k in range(run.inputs.shape[0]):
            x = model.f(x[None], run.inputs[k], dt)[0]
        e = model.boxminus(x[None], run.truth[-1][None])[0]
        return np.linalg.norm(e[0:3]), np.linalg.norm(e[3:6]), np.linalg.norm(e[6:9])

    e1, e2 = np.array(final_error(0.05)), np.array(final_error(0.025))
    assert e1[0] < 2e-3 and e1[2] < 1e-5       # metres after 10 s; rad
    ratio = e1 / e2
    assert np.all((ratio > 3.0) & (ratio < 5.0)), ratio


def _noiseless_config():
    quiet = ImuNoise(gyro_noise=0.0, accel_noise=0.0, gyro_bias_sigma=0.0, accel_bias_sigma=0.0)
    return VisNavConfig(cam_pos=syn.CAM_POS, cam_rot=syn.CAM_ROT, led_pos=syn.LEDS,
                        imu_leader=quiet, imu_follower=quiet)


# --------------------------------------------------------------------------------------------
# Seeded synthetic Monte Carlo (paper's sensor values)
# --------------------------------------------------------------------------------------------
MC_DURATION, MC_DT, MC_CAM_EVERY = 10.0, 0.05, 2     # 20 Hz IMU, 10 Hz camera, 100 frames per run


def _run_filter(name, run, model):
    """The filter through the library's driver (core.drive), one epoch per camera frame."""
    steps = np.concatenate([[0], run.cam_steps])
    epochs = [Epoch(float(steps[j + 1] * run.dt), CameraFrame(None, run.b_meas[j], None),
                    [(run.dt, run.inputs[k]) for k in range(steps[j], steps[j + 1])])
              for j in range(run.cam_steps.size)]
    track = drive(CameraFilter(make_filter(name, model)), ManifoldGaussian(run.mean0, run.cov0), epochs, t0=0.0)
    e = model.boxminus(run.truth[run.cam_steps], track.mean)
    return nees(e, track.cov), np.linalg.norm(e[:, 0:3], axis=1)


@pytest.fixture(scope="module")
def gaussian_mc():
    runs = [syn.simulate(400 + s, duration=MC_DURATION, dt=MC_DT, cam_every=MC_CAM_EVERY) for s in range(5)]
    model = RelNavModel(syn.default_config())
    return {name: [_run_filter(name, run, model) for run in runs] for name in FILTERS}


@pytest.mark.slow  # gaussian_mc: 5 runs through every filter, ~20 s
@pytest.mark.parametrize("name", FILTERS)
def test_gaussian_monte_carlo_anees_is_consistent(gaussian_mc, name):
    """5 runs x 100 camera frames, 21-dim error state (biases of both IMUs included).

    Per run the NEES is averaged over the frames, then over the runs. A consistent filter's
    per-frame NEES ~ chi2(21); a time average has the same mean and no more variance than one
    sample, so core.chi2_interval(21, 5, 0.99) = [14.3, 29.2] (0.99 two-sided, independent runs)
    is a conservative acceptance interval for the ANEES."""
    results = gaussian_mc[name]
    per_run = np.array([ne.mean() for ne, _ in results])
    assert np.all(np.isfinite(per_run))
    anees = per_run.mean()
    lo, hi = chi2_interval(21, len(results), 0.99)
    assert lo < anees < hi, f"{name}: ANEES {anees:.2f} outside [{lo:.2f}, {hi:.2f}]"


@pytest.mark.parametrize("name", FILTERS)
def test_gaussian_monte_carlo_no_divergence(gaussian_mc, name):
    """Diverged = final NEES above the chi2(21) 1 - 1e-6 quantile, or a final position error not
    below the initial 0.3 m std."""
    for ne, pe in gaussian_mc[name]:
        assert ne[-1] < chi2.ppf(1 - 1e-6, 21)
        assert pe[-1] < 0.3


@pytest.fixture(scope="module")
def glint_mc():
    runs = [syn.simulate(900 + s, duration=MC_DURATION, dt=MC_DT, cam_every=MC_CAM_EVERY, glint=True)
            for s in range(3)]
    model = RelNavModel(syn.default_config())
    return {name: [_run_filter(name, run, model) for run in runs] for name in FILTERS}


@pytest.mark.parametrize("name", FILTERS)
def test_glint_monte_carlo_no_divergence(glint_mc, name):
    """Glint (10 % of LOS samples at 5 x std): no filter diverges. The Kalman-type filters are
    overconfident by design here (their R is the nominal one), so only finiteness, error
    reduction from the 0.3 m prior and a loose NEES bound (the nominal-vs-true variance ratio
    0.9 + 0.1 * 25 = 3.4 times the chi2(21) 1 - 1e-6 quantile) are required."""
    for ne, pe in glint_mc[name]:
        assert np.all(np.isfinite(ne)) and np.all(np.isfinite(pe))
        assert pe[-1] < 0.3
        assert ne[-1] < 3.4 * chi2.ppf(1 - 1e-6, 21)


def test_repairs_and_unconverged_correntropy_updates_are_counted():
    """Health counts (core.tally): an indefinite covariance repaired by ensure_spd is one
    covariance repair; a correntropy update stopped at max_iter = 1 on an outlier is one
    non-converged iteration, and the driver records both per epoch."""
    with counting() as h, warnings.catch_warnings():
        warnings.simplefilter("ignore", SpdRepairWarning)
        ensure_spd(np.array([[1.0, 2.0], [2.0, 1.0]]))
        ensure_spd(np.eye(2))
    assert h.covariance_repairs == 1
    model = LinearGaussianModel(np.eye(2), 0.01 * np.eye(2))
    H, R = np.eye(2), 0.01 * np.eye(2)
    prior = Gaussian(np.zeros(2), np.eye(2))
    z_out, z_ok = np.array([30.0, 0.0]), np.array([0.01, -0.02])
    epochs = [Epoch(0.0, LinearMeasurement(z_ok, H, R)), Epoch(0.1, LinearMeasurement(z_out, H, R))]
    one = drive(make_mckf(model, max_iter=1, kernel_sigma=1.0), prior, epochs)
    many = drive(make_mckf(model, max_iter=50, kernel_sigma=1.0), prior, epochs)
    assert one.nonconverged_iterations.tolist() == [0, 1]
    assert many.nonconverged_iterations.tolist() == [0, 0]


def test_correntropy_fixed_point_failure_falls_back_to_the_kalman_update():
    """A diverged prior (N(0, I)) meets three exact, accurate rows (R = 1e-6 I) that place the
    state 360 sigma away: the correntropy weights of the prior hit their floor, H P~ H^T + R~ is
    indefinite to round-off and the fixed point raised LinAlgError (the run stopped). Now the step
    falls back to the plain Kalman update (the fixed point's start, eq. 47) and is counted as one
    fallback and one non-converged iteration, for MCKF and RHCF alike."""
    H, R = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]), 1e-6 * np.eye(3)
    x_true = np.array([300.0, -200.0])
    with pytest.raises(np.linalg.LinAlgError):
        correntropy_solve(np.eye(2), H, R, H @ x_true, kernel_sigma=3.0)
    model = LinearGaussianModel(np.eye(2), 0.01 * np.eye(2))
    prior = Gaussian(np.zeros(2), np.eye(2))
    epochs = [Epoch(0.0, LinearMeasurement(H @ x_true, H, R))]
    kalman = drive(make_ekf(model), prior, epochs).beliefs[0]
    for make in (make_mckf, make_rhcf):
        track = drive(make(model), prior, epochs)
        assert track.fallback_updates.tolist() == [1] and track.nonconverged_iterations.tolist() == [1]
        assert track.health()["nonconverged_steps"] == 1
        b = track.beliefs[0]
        assert np.allclose(b.mean, kalman.mean, rtol=1e-9, atol=1e-9) and np.allclose(b.cov, kalman.cov, rtol=1e-6)
        assert np.allclose(b.mean, x_true, atol=1e-2)  # the plain update takes the accurate rows
