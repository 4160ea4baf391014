"""Gauss-Newton / Levenberg-Marquardt: the one iteration of every factor graph of the testbed, and
the round iteration of its distributed (message-passing) solvers.

`solve(problem, x)` minimizes a batch of E independent robust least-squares problems at once (E = 1:
one graph, sparse; E > 1: the epochs of estimators.graph.batch, dense, or the agents of the
sliding window, estimators.window, block-tridiagonal). The problem gives:
    size                                  E
    evaluate(x) -> (cost (E,), memo)      robust objective sum rho(|b_k|) of each problem, and
                                          whatever `normal` may reuse at the same x (or None)
    normal(x, memo) -> normal equations   IRLS-weighted N delta = g of each problem at x
                                          (estimators.graph.linear: SparseNormal, DenseNormals,
                                          BlockTridiagonalNormals)
    retract(x, delta) -> x'               x "plus" the steps delta (E, k) (vector addition, or a
                                          manifold retraction for poses)
    select(mask, a, b) -> x               per problem a where mask (E,) else b
    subset(keep) -> problem (optional)    the problems keep (E,) bool alone; x then is a tuple of
                                          arrays with the problems on axis 0
`minimize(x, cost, system, retract)` is the same iteration for one problem given by three functions.

LM (Marquardt's scaling, Nielsen's damping update): solve (N + lam D) Delta = g with N = A^T A,
g = A^T b, D = diag(N); the gain ratio q = (F(x) - F(x + Delta)) / (L(0) - L(Delta)),
L(0) - L(Delta) = Delta^T (lam D Delta + g) / 2, decides: q > 0 accepts and
lam *= max(1/3, 1 - (2q - 1)^3), else lam *= nu, nu *= 2 (Madsen, Nielsen, Tingleff 2004, "Methods
for non-linear least squares problems", eq. 2.21 and algorithm 3.16); a damped matrix that is not
positive definite is a rejected step. GN: the undamped step with backtracking (halving) until the
cost does not rise by more than its round-off (`roundoff`); a singular N, or no halving that does
so, stops the iteration (the step that failed is not counted). A batch halves each problem's step
on its own.
Convergence, per problem: an accepted step whose largest component is below step_tol (GN: the full
step, which estimates the distance to the optimum, not a halved one), or (cost_tol > 0) whose
relative cost decrease is below cost_tol, or (step_sigma > 0) that is shorter than step_sigma
standard deviations of the estimate, sqrt(Delta^T N Delta) < step_sigma with N where the step
starts, or (stop given) that passes the caller's own test stop(delta, lin) -> (E,) bool, called
after every linear solve with its full step delta (E, k) and the normal equations lin it solved;
also a rejected (LM) or failed (GN) step whose largest component is below step_tol (the
minimum is within step_tol; round-off decides the cost there). Steps whose predicted decrease is
below the round-off of the cost (`roundoff` relative) are taken whatever the evaluated cost does:
there the cost cannot order the iterates (on coop-fg epochs it scatters by ~3e-14 relative, i.e. it cannot tell points
~5e-7 m apart along the weakest direction), so a cost test would stop short of the optimum; the
step test decides. Reaching max_iter is a result (converged False), never an exception.

`iterate_rounds(x, round_fn)` is the round iteration of the distributed solvers (the paper's
message iteration in estimators.factor_graph, loopy GBP in estimators.graph.gbp): every round the
nodes exchange messages and each takes its step; converged when every node's step is below tol,
stopped (not converged) when a step is not finite or above DIVERGED_M.
Every solver's result carries the `Report` of its iteration.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.graph.linear import SparseNormal

__all__ = ["ROUNDOFF", "DIVERGED_M", "Report", "Iterate", "solve", "minimize", "iterate_rounds",
           "marquardt_scaling", "damping_update"]

#: relative cost change at the round-off level of the cost sum
ROUNDOFF = 1e-14
#: a node step this large (metres) means a distributed iteration diverged
DIVERGED_M = 1e5
METHODS = ("gn", "lm")


@dataclass(frozen=True, slots=True)
class Report:
    """How an iteration of this module went.

    method: "gn", "lm" or "rounds"; iterations: (E,) int, linear solves per problem (LM: rejected
    steps included; GN: accepted steps) or rounds; converged: (E,) bool; cost: (E,) final robust
    cost (NaN for rounds); trace: one problem only (else empty): GN/LM the cost after each
    accepted step, first entry the initial cost; rounds: the largest node step of each round (m).
    """

    method: str
    iterations: np.ndarray
    converged: np.ndarray
    cost: np.ndarray
    trace: tuple


@dataclass(frozen=True, slots=True)
class Iterate:
    """Outcome of `minimize`: x, its cost, iterations (linear solves, rejected LM steps
    included), converged, history (cost after each accepted step, first entry: initial cost),
    N (sparse normal matrix A^T A at x, undamped) and the `Report`."""

    x: object
    cost: float
    iterations: int
    converged: bool
    history: tuple
    N: object
    report: Report


def marquardt_scaling(diag: np.ndarray) -> np.ndarray:
    """Marquardt's damping scale D (..., k) from the diagonal of the normal matrix diag(N) (..., k):
    diag(N) floored at 1e-12 of its largest entry (an unknown without information still gets a
    positive damping)."""
    return np.maximum(diag, 1e-12 * np.maximum(diag.max(axis=-1, keepdims=True, initial=0.0), 1e-300))


def damping_update(lam, nu, q, accept):
    """Nielsen's update of the damping lam and its growth nu after a step of gain ratio q (Madsen,
    Nielsen, Tingleff 2004, eq. 2.21): accepted lam max(1/3, 1 - (2q - 1)^3) and nu = 2, rejected
    lam nu and 2 nu. Scalars or arrays of one shape (one damping per problem); accept (bool, same
    shape) is the caller's test (q > 0)."""
    qc = np.clip(q, 0.0, 1.0)  # the factor is 1/3 for every q >= 1: no overflow for a huge |q|
    return (np.where(accept, lam * np.fmax(1.0 / 3.0, 1.0 - (2.0 * qc - 1.0) ** 3), lam * nu),
            np.where(accept, 2.0, nu * 2.0))


def _take(x: tuple, idx) -> tuple:
    return tuple(a[idx] for a in x)


def _put(full: tuple, idx, part: tuple) -> None:
    for a, b in zip(full, part):
        a[idx] = b


def solve(problem, x, *, method: str = "lm", max_iter: int = 50, step_tol: float = 1e-8, cost_tol: float = 1e-12,
          step_sigma: float = 0.0, max_halvings: int = 30, lm_lambda: float = 1e-4, stop=None,
          roundoff: float = ROUNDOFF):
    """Minimize every problem of the batch from x (see the module docstring); method "gn" or "lm";
    roundoff: the relative round-off of the problem's cost (ROUNDOFF for a plain sum of squares;
    larger where the cost is computed with cancellation). Returns (x, the normal equations at x
    (undamped), Report)."""
    if method not in METHODS:
        raise ValueError(f"lm.solve: method must be 'gn' or 'lm', got {method!r}")
    E0 = problem.size
    f, memo = problem.evaluate(x)
    lin = problem.normal(x, memo)
    trace = [float(f[0])] if E0 == 1 else None
    lam, nu = np.full(E0, float(lm_lambda)), np.full(E0, 2.0)
    active = np.full(E0, max_iter > 0)
    converged, iterations = np.zeros(E0, bool), np.zeros(E0, np.int64)
    ids, store = np.arange(E0), None
    while active.any():
        if hasattr(problem, "subset") and active.sum() <= active.size // 2:
            # most problems done: continue on the others alone, keep the results of the rest
            if store is None:
                store = (tuple(np.array(a) for a in x), type(lin)(lin.N.copy(), lin.g.copy()), f.copy(),
                         iterations.copy(), converged.copy())
            else:
                _put(store[0], ids, x)
                store[1].put(ids, lin)
                store[2][ids], store[3][ids], store[4][ids] = f, iterations, converged
            problem, x, lin, ids = problem.subset(active), _take(x, active), lin.take(active), ids[active]
            f, lam, nu, iterations, converged = f[active], lam[active], nu[active], iterations[active], converged[active]
            active = np.ones(ids.size, bool)
        iterations += active
        g = lin.g
        if method == "lm":
            D = marquardt_scaling(lin.diagonal())
            delta, ok = lin.solve(lam[:, None] * D)
        else:
            delta, ok = lin.solve(None)
        delta = np.where((active & ok)[:, None], delta, 0.0)
        step = np.abs(delta).max(axis=1, initial=0.0)
        own = stop(delta, lin) if stop is not None else False
        if method == "lm":
            x_new = problem.retract(x, delta)
            f_new, memo = problem.evaluate(x_new)
            # gain ratio q = (F(x) - F(x + Delta)) / (L(0) - L(Delta)), L(0) - L(Delta) = Delta^T (lam D Delta + g) / 2
            pred = 0.5 * np.einsum("ek,ek->e", delta, lam[:, None] * D * delta + g)
            with np.errstate(divide="ignore", invalid="ignore"):
                q = np.where(pred > 0, (f - f_new) / pred, -1.0)
            # the cost cannot tell this step apart: take it, the step test decides
            q = np.where(pred <= roundoff * f, 1.0, q)
            q = np.where(ok, q, -1.0)
            accept = active & (q > 0)
            # Madsen, Nielsen, Tingleff 2004, eq. 2.21 (algorithm 3.16)
            lam_new, nu_new = damping_update(lam, nu, q, accept)
            lam, nu = np.where(active, lam_new, lam), np.where(active, nu_new, nu)
            stopped = active & ~accept
            tiny = stopped & ok & (step < step_tol)
            stopped &= tiny | (lam > 1e16)  # else a rejected step: try again with more damping
        else:
            pred = 0.5 * np.einsum("ek,ek->e", g, delta)
            x_new, f_new = x, f.copy()
            accept, pending, t = np.zeros_like(active), active & ok, np.ones(delta.shape[0])
            for _ in range(max_halvings + 1):
                x_try = problem.retract(x, t[:, None] * delta)
                # the problems are independent and an accepted one keeps its t: the last trial's
                # memo is that of every accepted problem's new x
                f_try, memo = problem.evaluate(x_try)
                good = pending & ((f_try <= f * (1.0 + roundoff)) | (pred <= roundoff * f))
                x_new, f_new = problem.select(good, x_try, x_new), np.where(good, f_try, f_new)
                accept |= good
                pending &= ~good
                if not pending.any():
                    break
                t = np.where(pending, 0.5 * t, t)
            stopped = active & ~accept  # a singular N, or no halving lowers the cost
            iterations -= stopped
            tiny = stopped & ok & (step < step_tol)
        small = accept & (step < step_tol)
        if cost_tol > 0.0:
            small |= accept & (f - f_new < cost_tol * np.maximum(f, 1e-300))
        if step_sigma > 0.0:
            small |= accept & (lin.quad(delta) < step_sigma ** 2)
        small |= accept & own
        converged |= small | tiny
        active &= ~(small | stopped) & (iterations < max_iter)
        if accept.any():
            x = problem.select(accept, x_new, x)
            lin = problem.normal(x_new, memo).where(accept, lin)
            f = np.where(accept, f_new, f)
            if trace is not None:
                trace.append(float(f[0]))
    if store is not None:
        _put(store[0], ids, x)
        store[1].put(ids, lin)
        store[2][ids], store[3][ids], store[4][ids] = f, iterations, converged
        x, lin, f, iterations, converged = store
    return x, lin, Report(method, iterations, converged, f, tuple(trace or ()))


class _One:
    """One problem given by functions (see `minimize`) as a batch of one."""

    size = 1

    def __init__(self, cost, system, retract):
        self.cost, self.system, self._retract = cost, system, retract

    def evaluate(self, x):
        return np.array([float(self.cost(x))]), None

    def normal(self, x, memo):
        lin = self.system(x)
        return SparseNormal.from_whitened(*lin) if isinstance(lin, tuple) else lin

    def retract(self, x, delta):
        return self._retract(x, delta[0])

    @staticmethod
    def select(mask, a, b):
        return a if mask[0] else b


def minimize(x, cost, system, retract, *, method: str = "lm", max_iter: int = 50, step_tol: float = 1e-8,
             cost_tol: float = 1e-12, max_halvings: int = 30, lm_lambda: float = 1e-4) -> Iterate:
    """Minimize one problem from x (any object) with `solve`: cost(x) -> float the robust objective;
    system(x) -> the IRLS-weighted whitened system (A sparse (rows, k), b (rows,)) or its normal
    equations (a SparseNormal, e.g. a Newton step); retract(x, delta (k,)) -> x'."""
    x, lin, rep = solve(_One(cost, system, retract), x, method=method, max_iter=max_iter, step_tol=step_tol,
                        cost_tol=cost_tol, max_halvings=max_halvings, lm_lambda=lm_lambda)
    return Iterate(x, float(rep.cost[0]), int(rep.iterations[0]), bool(rep.converged[0]), rep.trace, lin.N, rep)


def iterate_rounds(x: np.ndarray, round_fn, *, max_rounds: int, tol: float | None, ord=None):
    """The distributed round iteration (module docstring) from the node estimates x (n, d):
    round_fn(r, x) -> x' runs round r (messages, each node's step). Stops when every node's step
    |x'_i - x_i| is below tol (converged; tol None: never, the caller runs max_rounds), after
    max_rounds, or when a step is not finite or above DIVERGED_M (not converged). ord: the
    vector norm of a node's step (numpy.linalg.norm's; None Euclidean, numpy.inf the largest
    component).
    Returns (x, history (rounds + 1, n, d) with x0 first, Report)."""
    hist, steps = [x.copy()], []
    converged = False
    for rnd in range(max_rounds):
        x_new = round_fn(rnd, x)
        step = float(np.linalg.norm(x_new - x, ord=ord, axis=1).max()) if x.shape[0] else 0.0
        x = x_new
        hist.append(x.copy())
        steps.append(step)
        if not np.isfinite(step) or step > DIVERGED_M:
            break  # diverged: reported with converged False, never as convergence
        if tol is not None and step < tol:
            converged = True
            break
    rep = Report("rounds", np.array([len(steps)]), np.array([converged]), np.array([np.nan]), tuple(steps))
    return x, np.asarray(hist), rep
