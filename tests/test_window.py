"""estimators.window: seed 001's factor graph over a sliding window, online.

- a window covering every epoch equals the batch solution of the same graph (estimators.graph
  .model.solve_graph, an independent general solver) at every epoch of the window;
- the distributed message iteration with exact broadcasts approaches the centralized window;
- the cost per epoch is bounded: the window never holds more than `window` epochs and each
  epoch's work is the same number of block solves whatever the run length (counted, not timed);
- time order is enforced (no look-ahead: an epoch's estimate is final when it is returned).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimators import window as sw
from estimators.graph.model import ConstantVelocity, Graph, Prior, Range, solve_graph

N, DT, Q = 5, 0.2, 1.0
ANCHORS = np.array([[0.0, 0.0, 3.0], [30.0, 5.0, 3.0]])


def synthetic(epochs: int, seed: int = 3, outage=(3, 6)) -> tuple[list[sw.Epoch], np.ndarray]:
    """n vehicles flying at 2 m/s with weaving; vehicles 0 and 1 lose GNSS at epochs in outage."""
    rng = np.random.default_rng(seed)
    t = np.arange(epochs) * DT
    base = np.array([[0.0, 0.0, 8.0], [0.0, 6.0, 14.0], [-6.0, 0.0, 4.0], [-6.0, 6.0, 11.0], [-12.0, 3.0, 7.0]])
    truth = base[None] + np.stack([2.0 * t, np.sin(t)[None].repeat(1, 0)[0], 0.1 * t], 1)[:, None, :]
    eps = []
    for k in range(epochs):
        fix = truth[k] + rng.normal(0, [1.5, 1.5, 3.0], (N, 3))
        if outage[0] <= k < outage[1]:
            fix[:2] = np.nan
        edges = np.array([(i, j) for i in range(N) for j in range(i + 1, N)])
        d = np.linalg.norm(truth[k, edges[:, 0]] - truth[k, edges[:, 1]], axis=1) + rng.normal(0, 0.1, len(edges))
        av = np.array([0, 1, 2])
        ad = np.linalg.norm(truth[k, av] - ANCHORS[[0, 1, 0]], axis=1) + rng.normal(0, 0.1, 3)
        eps.append(sw.Epoch(t=float(t[k]), fix=fix, fix_sigma=np.tile([1.5, 1.5, 3.0], (N, 1)), edges=edges, ranges=d,
                            range_sigma=np.full(len(edges), 0.1), anchor_vehicle=av, anchor_pos=ANCHORS[[0, 1, 0]],
                            anchor_range=ad, anchor_sigma=np.full(3, 0.1)))
    return eps, truth


def batch(eps: list[sw.Epoch], truth: np.ndarray, init_sigma_p: float = 1e3, init_sigma_v: float = 10.0):
    """The same graph built factor by factor for the general solver, started at the truth (the
    optimum nearest the truth; the online window starts from the fixes)."""
    g, init = Graph(), {}
    first = eps[0].fix
    p0 = np.where(np.isnan(first[:, :1]), np.nanmean(first, axis=0), first)
    for a, pos in enumerate(ANCHORS):
        g.add_variable(("a", a), "point", fixed=True)
        init[("a", a)] = pos
    for k, ep in enumerate(eps):
        for i in range(N):
            g.add_variable(("p", k, i), "point")
            g.add_variable(("v", k, i), "point")
            init[("p", k, i)], init[("v", k, i)] = truth[k, i], np.zeros(3)
            if not np.isnan(ep.fix[i, 0]):
                g.add(Prior(("p", k, i), ep.fix[i], np.diag(ep.fix_sigma[i] ** 2)))
            if k:
                g.add(ConstantVelocity(("p", k - 1, i), ("v", k - 1, i), ("p", k, i), ("v", k, i), ep.t - eps[k - 1].t, Q))
        for (i, j), d, s in zip(ep.edges, ep.ranges, ep.range_sigma):
            g.add(Range(("p", k, i), ("p", k, j), d, s))
        for i, pos, d, s in zip(ep.anchor_vehicle, ep.anchor_pos, ep.anchor_range, ep.anchor_sigma):
            a = int(np.flatnonzero((ANCHORS == pos).all(1))[0])
            g.add(Range(("p", k, i), ("a", a), d, s))
    for i in range(N):
        g.add(Prior(("p", 0, i), p0[i], np.eye(3) * init_sigma_p ** 2))
        g.add(Prior(("v", 0, i), np.zeros(3), np.eye(3) * init_sigma_v ** 2))
    return solve_graph(g, init, method="gn", max_iter=100, step_tol=1e-12)


def test_window_covering_everything_equals_batch():
    eps, truth = synthetic(8)
    est = sw.Centralized(N, window=len(eps), q=Q, max_iter=50, tol=1e-10)
    for ep in eps:
        last = est.add(ep)
    ref = batch(eps, truth)
    P = est._pos()
    for k in range(len(eps)):
        for i in range(N):
            assert np.allclose(P[k, i], ref.values[("p", k, i)], atol=1e-7), (k, i)
    for i in range(N):
        assert np.allclose(last.vel[i], ref.values[("v", len(eps) - 1, i)], atol=1e-7)
        assert np.allclose(last.pos_cov[i], ref.cov[("p", len(eps) - 1, i)], rtol=1e-6, atol=1e-12)


def test_marginalized_window_equals_batch_on_a_linear_graph():
    """Without ranges the graph is linear (GNSS + motion): marginalizing the epochs that slid out
    (Schur complement) loses nothing, so a 3-epoch window's newest estimate and covariance are
    the full batch's at that epoch."""
    eps, truth = synthetic(8)
    eps = [dataclasses.replace(ep, edges=np.zeros((0, 2), np.int64), ranges=np.zeros(0), range_sigma=np.zeros(0),
                               anchor_vehicle=np.zeros(0, np.int64), anchor_pos=np.zeros((0, 3)),
                               anchor_range=np.zeros(0), anchor_sigma=np.zeros(0)) for ep in eps]
    est = sw.Centralized(N, window=3, q=Q, max_iter=50, tol=1e-10)
    for ep in eps:
        last = est.add(ep)
    assert len(est.epochs) == 3
    ref = batch(eps, truth)
    for i in range(N):
        assert np.allclose(last.pos[i], ref.values[("p", len(eps) - 1, i)], atol=1e-7)
        assert np.allclose(last.vel[i], ref.values[("v", len(eps) - 1, i)], atol=1e-7)
        assert np.allclose(last.pos_cov[i], ref.cov[("p", len(eps) - 1, i)], rtol=1e-6)


def test_distributed_broadcasts_are_counted_and_deliveries_used():
    """Every round, every vehicle that ranged broadcasts once (72 bytes); a transport that
    delivers nothing leaves the vehicles on their own measurements (no neighbour heard)."""

    class Nothing:
        def deliver(self, rnd, src, dst, nbytes):
            return np.zeros(len(src), bool)

    eps, _ = synthetic(4)
    dis = sw.Distributed(N, window=3, q=Q, max_rounds=4, tol=0.0)
    alone = sw.Distributed(N, window=3, q=Q, max_rounds=4, tol=0.0)
    for ep in eps:
        d = dis.add(ep)
        a = alone.add(ep, Nothing())
        assert d.messages == 4 * N and d.bytes_sent == d.messages * sw.BROADCAST_BYTES
    assert not alone.heard[-1].any() and dis.heard[-1].sum() == N * (N - 1)
    assert not np.allclose(a.pos, d.pos)


def test_distributed_beats_gnss_and_does_not_drift():
    """Message iteration over the window: well below GNSS alone, and no drift of the swarm's
    common position (the last epochs are no worse than the first ones)."""
    eps, truth = synthetic(15)
    cen = sw.Centralized(N, window=5, q=Q)
    dis = sw.Distributed(N, window=5, q=Q, max_rounds=20, tol=1e-4)
    err_c, err_d, err_g = [], [], []
    for k, ep in enumerate(eps):
        c, d = cen.add(ep), dis.add(ep)
        err_c.append(np.linalg.norm(c.pos - truth[k], axis=1))
        err_d.append(np.linalg.norm(d.pos - truth[k], axis=1))
        err_g.append(np.linalg.norm(ep.fix - truth[k], axis=1))
    rms = lambda e: float(np.sqrt(np.nanmean(np.square(e))))  # noqa: E731
    assert rms(err_d) < 0.5 * rms(err_g)
    assert rms(err_c) <= rms(err_d)
    assert rms(err_d[-5:]) <= rms(err_d[:5])


def test_bounded_work_per_epoch(monkeypatch):
    """The number of block solves per epoch does not grow with the run length."""
    calls = []
    real = sw._solve_chain

    def counting(D, U, R):
        calls.append(D.shape[1])
        return real(D, U, R)

    monkeypatch.setattr(sw, "_solve_chain", counting)
    eps, _ = synthetic(40, outage=(100, 100))
    est = sw.Centralized(N, window=4, q=Q, max_iter=3, tol=0.0)
    per_epoch = []
    for ep in eps:
        calls.clear()
        est.add(ep)
        per_epoch.append(sum(calls))
        assert len(est.epochs) <= 4
    assert max(per_epoch) == 3 * 4 and per_epoch[-1] == per_epoch[10]


def test_time_order_enforced():
    eps, _ = synthetic(3)
    est = sw.Centralized(N)
    est.add(eps[1])
    with pytest.raises(ValueError, match="time order"):
        est.add(eps[0])


def test_tracklet_recovers_the_newest_epochs_own_fix_on_a_linear_graph():
    """The equivalent measurement of the newest epoch (marginal minus the window's prediction of
    it, estimators.window.equivalent_measurement) is exactly that epoch's new information: on a
    linear graph (GNSS + motion, vehicles independent) each vehicle's own fix and its declared
    covariance; a vehicle without a fix in that epoch brings nothing (projected, not full)."""
    eps, truth = synthetic(8)
    eps = [dataclasses.replace(ep, edges=np.zeros((0, 2), np.int64), ranges=np.zeros(0), range_sigma=np.zeros(0),
                               anchor_vehicle=np.zeros(0, np.int64), anchor_pos=np.zeros((0, 3)),
                               anchor_range=np.zeros(0), anchor_sigma=np.zeros(0)) for ep in eps]
    est = sw.Centralized(N, window=3, q=Q, max_iter=50, tol=1e-10)
    est.tracklets = True
    for k, ep in enumerate(eps):
        last = est.add(ep)
        if k == 0:
            assert last.tracklet is None  # nothing predicts the first epoch
            continue
        z, R, full = sw.equivalent_measurement(*last.tracklet)
        has = ~np.isnan(ep.fix[:, 0])
        np.testing.assert_array_equal(full, has)
        np.testing.assert_allclose(z[has], ep.fix[has], atol=1e-6)
        np.testing.assert_allclose(R[has], np.stack([np.diag(s ** 2) for s in ep.fix_sigma[has]]), rtol=1e-6, atol=1e-9)
        assert (np.linalg.eigvalsh(R[~has]) >= 1e3).all()  # no fix: (almost) no information
    assert any(np.isnan(ep.fix[:, 0]).any() for ep in eps[1:])  # the outage was exercised


def test_equivalent_measurement_removes_the_prior_from_a_fused_estimate():
    """Fusing a prior N(m0, P0) with a measurement N(z, R) and taking the prior out again gives
    back z and R (the information-form difference), batched; a fused estimate no more informative
    than its prior is projected."""
    rng = np.random.default_rng(1)
    A, Bm = rng.normal(size=(4, 3, 3)), rng.normal(size=(4, 3, 3))
    P0, R = A @ np.swapaxes(A, 1, 2) + np.eye(3), Bm @ np.swapaxes(Bm, 1, 2) + 0.1 * np.eye(3)
    m0, z = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    P = np.linalg.inv(np.linalg.inv(P0) + np.linalg.inv(R))
    m = np.einsum("nij,nj->ni", P, np.linalg.solve(P0, m0[..., None])[..., 0] + np.linalg.solve(R, z[..., None])[..., 0])
    z2, R2, full = sw.equivalent_measurement(m, P, m0, P0)
    assert full.all()
    np.testing.assert_allclose(z2, z, atol=1e-8)
    np.testing.assert_allclose(R2, R, atol=1e-8)
    _, R3, full3 = sw.equivalent_measurement(m0, P0, m0, P0)
    assert not full3.any() and (np.linalg.eigvalsh(R3) >= 1e3).all()
