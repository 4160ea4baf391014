"""Seed 003 estimator: EKF on carrier-phase ranges/range rates from M three-antenna masters.

Paper: Pan, Yin, Xu, Ordnance Industry Automation 2023 (shared/seeds/003), eq. 13-31.
State, frames, units and the measurement row ordering are documented in `estimators.phase_model`.
Pure numpy/scipy: usable on measurements that did not come from MuJoCo.

Public API
----------
transition(dt)                              Phi (18, 18), eq. 24
ProcessNoise                                white-acceleration densities: per antenna, body translation, body rotation
process_noise(dt, q, x)                     Q (18, 18), continuous white-noise-acceleration model
predict(belief, dt, q)                      time update, eq. 18/22
PhaseMeasurement                            one epoch: ranges, range rates, master antennas, sigmas, masks
Gate                                        innovation gate settings (w-test, family-wise false alarm)
update(belief, meas, gate, iterations)      EKF (or iterated EKF) measurement update (eq. 19-22, Joseph) -> (Gaussian, UpdateInfo)
linearized_update(belief, z, hx, H, r_var, valid, gate)   the same on any linearized measurement
initial_belief(p, v, R, R_dot, P_pos, P_vel, a, b)  prior on the 18-state from a body prior
body_state(belief)                          Gaussian over the 12 body quantities (eq. 29-30)
run_filter(prior, times, measurements, q, gate, iterations)   convenience loop
pcrb(states, times, master_pos, master_vel, P0, sigma_range, sigma_range_rate, q)   Tichavsky PCRB
pcrb_position_rmse(bounds, body)            sqrt(trace) of the position block of the bound

Process noise (choice documented here; the paper gives none)
-------------------------------------------------------------
Continuous white-noise acceleration, independent per antenna and per axis, spectral density q
(m^2/s^3):  Q = q [[tau^3/3 I9, tau^2/2 I9], [tau^2/2 I9, tau I9]]  (exact discretization of the
constant-velocity model of eq. 24).  Default q = DEFAULT_Q = 1e-7 m^2/s^3, for the eq. 31 motion:
the body translates at constant velocity, so antenna accelerations come only from the attitude
oscillation, amplitude A <= pi/18 rad at omega = 2 pi / 200 s on a 1 m lever arm:
|a| <= A omega^2 * 1 m ~ 1.7e-4 m/s^2, slowly varying. q must be large enough that the filter's
lag behind this acceleration stays below its own sigma. For the CV filter on position data of
density r_p = sigma_p^2 tau (sigma_p ~ 0.05 m per axis, tau = 0.1 s) the lag is a / omega_n^2 with
omega_n = (q / r_p)^(1/4) and the position sigma ~ q^(1/8) r_p^(3/8): lag < sigma needs
q > a^(8/5) r_p^(1/5), i.e. 1e-7 to 2e-7 m^2/s^3 for sigma_p = 0.02 to 0.05 m (the 15 ranges per
antenna give ~0.02 m along the lines of sight; the same argument on the range-rate loop gives a
few 1e-7). An order-of-magnitude bound, so it was checked
on the 200 s eq. 31 run (cross formation, 10 runs): q = 1e-8 lags (ANEES 83 for 18 dof at 100 s),
q = 1e-7 and 1e-6 do not (ANEES 8-15), and 1e-7 has the lower RMSE (1.7 cm vs 2.3 cm at 50 s), so
1e-7 is the default. Because the eq. 31 motion has no random acceleration at all, any q > 0 makes
the filter (and the PCRB) somewhat conservative on it. In `flown` mode (closed-loop quadrotors)
the accelerations are larger: the scenario must set q.

Rigid-body terms (ProcessNoise.translation, .rotation; zero = the paper's Q above). The three
antennas sit on one rigid body: a random body acceleration a (white, density q_t per axis) and a
random angular acceleration alpha (white, density q_r per body axis) move antenna j by
a + alpha x rho_j, rho_j = x_j - (x_2 + x_3) / 2 its lever arm from the body origin (eq. 29), in N.
The 9 x 9 acceleration density of the stacked antennas is then
    S_ij = q_t I3 + q_r [rho_i]x [rho_j]x^T   (+ q I3 if i = j, the independent term above),
and Q = [[dt^3/3 S, dt^2/2 S], [dt^2/2 S, dt S]], with rho from the state the prediction starts
from. This is exactly the motion of a scenario's [disturbance] (testbed.disturbance) on a body
whose attitude changes slowly over dt; the independent term q keeps covering the deterministic
attitude-driven accelerations of eq. 31. A rigid body has no random motion in the 6 directions
that stretch the antenna triangle (3 lengths and their rates), so on any rigid body's motion the 18-state
NEES is not chi-square there; the body position and velocity (6 dof) have no such deficit.
Measured (tests/test_phase_scenario.py, phase-cross-h000 with the follower's [disturbance] =
this Q's 1e-3 / 1e-5, range rows, 30 runs, 20 s): body position and velocity ANEES 5.78 in
[4.50, 7.75], all 12 rigid-body quantities of eq. 29-30 12.84 in [9.82, 14.43]; 18-state ANEES
39.0 against [15.3, 20.9], the side lengths and their rates being over-confident (NEES 18.2 for
6 dof) under q = 1e-7.

Innovation gate (cycle slips)
-----------------------------
Baarda's w-test with iterative data snooping on the innovation nu (m valid rows), S = H P H^T + R:
    w_k = (S^-1 nu)_k / sqrt((S^-1)_kk),   w_k ~ N(0, 1) for a correct row k,
the most powerful test of "row k alone carries a bias". Unlike nu_k / sqrt(S_kk) it uses the
redundancy of the 90 rows, so a one-wavelength slip (1-3 m, >= 20 range sigmas) is caught even
while the prior is still metres wide. Threshold k_w = Phi^-1(1 - alpha / (2 m)) (Bonferroni): the
probability of rejecting any good row in an epoch is <= alpha (default 1e-3, k_w = 4.39 for m = 90).
The row with the largest |w| above k_w is rejected, S refactorized without it, and the test
repeated (at most `max_rejections` rows per epoch). Rejected rows are listed in `UpdateInfo`;
they never enter the state.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, special
from scipy.linalg import lapack

from estimators.core import Gaussian, kf_predict, symmetrize
from estimators.so3 import skew
from estimators.phase_model import (
    N_STATE,
    ROWS_PER_MASTER,
    antenna_state_from_body,
    body_from_antennas,
    measurement_model,
    row_label,
    stack_rows,
)

#: default white-noise-acceleration spectral density per antenna axis, m^2/s^3 (see module doc)
DEFAULT_Q = 1e-7


# ------------------------------------------------------------------------------------------------
# Time update
# ------------------------------------------------------------------------------------------------
def transition(dt: float) -> np.ndarray:
    """State transition Phi (18, 18) over dt seconds (paper eq. 24, tau = dt)."""
    # eq. 24: Phi = [[I9, tau I9], [0, I9]]
    F = np.eye(N_STATE)
    F[:9, 9:] = dt * np.eye(9)
    return F


@dataclass(frozen=True, slots=True)
class ProcessNoise:
    """White-acceleration spectral densities of the CV model (module docstring, "Process noise").

    antenna: independent per antenna and axis (m^2/s^3), the paper-style Q; translation: common
    body acceleration per axis (m^2/s^3); rotation: body angular acceleration per axis (rad^2/s^3).
    """

    antenna: float = DEFAULT_Q
    translation: float = 0.0
    rotation: float = 0.0

    def density(self, x: np.ndarray | None) -> np.ndarray:
        """Acceleration density S (9, 9) of the stacked antennas at state x (18,) (needed only
        if rotation > 0: the lever arms rho_j = x_j - (x_2 + x_3) / 2)."""
        S = self.antenna * np.eye(9)
        if self.translation:
            S += np.kron(np.full((3, 3), self.translation), np.eye(3))
        if self.rotation:
            P = np.asarray(x, float)[:9].reshape(3, 3)
            rho = P - 0.5 * (P[1] + P[2])
            Sk = skew(rho)  # (3, 3, 3): [rho_j]x
            S += self.rotation * np.einsum("iab,jcb->iajc", Sk, Sk).reshape(9, 9)
        return S


def process_noise(dt: float, q: float | ProcessNoise = DEFAULT_Q, x: np.ndarray | None = None) -> np.ndarray:
    """Process noise Q (18, 18) of the CV model over dt s.

    q: a density per antenna axis (m^2/s^3), Q = q [[dt^3/3 I9, dt^2/2 I9], [dt^2/2 I9, dt I9]]
    (eq. 14's Q_k), or a ProcessNoise, Q = [[dt^3/3 S, dt^2/2 S], [dt^2/2 S, dt S]] with S its
    density at the state x (18,) the interval starts from (module docstring).
    """
    S = ProcessNoise(antenna=q).density(None) if not isinstance(q, ProcessNoise) else q.density(x)
    return np.block([[dt ** 3 / 3 * S, dt ** 2 / 2 * S], [dt ** 2 / 2 * S, dt * S]])


def predict(belief: Gaussian, dt: float, q: float | ProcessNoise = DEFAULT_Q) -> Gaussian:
    """EKF time update over dt s (eq. 15, 18, 23): x' = Phi x, P' = Phi P Phi^T + Q."""
    # eq. 22 (first two lines) with f linear: eq. 23-24
    return kf_predict(belief, transition(dt), process_noise(dt, q, belief.mean))


# ------------------------------------------------------------------------------------------------
# Measurement update
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class PhaseMeasurement:
    """One epoch of master -> follower carrier-phase observables (all in the navigation frame N).

    ranges: (M, 3, 3) r[m, i, j], m: master m's slot-i antenna to follower antenna j (eq. 5-6);
    range_rates: (M, 3, 3) rdot[m, i, j], m/s (eq. 7);
    master_pos, master_vel: (M, 3, 3) master antenna positions (m) / velocities (m/s) [m, slot, xyz]
        as reported by the masters' own navigation (an input stream, not the simulator's state);
    sigma_range (m), sigma_range_rate (m/s): 1-sigma noise, scalars or arrays broadcastable to (M, 3, 3);
    valid_range, valid_range_rate: optional (M, 3, 3) bool masks (False = missing / flagged).
    rate_window: None = the rates are instantaneous (the paper's eq. 10); W (s, scalar or
        (M, 3, 3)) = each rate is the mean range rate over [t - W, t] (eq. 7 as measured; see
        phase_model.measurement_model).
    Non-finite ranges or rates are treated as missing.
    """

    ranges: np.ndarray
    range_rates: np.ndarray
    master_pos: np.ndarray
    master_vel: np.ndarray
    sigma_range: float | np.ndarray = 0.05
    sigma_range_rate: float | np.ndarray = 0.1
    valid_range: np.ndarray | None = None
    valid_range_rate: np.ndarray | None = None
    rate_window: float | np.ndarray | None = None

    @property
    def n_masters(self) -> int:
        return int(np.shape(self.master_pos)[0])

    def stacked(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """z (18 M,), noise variances r_var (18 M,), valid (18 M,) bool, in the eq. 12/25 row order."""
        # [m, kind, i, j] is row 18 m + 9 kind + 3 i + j (phase_model.stack_rows, written in place)
        shape = (self.n_masters, 2, 3, 3)
        z = np.empty(shape)
        z[:, 0], z[:, 1] = self.ranges, self.range_rates
        r_var = np.empty(shape)
        r_var[:, 0] = np.square(self.sigma_range, dtype=float)
        r_var[:, 1] = np.square(self.sigma_range_rate, dtype=float)
        valid = np.isfinite(z)
        if self.valid_range is not None:
            valid[:, 0] &= np.asarray(self.valid_range, bool)
        if self.valid_range_rate is not None:
            valid[:, 1] &= np.asarray(self.valid_range_rate, bool)
        return z.reshape(-1), r_var.reshape(-1), valid.reshape(-1)


@dataclass(frozen=True, slots=True)
class Gate:
    """Innovation gate: iterative Baarda w-test (see module docstring).

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
    rejected_labels: (master, kind, slot i, antenna j) of each rejected row (see phase_model.row_label);
    nis: nu^T S^-1 nu over the used rows, dof = number of used rows; threshold: the |w| threshold;
    gain: the gain K (n, number of used rows), columns in the order of the used rows (for a
    covariance analysis of the filter against another model of the true motion, e.g. Gelb 1974 ch. 7).
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


def _cholesky_upper(a: np.ndarray) -> np.ndarray:
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


def _cho_solve(U: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^-1 b for a = U^T U (U from `_cholesky_upper`), b: (n,) or (n, k); LAPACK dpotrs."""
    x, info = lapack.dpotrs(U, b, 0)  # lower=0
    if info != 0:
        raise ValueError(f"dpotrs: illegal argument {-info}")
    return x


def _cho_inverse_upper(U: np.ndarray) -> np.ndarray:
    """Upper triangle of a^-1 for a = U^T U (U from `_cholesky_upper`); strict lower triangle zero.

    LAPACK dpotri; for consumers that read only the upper triangle (`_cholesky_upper`).
    """
    a_inv, info = lapack.dpotri(U, 0)  # lower=0
    if info != 0:
        raise np.linalg.LinAlgError(f"dpotri: singular factor (info = {info})")
    return a_inv


def linearized_update(belief: Gaussian, z: np.ndarray, hx: np.ndarray, H: np.ndarray,
                      r_var: np.ndarray, valid: np.ndarray | None = None,
                      gate: Gate = Gate(), labels=None) -> tuple[Gaussian, UpdateInfo]:
    """EKF update on a linearized measurement z ~ hx + H (x - x_prior) + v, v ~ N(0, diag(r_var)).

    belief: prior (n,); z, hx, r_var: (m,); H: (m, n); valid: (m,) bool or None (all rows).
    Rows with valid False or non-finite z are skipped; the gate may reject more (see module doc).
    labels: optional callable row -> label for UpdateInfo.rejected_labels.

    R is diagonal, so the used rows are whitened once, Hw = R^-1/2 H, nuw = R^-1/2 nu. Gain in
    information form: m (90) > n (18), so instead of factorizing the m x m innovation covariance S
    the update factorizes the n x n information matrix
        A = P^-1 + Hw^T Hw,   Xw = A^-1 Hw^T,   K = Xw R^-1/2 = P H^T S^-1     (eq. 20, Woodbury)
    and the same Xw gives the gate's S^-1 nu and diag(S^-1) for free:
        S^-1 = R^-1/2 (I - Hw A^-1 Hw^T) R^-1/2.
    The covariance is still the Joseph form of eq. 21 with that gain (not A^-1), evaluated as
    the symmetric product C C^T, C = [(I - K H) U^T, Xw] with P = U^T U (Cholesky), so no
    symmetrization is needed.
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
    U = _cholesky_upper(P)
    P_inv_upper = _cho_inverse_upper(U)
    while True:
        # all rows used: no copies
        Hr, nu, r = (H, nu_all, r_var) if rows.size == m_all else (H[rows], nu_all[rows], r_var[rows])
        s_inv = 1.0 / np.sqrt(r)
        Hw = Hr * s_inv[:, None]
        nuw = nu * s_inv
        # eq. 20 in information form: A = P^-1 + Hw^T Hw (upper triangle), Xw = A^-1 Hw^T
        Xw = _cho_solve(_cholesky_upper(P_inv_upper + Hw.T @ Hw), Hw.T)
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
    info = UpdateInfo(nu_all, nn_all, w_all, used, np.array(rejected, int), lab,
                      float(nuw @ e), int(rows.size), thr, K)
    return Gaussian(x, Pn), info


def update(belief: Gaussian, measurement: PhaseMeasurement, gate: Gate = Gate(),
           iterations: int = 1) -> tuple[Gaussian, UpdateInfo]:
    """EKF measurement update with the M-master carrier-phase model (eq. 16-22, 25-28).

    belief: prior over the 18-state (phase_model docstring); measurement: one epoch.
    iterations: 1 = the paper's EKF. n > 1 = iterated EKF (Gauss-Newton): the model is
    relinearized n - 1 more times at the latest estimate x_i, with the rows kept by the gate in
    the first pass, z_lin = z - h(x_i) + H_i x_i; it removes the linearization error of the first
    epochs when the prior is metres wide (tests/test_phase_ekf.py measures it).
    Returns the posterior and an UpdateInfo (rows in the eq. 12/25 order, gate decisions).
    """
    z, r_var, valid = measurement.stacked()
    # eq. 17, 26-28: h and H at the predicted state
    hx, H = measurement_model(belief.mean, measurement.master_pos, measurement.master_vel,
                              rate_window=measurement.rate_window)
    post, info = linearized_update(belief, z, hx, H, r_var, valid, gate, labels=row_label)
    for _ in range(iterations - 1):
        xi = post.mean
        hx, H = measurement_model(xi, measurement.master_pos, measurement.master_vel,
                                  rate_window=measurement.rate_window)
        # h(x) ~ h(x_i) + H_i (x - x_i), written about the prior mean x_p: hx_p = h(x_i) + H_i (x_p - x_i)
        post, _ = linearized_update(belief, z, hx + H @ (belief.mean - xi), H, r_var, info.used, NO_GATE)
    return post, info


# ------------------------------------------------------------------------------------------------
# Initialization, body state, driver
# ------------------------------------------------------------------------------------------------
def initial_belief(p: np.ndarray, v: np.ndarray, R: np.ndarray, R_dot: np.ndarray,
                   P_pos: np.ndarray, P_vel: np.ndarray, a: float = 1.0, b: float = 1.0) -> Gaussian:
    """Prior on the 18-state from a body prior (paper section 4.2, "spread to the three antennas").

    p, v: (3,) estimated body position (m) / velocity (m/s) in N; R, R_dot: (3, 3) assumed
    R_N_from_body and its rate; P_pos, P_vel: (3, 3) covariances (m^2, m^2/s^2).
    Mean: antennas placed by eq. 1/8. Covariance: each antenna gets P_pos / P_vel, antennas
    independent (the attitude is not assumed known, so the triangle is not imposed).
    """
    mean = antenna_state_from_body(np.asarray(p, float), np.asarray(v, float), R, R_dot, a, b)
    cov = linalg.block_diag(*([np.asarray(P_pos, float)] * 3 + [np.asarray(P_vel, float)] * 3))
    return Gaussian(mean, cov)


def body_state(belief: Gaussian) -> Gaussian:
    """Body state (12,) = [p, v, yaw, pitch, roll, yaw/pitch/roll rates] with covariance J P J^T.

    Units m, m/s, rad, rad/s; frame N; see phase_model.body_from_antennas (eq. 29-30).
    """
    y, J = body_from_antennas(belief.mean)
    return Gaussian(y, symmetrize(J @ belief.cov @ J.T))


def run_filter(prior: Gaussian, times: np.ndarray, measurements, q: float | ProcessNoise = DEFAULT_Q,
               gate: Gate = Gate(), iterations: int = 1) -> tuple[np.ndarray, np.ndarray, list[UpdateInfo]]:
    """Filter a sequence: at k = 0 update the prior with measurements[0]; for k > 0 predict over
    times[k] - times[k-1] then update. times: (K,) s; measurements: K PhaseMeasurement (or None).

    Returns means (K, 18), covariances (K, 18, 18), and the K UpdateInfo (None where skipped).
    """
    K = len(times)
    means = np.empty((K, N_STATE))
    covs = np.empty((K, N_STATE, N_STATE))
    infos: list[UpdateInfo | None] = []
    bel = prior
    for k in range(K):
        if k > 0:
            bel = predict(bel, float(times[k] - times[k - 1]), q)
        info = None
        if measurements[k] is not None:
            bel, info = update(bel, measurements[k], gate, iterations)
        means[k], covs[k] = bel.mean, bel.cov
        infos.append(info)
    return means, covs, infos


# ------------------------------------------------------------------------------------------------
# Posterior Cramer-Rao bound (Tichavsky, Muravchik, Nehorai 1998)
# ------------------------------------------------------------------------------------------------
def pcrb(states: np.ndarray, times: np.ndarray, master_pos: np.ndarray, master_vel: np.ndarray,
         P0: np.ndarray, sigma_range: float | np.ndarray, sigma_range_rate: float | np.ndarray,
         q: float | ProcessNoise = DEFAULT_Q, valid: np.ndarray | None = None,
         rate_window: float | np.ndarray | None = None) -> np.ndarray:
    """PCRB covariance per step for the linear-Gaussian CV dynamics + nonlinear phase measurements.

    states: (K, 18) state trajectory at which H is evaluated (the scorer passes the true one);
    times: (K,) s; master_pos, master_vel: (K, M, 3, 3) or (M, 3, 3) (constant); P0: (18, 18)
    prior covariance at times[0]; q as in `process_noise` (its lever arms from states[k - 1]);
    sigmas as in PhaseMeasurement (scalars or (M, 3, 3)), or
    (K, M, 3, 3) per step;
    valid: optional (K, 18 M) bool rows available per step; rate_window: None (instantaneous
    rates) or the eq. 7 window W (s): scalar, (M, 3, 3), or (K, M, 3, 3) per step.
    Same timing as run_filter: measurements at every step including k = 0:
        J_0 = P0^-1 + H_0^T R^-1 H_0,
        J_k = (Q + Phi J_{k-1}^-1 Phi^T)^-1 + H_k^T R^-1 H_k    (additive Gaussian noise, linear
        dynamics: the D11/D12/D22 terms of Tichavsky et al. reduce to this form).
    Returns bounds (K, 18, 18) = J_k^-1 (m^2, m^2/s, m^2/s^2).
    """
    states = np.asarray(states, float)
    K = states.shape[0]
    Xs = np.asarray(master_pos, float)
    Vs = np.asarray(master_vel, float)
    if Xs.ndim == 3:
        Xs = np.broadcast_to(Xs, (K,) + Xs.shape)
        Vs = np.broadcast_to(Vs, (K,) + Vs.shape)
    M = Xs.shape[1]
    shape = (M, 3, 3)
    def _r_inv(k: int) -> np.ndarray:
        sr, sd = (np.asarray(v, float) for v in (sigma_range, sigma_range_rate))
        sr, sd = (v[k] if v.ndim == 4 else v for v in (sr, sd))
        return 1.0 / stack_rows(np.broadcast_to(sr ** 2, shape), np.broadcast_to(sd ** 2, shape))

    out = np.empty((K, N_STATE, N_STATE))
    I = np.eye(N_STATE)
    C = np.asarray(P0, float)
    for k in range(K):
        if k > 0:
            dt = float(times[k] - times[k - 1])
            F = transition(dt)
            C = symmetrize(F @ C @ F.T + process_noise(dt, q, states[k - 1]))
        W = None if rate_window is None else (rate_window[k] if np.ndim(rate_window) == 4 else rate_window)
        _, H = measurement_model(states[k], Xs[k], Vs[k], rate_window=W)
        r_inv = _r_inv(k)
        wts = r_inv if valid is None else r_inv * np.asarray(valid[k], bool)
        # J = (Q + Phi J^-1 Phi^T)^-1 + H^T R^-1 H
        J = linalg.cho_solve(linalg.cho_factor(C), I) + H.T @ (wts[:, None] * H)
        C = symmetrize(linalg.cho_solve(linalg.cho_factor(symmetrize(J)), I))
        out[k] = C
    return out


def pcrb_position_rmse(bounds: np.ndarray, body: bool = False) -> np.ndarray:
    """sqrt(trace) of the position block of bounds (K, 18, 18) -> (K,) metres.

    body False: the 9x9 block of the three antenna positions (RMSE of the stacked antenna
    positions); body True: the body-origin position (x2 + x3)/2 (eq. 29), 3x3 block B C B^T.
    """
    bounds = np.asarray(bounds)
    if not body:
        return np.sqrt(np.trace(bounds[..., :9, :9], axis1=-2, axis2=-1))
    B = np.zeros((3, N_STATE))
    B[:, 3:6] = B[:, 6:9] = 0.5 * np.eye(3)
    return np.sqrt(np.trace(B @ bounds @ B.T, axis1=-2, axis2=-1))


__all__ = [
    "DEFAULT_Q", "Gate", "NO_GATE", "PhaseMeasurement", "ProcessNoise", "UpdateInfo", "body_state", "initial_belief",
    "linearized_update", "pcrb", "pcrb_position_rmse", "predict", "process_noise", "run_filter",
    "transition", "update", "ROWS_PER_MASTER",
]
