"""One factor-graph library: every factor-graph solver of the testbed runs the iteration of
estimators.graph.lm (`solve` for Gauss-Newton / Levenberg-Marquardt, `iterate_rounds` for the
distributed message iterations), and its result carries the Report that iteration returned.

The spy replaces lm.solve and lm.iterate_rounds by wrappers that record the Report of every call:
a solver with its own loop would leave the record empty, or return a report the library did not
make (checked by identity), or counts that differ from the report's.
"""
import dataclasses

import numpy as np
import pytest

from estimators import window as sw
from estimators.factor_graph import solve_centralized, solve_distributed
from estimators.graph import lm
from estimators.graph import model as gm
from estimators.graph.batch import EpochFactors, solve_epochs
from estimators.graph.flooding import solve_flooding
from estimators.graph.linear import BlockTridiagonalNormals, DenseNormals
from estimators.graph.gbp import solve_gbp
from testbed.synthetic.coop import make_epoch
from tests.test_window import N, Q, synthetic


@pytest.fixture
def spy(monkeypatch):
    """The Reports returned by lm.solve and lm.iterate_rounds during the test, in call order."""
    seen = []
    solve, rounds = lm.solve, lm.iterate_rounds

    def solve_spy(*a, **k):
        out = solve(*a, **k)
        seen.append(out[2])
        return out

    def rounds_spy(*a, **k):
        out = rounds(*a, **k)
        seen.append(out[2])
        return out

    monkeypatch.setattr(lm, "solve", solve_spy)
    monkeypatch.setattr(lm, "iterate_rounds", rounds_spy)
    return seen


@pytest.fixture(scope="module")
def epoch():
    return make_epoch(18, seed=2).problem


@pytest.mark.parametrize("kw,method,calls", [({}, "gn", 1), ({"huber": 1.345}, "gn", 2), ({"method": "lm"}, "lm", 1)])
def test_centralized_runs_the_library_iteration(spy, epoch, kw, method, calls):
    res = solve_centralized(epoch, covariance="none", **kw)
    assert len(spy) == calls and res.report is spy[-1]  # huber: least squares first, then the Huber cost
    assert res.report.method == method and res.converged
    assert res.iterations == res.report.iterations[0] >= 1
    assert res.history == res.report.trace and res.cost == res.report.cost[0]


def test_centralized_general_graph_runs_the_library_iteration(spy, epoch):
    fixed = np.zeros(epoch.n, bool)
    fixed[:4] = True
    res = solve_centralized(dataclasses.replace(epoch, fixed=fixed), covariance="none")
    assert len(spy) == 1 and res.report is spy[0] and res.report.method == "gn"
    assert np.array_equal(res.positions[fixed], epoch.gnss_pos[fixed])


def test_flooding_solves_with_the_library_iteration(spy, epoch):
    res = solve_flooding(epoch, covariance="none")
    assert res.converged and len(spy) == 1 and res.report is spy[0] and res.report.method == "gn"


@pytest.mark.parametrize("solver", ["distributed", "gbp"])
def test_message_iterations_run_the_library_rounds(spy, epoch, solver):
    res = (solve_distributed(epoch, max_rounds=40, tol=1e-3) if solver == "distributed"
           else solve_gbp(epoch, max_rounds=40, tol=1e-3))
    assert len(spy) == 1 and res.report is spy[0] and res.report.method == "rounds"
    assert res.rounds == res.report.iterations[0] == len(res.max_step) == res.positions_history.shape[0] - 1
    assert res.converged == res.report.converged[0]
    np.testing.assert_array_equal(res.max_step, res.report.trace)


def _points_to_anchors(E: int, rng) -> tuple[EpochFactors, np.ndarray, np.ndarray, np.ndarray]:
    """E epochs of one point ranged by 4 fixed anchors (sigma 0.05 m), starts 0.01-3 m off."""
    anchors = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 1.0], [0.0, 10.0, 2.0], [10.0, 10.0, 5.0]])
    truth = rng.uniform(2.0, 8.0, (E, 3))
    ep = np.repeat(np.arange(E), 4)
    d = np.linalg.norm(truth[ep] - anchors[np.tile(np.arange(4), E)], axis=1) + 0.05 * rng.normal(size=4 * E)
    f = EpochFactors(kinds=("point",), r_epoch=ep, r_a=np.zeros(4 * E, np.int64), r_b=np.full(4 * E, -1),
                     r_arm_a=np.zeros((4 * E, 3)), r_arm_b=np.tile(anchors, (E, 1)), r_d=d,
                     r_sigma=np.full(4 * E, 0.05), **EpochFactors.empty_rows())
    off = rng.normal(size=(E, 3))
    p0 = truth + off / np.linalg.norm(off, axis=1, keepdims=True) * np.geomspace(0.01, 3.0, E)[:, None]
    return f, p0[:, None], np.tile(np.eye(3), (E, 1, 1, 1)), truth


def test_epoch_batch_runs_the_library_iteration_epoch_by_epoch(spy):
    """The batch (epochs finishing at different iterations, so the iteration continues on the
    others alone) gives each epoch what the same iteration gives it alone."""
    f, p0, R0, _ = _points_to_anchors(8, np.random.default_rng(5))
    res = solve_epochs(f, p0, R0)
    assert len(spy) == 1 and res.report is spy[0] and res.report.method == "lm"
    np.testing.assert_array_equal(res.iterations, res.report.iterations)
    np.testing.assert_array_equal(res.converged, res.report.converged)
    assert res.iterations.max() > 2 * res.iterations.min()  # most epochs done while the others go on
    for e in range(8):
        keep = f.r_epoch == e
        one = dataclasses.replace(f, **{k: getattr(f, k)[keep] for k in ("r_a", "r_b", "r_arm_a", "r_arm_b", "r_d", "r_sigma")},
                                  r_epoch=np.zeros(4, np.int64), r_bias=None)
        alone = solve_epochs(one, p0[e:e + 1], R0[e:e + 1])
        np.testing.assert_allclose(res.p[e], alone.p[0], rtol=0, atol=1e-12)
        assert res.iterations[e] == alone.iterations[0] and res.converged[e] == alone.converged[0]


def test_general_graph_runs_the_library_iteration(spy):
    g = gm.Graph()
    g.add_variable("q", "point")
    for j, a in enumerate(np.eye(3) * 10.0):
        g.add_variable(f"a{j}", "point", fixed=True)
        g.add(gm.Range("q", f"a{j}", float(np.linalg.norm(a - [1.0, 2.0, 3.0])), 0.05))
    g.add(gm.Height("q", 3.0, 0.05))
    init = {"q": np.array([2.0, 1.0, 2.0]), **{f"a{j}": a for j, a in enumerate(np.eye(3) * 10.0)}}
    res = gm.solve_graph(g, init)
    assert len(spy) == 1 and res.report is spy[0] and res.report.method == "lm" and res.converged
    np.testing.assert_allclose(res.values["q"], [1.0, 2.0, 3.0], atol=1e-9)


@pytest.fixture(scope="module")
def window_epochs():
    return synthetic(4)[0]


def test_centralized_window_runs_the_library_iteration(spy, window_epochs):
    """The centralized window's Gauss-Newton is lm.solve: one call per epoch (a second after a
    mirror image was kept), the estimate carries the last call's report, its iterations the sum."""
    est = sw.Centralized(N, window=3, q=Q, huber=1.345)
    for ep in window_epochs:
        spy.clear()
        e = est.add(ep)
        assert len(spy) == 1 + (e.mirrored > 0) and e.report is spy[-1] and e.report.method == "gn"
        assert e.iterations == sum(int(r.iterations[0]) for r in spy) >= 1
        assert e.converged == e.report.converged[0]
        assert np.all(np.diff(e.report.trace) <= sw.COST_ROUNDOFF * e.report.trace[0])  # never a rise past round-off
    assert e.converged  # the stopping rule (lm's caller test) did stop a solve


def test_distributed_window_runs_the_library_rounds_and_steps(spy, window_epochs):
    """The distributed window's rounds are lm.iterate_rounds and every vehicle's local step is
    lm.solve over the vehicles as a batch (one Gauss-Newton step each, its own step halving): a
    step before the rounds (after the first epoch), one per round, the estimate carrying the
    rounds' report."""
    est = sw.Distributed(N, window=3, q=Q, max_rounds=6, tol=1e-3)
    for k, ep in enumerate(window_epochs):
        spy.clear()
        e = est.add(ep)
        rounds = [r for r in spy if r.method == "rounds"]
        steps = [r for r in spy if r.method == "gn"]
        assert len(rounds) == 1 and e.report is rounds[0] and len(steps) + len(rounds) == len(spy)
        assert e.iterations == e.report.iterations[0] == len(e.report.trace) >= 1
        assert e.converged == e.report.converged[0]
        assert len(steps) == e.iterations + (k > 0) + (e.mirrored > 0)
        assert all(r.iterations.shape == (N,) and r.iterations.max() <= 1 for r in steps)
        assert e.report.trace[-1] < 1e-3 if e.converged else e.iterations == 6


def test_rounds_stop_on_tolerance_cap_and_divergence():
    x0 = np.ones((4, 3))
    x, hist, rep = lm.iterate_rounds(x0, lambda r, x: 0.5 * x, max_rounds=100, tol=1e-3)
    # |x_r - x_{r-1}| = sqrt(3) 2^-r < 1e-3 first at r = 11
    assert rep.converged[0] and rep.iterations[0] == 11 and hist.shape == (12, 4, 3)
    _, _, rep = lm.iterate_rounds(x0, lambda r, x: 0.5 * x, max_rounds=5, tol=1e-3)
    assert not rep.converged[0] and rep.iterations[0] == 5
    _, _, rep = lm.iterate_rounds(x0, lambda r, x: x * 1e6, max_rounds=50, tol=1e-3)
    assert not rep.converged[0] and rep.iterations[0] == 1  # a step above DIVERGED_M stops at once
    _, _, rep = lm.iterate_rounds(x0, lambda r, x: 0.5 * x, max_rounds=100, tol=1e-3, ord=np.inf)
    assert rep.converged[0] and rep.iterations[0] == 10  # a node's largest component: 2^-r < 1e-3 first at r = 10


class _Line:
    """One problem of one unknown for lm.solve: cost(x) = 1 + slope x, normal equations N = 1,
    g = 1 (every step +1); retract x + delta."""

    size = 1

    def __init__(self, slope: float):
        self.slope = slope

    def evaluate(self, x):
        return np.array([1.0 + self.slope * x[0]]), None

    def normal(self, x, memo):
        return DenseNormals(np.ones((1, 1, 1)), np.ones((1, 1)))

    @staticmethod
    def retract(x, delta):
        return x + delta[0]

    @staticmethod
    def select(mask, a, b):
        return a if mask[0] else b


def test_callers_stop_test_and_cost_roundoff():
    """lm.solve's `stop` is called after every linear solve with the full step and the normal
    equations solved, and converges an accepted step it passes; `roundoff` is the relative rise
    of the cost that a Gauss-Newton step may take (a cost flat to round-off)."""
    seen = []

    def stop(delta, lin):
        seen.append((delta.copy(), lin))
        return np.array([len(seen) == 2])

    _, _, rep = lm.solve(_Line(-1.0), np.zeros(1), method="gn", step_tol=0.0, cost_tol=0.0, stop=stop)
    assert rep.converged[0] and rep.iterations[0] == 2 and len(seen) == 2
    assert all(np.array_equal(d, [[1.0]]) and isinstance(lin, DenseNormals) for d, lin in seen)
    # each step raises the cost by 1e-13 relative: above lm.ROUNDOFF, within 1e-12
    flat = dict(method="gn", max_iter=3, step_tol=0.0, cost_tol=0.0, max_halvings=0)
    assert lm.solve(_Line(1e-13), np.zeros(1), **flat)[2].iterations[0] == 0
    assert lm.solve(_Line(1e-13), np.zeros(1), roundoff=1e-12, **flat)[2].iterations[0] == 3


def test_normal_equation_objects_equal_their_dense_matrices():
    """BlockTridiagonalNormals (the window's) and DenseNormals.inverse against the dense matrix
    they stand for: diagonal, quadratic form, damped solve, the newest epoch's information (the
    inverse of its marginal covariance) and per-chain selection; random SPD chains, to 1e-10."""
    rng = np.random.default_rng(7)
    B, K, s = 3, 4, 2
    J = np.zeros((B, K, s, K, s))  # block-bidiagonal: each block row links epochs k and k + 1
    for k in range(K):
        J[:, k, :, k] = rng.normal(size=(B, s, s))
        if k + 1 < K:
            J[:, k, :, k + 1] = rng.normal(size=(B, s, s))
    J = J.reshape(B, K * s, K * s)
    H = np.einsum("bri,brj->bij", J, J) + np.eye(K * s)  # SPD, block-tridiagonal
    blk = H.reshape(B, K, s, K, s)
    D = np.stack([blk[:, k, :, k, :] for k in range(K)], 1)
    U = np.stack([blk[:, k, :, k + 1, :] for k in range(K - 1)], 1)
    R = rng.normal(size=(B, K, s))
    lin = BlockTridiagonalNormals(D, U, R)
    delta = rng.normal(size=(B, K * s))
    np.testing.assert_allclose(lin.diagonal(), np.diagonal(H, axis1=1, axis2=2), rtol=1e-12)
    np.testing.assert_allclose(lin.quad(delta), np.einsum("bi,bij,bj->b", delta, H, delta), rtol=1e-10)
    shift = rng.uniform(0.1, 1.0, (B, K * s))
    step, ok = lin.solve(shift)
    Hs = H + shift[:, :, None] * np.eye(K * s)
    np.testing.assert_allclose(step, np.linalg.solve(Hs, R.reshape(B, -1)[..., None])[..., 0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.linalg.inv(lin.S), np.linalg.inv(Hs)[:, -s:, -s:], rtol=1e-10)
    assert ok.all()
    other = BlockTridiagonalNormals(2.0 * D, U, R)
    mixed = lin.where(np.array([True, False, True]), other)
    np.testing.assert_array_equal(mixed.D[1], 2.0 * D[1])
    np.testing.assert_array_equal(mixed.D[0], D[0])
    P = DenseNormals(H, R.reshape(B, -1)).inverse()
    np.testing.assert_allclose(P, np.linalg.inv(H), rtol=1e-10, atol=1e-12)
