"""The filter family of seed 004 on one shared model interface: EKF, CKF, HCKF, MCKF, RHCF.

Every filter is one ``ComposedFilter(name, model, time_update, measurement_update)`` on the
estimator interface of ``estimators.core`` (predict(belief, dt, u), update(belief, measurement),
run by ``core.drive``); the five differ only in the step where the method differs:

    filter  time update                      measurement update
    EKF     linearized (analytic F)          Kalman, analytic Jacobian H, Joseph form
    CKF     third-degree cubature            Kalman on the cubature moments (P_yy, P_xy)
    HCKF    fifth-degree cubature            Kalman on the fifth-degree moments
    MCKF    linearized (analytic F)          correntropy fixed point (Chen et al. 2017), analytic H
    RHCF    fifth-degree cubature (eq. 18-22) correntropy fixed point on the statistically
                                             linearized measurement H = (P^-1 P_xy)^T (eq. 23-48)

Model interface (``StateSpaceModel``): the mean x is a point of a manifold stored as a vector
(nx,), the covariance lives in the tangent space (n, n), n = model.dim. The true state is
x_true = x (+) dx with dx ~ N(0, P). ``boxplus(X, dX)`` and ``boxminus(Xa, Xb)`` are batched
over the first axis, so attitude is never subtracted naively. For a Euclidean model nx = n and
(+) is +. Process: ``f(X, u, dt)`` maps a batch (N, nx) of states, ``F(x, u, dt)`` is the (n, n)
Jacobian of the error state (dx' = F dx), ``Q(x, u, dt)`` the (n, n) additive process noise.
Measurements come as ``Measurement`` objects: the measured vector y (m,), the noise R (m, m),
the batched prediction h(X) -> (N, m) and the analytic Jacobian jacobian(x) -> (m, n) (EKF/MCKF).

Sigma points are one array (L, nx); every step is vectorized over the points.

SPD handling (HCKF, negative weights for n > 4): every covariance a filter returns passes through
``ensure_spd``: symmetrize, then a Cholesky test. When the test fails (the weighted sum with
negative weights of a strongly nonlinear map is indefinite) the covariance is repaired by an
eigenvalue floor applied in correlation coordinates (D^-1 P D^-1, D = sqrt(diag P)), so that
states of very different units (metres and rad/s biases) each keep their own scale, and a
``SpdRepairWarning`` is emitted and the repair is counted (``core.tally``: the driver records
it in the track's ``covariance_repairs``). A correntropy update whose fixed point fails (stops at ``max_iter``
unconverged, LinAlgError, non-finite iterate) falls back to the plain Kalman update for that step and
is counted as ``nonconverged_iterations`` and ``fallback_updates``. The same test guards P_yy before its Cholesky solve. In addition
the cubature Kalman update is computed in Joseph form with the *effective* noise
R_eff = P_yy - H P H^T, H = P_xy^T P^-1; this is algebraically the textbook P - K P_yy K^T and
stays PSD whenever R_eff is PSD (always, for a rule with positive weights).

Pure numpy/scipy; never imports mujoco or testbed.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable, Literal, NamedTuple, Protocol

import numpy as np
from scipy import linalg

from estimators.core import Gaussian, joseph_update, kalman_gain, symmetrize, tally
from estimators.cubature import CubatureRule, fifth_degree_rule, third_degree_rule


# --------------------------------------------------------------------------------------------
# Beliefs and model interface
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ManifoldGaussian(Gaussian):
    """A Gaussian on a manifold: mean (nx,) is a point, cov (n, n) lives in the tangent space at it.

    x_true = mean (+) dx, dx ~ N(0, cov). nx may exceed n (a quaternion has 4 numbers, 3 degrees of
    freedom); everything else is as core.Gaussian. NEES: core.nees(model.boxminus(est, true_state), cov).
    """

    def __post_init__(self) -> None:
        if self.mean.ndim != 1 or self.cov.ndim != 2 or self.cov.shape[0] != self.cov.shape[1]:
            raise ValueError(f"ManifoldGaussian: mean {self.mean.shape}, cov {self.cov.shape}")
        if self.cov.shape[0] > self.mean.shape[0]:
            raise ValueError("ManifoldGaussian: tangent dimension exceeds the mean's length")


class Measurement(Protocol):
    """One measurement, ready for any filter of the family.

    y: (m,) measured vector; R: (m, m) noise covariance (SPD);
    h(X): (N, nx) -> (N, m) prediction, batched; jacobian(x): (nx,) -> (m, n) d h / d dx at x.
    """

    y: np.ndarray
    R: np.ndarray

    def h(self, X: np.ndarray) -> np.ndarray: ...

    def jacobian(self, x: np.ndarray) -> np.ndarray: ...


class StateSpaceModel(Protocol):
    """The model interface shared by all filters (see module docstring)."""

    dim: int

    def f(self, X: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray: ...

    def F(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray: ...

    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray: ...

    def boxplus(self, X: np.ndarray, dX: np.ndarray) -> np.ndarray: ...

    def boxminus(self, Xa: np.ndarray, Xb: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True, slots=True, eq=False)
class FunctionMeasurement:
    """A Measurement built from two callables. Shapes as in ``Measurement``."""

    y: np.ndarray
    R: np.ndarray
    h_fn: Callable[[np.ndarray], np.ndarray]
    jacobian_fn: Callable[[np.ndarray], np.ndarray]

    def h(self, X: np.ndarray) -> np.ndarray:
        return self.h_fn(X)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        return self.jacobian_fn(x)


@dataclass(frozen=True, slots=True, eq=False)
class LinearGaussianModel:
    """Euclidean linear model x' = A x + B u + w, w ~ N(0, Qd); the reference for the tests.

    A: (n, n); Qd: (n, n) per step; B: (n, k) or None. dt is accepted and ignored.
    """

    A: np.ndarray
    Qd: np.ndarray
    B: np.ndarray | None = None

    @property
    def dim(self) -> int:
        return int(self.A.shape[0])

    def f(self, X, u, dt):
        out = X @ self.A.T
        if self.B is not None and u is not None:
            out = out + self.B @ u
        return out

    def F(self, x, u, dt):
        return self.A

    def Q(self, x, u, dt):
        return self.Qd

    def boxplus(self, X, dX):
        return X + dX

    def boxminus(self, Xa, Xb):
        return Xa - Xb


@dataclass(frozen=True, slots=True, eq=False)
class LinearMeasurement:
    """y = H x + v, v ~ N(0, R). y: (m,), H: (m, n), R: (m, m)."""

    y: np.ndarray
    H: np.ndarray
    R: np.ndarray

    def h(self, X):
        return X @ self.H.T

    def jacobian(self, x):
        return self.H


# --------------------------------------------------------------------------------------------
# Numerics
# --------------------------------------------------------------------------------------------
class SpdRepairWarning(UserWarning):
    """A covariance was not positive definite and was repaired by an eigenvalue floor."""


def ensure_spd(P: np.ndarray, rel_floor: float = 1e-12, what: str = "covariance") -> np.ndarray:
    """Return P symmetrized and, if its Cholesky factorization fails, repaired to SPD.

    P: (n, n). Repair: D = sqrt(diag P) (non-positive diagonal entries replaced by
    rel_floor * max diag), C = D^-1 P D^-1, eigenvalues of C floored at rel_floor * max(1, lambda_max),
    P = D C D. When a repair happens, emits SpdRepairWarning and tallies a covariance repair
    (core.tally); an SPD input is returned as symmetrize(P), untouched otherwise.
    """
    P = symmetrize(np.asarray(P, dtype=float))
    try:
        np.linalg.cholesky(P)
        return P
    except np.linalg.LinAlgError:
        pass
    if not np.all(np.isfinite(P)):
        raise FloatingPointError(f"ensure_spd: {what} has non-finite entries")
    diag = np.diag(P).copy()
    dmax = float(diag.max()) if diag.max() > 0 else 1.0
    diag = np.where(diag > rel_floor * dmax, diag, rel_floor * dmax)
    d = np.sqrt(diag)
    C = P / np.outer(d, d)
    lam, V = np.linalg.eigh(symmetrize(C))
    lam = np.maximum(lam, rel_floor * max(1.0, float(lam.max())))
    C = (V * lam) @ V.T
    tally(covariance_repairs=1)
    warnings.warn(f"{what} was not positive definite; repaired by an eigenvalue floor",
                  SpdRepairWarning, stacklevel=2)
    return symmetrize(C * np.outer(d, d))


def _chol(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor S of an SPD P (P = S S^T)."""
    return np.linalg.cholesky(P)


def _new_belief(like: Gaussian, mean: np.ndarray, cov: np.ndarray) -> Gaussian:
    return type(like)(mean, cov)


def sigma_points(model: StateSpaceModel, belief: Gaussian, rule: CubatureRule) -> tuple[np.ndarray, np.ndarray]:
    """Cubature points of a belief (eq. 18 / 23): X_i = mean (+) S xi_i, P = S S^T.

    Returns X (L, nx) and the tangent offsets dX = S xi_i as rows (L, n).
    """
    S = _chol(belief.cov)
    dX = (S @ rule.points).T
    X = model.boxplus(np.broadcast_to(belief.mean, (rule.size, belief.mean.size)), dX)
    return X, dX


def manifold_weighted_mean(model: StateSpaceModel, X: np.ndarray, w: np.ndarray,
                           ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean of points X (L, nx) on the manifold, and the deviations from it (L, n).

    One Gauss-Newton step about the reference point ref (nx,): mean = ref (+) sum_i w_i (X_i (-) ref),
    then deviations D_i = X_i (-) mean with their weighted mean removed. For a Euclidean model this
    is exactly sum_i w_i X_i (eq. 20 / 25).
    """
    L = X.shape[0]
    d_ref = model.boxminus(X, np.broadcast_to(ref, X.shape))
    mean = model.boxplus(ref[None, :], (w @ d_ref)[None, :])[0]
    D = model.boxminus(X, np.broadcast_to(mean, (L, mean.size)))
    return mean, D - w @ D


# --------------------------------------------------------------------------------------------
# Time updates
# --------------------------------------------------------------------------------------------
def linearized_predict(model: StateSpaceModel, belief: Gaussian, u: np.ndarray | None, dt: float) -> Gaussian:
    """EKF time update: x' = f(x), P' = F P F^T + Q (F, Q at the prior mean)."""
    x = belief.mean
    F = model.F(x, u, dt)
    xp = model.f(x[None, :], u, dt)[0]
    P = ensure_spd(F @ belief.cov @ F.T + model.Q(x, u, dt), what="EKF predicted covariance")
    return _new_belief(belief, xp, P)


@dataclass(frozen=True, slots=True)
class CubaturePredict:
    """Cubature time update with the rule ``rule_for(n)`` (eq. 18-21).

    Points X_i = x (+) S xi_i are propagated as one batch together with the mean itself (the
    reference of the manifold mean); P' = sum_i w_i D_i D_i^T + Q, then ensure_spd.
    """

    rule_for: Callable[[int], CubatureRule]

    def __call__(self, model: StateSpaceModel, belief: Gaussian, u: np.ndarray | None, dt: float) -> Gaussian:
        rule = self.rule_for(model.dim)
        X, _ = sigma_points(model, belief, rule)
        # eq. 19: propagate all points (and the mean, row 0) in one vectorized call
        Xp = model.f(np.vstack([belief.mean[None, :], X]), u, dt)
        # eq. 20
        mean, D = manifold_weighted_mean(model, Xp[1:], rule.weights, Xp[0])
        # eq. 21
        P = D.T @ (rule.weights[:, None] * D) + model.Q(belief.mean, u, dt)
        return _new_belief(belief, mean, ensure_spd(P, what="cubature predicted covariance"))


# --------------------------------------------------------------------------------------------
# Linearizations of a measurement: what the update steps consume
# --------------------------------------------------------------------------------------------
class Linearization(NamedTuple):
    """A measurement linearized about the prior.

    y_pred: (m,) predicted measurement; H: (m, n); Pxy: (n, m); Pyy: (m, m) innovation covariance
    (R included); R: (m, m) nominal noise; R_eff: (m, m) = Pyy - H P H^T (R plus the
    statistical-linearization error; equals R for the analytic linearization).
    """

    y_pred: np.ndarray
    H: np.ndarray
    Pxy: np.ndarray
    Pyy: np.ndarray
    R: np.ndarray
    R_eff: np.ndarray


def jacobian_linearization(model: StateSpaceModel, belief: Gaussian, meas: Measurement) -> Linearization:
    """Analytic (EKF) linearization: y_pred = h(x), H = dh/ddx, Pxy = P H^T, Pyy = H P H^T + R."""
    x, P = belief.mean, belief.cov
    H = meas.jacobian(x)
    Pxy = P @ H.T
    Pyy = symmetrize(H @ Pxy + meas.R)
    return Linearization(meas.h(x[None, :])[0], H, Pxy, Pyy, meas.R, meas.R)


@dataclass(frozen=True, slots=True)
class CubatureLinearization:
    """Statistical linearization with a cubature rule (eq. 23-27 and 31)."""

    rule_for: Callable[[int], CubatureRule]

    def __call__(self, model: StateSpaceModel, belief: Gaussian, meas: Measurement) -> Linearization:
        rule = self.rule_for(model.dim)
        w = rule.weights
        # eq. 23
        X, dX = sigma_points(model, belief, rule)
        dX = dX - w @ dX
        # eq. 24
        Y = meas.h(X)
        # eq. 25
        y_pred = w @ Y
        dY = Y - y_pred
        # eq. 26
        Pyy = ensure_spd(dY.T @ (w[:, None] * dY) + meas.R, what="innovation covariance P_yy")
        # eq. 27
        Pxy = dX.T @ (w[:, None] * dY)
        # eq. 31: H = (P^-1 P_xy)^T, by a Cholesky solve
        H = linalg.cho_solve(linalg.cho_factor(belief.cov), Pxy).T
        R_eff = symmetrize(Pyy - H @ belief.cov @ H.T)
        return Linearization(y_pred, H, Pxy, Pyy, meas.R, R_eff)


# --------------------------------------------------------------------------------------------
# Measurement updates
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class KalmanUpdate:
    """Kalman measurement update on a linearization.

    K = P_xy P_yy^-1 (Cholesky solve), dx = K (y - y_pred), x+ = x (+) dx,
    P+ = (I - K H) P (I - K H)^T + K R_eff K^T (Joseph; = P - K P_yy K^T, see module docstring).
    """

    linearize: Callable[[StateSpaceModel, Gaussian, Measurement], Linearization]

    def __call__(self, model: StateSpaceModel, belief: Gaussian, meas: Measurement) -> Gaussian:
        return kalman_step(model, belief, meas.y, self.linearize(model, belief, meas))


def kalman_step(model: StateSpaceModel, belief: Gaussian, y: np.ndarray, lin: Linearization) -> Gaussian:
    """The Kalman update of `KalmanUpdate` on a given linearization; y: (m,) the measured vector."""
    K = kalman_gain(lin.Pxy, lin.Pyy)
    dx = K @ (y - lin.y_pred)
    P = ensure_spd(joseph_update(belief.cov, K, lin.H, lin.R_eff), what="posterior covariance")
    return _new_belief(belief, model.boxplus(belief.mean[None, :], dx[None, :])[0], P)


class CorrentropySolution(NamedTuple):
    """Result of the correntropy fixed point: dx (n,), gain K (n, m), weights psi (m + n,)
    (measurement rows first), iterations used, converged flag, covariance P (n, n)."""

    dx: np.ndarray
    K: np.ndarray
    psi: np.ndarray
    iterations: int
    converged: bool
    P: np.ndarray


def correntropy_solve(P: np.ndarray, H: np.ndarray, R: np.ndarray, r: np.ndarray, *,
                      kernel_sigma: float, tol: float = 1e-6, max_iter: int = 50,
                      covariance: Literal["joseph", "information"] = "joseph",
                      weight_floor: float = 1e-12) -> CorrentropySolution:
    r"""Maximum-correntropy measurement update in error-state form (eq. 32-48; Chen et al. 2017).

    Prior dx ~ N(0, P) (n, n); linearized measurement r = y - y_pred = H dx + v, v ~ N(0, R),
    H (m, n), R (m, m). Whitening with Cholesky factors P = Lp Lp^T, R = Lr Lr^T (eq. 33-36,
    T^-1/2 := blockdiag(Lr, Lp)^-1):
        z = [Lr^-1 r ; 0],  M = [Lr^-1 H ; Lp^-1],  z = M dx + xi   (eq. 37).
    Criterion (eq. 38): J(dx) = sum_i K_s(e_i), e = z - M dx, K_s(e) = exp(-e^2 / (2 s^2)).

    Derivation of the fixed point (settles eq. 41 vs 42/43):
        dJ/d dx = sum_i K_s'(e_i) de_i/d dx,   K_s'(e) = -(e / s^2) K_s(e)          (eq. 41, correct)
                = -(1/s^2) sum_i K_s(e_i) e_i de_i/d dx = 0.
    The factor -1/s^2 is a nonzero constant of the stationarity condition, so eq. 42 with
    phi(e) = e K_s(e) is the same condition; phi is -s^2 K_s', not K_s'. Hence
        psi(e) = phi(e) / e = K_s(e)                                               (eq. 43)
    -- the weight is the kernel value itself, dimensionless, in (0, 1], -> 1 as s -> inf (the KF).
    Keeping the 1/s^2 inside Psi would not change the fixed point (eq. 46 is homogeneous in Psi)
    but would scale the eq. 48 covariance by s^2, which is wrong. With Psi = diag(psi) (eq. 44),
    M^T Psi (M dx - z) = 0 (eq. 45) is solved by iterating eq. 46 from the least-squares start
    eq. 47 (= the Kalman update). Eq. 46 in information form needs P^-1, badly conditioned when
    states of very different scales share P; we use the algebraically identical gain form of
    Chen et al. (matrix inversion lemma):
        P~ = Lp Psi_x^-1 Lp^T,  R~ = Lr Psi_y^-1 Lr^T,  K = P~ H^T (H P~ H^T + R~)^-1,  dx = K r.
    Weights are floored at weight_floor so P~ and R~ stay finite. Stop when the step, whitened
    by the prior, |Lp^-1 (dx_new - dx)| <= tol (scale-free), or after max_iter iterations.

    Covariance:
        "joseph"       Chen et al. 2017: (I - K H) P (I - K H)^T + K R K^T with the final gain;
        "information"  the paper's eq. 48, (M^T Psi M)^-1 = (I - K H) P~, computed in Joseph
                       form with (P~, R~).
    Both equal the Kalman covariance when Psi = I.
    """
    n, m = P.shape[0], r.size
    Lp = _chol(P)
    Lr = _chol(R)
    # whitening by triangular solves (never an explicit inverse); vector right-hand sides only
    def white_p(v: np.ndarray) -> np.ndarray:
        return linalg.solve_triangular(Lp, v, lower=True, check_finite=False)

    def white_r(v: np.ndarray) -> np.ndarray:
        return linalg.solve_triangular(Lr, v, lower=True, check_finite=False)

    def gain(psi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        psi_y, psi_x = psi[:m], psi[m:]
        Pt = symmetrize((Lp / psi_x[None, :]) @ Lp.T)
        Rt = symmetrize((Lr / psi_y[None, :]) @ Lr.T)
        PtHt = Pt @ H.T
        S = symmetrize(H @ PtHt + Rt)
        K = linalg.cho_solve(linalg.cho_factor(S, check_finite=False), PtHt.T, check_finite=False).T
        return K, Pt, Rt

    # eq. 47: unweighted least squares = the Kalman update
    psi = np.ones(m + n)
    K, Pt, Rt = gain(psi)
    dx = K @ r
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        # eq. 39: whitened residuals at the current iterate
        e = np.concatenate([white_r(r - H @ dx), -white_p(dx)])
        # eq. 43-44 (psi = kernel value, see the derivation above), eq. 15
        psi = np.maximum(np.exp(-0.5 * (e / kernel_sigma) ** 2), weight_floor)
        # eq. 46 (gain form)
        K, Pt, Rt = gain(psi)
        dx_new = K @ r
        step = float(np.linalg.norm(white_p(dx_new - dx)))
        dx = dx_new
        if step <= tol:
            converged = True
            break
    if covariance == "joseph":
        Pn = joseph_update(P, K, H, R)
    elif covariance == "information":
        # eq. 48
        Pn = joseph_update(Pt, K, H, Rt)
    else:
        raise ValueError(f"correntropy_solve: unknown covariance {covariance!r}")
    return CorrentropySolution(dx, K, psi, it, converged, Pn)


@dataclass(frozen=True, slots=True)
class CorrentropyUpdate:
    """Maximum-correntropy measurement update on a linearization (see correntropy_solve).

    The linearized regression (eq. 30, 32) uses H from ``linearize`` and the nominal R (eq. 33).
    kernel_sigma: kernel width in whitened (standard-deviation) units; tol, max_iter: the
    fixed-point stop; covariance: "joseph" (Chen 2017) or "information" (eq. 48).

    Graceful degradation: when the fixed point fails for a step -- it stops at max_iter
    unconverged, a factorization raises LinAlgError (e.g. H P~ H^T + R~ indefinite to round-off
    once the prior's weights hit the floor), or the iterate or its covariance is not finite --
    the step falls back to the plain Kalman update on the same linearization (`kalman_step`,
    i.e. the fixed point's own start, eq. 47, with its Joseph covariance) and is counted as one
    non-converged iteration and one fallback update (core.tally), so that a run never stops on it
    and the count reaches metrics.json (`nonconverged_steps`).
    """

    linearize: Callable[[StateSpaceModel, Gaussian, Measurement], Linearization]
    kernel_sigma: float
    tol: float = 1e-6
    max_iter: int = 50
    covariance: Literal["joseph", "information"] = "joseph"

    def __call__(self, model: StateSpaceModel, belief: Gaussian, meas: Measurement) -> Gaussian:
        lin = self.linearize(model, belief, meas)
        try:
            sol = correntropy_solve(belief.cov, lin.H, lin.R, meas.y - lin.y_pred,
                                    kernel_sigma=self.kernel_sigma, tol=self.tol,
                                    max_iter=self.max_iter, covariance=self.covariance)
            failed = not (sol.converged and np.isfinite(sol.dx).all() and np.isfinite(sol.P).all())
        except (np.linalg.LinAlgError, FloatingPointError):
            failed = True
        if failed:
            tally(nonconverged_iterations=1, fallback_updates=1)
            return kalman_step(model, belief, meas.y, lin)
        P = ensure_spd(sol.P, what="correntropy posterior covariance")
        return _new_belief(belief, model.boxplus(belief.mean[None, :], sol.dx[None, :])[0], P)


# --------------------------------------------------------------------------------------------
# The filter and the five members of the family
# --------------------------------------------------------------------------------------------
TimeUpdate = Callable[[StateSpaceModel, Gaussian, "np.ndarray | None", float], Gaussian]
MeasurementUpdate = Callable[[StateSpaceModel, Gaussian, Measurement], Gaussian]


@dataclass(frozen=True, slots=True, eq=False)
class ComposedFilter:
    """A filter = a model, a time update and a measurement update (a core.Filter). Pure: returns
    new beliefs.

    predict(belief, dt, u): dt seconds, u the model's input (for visnav the IMU readings (12,)).
    update(belief, measurement): a Measurement built by the model.
    """

    name: str
    model: StateSpaceModel
    time_update: TimeUpdate
    measurement_update: MeasurementUpdate

    def predict(self, belief: Gaussian, dt: float, u: np.ndarray | None = None) -> Gaussian:
        return self.time_update(self.model, belief, u, dt)

    def update(self, belief: Gaussian, measurement: Measurement) -> Gaussian:
        return self.measurement_update(self.model, belief, measurement)


#: default kernel width (whitened units) of MCKF and RHCF; the paper gives none.
DEFAULT_KERNEL_SIGMA = 3.0


def make_ekf(model: StateSpaceModel) -> ComposedFilter:
    """Extended Kalman filter: analytic F and H, Joseph-form update."""
    return ComposedFilter("ekf", model, linearized_predict, KalmanUpdate(jacobian_linearization))


def make_ckf(model: StateSpaceModel) -> ComposedFilter:
    """Cubature Kalman filter: third-degree rule (2n points) in both steps."""
    return ComposedFilter("ckf", model, CubaturePredict(third_degree_rule),
                  KalmanUpdate(CubatureLinearization(third_degree_rule)))


def make_hckf(model: StateSpaceModel) -> ComposedFilter:
    """High-degree cubature Kalman filter: fifth-degree rule (2n^2 + 1 points) in both steps."""
    return ComposedFilter("hckf", model, CubaturePredict(fifth_degree_rule),
                  KalmanUpdate(CubatureLinearization(fifth_degree_rule)))


def make_mckf(model: StateSpaceModel, *, kernel_sigma: float = DEFAULT_KERNEL_SIGMA, tol: float = 1e-6,
              max_iter: int = 50, covariance: Literal["joseph", "information"] = "joseph") -> ComposedFilter:
    """Maximum-correntropy KF (Chen et al. 2017) on the EKF linearization (analytic F, H)."""
    return ComposedFilter("mckf", model, linearized_predict,
                  CorrentropyUpdate(jacobian_linearization, kernel_sigma, tol, max_iter, covariance))


def make_rhcf(model: StateSpaceModel, *, kernel_sigma: float = DEFAULT_KERNEL_SIGMA, tol: float = 1e-6,
              max_iter: int = 50, covariance: Literal["joseph", "information"] = "joseph") -> ComposedFilter:
    """Robust high-degree cubature filter (the seed's RHCF, eq. 16-48): fifth-degree time update,
    correntropy update on the fifth-degree statistical linearization H = (P^-1 P_xy)^T (eq. 31).

    The state update is eq. 23-47 exactly; the posterior covariance defaults to Chen et al.'s
    Joseph form (same as MCKF, so the two differ only in linearization and time update);
    covariance="information" gives the paper's eq. 48, (M^T Psi M)^-1."""
    return ComposedFilter("rhcf", model, CubaturePredict(fifth_degree_rule),
                  CorrentropyUpdate(CubatureLinearization(fifth_degree_rule), kernel_sigma, tol,
                                    max_iter, covariance))


FILTER_FACTORIES: dict[str, Callable[..., ComposedFilter]] = {
    "ekf": make_ekf, "ckf": make_ckf, "hckf": make_hckf, "mckf": make_mckf, "rhcf": make_rhcf,
}


def make_filter(name: str, model: StateSpaceModel, *, kernel_sigma: float = DEFAULT_KERNEL_SIGMA,
                tol: float = 1e-6, max_iter: int = 50,
                covariance: Literal["joseph", "information"] = "joseph") -> ComposedFilter:
    """Build a filter by name ("ekf", "ckf", "hckf", "mckf", "rhcf"). The correntropy options
    (kernel_sigma, tol, max_iter, covariance) apply to "mckf" and "rhcf" and are ignored otherwise."""
    if name not in FILTER_FACTORIES:
        raise ValueError(f"unknown filter {name!r}; known: {sorted(FILTER_FACTORIES)}")
    if name in ("mckf", "rhcf"):
        return FILTER_FACTORIES[name](model, kernel_sigma=kernel_sigma, tol=tol, max_iter=max_iter,
                                      covariance=covariance)
    return FILTER_FACTORIES[name](model)
