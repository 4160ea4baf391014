"""The general seed 001 solver (issue #16 section 2, #15 item 5): Levenberg-Marquardt with a
convergence test and an iteration cap, fixed nodes and optional priors with a gauge check,
co-located initial guesses, robust losses per factor type (IRLS), warm starts, GTSAM agreement.

Statistical assertions are sign tests (binomial under H0: p = 1/2, alpha = 1e-3).
"""
import dataclasses
import warnings

import numpy as np
import pytest
from scipy.stats import binom

from testbed.synthetic.coop import make_epoch, nlos_epoch
from estimators import factor_graph as fg
from estimators.factor_graph import CoopProblem, GaugeWarning, Loss, cost, range_jacobian, solve_centralized, solve_distributed
from estimators.graph.losses import loss_rho, loss_weight

gtsam_reference = pytest.importorskip("estimators.gtsam_reference")


def _sign_test_min(k: int, alpha: float = 1e-3) -> int:
    """Fewest successes of k that reject P(success) = 1/2 at level alpha (one-sided)."""
    return int(binom.isf(alpha, k, 0.5)) + 1


def _anchored(ep, anchors, *, prior=False) -> CoopProblem:
    """The epoch with nodes `anchors` fixed at their true positions and (prior=False) no GNSS
    factor on any other node: a range-only network."""
    n = ep.problem.n
    fixed = np.zeros(n, bool)
    fixed[list(anchors)] = True
    z = ep.problem.gnss_pos.copy()
    z[fixed] = ep.truth[fixed]
    return dataclasses.replace(ep.problem, gnss_pos=z, fixed=fixed, prior=np.full(n, prior))


# ------------------------------------------------------------------------------------ losses
@pytest.mark.parametrize("kind,scale", [("huber", 1.345), ("cauchy", 2.385)])
def test_irls_weight_is_rho_prime_over_s(kind, scale):
    loss = Loss(kind=kind, scale=scale)
    s = np.linspace(0.01, 8.0, 200)
    h = 1e-6
    drho = (loss_rho(loss, s + h) - loss_rho(loss, s - h)) / (2 * h)
    np.testing.assert_allclose(loss_weight(loss, s), drho / s, rtol=1e-6)
    np.testing.assert_allclose(loss_rho(None, s), 0.5 * s * s)
    with pytest.raises(ValueError, match="kind"):
        Loss(kind="tukey")


# ------------------------------------------------------------------------------------- LM / GN
def test_lm_reaches_the_gauss_newton_optimum_and_reports():
    for seed in (1, 2, 3):
        p = make_epoch(18, seed=seed).problem
        gn = solve_centralized(p)
        lm = solve_centralized(p, method="lm")
        assert lm.converged and lm.method == "lm" and lm.observable and lm.iterations >= 1
        assert lm.cost == pytest.approx(gn.cost, rel=1e-10)
        np.testing.assert_allclose(lm.positions, gn.positions, atol=1e-6)
        np.testing.assert_allclose(lm.cov, gn.cov, rtol=1e-5, atol=1e-12)


def test_iteration_cap_is_a_result_not_an_exception():
    p = make_epoch(18, seed=2).problem
    x0 = p.gnss_pos + np.random.default_rng(0).normal(0, 20.0, p.gnss_pos.shape)
    for method in ("gn", "lm"):
        r = solve_centralized(p, x0=x0, method=method, max_iter=1, covariance="none")
        assert not r.converged and r.iterations == 1 and np.isfinite(r.cost)
        assert r.cost < cost(p, x0)


def test_agrees_with_gtsam_to_1e_8_m():
    """Issue #15 item 5: both sides stop on the step, not on the cost (ours: the defaults, a full
    Gauss-Newton step below 1e-10 m; GTSAM: Gauss-Newton with QR driven to a step below 1e-10 m),
    so both reach the optimum and positions agree to <= 1e-8 m, marginals to 1e-9 of each UAV's
    largest entry (testbed.plugins.graph_check.COV_RTOL). Measured on seeds 1-6: <= 2.8e-13 m and
    <= 1.3e-13 relative (GN and LM)."""
    for seed in (1, 2, 3, 4):
        p = make_epoch(18, seed=seed).problem
        Xg, Pg = gtsam_reference.solve_gtsam(p)
        scale = np.abs(Pg).max(axis=(1, 2))[:, None, None]
        for method in ("gn", "lm"):
            ours = solve_centralized(p, method=method)
            assert ours.converged
            assert np.abs(ours.positions - Xg).max() <= 1e-8
            assert np.all(np.abs(ours.cov - Pg) <= 1e-9 * scale)


# ------------------------------------------------------------------- fixed nodes, gauge, priors
def test_fixed_anchors_range_only_network_equals_gtsam():
    """Five fixed anchors (true positions), no GNSS on the other 13 UAVs: observable, the anchors
    stay put with zero covariance, the rest is near the truth and equals GTSAM (anchors held by
    NonlinearEqualityPoint3) to 1e-8 m, marginals to 1e-9 relative: both stop on the step, not on
    the cost (measured 7e-14 m GN, 2e-11 m LM, 2.6e-11 relative)."""
    ep = make_epoch(18, seed=1)
    p = _anchored(ep, [0, 4, 8, 12, 16])
    x0 = ep.truth + np.random.default_rng(1).normal(0, 2.0, ep.truth.shape)
    for method in ("gn", "lm"):
        r = solve_centralized(p, x0=x0, method=method)
        assert r.converged and r.observable
        np.testing.assert_array_equal(r.positions[p.fixed], ep.truth[p.fixed])
        assert np.all(r.cov[p.fixed] == 0.0)
        assert np.abs(r.positions - ep.truth).max() < 1.0
        Xg, Pg = gtsam_reference.solve_gtsam(p, x0=x0)
        assert np.abs(r.positions - Xg).max() <= 1e-8
        free = ~p.fixed
        scale = np.abs(Pg[free]).max(axis=(1, 2))[:, None, None]
        assert np.all(np.abs(r.cov[free] - Pg[free]) <= 1e-9 * scale)


def test_unobservable_problem_warns_and_flags():
    """Ranges only, no prior, no fixed node: translation and rotation are free. Both methods
    return (no exception), flag observable=False, issue a GaugeWarning and give NaN covariances.
    One fixed anchor still leaves the rotation free."""
    ep = make_epoch(18, seed=1)
    for anchors in ([], [3]):
        p = _anchored(ep, anchors)
        for method in ("lm", "gn"):
            with pytest.warns(GaugeWarning):
                r = solve_centralized(p, x0=ep.truth + 0.5, method=method)
            assert not r.observable and np.all(np.isnan(r.cov[~p.fixed]))
            assert np.all(np.isfinite(r.positions))
    with warnings.catch_warnings():
        warnings.simplefilter("error", GaugeWarning)
        assert solve_centralized(_anchored(ep, [3], prior=True), method="lm").observable


def test_general_system_jacobian_matches_central_differences():
    """The general whitened system (fixed nodes dropped, priors on some nodes, Cauchy-weighted
    rows at a fixed weight) has A = -db/dx."""
    ep = make_epoch(10, seed=3)
    p = dataclasses.replace(ep.problem, fixed=np.arange(10) < 2, prior=np.arange(10) % 2 == 0)
    X = ep.truth + 0.3
    A, b = fg._general_system(p, X, {})
    free = ~p.fixed

    def bfun(v):
        Y = X.copy()
        Y[free] = v.reshape(-1, 3)
        return fg._general_system(p, Y, {})[1]

    v0, h = X[free].reshape(-1), 1e-5
    num = np.stack([(bfun(v0 + h * e) - bfun(v0 - h * e)) / (2 * h) for e in np.eye(v0.size)], axis=1)
    np.testing.assert_allclose(A.toarray(), -num, rtol=1e-6, atol=1e-6)


def test_colocated_initial_guesses_do_not_raise():
    """Co-located initial guesses (the range Jacobian is undefined there) get distinct unit
    subgradients. Two UAVs started at one point: LM reaches the optimum found from the GNSS
    fixes. Every UAV started at one point: no exception, a finite result that lowers the cost
    (from there it may end in another local minimum, e.g. a mirror image)."""
    u, v = range_jacobian(np.zeros((4, 3)), np.zeros((4, 3)))
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0)
    np.testing.assert_array_equal(v, -u)
    assert len({tuple(np.round(x, 6)) for x in u}) == 4
    for seed in (5, 6, 7):
        p = make_epoch(18, seed=seed).problem
        ref = solve_centralized(p, method="lm", covariance="none")
        x0 = p.gnss_pos.copy()
        x0[p.edges[0, 1]] = x0[p.edges[0, 0]]
        r = solve_centralized(p, x0=x0, method="lm", covariance="none", max_iter=200)
        assert r.converged
        np.testing.assert_allclose(r.positions, ref.positions, atol=1e-6)  # measured <= 2.3e-8 m
    x0 = np.tile(p.gnss_pos.mean(axis=0), (p.n, 1))
    A, b = fg.whitened_system(p, x0)
    assert np.all(np.isfinite(A.data)) and np.all(np.isfinite(b))
    for method in ("gn", "lm"):
        r = solve_centralized(p, x0=x0, method=method, covariance="none", max_iter=200)
        assert np.all(np.isfinite(r.positions)) and r.cost < cost(p, x0)
    d = solve_distributed(p, x0=x0, max_rounds=3)
    assert np.all(np.isfinite(d.positions))


# ------------------------------------------------------------------------------------- robust
def test_cauchy_irls_is_stationary_and_beats_least_squares_under_nlos():
    """One range between two SPP UAVs gets a +5 m NLOS bias. Cauchy (c = 2.385) on the range
    factors: the IRLS fixed point is a stationary point of the robust cost (its numerical gradient
    vanishes), and over 30 epochs its endpoint error is below least squares' in a significant
    majority. Measured: 30/30."""
    K, wins = 30, 0
    losses = {"range": Loss(kind="cauchy", scale=2.385)}
    for s in range(K):
        ep, k = nlos_epoch(s)
        p = ep.problem
        ls = solve_centralized(p, covariance="none")
        rb = solve_centralized(p, method="lm", losses=losses, covariance="none", step_tol=1e-10, max_iter=200)
        assert rb.converged
        if s == 0:
            x, h = rb.positions.reshape(-1), 1e-6
            grad = [(fg._general_cost(p, (x + h * e).reshape(-1, 3), losses)
                     - fg._general_cost(p, (x - h * e).reshape(-1, 3), losses)) / (2 * h) for e in np.eye(x.size)]
            assert np.abs(grad).max() < 1e-4  # vs O(10) at the least-squares solution
        ends = list(p.edges[k])
        err = lambda X: np.linalg.norm(X[ends] - ep.truth[ends], axis=1).mean()  # noqa: E731
        wins += err(rb.positions) < err(ls.positions)
    assert wins >= _sign_test_min(K)


def test_losses_are_per_factor_type():
    """A 30 m blunder on one SPP fix: a robust loss on the GNSS factors (not on the ranges) keeps
    that UAV's estimate near the blunder-free optimum, least squares does not. Measured (seeds
    5-7): distance to the blunder-free solution 0.29/0.04/0.10 m (least squares) against
    0.026/0.004/0.013 m (Huber) and 0.021/0.003/0.011 m (Cauchy). A loss on an unknown factor
    type is refused."""
    for seed in (5, 6, 7):
        ep = make_epoch(18, seed=seed)
        k = int(np.flatnonzero(~ep.is_rtk)[0])
        z = ep.problem.gnss_pos.copy()
        z[k] += [30.0, 0.0, 0.0]
        p = dataclasses.replace(ep.problem, gnss_pos=z)
        ref = solve_centralized(ep.problem, covariance="none").positions[k]
        ls = solve_centralized(p, method="lm", covariance="none").positions[k]
        for loss in (Loss(kind="huber", scale=1.345), Loss(kind="cauchy", scale=2.385)):
            rb = solve_centralized(p, method="lm", losses={"gnss": loss}, covariance="none").positions[k]
            assert np.linalg.norm(rb - ref) < 0.3 * np.linalg.norm(ls - ref)
    with pytest.raises(ValueError, match="unknown factor types"):
        solve_centralized(p, losses={"height": Loss(kind="huber")})


# --------------------------------------------------------------------------------- warm start
def test_warm_start_centralized_and_distributed():
    """From the previous solution the centralized solve stops after at most 2 iterations at the
    same optimum; the distributed iteration warm-started from its own converged state (positions
    and covariances) stops after one round, at the same positions."""
    p = make_epoch(18, seed=1).problem
    c = solve_centralized(p, method="lm", step_tol=1e-12, cost_tol=0.0)
    w = solve_centralized(p, x0=c.positions, method="lm", step_tol=1e-12, cost_tol=0.0)
    assert w.converged and w.iterations <= 2 < c.iterations
    np.testing.assert_allclose(w.positions, c.positions, atol=1e-9)
    cold = solve_distributed(p, neighbour_model="fixed", damping=0.5, max_rounds=6000, tol=1e-6)
    warm = solve_distributed(p, neighbour_model="fixed", damping=0.5, max_rounds=6000, tol=1e-6,
                             x0=cold.positions, cov0=cold.cov)
    assert cold.converged and warm.converged and warm.rounds == 1 < cold.rounds
    np.testing.assert_allclose(warm.positions, cold.positions, atol=1e-6)


def test_distributed_with_fixed_nodes_and_missing_priors():
    """Five fixed anchors at their true positions, GNSS on every second other UAV only: the
    consistent distributed variant keeps the anchors still, runs finite and reaches the
    centralized optimum of the same graph to 1 cm."""
    ep = make_epoch(18, seed=1)
    p = _anchored(ep, [0, 4, 8, 12, 16])
    p = dataclasses.replace(p, prior=np.arange(18) % 2 == 1)
    c = solve_centralized(p, method="lm")
    assert c.observable and c.converged
    d = solve_distributed(p, neighbour_model="fixed", damping=0.5, max_rounds=6000, tol=1e-6)
    np.testing.assert_array_equal(d.positions[p.fixed], ep.truth[p.fixed])
    assert np.all(np.isfinite(d.positions)) and np.all(np.isfinite(d.cov))
    assert np.linalg.norm(d.positions - c.positions, axis=1).max() < 0.01
