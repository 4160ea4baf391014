"""Seed 001: consistency of the centralized estimator under the two-way ranging error model.

The UWB sensor's ranges carry per-device errors (antenna delay, clock offset; testbed.sensors.uwb)
that every link of a radio shares. These tests draw ranges from that model on synthetic 18-UAV
epochs (no physics, seconds) and score the coop-fg pipeline's centralized estimator with the
coop-fg scenario's known model. Tolerances: chi-square intervals at the stated sample sizes
(epochs with fresh per-device draws are independent), Monte Carlo covariances with their
sampling error; nothing is tuned until green.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import block_diag
from scipy.stats import chi2

from estimators.core import nees
from estimators.factor_graph import CoopProblem, solve_centralized
from testbed.scoring.metrics import anees_interval, anees_run_interval
from testbed.plugins import builtin_coop as coop
from testbed.config.scenario import load
from estimators.sensor_models import twr_range_covariance, twr_range_variance
from testbed.sensors.noise import twr_range
from testbed.synthetic.coop import make_epoch

N, DOF = 18, 54


def _setup():
    """The coop-fg scenario (known model = sensor model) and its geometry: the 18 UAVs at their
    base points (the scenario's 69 links within 100 m)."""
    sc = load("coop-fg")
    truth = np.array(sc.trajectory.bases, float)
    is_rtk = np.zeros(N, bool)
    is_rtk[[r - 1 for r in sc.trajectory.rtk]] = True  # 1-based UAV numbers
    iu, ju = np.triu_indices(N, 1)
    d = np.linalg.norm(truth[iu] - truth[ju], axis=1)
    edges = np.stack([iu, ju], axis=1)[d <= sc.sensors.uwb.max_range]
    return sc, truth, is_rtk, edges


def _joint_nees(sc, truth, is_rtk, edges, rng, ppm, delay, *, correlated: bool = True) -> float:
    """Centralized joint NEES (54 dof) of one epoch: GNSS white with the known covariance, ranges
    twr(d, k_src, k_dst) + b_src + b_dst + white (the sensor's model, testbed.sensors.uwb) with the
    per-device clock offsets ppm (N,) and antenna delays delay (N,) m. correlated False: the
    estimator treats the ranges as independent (their marginal sigma only)."""
    cfg, u = sc.pipeline, sc.sensors.uwb
    Sg = coop.gnss_covariances(cfg, is_rtk)
    z = truth + (np.linalg.cholesky(Sg) @ rng.standard_normal((N, 3, 1)))[..., 0]
    i, j = edges[:, 0], edges[:, 1]
    d = np.linalg.norm(truth[i] - truth[j], axis=1)
    y = twr_range(u.mode, d, ppm[i], ppm[j], u.reply_time) + delay[i] + delay[j] + u.noise * rng.standard_normal(d.size)
    prob = coop.epoch_problem(cfg, z, Sg, edges, y)
    if not correlated:
        prob = CoopProblem(gnss_pos=z, gnss_cov=Sg, edges=edges, ranges=y, range_sigma=prob.range_sigma)
    res = solve_centralized(prob, covariance="full")
    return float(nees((res.positions - truth).reshape(-1), res.cov_full))


def _device_draws(sc, rng):
    u = sc.sensors.uwb
    return u.clock_ppm * rng.standard_normal(N), u.antenna_delay_sigma * rng.standard_normal(N)


def test_centralized_consistent_with_per_device_ranging_errors():
    """K = 300 independent epochs (fresh clocks and delays each): the pipeline's centralized
    joint ANEES lies in the 99 % chi-square interval of 54 dof. Treating the ranges as
    independent (each with its full marginal variance, the model before the fix) is over-confident:
    the links of one radio share its delay, and that ANEES lies above the same interval (it
    measured 55.85 over 20 x 300 s physics runs)."""
    sc, truth, is_rtk, edges = _setup()
    K = 300
    lo, hi = anees_interval(DOF, K)
    got = {}
    for correlated in (True, False):
        rng = np.random.default_rng(11)
        got[correlated] = np.mean([_joint_nees(sc, truth, is_rtk, edges, rng, *_device_draws(sc, rng), correlated=correlated)
                                   for _ in range(K)])
    assert lo <= got[True] <= hi, (got, lo, hi)
    assert got[False] > hi, (got, lo, hi)


def test_constant_device_errors_make_epochs_dependent():
    """With the clocks and delays constant over a run (as in the sensor), the epochs of a run are
    dependent. On the linearised seed 001 problem (error = P H^T S^-1 v at the truth, S the known
    covariance with the joint range covariance: consistent by construction, exact and fast), R = 60
    runs of K = 100 epochs: the per-run ANEES spread far more than independent epochs allow,
    (R - 1) s^2 / (2 dof / K) above the chi-square(R - 1) 0.999 quantile, while their mean lies in
    the interval anees_run_interval derives from that spread (the one the reproduction uses)."""
    sc, truth, is_rtk, edges = _setup()
    cfg, u = sc.pipeline, sc.sensors.uwb
    i, j = edges[:, 0], edges[:, 1]
    d = np.linalg.norm(truth[i] - truth[j], axis=1)
    m = d.size
    H = np.zeros((3 * N + m, 3 * N))
    H[:3 * N] = np.eye(3 * N)
    unit = (truth[i] - truth[j]) / d[:, None]
    for c in range(3):
        H[3 * N + np.arange(m), 3 * i + c], H[3 * N + np.arange(m), 3 * j + c] = unit[:, c], -unit[:, c]
    S = block_diag(*coop.gnss_covariances(cfg, is_rtk), coop.range_covariance(cfg, edges, d))
    info = H.T @ np.linalg.solve(S, H)
    gain = np.linalg.solve(info, np.linalg.solve(S, H).T)  # P H^T S^-1 (3N, 3N + m)
    R, K = 60, 100
    rng = np.random.default_rng(12)
    sg = np.sqrt(np.diagonal(coop.gnss_covariances(cfg, is_rtk), axis1=1, axis2=2)).reshape(-1)  # diagonal
    per_run = np.empty(R)
    for r in range(R):
        ppm, delay = _device_draws(sc, rng)
        rng_err = twr_range(u.mode, d, ppm[i], ppm[j], u.reply_time) - d + delay[i] + delay[j]
        v = np.concatenate([sg * rng.standard_normal((K, 3 * N)), rng_err + u.noise * rng.standard_normal((K, m))], axis=1)
        e = v @ gain.T  # (K, 3N)
        per_run[r] = np.mean(np.einsum("ka,ab,kb->k", e, info, e))
    ratio = (R - 1) * per_run.var(ddof=1) / (2 * DOF / K)
    assert ratio > chi2.ppf(0.999, R - 1), (ratio, per_run)
    lo, hi = anees_run_interval(per_run, DOF)
    assert lo <= per_run.mean() <= hi, (lo, per_run.mean(), hi)


def test_anees_run_interval():
    """dof -+ t(0.995, R - 1) s / sqrt(R); refuses a single run."""
    x = np.array([50.0, 52.0, 57.0, 55.0])
    lo, hi = anees_run_interval(x, 54)
    h = 5.840909309733349 * x.std(ddof=1) / 2.0  # t(0.995, 3)
    assert (lo, hi) == pytest.approx((54 - h, 54 + h), rel=1e-12)
    with pytest.raises(ValueError):
        anees_run_interval(x[:1], 54)


@pytest.mark.parametrize("mode", ["scale", "ss-twr", "ds-twr"])
def test_twr_range_covariance_matches_monte_carlo(mode):
    """Three links 0-1, 0-2, 1-2 over n = 20000 draws of the three devices' clocks and delays: the
    sample covariance matches twr_range_covariance entry by entry within 5 standard errors
    (se of a covariance estimate: sqrt((C_aa C_bb + C_ab^2) / n)); its diagonal is
    twr_range_variance."""
    n, ppm, reply, sad = 20000, 20.0, 330e-6, 0.035
    rng = np.random.default_rng(3)
    src, dst, d = np.array([0, 0, 1]), np.array([1, 2, 2]), np.array([80.0, 40.0, 95.0])
    k, b = ppm * rng.standard_normal((n, 3)), sad * rng.standard_normal((n, 3))
    err = twr_range(mode, d, k[:, src], k[:, dst], reply) - d + b[:, src] + b[:, dst]  # (n, 3)
    C = twr_range_covariance(mode, d, src, dst, ppm, reply, sad)
    assert np.diagonal(C) == pytest.approx(twr_range_variance(mode, d, ppm, reply, sad), rel=1e-12)
    S = err.T @ err / n
    se = np.sqrt((np.outer(np.diagonal(C), np.diagonal(C)) + C ** 2) / n)
    assert np.all(np.abs(S - C) < 5 * se), (S, C)
    if mode != "ss-twr":  # (SS-TWR: a device's reply-time term changes sign between initiator and responder)
        assert C[0, 1] > 0 and C[0, 2] > 0 and C[1, 2] > 0  # links that share a radio share its errors


def test_coop_problem_range_cov():
    """A diagonal range_cov gives the independent-range solution; a range_cov whose diagonal is
    not range_sigma^2, or with a robust loss, is refused."""
    ep = make_epoch(seed=4)
    p = ep.problem
    diag = CoopProblem(gnss_pos=p.gnss_pos, gnss_cov=p.gnss_cov, edges=p.edges, ranges=p.ranges,
                       range_sigma=p.range_sigma, range_cov=np.diag(p.range_sigma ** 2))
    a, b = solve_centralized(p, covariance="full"), solve_centralized(diag, covariance="full")
    assert np.abs(a.positions - b.positions).max() < 1e-9
    assert np.abs(a.cov_full - b.cov_full).max() < 1e-9 * np.abs(a.cov_full).max()
    with pytest.raises(ValueError, match="diagonal"):
        CoopProblem(gnss_pos=p.gnss_pos, gnss_cov=p.gnss_cov, edges=p.edges, ranges=p.ranges,
                    range_sigma=p.range_sigma, range_cov=np.diag(2 * p.range_sigma ** 2))
    with pytest.raises(ValueError):
        solve_centralized(diag, huber=1.345)
    assert math.isfinite(b.cost)
