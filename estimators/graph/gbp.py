"""Gaussian belief propagation for the seed 001 graph: an accelerated distributed solver.

Loopy Gaussian belief propagation with relinearization of the range factors at the current
beliefs (Ortiz, Evans, Davison 2021, "A visual introduction to Gaussian belief propagation",
arXiv:2107.02308; Davison, Ortiz 2019, "FutureMapping 2: Gaussian belief propagation for spatial
AI", arXiv:1910.14139; Bickson 2008, "Gaussian belief propagation: theory and application").
Information form: a belief over UAV i's position p_i (3,) is (eta_i, Lam_i), mean Lam_i^-1 eta_i.
Every round:
1. each range factor (i, j) is linearized at the current means: h = |p_i - p_j| ~ h0 + u^T(dp_i -
   dp_j); its information over [p_i; p_j] is J^T J / sigma^2, J = [u^T, -u^T], and
   eta_f = J^T (d - h0 + J x0) / sigma^2;
2. the factor-to-variable message to i marginalizes p_j out of (factor + the message from j to the
   factor, i.e. j's belief minus the factor's last message to j) by a Schur complement;
3. Lam_i = GNSS information + sum of incoming messages, eta_i likewise; mean = Lam_i^-1 eta_i.
A fixed point is a stationary point of the centralized problem (the beliefs' means satisfy the
normal equations at the linearization point), so it reaches the centralized optimum, unlike the
paper's scheme. The beliefs' covariances Lam_i^-1 are the loopy-BP approximations (typically
over-confident on loopy graphs); the means are what is claimed. Messages: each UAV broadcasts its
belief (mean 3, eta 3, Lam 6 unique) = 12 float64 = 96 bytes per round; both ends of a link
compute the factor's messages from the same broadcasts. Damping (a fraction of the new message,
information and eta alike) is the usual remedy on strongly coupled loops.
Never imports mujoco, testbed or gtsam.
"""
from __future__ import annotations

import numpy as np

from estimators.factor_graph import DistributedResult
from estimators.graph.factors import range_terms
from estimators.graph.linear import DenseNormals
from estimators.graph import lm

__all__ = ["GBP_MESSAGE_BYTES", "solve_gbp"]

#: payload of one GBP broadcast: mean (3), eta (3), information (6 unique), float64
GBP_MESSAGE_BYTES = 12 * 8


def solve_gbp(problem, *, max_rounds: int = 100, tol: float = 1e-4, damping: float = 0.0,
              x0: np.ndarray | None = None) -> DistributedResult:
    """Loopy GBP with relinearization on a CoopProblem (every node with a prior, none fixed).

    Returns a DistributedResult: cov holds the belief covariances (loopy-BP approximation),
    bytes_sent counts GBP_MESSAGE_BYTES per broadcast, deliveries 2 m per round (no loss model).

    damping: weight of the previous message in [0, 1) (0: none); x0: warm start (n, 3) m.
    """
    if not problem.is_plain:
        raise ValueError("solve_gbp: needs every node with a prior and none fixed")
    if not 0.0 <= damping < 1.0:
        raise ValueError(f"solve_gbp: damping must be in [0, 1), got {damping}")
    n, m = problem.n, problem.m
    Lg = np.linalg.inv(problem.gnss_cov)
    eg = np.einsum("nab,nb->na", Lg, problem.gnss_pos)
    X = problem.gnss_pos.copy() if x0 is None else np.array(x0, float)
    # directed factor-to-variable messages: index e (0..m-1) to edges[:, 0], e + m to edges[:, 1]
    dst = np.concatenate([problem.edges[:, 0], problem.edges[:, 1]])
    oth = np.concatenate([problem.edges[:, 1], problem.edges[:, 0]])
    rev = np.concatenate([np.arange(m, 2 * m), np.arange(m)])
    d = np.concatenate([problem.ranges, problem.ranges])
    w = 1.0 / np.concatenate([problem.range_sigma, problem.range_sigma]) ** 2
    mL = np.zeros((2 * m, 3, 3))
    me = np.zeros((2 * m, 3))
    Lam, eta = Lg.copy(), eg.copy()

    def one_round(rnd: int, X: np.ndarray) -> np.ndarray:
        """One GBP round at the current means X (n, 3): new messages, beliefs, their means."""
        nonlocal mL, me, Lam, eta
        h0, u = range_terms(X[dst], X[oth])
        # factor information over [p_dst; p_oth]: w [u; -u][u; -u]^T; eta_f = w J^T (d - h0 + J x0)
        uu = w[:, None, None] * u[:, :, None] * u[:, None, :]
        r = w * (d - h0 + np.einsum("ka,ka->k", u, X[dst] - X[oth]))
        # message from oth to the factor: oth's belief minus the factor's last message to oth
        Lo = Lam[oth] - mL[rev] + uu
        eo = eta[oth] - me[rev] - r[:, None] * u
        # Schur complement: Lam_dst <- uu - uu Lo^-1 uu, eta_dst <- r u - (-uu) Lo^-1 eo
        S = np.linalg.solve(Lo, np.concatenate([uu, eo[:, :, None]], axis=2))
        new_L = uu - uu @ S[:, :, :3]
        new_e = r[:, None] * u + (uu @ S[:, :, 3:])[:, :, 0]
        mL = damping * mL + (1.0 - damping) * new_L
        me = damping * me + (1.0 - damping) * new_e
        Lam, eta = Lg.copy(), eg.copy()
        np.add.at(Lam, dst, mL)
        np.add.at(eta, dst, me)
        mean, ok = DenseNormals(Lam, eta).solve(None)  # each belief's mean
        if not ok.all():  # a failed factorization gives a zero step, never a belief's mean
            raise np.linalg.LinAlgError(f"GBP: the belief information of node(s) {np.flatnonzero(~ok).tolist()} "
                                        "is not positive definite")
        return mean

    # the round iteration of the graph library (estimators.graph.lm): stops on tol or a diverged step
    X, hist, report = lm.iterate_rounds(X, one_round, max_rounds=max_rounds, tol=tol)
    rounds, converged = int(report.iterations[0]), bool(report.converged[0])
    cov = DenseNormals(Lam, eta).inverse()
    cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    return DistributedResult(X, cov, rounds, converged, rounds * n, rounds * n * GBP_MESSAGE_BYTES, rounds * 2 * m,
                             np.asarray(report.trace), hist, report)
