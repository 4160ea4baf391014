"""The GTSAM check of the centralized factor-graph solver, applied to the epoch graphs of ANY
estimator that exposes them: an estimator object with `factor_graphs()` -> [(t s, CoopProblem)]
(estimators.factor_graph; the coop.* built-ins, testbed.plugins.builtin_coop).

Each graph is solved with independent ranges (its `range_sigma`, no joint `range_cov`: GTSAM's
range factors are independent) by our Gauss-Newton (estimators.factor_graph.solve_centralized,
its defaults) and by GTSAM's (estimators.gtsam_reference.solve_gtsam: Gauss-Newton with QR, driven
to a step below 1e-10 m). Both stop on the step, not on the cost, so both reach the optimum to
~1e-11 m and POS_TOL_M = 1e-8 m tests it with margin. GTSAM's Levenberg-Marquardt is reported, not
judged: it accepts a step only if the evaluated cost decreases, and the cost's round-off (~3e-14
relative) stalls it up to ~8e-7 m short of the optimum on coop-fg epochs. The check compares the
solver on the graph, not the estimator's own estimates (a distributed estimator solves the same
graph approximately).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

#: our centralized optimum vs GTSAM's Gauss-Newton on every epoch (both reach ~1e-11 m of it)
POS_TOL_M = 1e-8
#: relative to each vehicle's largest marginal entry: above the round-off of inverting A^T A
#: (cond(A^T A) eps <= 1.9e4 * 2.2e-16 = 4e-12; measured <= 2e-13) and above what the 1e-8 m position
#: tolerance can move the Jacobian (1e-8 m / 22 m, the shortest range of seed 1 in 300 s: 5e-10)
COV_RTOL = 1e-9
CRITERION = (f"every epoch: positions within {POS_TOL_M:g} m of GTSAM Gauss-Newton, marginal covariances within "
             f"{COV_RTOL:g} of each vehicle's largest entry (GTSAM Levenberg-Marquardt reported only: its cost-based "
             "acceptance stalls at round-off)")


def exposes_graphs(obj: object) -> bool:
    """Does the estimator (class or object) expose its epoch graphs (factor_graphs())?"""
    return callable(getattr(obj, "factor_graphs", None))


def _key(t: float, prob) -> tuple:
    """An epoch graph's identity (time and every array the check solves), to check a graph once."""
    return (round(float(t), 9), prob.gnss_pos.tobytes(), prob.gnss_cov.tobytes(), prob.edges.tobytes(),
            prob.ranges.tobytes(), np.asarray(prob.range_sigma).tobytes())


def _one(prob) -> tuple[float, float, float]:
    """(max |dx| m vs GTSAM GN, max covariance difference relative to each vehicle's largest entry,
    max |dx| m vs GTSAM LM) of one graph with independent ranges."""
    # lazy: GTSAM is a heavy optional dependency, loaded only for this check
    from estimators.factor_graph import solve_centralized
    from estimators.gtsam_reference import solve_gtsam

    prob = replace(prob, range_cov=None)
    ours = solve_centralized(prob)
    Xg, Pg = solve_gtsam(prob)
    Xl, _ = solve_gtsam(prob, optimizer="lm", marginals=False)
    scale = np.abs(Pg).max(axis=(1, 2))[:, None, None]
    return (float(np.abs(ours.positions - Xg).max()), float((np.abs(ours.cov - Pg) / scale).max()),
            float(np.abs(ours.positions - Xl).max()))


def gtsam_check(estimators: dict[str, object]) -> dict[str, dict]:
    """{key: check} for every estimator object of `estimators` ({key: object}) that exposes its
    epoch graphs (others are left out); a graph shared by several is solved once. check: epochs,
    max and median position difference (m), max relative covariance difference, max position
    difference vs GTSAM LM (m), holds (both tolerances on every epoch), criterion."""
    done: dict[tuple, tuple[float, float, float]] = {}
    out = {}
    for key, est in estimators.items():
        if not exposes_graphs(est):
            continue
        diffs = []
        for t, prob in est.factor_graphs():
            k = _key(t, prob)
            if k not in done:
                done[k] = _one(prob)
            diffs.append(done[k])
        d = np.array(diffs, float).reshape(-1, 3)
        dpos, dcov = float(d[:, 0].max(initial=0.0)), float(d[:, 1].max(initial=0.0))
        out[key] = {"epochs": int(d.shape[0]), "max_position_diff_m": dpos,
                    "median_position_diff_m": float(np.median(d[:, 0])) if d.size else 0.0,
                    "max_cov_rel_diff": dcov, "max_position_diff_vs_gtsam_lm_m": float(d[:, 2].max(initial=0.0)),
                    "holds": bool(d.shape[0] > 0 and dpos <= POS_TOL_M and dcov <= COV_RTOL), "criterion": CRITERION}
    return out
