"""GTSAM reference for the centralized cooperative-navigation problem of seed 001.

The same factor graph as estimators.factor_graph.solve_centralized, built with GTSAM 4.x:
`PriorFactorPoint3` (GNSS fix with its full 3x3 covariance) and `RangeFactor3` (Point3-Point3
range with an isotropic 1-D sigma), optimized by Gauss-Newton (default) or Levenberg-Marquardt,
marginal covariances from `gtsam.Marginals`. Nodes without a prior get no prior factor; fixed
nodes are held by `NonlinearEqualityPoint3` at their given position. Used only in tests and benchmarks; the library itself
never imports gtsam.
"""
from __future__ import annotations

import numpy as np
import gtsam

from estimators.factor_graph import CoopProblem


def build_graph(problem: CoopProblem) -> gtsam.NonlinearFactorGraph:
    """Factor graph with keys 0..n-1 for the UAV positions (Point3, metres ENU)."""
    g = gtsam.NonlinearFactorGraph()
    for i in range(problem.n):
        if problem.fixed[i]:
            g.add(gtsam.NonlinearEqualityPoint3(i, problem.gnss_pos[i].copy()))
        elif problem.prior[i]:
            g.add(gtsam.PriorFactorPoint3(i, problem.gnss_pos[i], gtsam.noiseModel.Gaussian.Covariance(problem.gnss_cov[i])))
    for (i, j), d, s in zip(problem.edges, problem.ranges, problem.range_sigma):
        g.add(gtsam.RangeFactor3(int(i), int(j), float(d), gtsam.noiseModel.Isotropic.Sigma(1, float(s))))
    return g


def solve_gtsam(problem: CoopProblem, x0: np.ndarray | None = None, *, optimizer: str = "gn",
                max_iter: int = 100, marginals: bool = True, tol: float = 1e-15) -> tuple[np.ndarray, np.ndarray | None]:
    """Solve the centralized problem with GTSAM.

    x0: (n, 3) initial positions (default: the GNSS fixes). optimizer: "gn" or "lm".
    tol: GTSAM's relative and absolute error-decrease tolerances (its error tolerance is 0).
    Returns (positions (n, 3) metres, marginal covariances (n, 3, 3) m^2 or None).
    """
    graph = build_graph(problem)
    init = gtsam.Values()
    X0 = np.array(problem.gnss_pos if x0 is None else x0, dtype=float)
    X0[problem.fixed] = problem.gnss_pos[problem.fixed]  # NonlinearEquality needs a feasible start
    for i in range(problem.n):
        init.insert(i, X0[i].copy())
    kinds = {"gn": (gtsam.GaussNewtonParams, gtsam.GaussNewtonOptimizer),
             "lm": (gtsam.LevenbergMarquardtParams, gtsam.LevenbergMarquardtOptimizer)}
    if optimizer not in kinds:
        raise ValueError(f"solve_gtsam: optimizer must be 'gn' or 'lm', got {optimizer!r}")
    make_params, make_optimizer = kinds[optimizer]
    params = make_params()
    params.setRelativeErrorTol(tol)
    params.setAbsoluteErrorTol(tol)
    params.setErrorTol(0.0)
    params.setMaxIterations(max_iter)
    result = make_optimizer(graph, init, params).optimize()
    X = np.array([result.atPoint3(i) for i in range(problem.n)])
    if not marginals:
        return X, None
    marg = gtsam.Marginals(graph, result)
    P = np.array([marg.marginalCovariance(i) for i in range(problem.n)])
    return X, P
