"""Gauss-Newton / Levenberg-Marquardt iteration on any whitened least-squares problem.

The problem is given by three functions of the current iterate x (any object):
    cost(x) -> float                      robust objective sum rho(|b_k|)
    system(x) -> (A, b)                   IRLS-weighted whitened Jacobian (sparse, rows x k) and error
    retract(x, delta) -> x'               x "plus" the step delta (k,) (vector addition, or a
                                          manifold retraction for poses)
LM (Marquardt's scaling, Nielsen's damping update): solve (N + lam D) Delta = g with N = A^T A,
g = A^T b, D = diag(N); the gain ratio q = (F(x) - F(x + Delta)) / (L(0) - L(Delta)),
L(0) - L(Delta) = Delta^T (lam D Delta + g) / 2, decides: q > 0 accepts and
lam *= max(1/3, 1 - (2q - 1)^3), else lam *= nu, nu *= 2 (Madsen, Nielsen, Tingleff 2004, "Methods
for non-linear least squares problems", eq. 2.21 and algorithm 3.16). GN: the undamped step with
backtracking (halving) until the cost does not rise; a singular N stops the iteration.
Convergence: an accepted step whose largest component is below step_tol (GN: the full step, which
estimates the distance to the optimum, not a halved one) or, if cost_tol > 0, whose relative cost
decrease is below cost_tol. Steps whose predicted decrease is below the round-off of the cost
(ROUNDOFF relative) are accepted whatever the evaluated cost does: there the cost cannot order the
iterates (on coop-fg epochs it scatters by ~3e-14 relative, i.e. it cannot tell points ~5e-7 m
apart along the weakest direction), so a cost test would stop short of the optimum; the step test
decides. Reaching max_iter is a result (converged False), never an exception.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from estimators.graph.linear import factor_spd

__all__ = ["ROUNDOFF", "Iterate", "minimize", "marquardt_scaling", "damping_update"]

#: relative cost change at the round-off level of the cost sum
ROUNDOFF = 1e-14


@dataclass(frozen=True, slots=True)
class Iterate:
    """Outcome of `minimize`: x, its cost, iterations (linear solves, rejected LM steps
    included), converged, history (cost after each accepted step, first entry: initial cost),
    N (sparse normal matrix A^T A at x, undamped)."""

    x: object
    cost: float
    iterations: int
    converged: bool
    history: tuple
    N: sparse.csc_matrix


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


def minimize(x, cost, system, retract, *, method: str = "lm", max_iter: int = 50, step_tol: float = 1e-8,
             cost_tol: float = 1e-12, max_halvings: int = 30, lm_lambda: float = 1e-4) -> Iterate:
    """Minimize cost from x (see the module docstring); method "gn" or "lm"."""
    if method not in ("gn", "lm"):
        raise ValueError(f"minimize: method must be 'gn' or 'lm', got {method!r}")
    f = cost(x)
    history = [f]
    converged = False
    it = 0
    lam, nu = lm_lambda, 2.0
    A, b = system(x)
    N, g = (A.T @ A).tocsc(), A.T @ b
    while it < max_iter:
        it += 1
        if method == "lm":
            D = marquardt_scaling(N.diagonal())
            fac = factor_spd(N + sparse.diags(lam * D))
            if not fac.ok:  # as a rejected step
                lam, nu = damping_update(lam, nu, -1.0, False)
                continue
            delta = fac.solve(g)
            x_new = retract(x, delta)
            f_new = cost(x_new)
            pred = 0.5 * float(delta @ (lam * D * delta + g))
            q = (f - f_new) / pred if pred > 0 else -1.0
            if pred <= ROUNDOFF * f:
                q = 1.0  # the cost cannot judge a step this small (its own round-off): take it, the step test decides
            lam, nu = damping_update(lam, nu, q, not q <= 0)
            if q <= 0:
                if lam > 1e16:  # no decrease even for a vanishing step: at a minimum to round-off
                    converged = bool(np.abs(delta).max() < step_tol)
                    break
                continue
            step = np.abs(delta).max()
        else:
            fac = factor_spd(N)
            if not fac.ok:
                it -= 1
                break
            delta = fac.solve(g)
            pred = 0.5 * float(delta @ g)
            t = 1.0
            for _ in range(max_halvings + 1):
                x_new = retract(x, t * delta)
                f_new = cost(x_new)
                if f_new <= f * (1.0 + ROUNDOFF) or pred <= ROUNDOFF * f:
                    break
                t *= 0.5
            else:
                converged = bool(np.abs(delta).max() < step_tol)
                it -= 1
                break
            step = np.abs(delta).max()  # the full step estimates the distance to the optimum, a halved one does not
        small = step < step_tol or (cost_tol > 0.0 and f - f_new < cost_tol * max(f, 1e-300))
        x, f = x_new, f_new
        history.append(f)
        A, b = system(x)
        N, g = (A.T @ A).tocsc(), A.T @ b
        if small:
            converged = True
            break
    return Iterate(x, f, it, converged, tuple(history), N)
