"""Banded Cholesky after reverse Cuthill-McKee: solves, pivots and the selected inverse equal the
dense results on seed 001 normal matrices large enough to take the banded path."""
import numpy as np
import pytest
from scipy import sparse

from estimators.factor_graph import CoopProblem, whitened_system
from estimators.graph.banded import band_order, factor_banded, selected_inverse_diag
from estimators.graph.linear import factor_spd, narrow_band


def _chain_normal(n: int, seed: int = 0) -> sparse.csc_matrix:
    """N = A^T A of a swarm along a line (ranges to the next three UAVs): narrow band after RCM,
    shuffled so that the natural order is not banded."""
    rng = np.random.default_rng(seed)
    pos = np.c_[np.arange(n) * 10.0, rng.normal(0, 3, (n, 2))][rng.permutation(n)]
    rank = np.argsort(np.argsort(pos[:, 0]))
    order = np.argsort(rank)
    edges = np.array([(order[a], order[a + d]) for a in range(n) for d in (1, 2, 3) if a + d < n])
    d = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1) + rng.normal(0, 0.1, len(edges))
    prob = CoopProblem(pos + rng.normal(0, 1.5, pos.shape), np.tile(np.diag([2.25, 2.25, 9.0]), (n, 1, 1)),
                       edges, d, 0.1)
    A, _ = whitened_system(prob, prob.gnss_pos)
    return (A.T @ A).tocsc()


def test_banded_solve_pivots_and_marginals_equal_the_dense_ones():
    N = _chain_normal(300)
    order = narrow_band(N)
    assert order is not None and order.width < 40  # a chain: narrow band after RCM
    assert band_order(N) is order  # cached per pattern
    fac = factor_banded(N)
    Nd = N.toarray()
    g = np.random.default_rng(1).normal(size=(N.shape[0], 2))
    assert np.allclose(fac.solve(g), np.linalg.solve(Nd, g), rtol=1e-10, atol=1e-12)
    L = np.linalg.cholesky(Nd[np.ix_(order.perm, order.perm)])
    assert np.allclose(fac.pivots()[order.perm], np.diag(L) ** 2, rtol=1e-12)
    inv = np.linalg.inv(Nd)
    idx = np.arange(300)
    blocks = inv.reshape(300, 3, 300, 3)[idx, :, idx, :]
    assert np.allclose(selected_inverse_diag(fac), blocks, rtol=1e-9, atol=1e-12)
    spd = factor_spd(N)
    assert spd.ok and spd.observable and np.allclose(spd.solve(g), np.linalg.solve(Nd, g), rtol=1e-10, atol=1e-12)


def test_banded_path_reports_an_indefinite_or_singular_matrix():
    N = _chain_normal(250).tolil()
    N[5, 5] = -1.0
    assert factor_banded(N.tocsc()) is None
    assert not factor_spd(N.tocsc()).ok
    with pytest.raises(np.linalg.LinAlgError):
        factor_spd(N.tocsc()).solve(np.ones(750))
