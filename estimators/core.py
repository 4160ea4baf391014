"""The estimator interface of the project, the one driver every filter runs through, and the
numerics the filters share.

The interface
-------------
A filter's belief is Gaussian: a mean and a covariance (`Gaussian`; `sigma_filters.ManifoldGaussian`
when the mean is a point of a manifold and the covariance lives in its tangent space). A filter
is two pure functions of the belief (the `Filter` protocol),

    predict(belief, dt, u) -> belief          time update over dt seconds with the input u
    update(belief, measurement) -> belief      measurement update with one measurement epoch

each returning a NEW belief (never modifying its argument). A filter's fixed settings (model,
process noise, gate, kernel width) are fields of the filter object, not arguments. Variants
override one step instead of copying a filter: the five filters of seed 004 are one
`sigma_filters.ComposedFilter` with different time updates (linearized, third- or fifth-degree
cubature) and measurement updates (Kalman, maximum correntropy); the seed 003 EKF
(`phase_ekf.PhaseEkf`) and its covariance-analysis variant differ in nothing else.

What a step repaired or refused is counted, not hidden: a step calls `tally(...)` when it
repairs a covariance that was not positive definite, rejects measurements in a gate, or stops an
iteration that did not converge; the driver records the counts of every step (`Health`). Outside
the driver `tally` does nothing.

The driver
----------
`drive(filter, prior, epochs) -> Track` is the one loop every filter of the four papers runs
through. An `Epoch` is a time t (s), the measurement taken at t (or None), and how to predict
to t: `controls = None` predicts once over t - t_previous with u = None (nothing when the belief
is already at t); a sequence of (dt, u) runs exactly those predicts (e.g. one per IMU step).
At every epoch the driver predicts, updates, and records the belief, the health counts and the
wall time of both steps. It is incremental and time-ordered: `Stepper.step(epoch)` does one
epoch with no look-ahead (an epoch earlier than the belief is an error), so the same code runs
offline over a recorded log (`drive`) or online, fed one epoch at a time inside a simulation loop.

How the four papers fit:
- seed 004 (visnav): EKF, CKF, HCKF, MCKF, RHCF are `sigma_filters.ComposedFilter`s;
  `visnav.CameraFilter` adapts them to raw camera frames (each frame is linearized about the
  predicted mean, so it becomes a `Measurement` inside update). u = both IMUs' readings.
- seed 003 (carrier phase): `phase_ekf.PhaseEkf`, u = None; its update uses
  `linearized_update` below (whitened information form, Baarda gate).
- seed 000 (bandwidth-limited distributed fusion): `bandwidth.FusionFilter`. Its belief is the
  stack of every node's estimate and bound (mean (..., N, n), cov (..., N, n, n)); the paper's
  estimator is in one-step-predictor form (the gain of eq. 18 is a predictor gain), so update
  only stores the epoch's measurements and predict applies them with the exchange and fusion of
  eqs. 4-7; u = the step's delivered selection masks and weights.
- seed 001 (GNSS + UWB factor graph) is NOT a recursive filter: `factor_graph` solves every
  epoch as its own batch least-squares problem (Gauss-Newton over all UAVs' positions, no
  motion model, no prior carried from the previous epoch), so there is no predict and nothing
  for an update to refine. It fits the driver only degenerately (an identity predict and an
  update that ignores the prior), which would hide that; it is run per epoch by its pipeline.

Shared numerics
---------------
Cholesky factorizations and solves (`cholesky_upper`, `cho_solve_upper`, `cho_inverse_upper`:
LAPACK dpotrf/dpotrs/dpotri called directly, never an explicit inverse); the Kalman gain and
the Joseph-form covariance for a dense measurement noise (`kalman_gain`, `joseph_update`; the
sigma-point filters); the linearized update for a diagonal measurement noise with many rows
(`linearized_update`: noise-whitened information-form gain, Joseph form as one product C C^T,
Baarda w-test gate; the phase EKF); the linear Kalman steps; NEES and its chi-square interval.

This module never imports mujoco or testbed: estimators run on data that did not come from MuJoCo.
"""
from __future__ import annotations

import functools
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy import special
from scipy.linalg import lapack


# ------------------------------------------------------------------------------------------------
# Belief and interface
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Gaussian:
    """A Gaussian belief.

    mean: (n,) state estimate; cov: (n, n) symmetric positive definite covariance, same units.
    """

    mean: np.ndarray
    cov: np.ndarray

    def __post_init__(self) -> None:
        n = self.mean.shape[0]
        if self.mean.ndim != 1 or self.cov.shape != (n, n):
            raise ValueError(f"Gaussian: mean {self.mean.shape} and cov {self.cov.shape} do not match")


class Belief(Protocol):
    """What the driver records of a belief: a mean and a covariance (a `Gaussian`, or a stack of
    them such as `bandwidth.FusionState`)."""

    @property
    def mean(self) -> np.ndarray: ...

    @property
    def cov(self) -> np.ndarray: ...


class Filter(Protocol):
    """THE estimator interface (module docstring): two pure steps returning new beliefs.

    predict(belief, dt, u): time update over dt s with the filter's input u (None if it has none);
    update(belief, measurement): measurement update with one epoch's measurement.
    """

    def predict(self, belief: Any, dt: float, u: Any = None) -> Any: ...

    def update(self, belief: Any, measurement: Any) -> Any: ...


# ------------------------------------------------------------------------------------------------
# Health counts
# ------------------------------------------------------------------------------------------------
@dataclass(slots=True)
class Health:
    """What the steps of one epoch repaired or refused (counts).

    covariance_repairs: covariances that were not positive definite, or not symmetric beyond
    round-off (core.symmetrize), and were repaired;
    rejected_measurements: measurement rows rejected by a gate;
    nonconverged_iterations: iterative updates stopped at their iteration limit unconverged;
    fallback_updates: iterative updates that failed (no convergence, a factorization error or a
    non-finite iterate) and were replaced by the plain (non-iterative) update of that step; each
    is also a nonconverged iteration, so it reaches metrics.json in `nonconverged_steps`;
    skipped_updates: measurement epochs (or rows) that could not be used at all (degenerate
    geometry, e.g. a range whose two ends coincide) and were skipped.
    """

    covariance_repairs: int = 0
    rejected_measurements: int = 0
    nonconverged_iterations: int = 0
    fallback_updates: int = 0
    skipped_updates: int = 0


_HEALTH: ContextVar[Health | None] = ContextVar("estimators_core_health", default=None)


def tally(*, covariance_repairs: int = 0, rejected_measurements: int = 0,
          nonconverged_iterations: int = 0, fallback_updates: int = 0, skipped_updates: int = 0) -> None:
    """Add to the counts of the step in progress (`counting`); does nothing outside one."""
    h = _HEALTH.get()
    if h is not None:
        h.covariance_repairs += covariance_repairs
        h.rejected_measurements += rejected_measurements
        h.nonconverged_iterations += nonconverged_iterations
        h.fallback_updates += fallback_updates
        h.skipped_updates += skipped_updates


@contextmanager
def counting() -> Iterator[Health]:
    """Collect the `tally` calls made inside the block into a fresh Health."""
    h = Health()
    token = _HEALTH.set(h)
    try:
        yield h
    finally:
        _HEALTH.reset(token)


# ------------------------------------------------------------------------------------------------
# The driver
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Epoch:
    """One epoch for the driver.

    t: time (s) of the measurement; measurement: what the filter's update takes, or None (predict
    and record only); controls: None = one predict over t - t_previous with u = None (none if the
    belief is already at t), or a sequence of (dt s, u) predict steps ending at t.
    """

    t: float
    measurement: Any = None
    controls: Sequence[tuple[float, Any]] | None = None


@dataclass(frozen=True, slots=True, eq=False)
class Track:
    """What the driver recorded, one row per epoch (E epochs).

    t: (E,) s; beliefs: the E beliefs after each epoch's update; covariance_repairs,
    rejected_measurements, nonconverged_iterations: (E,) int health counts of each epoch (predicts
    and update); predict_s, update_s: (E,) wall time (s) of the epoch's predicts and of its update;
    fallback_updates, skipped_updates: (E,) int, the breakdown of `Health` (fallbacks are also in
    nonconverged_iterations; neither is in `health()`, whose keys are the metrics.json contract).
    """

    t: np.ndarray
    beliefs: tuple
    covariance_repairs: np.ndarray
    rejected_measurements: np.ndarray
    nonconverged_iterations: np.ndarray
    predict_s: np.ndarray
    update_s: np.ndarray
    fallback_updates: np.ndarray | None = None
    skipped_updates: np.ndarray | None = None

    @property
    def mean(self) -> np.ndarray:
        """(E, ...) the recorded means stacked."""
        return np.stack([b.mean for b in self.beliefs])

    @property
    def cov(self) -> np.ndarray:
        """(E, ..., n, n) the recorded covariances stacked."""
        return np.stack([b.cov for b in self.beliefs])

    def health(self) -> dict[str, int]:
        """The run's health counts for metrics.json: covariance_repairs and rejected_measurements
        (totals over the epochs), nonconverged_steps (epochs with an iterative update stopped
        unconverged at its limit)."""
        return {"covariance_repairs": int(self.covariance_repairs.sum()),
                "rejected_measurements": int(self.rejected_measurements.sum()),
                "nonconverged_steps": int(np.count_nonzero(self.nonconverged_iterations))}


class Stepper:
    """The driver one epoch at a time: `step(epoch)` predicts to the epoch, updates, records.

    filter: a `Filter`; prior: the belief at t0 (s), or at the first epoch's time if t0 is None.
    `belief` and `t` are the latest belief and its time; `track()` the record so far.
    """

    def __init__(self, filter: Filter, prior: Any, t0: float | None = None) -> None:
        self.filter = filter
        self.belief = prior
        self.t = t0
        self._rows: list[tuple] = []

    def step(self, epoch: Epoch) -> Any:
        """Process one epoch (time-ordered: epoch.t >= self.t); returns the updated belief."""
        if self.t is not None and epoch.t < self.t:
            raise ValueError(f"Stepper: epoch at t = {epoch.t} s is earlier than the belief (t = {self.t} s)")
        f, b = self.filter, self.belief
        with counting() as health:
            t0 = time.perf_counter()
            if epoch.controls is not None:
                for dt, u in epoch.controls:
                    b = f.predict(b, dt, u)
            elif self.t is not None and epoch.t != self.t:
                b = f.predict(b, epoch.t - self.t, None)
            t1 = time.perf_counter()
            if epoch.measurement is not None:
                b = f.update(b, epoch.measurement)
            t2 = time.perf_counter()
        self.belief, self.t = b, epoch.t
        self._rows.append((epoch.t, b, health.covariance_repairs, health.rejected_measurements,
                           health.nonconverged_iterations, t1 - t0, t2 - t1, health.fallback_updates,
                           health.skipped_updates))
        return b

    def track(self) -> Track:
        """The epochs processed so far as a Track."""
        cols = list(zip(*self._rows)) if self._rows else [()] * 9
        t, beliefs, rep, rej, nc, tp, tu, fb, sk = cols
        ints = (np.array(c, dtype=int) for c in (rep, rej, nc))
        return Track(np.array(t, dtype=float), tuple(beliefs), *ints, np.array(tp, dtype=float),
                     np.array(tu, dtype=float), np.array(fb, dtype=int), np.array(sk, dtype=int))


def drive(filter: Filter, prior: Any, epochs: Iterable[Epoch], t0: float | None = None) -> Track:
    """Run a filter over time-ordered epochs (module docstring): the one loop of every filter."""
    stepper = Stepper(filter, prior, t0)
    for epoch in epochs:
        stepper.step(epoch)
    return stepper.track()


# ------------------------------------------------------------------------------------------------
# Cholesky (LAPACK directly) and the dense Kalman numerics
# ------------------------------------------------------------------------------------------------
SYMMETRY_ROUNDOFF = 1e-9  # relative asymmetry max|P - P^T| / max|P| still counted as round-off


def symmetrize(P: np.ndarray) -> np.ndarray:
    """(P + P^T) / 2: removes the round-off asymmetry of a covariance product. An asymmetry beyond
    round-off (max|P - P^T| > SYMMETRY_ROUNDOFF * max|P|) is a repair and is counted (`tally`).
    Batched: P (..., n, n), each matrix checked and counted on its own (the same numbers as one
    call per matrix)."""
    Pt = np.swapaxes(P, -1, -2)
    A = P - Pt
    if P.ndim == 2:
        repairs = int(np.abs(A).max(initial=0.0) > SYMMETRY_ROUNDOFF * np.abs(P).max(initial=0.0))
    else:
        big = np.abs(P).max(axis=(-2, -1), initial=0.0)
        repairs = int(np.count_nonzero(np.abs(A).max(axis=(-2, -1), initial=0.0) > SYMMETRY_ROUNDOFF * big))
    if repairs:
        tally(covariance_repairs=repairs)
    return 0.5 * (P + Pt)


def is_spd(P: np.ndarray) -> bool:
    """True if P is symmetric (to round-off) and its Cholesky factorization succeeds."""
    if not np.allclose(P, P.T, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(P).max()))):
        return False
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return False
    return True


def cholesky_upper(a: np.ndarray) -> np.ndarray:
    """Upper Cholesky factor U of an SPD (n, n) matrix, a = U^T U (strict lower triangle zero).

    LAPACK dpotrf called directly (scipy.linalg.cho_factor's validation costs more than the
    factorization at n = 18); reads only the upper triangle of a. Raises LinAlgError if a is not
    positive definite.
    """
    # positional lower=0, clean=1: at n = 18 keyword parsing is a noticeable part of the call
    U, info = lapack.dpotrf(a, 0, 1)
    if info != 0:
        raise np.linalg.LinAlgError(f"dpotrf: matrix not positive definite (info = {info})")
    return U


def cho_solve_upper(U: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^-1 b for a = U^T U (U from `cholesky_upper`), b: (n,) or (n, k); LAPACK dpotrs."""
    x, info = lapack.dpotrs(U, b, 0)  # lower=0
    if info != 0:
        raise ValueError(f"dpotrs: illegal argument {-info}")
    return x


def cho_inverse_upper(U: np.ndarray) -> np.ndarray:
    """Upper triangle of a^-1 for a = U^T U (U from `cholesky_upper`); strict lower triangle zero.

    LAPACK dpotri; for consumers that read only the upper triangle (`cholesky_upper`).
    """
    a_inv, info = lapack.dpotri(U, 0)  # lower=0
    if info != 0:
        raise np.linalg.LinAlgError(f"dpotri: singular factor (info = {info})")
    return a_inv


def kalman_gain(P_xz: np.ndarray, S: np.ndarray) -> np.ndarray:
    """K = P_xz S^-1 by a Cholesky solve (never an explicit inverse).

    P_xz: (n, m) state-measurement cross covariance; S: (m, m) innovation covariance (SPD).
    """
    return cho_solve_upper(cholesky_upper(S), P_xz.T).T


def joseph_update(P: np.ndarray, K: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Joseph-form covariance update (I - K H) P (I - K H)^T + K R K^T, symmetrized.

    Stays positive definite for any gain K, unlike (I - K H) P. For any (dense) R; with a diagonal
    R and many rows `linearized_update` evaluates the same form as one product C C^T.
    """
    I_KH = np.eye(P.shape[0]) - K @ H
    return symmetrize(I_KH @ P @ I_KH.T + K @ R @ K.T)


def white_acceleration_q(dt: float) -> np.ndarray:
    """Covariance (2, 2) of one axis's [position, velocity] after dt (s) of white acceleration of
    unit density (multiply by the density q, m^2/s^3): [[dt^3/3, dt^2/2], [dt^2/2, dt]], the exact
    discretization of the constant-velocity model. For a density matrix S over several axes the
    process noise is np.kron(white_acceleration_q(dt), S)."""
    return np.array([[dt ** 3 / 3.0, dt ** 2 / 2.0], [dt ** 2 / 2.0, dt]])


def kf_predict(belief: Gaussian, F: np.ndarray, Q: np.ndarray, u: np.ndarray | None = None) -> Gaussian:
    """Linear prediction x' = F x + u, P' = F P F^T + Q."""
    x = F @ belief.mean if u is None else F @ belief.mean + u
    return Gaussian(x, symmetrize(F @ belief.cov @ F.T + Q))


def kf_update(belief: Gaussian, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> Gaussian:
    """Linear Kalman measurement update with the Joseph-form covariance.

    z: (m,) measurement; H: (m, n); R: (m, m) measurement noise covariance.
    """
    P = belief.cov
    S = symmetrize(H @ P @ H.T + R)
    K = kalman_gain(P @ H.T, S)
    x = belief.mean + K @ (z - H @ belief.mean)
    return Gaussian(x, joseph_update(P, K, H, R))


# ------------------------------------------------------------------------------------------------
# Linearized update for a diagonal measurement noise: information-form gain, Baarda gate
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Gate:
    """Innovation gate of `linearized_update`: Baarda's w-test with iterative data snooping.

    On the innovation nu (m valid rows), S = H P H^T + R:
        w_k = (S^-1 nu)_k / sqrt((S^-1)_kk),   w_k ~ N(0, 1) for a correct row k,
    the most powerful test of "row k alone carries a bias"; unlike nu_k / sqrt(S_kk) it uses the
    redundancy of the rows, so a large outlier is caught even while the prior is wide. Threshold
    k_w = Phi^-1(1 - alpha / (2 m)) (Bonferroni): the probability of rejecting any good row in an
    epoch is <= alpha. The row with the largest |w| above k_w is rejected, S refactorized without
    it, and the test repeated (at most `max_rejections` rows per epoch).


    alpha: family-wise probability of rejecting at least one good row per epoch;
    max_rejections: at most this many rows rejected per epoch; enabled: False = no gate.
    """

    alpha: float = 1e-3
    max_rejections: int = 12
    enabled: bool = True

    def threshold(self, m: int) -> float:
        """|w| threshold for m rows: Phi^-1(1 - alpha / (2 m)) (= scipy.stats.norm.isf, without its overhead)."""
        return float(-special.ndtri(self.alpha / (2.0 * max(m, 1))))


NO_GATE = Gate(enabled=False)


@dataclass(frozen=True, slots=True)
class UpdateInfo:
    """What one update did. Row arrays are (m_total,) in the stacked order; NaN where unused.

    innovation: z - h(x_prior); normalized_innovation: nu_k / sqrt(S_kk) (final S);
    w: Baarda w-statistics (final S; rejected rows keep the value at which they were rejected;
       NaN everywhere if the gate is disabled);
    used: rows that entered the update; rejected: indices of rows rejected by the gate;
    rejected_labels: labels of the rejected rows (the caller's `labels`, e.g. phase_model.row_label);
    nis: nu^T S^-1 nu over the used rows, dof = number of used rows; threshold: the |w| threshold;
    gain: the gain K (n, number of used rows), columns in the order of the used rows (for a
    covariance analysis of the filter against another model of the true motion, e.g. Gelb 1974 ch. 7);
    jacobian: H of the used rows (number of used rows, n), in the same order.
    """

    innovation: np.ndarray
    normalized_innovation: np.ndarray
    w: np.ndarray
    used: np.ndarray
    rejected: np.ndarray
    rejected_labels: tuple = field(default_factory=tuple)
    nis: float = 0.0
    dof: int = 0
    threshold: float = np.inf
    gain: np.ndarray | None = None
    jacobian: np.ndarray | None = None


def linearized_update(belief: Gaussian, z: np.ndarray, hx: np.ndarray, H: np.ndarray,
                      r_var: np.ndarray, valid: np.ndarray | None = None,
                      gate: Gate = Gate(), labels=None) -> tuple[Gaussian, UpdateInfo]:
    """EKF update on a linearized measurement z ~ hx + H (x - x_prior) + v, v ~ N(0, diag(r_var)).

    belief: prior (n,); z, hx, r_var: (m,); H: (m, n); valid: (m,) bool or None (all rows).
    Rows with valid False or non-finite z are skipped; the gate may reject more (see `Gate`).
    labels: optional callable row -> label for UpdateInfo.rejected_labels.

    R is diagonal, so the used rows are whitened once, Hw = R^-1/2 H, nuw = R^-1/2 nu. Gain in
    information form: made for m > n (the phase EKF: m = 90 rows, n = 18), so instead of factorizing the m x m innovation covariance S
    the update factorizes the n x n information matrix
        A = P^-1 + Hw^T Hw,   Xw = A^-1 Hw^T,   K = Xw R^-1/2 = P H^T S^-1     (Woodbury)
    and the same Xw gives the gate's S^-1 nu and diag(S^-1) for free:
        S^-1 = R^-1/2 (I - Hw A^-1 Hw^T) R^-1/2.
    The covariance is still the Joseph form with that gain (not A^-1), evaluated as
    the symmetric product C C^T, C = [(I - K H) U^T, Xw] with P = U^T U (Cholesky), so no
    symmetrization is needed. Equation numbers in the comments: seed 003 (the phase EKF).
    Rejected rows are counted (`tally`).
    """
    z = np.asarray(z, float)
    m_all = z.shape[0]
    ok = np.isfinite(z)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    rows = ok.nonzero()[0]
    nu_all = z - hx
    if rows.size < m_all:
        nu_all[~ok] = np.nan
    w_all = np.full(m_all, np.nan)
    nn_all = w_all.copy()
    P = belief.cov
    rejected: list[int] = []
    thr = gate.threshold(rows.size) if gate.enabled else np.inf
    if rows.size == 0:
        info = UpdateInfo(nu_all, nn_all, w_all, np.zeros(m_all, bool), np.array([], int), (), 0.0, 0, thr)
        return belief, info
    # P = U^T U; upper triangle of P^-1 (dpotri), all that the factorization of A below reads
    U = cholesky_upper(P)
    P_inv_upper = cho_inverse_upper(U)
    while True:
        # all rows used: no copies
        Hr, nu, r = (H, nu_all, r_var) if rows.size == m_all else (H[rows], nu_all[rows], r_var[rows])
        s_inv = 1.0 / np.sqrt(r)
        Hw = Hr * s_inv[:, None]
        nuw = nu * s_inv
        # eq. 20 in information form: A = P^-1 + Hw^T Hw (upper triangle), Xw = A^-1 Hw^T
        Xw = cho_solve_upper(cholesky_upper(P_inv_upper + Hw.T @ Hw), Hw.T)
        # eq. 19 correction: K nu = Xw nuw
        dx = Xw @ nuw
        # Woodbury: S^-1 nu = R^-1/2 e, e = nuw - Hw A^-1 Hw^T nuw
        e = nuw - Hw @ dx
        if not gate.enabled:
            break
        # Baarda w-test statistic per row: w_k = (S^-1 nu)_k / sqrt((S^-1)_kk)
        #   = e_k / sqrt(1 - (Hw A^-1 Hw^T)_kk)
        w = e / np.sqrt(1.0 - np.einsum("kj,jk->k", Hw, Xw))
        w_all[rows] = w
        k = int(np.argmax(np.abs(w)))
        if abs(w[k]) > thr and len(rejected) < gate.max_rejections and rows.size > 1:
            rejected.append(int(rows[k]))
            rows = np.delete(rows, k)
            continue
        break
    # S_kk = H_k P H_k^T + r_k = |(H U^T)_k|^2 + r_k, for the normalized innovations
    HU = Hr @ U.T
    nn_all[rows] = nu / np.sqrt(np.einsum("kj,kj->k", HU, HU) + r)
    # eq. 20: K = P H^T (H P H^T + R)^-1 = A^-1 H^T R^-1 = Xw R^-1/2
    K = Xw * s_inv
    # eq. 19: x = x_pred + K (z - h(x_pred))
    x = belief.mean + dx
    # eq. 21: Joseph form (I - K H) P (I - K H)^T + K R K^T = C C^T, one symmetric product, with
    # C = [(I - K H) U^T, K R^1/2] = [U^T - K (H U^T), Xw] (R diagonal)
    C = np.concatenate([U.T - K @ HU, Xw], axis=1)
    Pn = C @ C.T
    used = ok
    if rejected:
        used[rejected] = False
    lab = tuple(labels(r) for r in rejected) if labels is not None else ()
    tally(rejected_measurements=len(rejected))
    info = UpdateInfo(nu_all, nn_all, w_all, used, np.array(rejected, int), lab,
                      float(nuw @ e), int(rows.size), thr, K, Hr)
    return Gaussian(x, Pn), info


# ------------------------------------------------------------------------------------------------
# Consistency
# ------------------------------------------------------------------------------------------------
def nees(error: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Normalized estimation error squared e^T P^-1 e.

    error: (..., n) estimate minus true value; cov: (..., n, n). Returns (...,).
    """
    e = np.asarray(error)[..., None]
    sol = np.linalg.solve(cov, e)
    return (e * sol).sum(axis=(-2, -1))


@functools.lru_cache(maxsize=256)  # scoring asks for the same (dof, runs) for every vehicle
def chi2_interval(dof: int, runs: float, level: float = 0.99) -> tuple[float, float]:
    """Two-sided interval for the ANEES of `runs` independent NEES samples of `dof` degrees each.

    runs * ANEES ~ chi2(runs * dof) for a consistent filter; returns the interval divided by runs,
    so a consistent filter's ANEES (expected value dof) lies inside with probability `level`.
    `runs` may be an effective (non-integer) number of samples of correlated NEES.
    """
    # lazy: scipy.stats takes seconds to import on a cold cache, and only scoring needs it
    from scipy.stats import chi2

    a = (1.0 - level) / 2.0
    k = runs * dof
    return float(chi2.ppf(a, k) / runs), float(chi2.ppf(1.0 - a, k) / runs)
