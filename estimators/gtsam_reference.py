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
from estimators.graph import model as gm


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
                max_iter: int = 100, marginals: bool = True, step_tol: float = 1e-10,
                linear_solver: str = "MULTIFRONTAL_QR") -> tuple[np.ndarray, np.ndarray | None]:
    """Solve the centralized problem with GTSAM.

    x0: (n, 3) initial positions (default: the GNSS fixes). optimizer: "gn" or "lm".
    The iteration is driven here, one `optimizer.iterate()` at a time, and stops when the largest
    position change of an iteration is below step_tol (metres) or after max_iter iterations.
    GTSAM's own stopping rules (relative/absolute error decrease, `optimize()`) are not used: they
    test the cost, which cannot order iterates closer than ~5e-7 m along the weakest direction of a
    coop-fg epoch (its evaluation scatters by ~3e-14 relative), so they stop Gauss-Newton, which
    converges only linearly on this problem (nonzero range residuals; measured contraction 0.035
    per iteration, at most 0.15), up to 4e-8 m short of the optimum. Levenberg-Marquardt still
    accepts a step only if the evaluated cost decreases, so it stalls at that round-off (up to
    8e-7 m from the optimum measured); Gauss-Newton is the reference.
    linear_solver: GTSAM's LinearSolverType name ("MULTIFRONTAL_QR": QR of the whitened Jacobian;
    "MULTIFRONTAL_CHOLESKY": normal equations; cond(J) <= 136 on the coop-fg epochs, both reach the
    same optimum to 1e-11 m).
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
    params.setLinearSolverType(linear_solver)
    opt = make_optimizer(graph, init, params)
    X = X0
    for _ in range(max_iter):
        opt.iterate()
        X_new = gtsam.utilities.extractPoint3(opt.values())
        step = np.abs(X_new - X).max(initial=0.0)
        X = X_new
        if step < step_tol:
            break
    if not marginals:
        return X, None
    marg = gtsam.Marginals(graph, opt.values())
    P = np.array([marg.marginalCovariance(i) for i in range(problem.n)])
    return X, P


_FREE_VAR = 1e12  # m^2, "no information" variance of the height factor's horizontal axes


def solve_graph_gtsam(graph, init: dict, *, max_iter: int = 200) -> dict:
    """A general graph (estimators.graph.model) with GTSAM, Gauss-Newton, no error tolerances.

    Supported subset: "pose" (Pose3) and "point" (Point3) variables, fixed ones held by
    NonlinearEquality; Range with a lever arm on its first end only (RangeFactorWithTransform to a
    Point3, or to a Pose3's origin) or none (RangeFactor3D / RangeFactor3), no bias;
    PosePositionPrior (PoseTranslationPrior3D), PoseRotationPrior (PoseRotationPrior3D), Prior on
    points, Height on a pose without lever arm (a translation prior, free in east and north). Returns {key: point (3,) | (p (3,), R (3, 3))}.
    """
    ids = {key: i for i, key in enumerate(graph.kinds)}
    g = gtsam.NonlinearFactorGraph()
    vals = gtsam.Values()
    for key, kind in graph.kinds.items():
        if kind == "pose":
            p, R = init[key]
            v = gtsam.Pose3(gtsam.Rot3(np.asarray(R, float)), np.asarray(p, float))
            vals.insert(ids[key], v)
            if key in graph.fixed:
                g.add(gtsam.NonlinearEqualityPose3(ids[key], v))
        elif kind == "point":
            v = np.asarray(init[key], float).copy()
            vals.insert(ids[key], v)
            if key in graph.fixed:
                g.add(gtsam.NonlinearEqualityPoint3(ids[key], v))
        else:
            raise ValueError(f"solve_graph_gtsam: variable kind {kind!r} not supported")
    for f in graph.factors:
        if isinstance(f, gm.Range):
            if f.bias is not None or (f.lever_b is not None and np.any(f.lever_b)):
                raise ValueError("solve_graph_gtsam: ranges with a bias or a lever on the second end are not supported")
            noise = gtsam.noiseModel.Isotropic.Sigma(1, float(f.sigma))
            a, b = ids[f.a], ids[f.b]
            kb = graph.kinds[f.b]
            if graph.kinds[f.a] == "pose":
                T = gtsam.Pose3(gtsam.Rot3(), np.zeros(3) if f.lever_a is None else np.asarray(f.lever_a, float))
                cls = gtsam.RangeFactorWithTransformPose3 if kb == "pose" else gtsam.RangeFactorWithTransform3D
                g.add(cls(a, b, float(f.d), noise, T))
            elif kb == "point":
                g.add(gtsam.RangeFactor3(a, b, float(f.d), noise))
            else:
                g.add(gtsam.RangeFactor3D(b, a, float(f.d), noise))
        elif isinstance(f, gm.PoseRotationPrior):
            g.add(gtsam.PoseRotationPrior3D(ids[f.key], gtsam.Rot3(np.asarray(f.z, float)),
                                            gtsam.noiseModel.Gaussian.Covariance(np.asarray(f.cov, float))))
        elif isinstance(f, gm.Prior) and graph.kinds[f.key] == "pose":
            g.add(gtsam.PoseTranslationPrior3D(ids[f.key], np.asarray(f.z, float),
                                               gtsam.noiseModel.Gaussian.Covariance(np.asarray(f.cov, float))))
        elif isinstance(f, gm.Height) and graph.kinds[f.key] == "pose" and (f.lever is None or not np.any(f.lever)):
            # GTSAM has no height factor: a translation prior with (east, north) variance 1e12 m^2
            # (weight 1e-12: it moves the optimum by ~1e-14 m at 10 m offsets) and sigma on up
            cov = np.diag([_FREE_VAR, _FREE_VAR, float(f.sigma) ** 2])
            g.add(gtsam.PoseTranslationPrior3D(ids[f.key], np.array([0.0, 0.0, float(f.z)]),
                                               gtsam.noiseModel.Gaussian.Covariance(cov)))
        elif isinstance(f, gm.Prior) and graph.kinds[f.key] == "point":
            g.add(gtsam.PriorFactorPoint3(ids[f.key], np.asarray(f.z, float),
                                          gtsam.noiseModel.Gaussian.Covariance(np.asarray(f.cov, float))))
        else:
            raise ValueError(f"solve_graph_gtsam: factor {type(f).__name__} not supported")
    params = gtsam.GaussNewtonParams()
    params.setRelativeErrorTol(0.0)
    params.setAbsoluteErrorTol(0.0)
    params.setErrorTol(0.0)
    params.setMaxIterations(max_iter)
    res = gtsam.GaussNewtonOptimizer(g, vals, params).optimize()
    out = {}
    for key, kind in graph.kinds.items():
        if kind == "pose":
            T = res.atPose3(ids[key])
            out[key] = (np.asarray(T.translation(), float), np.asarray(T.rotation().matrix(), float))
        else:
            out[key] = np.asarray(res.atPoint3(ids[key]), float)
    return out
