"""Seed 003 estimator: EKF on carrier-phase ranges/range rates from M three-antenna masters.

Paper: Pan, Yin, Xu, Ordnance Industry Automation 2023 (docs/papers.md), eq. 13-31.
State, frames, units and the measurement row ordering are documented in `estimators.phase_model`.
Pure numpy/scipy: usable on measurements that did not come from MuJoCo.

Public API
----------
transition(dt)                              Phi (18, 18), eq. 24
ProcessNoise                                white-acceleration densities: per antenna, body translation, body rotation
process_noise(dt, q, x, P)                  Q (18, 18), continuous white-noise-acceleration model
PhaseEkf(q, gate, iterations, rigid)        THE filter on the estimator interface (core.Filter):
                                            predict(belief, dt), update(belief, measurement) -> belief
PhaseEkfCovarianceAnalysis                  the same filter, also carrying its ACTUAL error covariance
time_update(belief, dt, q, rigid)           time update, eq. 18/22 (rigid: with rigid_transition and its input noise)
rigid_transition(x, dt)                     eq. 24 plus the centripetal acceleration of a turning rigid body
PhaseMeasurement                            one epoch: ranges, range rates, master antennas, sigmas, masks
measurement_update(belief, meas, gate, iterations)   EKF (or iterated EKF) measurement update
                                            (eq. 19-22, Joseph) -> (Gaussian, core.UpdateInfo)
initial_belief(p, v, R, R_dot, P_pos, P_vel, a, b)  prior on the 18-state from a body prior
body_state(belief)                          Gaussian over the 12 body quantities (eq. 29-30)
pcrb(states, times, master_pos, master_vel, P0, sigma_range, sigma_range_rate, q)   Tichavsky PCRB
pcrb_position_rmse(bounds, body)            sqrt(trace) of the position block of the bound

Process noise (choice documented here; the paper gives none)
-------------------------------------------------------------
Continuous white-noise acceleration, independent per antenna and per axis, spectral density q
(m^2/s^3):  Q = q [[tau^3/3 I9, tau^2/2 I9], [tau^2/2 I9, tau I9]]  (exact discretization of the
constant-velocity model of eq. 24).  DEFAULT_Q = 1e-7 m^2/s^3 is only this module's default
(the bound of the eq. 31 antenna accelerations: amplitude <= pi/18 rad at omega = 2 pi / 200 s on a
1 m lever arm, |a| <= 1.7e-4 m/s^2, matched by q T = (A omega 1 m)^2 over T = 200 s gives 1.5e-7).
The eq. 31 body itself moves at exactly constant velocity, so no physical q exists to copy: the
built-in scenarios choose their `pipeline.q` by a stated rule on calibration seeds disjoint from
every evaluation (the q whose ANEES is closest to its dof; testbed/reproduce/phase_q.py), which
gives 1e-12, or 1e-9 on line H000, over whole 200 s runs. Any q > 0 makes the filter's P at least
its actual error covariance for a motion without random acceleration (PhaseEkfCovarianceAnalysis:
Gelb's covariance analysis from the filter's own gains and Jacobians, its inputs the measurements
only).
In `flown` mode (closed-loop quadrotors) the accelerations are larger: the scenario sets q_flown.

Rigid-body terms (ProcessNoise.translation, .rotation; zero = the paper's Q above). The three
antennas sit on one rigid body: a random body acceleration a (white, density q_t per axis) and a
random angular acceleration alpha (white, density q_r per body axis) move antenna j by
a + alpha x rho_j, rho_j = x_j - (x_2 + x_3) / 2 its lever arm from the body origin (eq. 29), in N.
The 9 x 9 acceleration density of the stacked antennas is then
    S_ij = q_t I3 + q_r [rho_i]x [rho_j]x^T   (+ q I3 if i = j, the independent term above),
and Q = [[dt^3/3 S, dt^2/2 S], [dt^2/2 S, dt S]], with rho from the state the prediction starts
from (and, in the filter, averaged over its covariance: "Uncertain lever arms" below). This is exactly the motion of a scenario's [disturbance] (testbed.sim.disturbance) on a body
whose attitude changes slowly over dt. At the small q the built-in scenarios use, the independent
term no longer covers the deterministic attitude-driven antenna accelerations of eq. 31; the
rotational term does, and the scenarios set it by the rule's stage 2 (testbed/reproduce/phase_q.py). A rigid body has no random motion in the 6 directions
that stretch the antenna triangle (3 lengths and their rates), so on any rigid body's motion the 18-state
NEES is not chi-square there; the body position and velocity (6 dof) have no such deficit.
Measured (tests/test_phase_scenario.py, phase-cross-h000 with the follower's [disturbance] =
this Q's 1e-3 / 1e-5, range rows, 30 runs, 20 s, the scenario's q = 1e-9): body position and
velocity ANEES 5.78 in [4.50, 7.75], all 12 rigid-body quantities of eq. 29-30 13.07 in
[9.82, 14.43] (99 % intervals); 18-state ANEES 95.2 against [15.3, 20.9], the side lengths and
their rates being over-confident (NEES 38.6 for 6 dof; 18.2 under q = 1e-7): a small independent
q leaves the rigid triangle's shape almost without process noise.

Uncertain lever arms (the rotational term of ProcessNoise, with the belief's covariance)
----------------------------------------------------------------------------------------
The rotational term moves antenna j by alpha x rho_j, and rho_j is the filter's ESTIMATE of the
lever arm, not the true one. Where the attitude is well observed (sd of a few mrad) the two agree;
where it is not (line H000: a line of masters does not see the turn about it, attitude sd of
20-500 deg) the noise at the estimated arms goes in the wrong directions and misses the ones the
true rotation moves the antennas in. The time update therefore takes the density's expectation
over the arms' Gaussian uncertainty rho_j = rho_hat_j + d_j, d = L x[:9] with L the (9, 9) map of
lever_arms and C = L P[:9, :9] L^T its covariance, C_ij = E[d_i d_j^T] (3, 3):
    E[[rho_i]x [rho_j]x^T] = [rho_hat_i]x [rho_hat_j]x^T + tr(C_ij) I3 - C_ji           ("Uncertain lever arms")
(from [a]x [b]x^T = (a . b) I - b a^T; exact for Gaussian d, since the term is quadratic in it).
The body origin still gets nothing: rho_2 + rho_3 = 0 for every state, so d_2 + d_3 = 0 too.
On the seven formations that observe the attitude C is of mm^2 against 1 m^2 arms once the
filter has converged; only the first seconds, while the prior is metres wide, see a change
(cross H000, seed 1000, 20 s: means within 2.7e-6 m, variances within 5.6e-4 relative, body
ANEES 7.0944454 -> 7.0944461, 18-state 18.604 -> 18.598). Measured on line H000, calibration
seed 1002, 200 s: the body NEES (6 dof) at 40-65 s was 21-27 with the arms' estimate alone and 6-8
with the expectation (docs/papers.md, seed 003, "Line H000 over 200 s"). The PCRB (along the true trajectory) uses the true
arms, without this term.

Rigid rotation (rigid=True; the paper's eq. 24 is rigid=False)
-----------------------------------------------------------------
The three antennas sit on one rigid body that turns. Antenna j, at rho_j from the body origin,
accelerates by alpha x rho_j + omega x (omega x rho_j). Eq. 24 predicts every antenna at
constant velocity, so it has neither term. The angular acceleration alpha is random to the filter
(ProcessNoise.rotation). The centripetal term omega x (omega x rho_j) = omega x rho_dot_j is not:
omega follows from the state itself (phase_model.angular_velocity, from the arms and their
rates), and the term points along the lever arms, into the 6 directions that stretch the
triangle, which no rigid-body noise reaches. Without it a constant-velocity prediction moves each
antenna along its tangent and lengthens its arm by (omega t)^2 / 2: at the eq. 31 attitude rate
(<= 5.5e-3 rad/s) that is 3e-5 m/s^2 on a 1 m arm, 0.15 m over a 100 s memory, against
centimetre-level errors. Measured (docs/papers.md, seed 003, phase-cross-h000, calibration seeds,
200 s, q = 1e-12, q_rotation = 1e-7): 18-state ANEES 1538 without the term, 30 with it; the
attitude's 36.6 and 5.0. rigid_transition adds the term to the predicted mean, held over dt
(second order in dt). The term is computed from the estimate, so it carries the estimate's error:
a(x) - a(x_true) ~ J_a (x - x_true), J_a = d a / d x (phase_model.centripetal_acceleration). The
covariance takes it as an input noise independent of the state's error:
    P' = Phi P Phi^T + Q + G J_a P J_a^T G^T,   G = [dt^2/2 I9; dt I9]        ("Rigid rotation")
(the linearized transition Phi + G J_a would also correlate the term with the state's error; that
correlation is dropped). Without it the 6 directions that stretch the triangle, which no rigid-body noise
reaches, kept only q = 1e-12 and the 18-state was over-confident at 20 s (cross H000, calibration
seeds 1000..1009: final 18-state NEES 30.5, 6 side lengths and rates 19.2; with it 19.6 and 9.8).
J_a in Phi instead (the linearized transition) diverged in 2 of 10 runs while the prior's
velocities were metres per second apart and the implied omega wild (body ANEES 1565 and 620).
The body origin gets none of the term (rho_dot_2 + rho_dot_3 = 0, so the rows of J_a of antennas
2 and 3 cancel in the body): the body's prediction and covariance are eq. 24's.

Innovation gate (cycle slips)
-----------------------------
core.Gate: Baarda's w-test with iterative data snooping on the innovation of all rows (the
numerics are core.linearized_update's). It uses the redundancy of the 90 rows, so a one-wavelength
slip (1-3 m, >= 20 range sigmas) is caught even while the prior is still metres wide. Default
alpha = 1e-3, k_w = 4.39 for m = 90. Rejected rows are listed in `UpdateInfo` (labelled by
phase_model.row_label) and counted in the driver's health counts; they never enter the state.

Running it: core.drive(PhaseEkf(q, gate, iterations), prior, epochs), one core.Epoch per
measurement epoch (controls None: the prior is at the first epoch, which is updated without a
predict; every later epoch is predicted over the time since the previous one).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from estimators.core import (NO_GATE, Gate, Gaussian, UpdateInfo, kf_predict, linearized_update, symmetrize,
                             white_acceleration_q)
from estimators.phase_model import (
    LEVER_ARMS_JACOBIAN,
    N_STATE,
    ROWS_PER_MASTER,
    antenna_state_from_body,
    body_from_antennas,
    centripetal_acceleration,
    lever_arms,
    measurement_model,
    row_label,
    stack_rows,
)
from estimators.so3 import skew

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

    def density(self, x: np.ndarray | None, P: np.ndarray | None = None) -> np.ndarray:
        """Acceleration density S (9, 9) of the stacked antennas at state x (18,) (needed only
        if rotation > 0: the lever arms rho_j = x_j - (x_2 + x_3) / 2); with P (18, 18), the
        covariance of x, the rotational term is averaged over the lever arms' uncertainty
        (module docstring, "Uncertain lever arms")."""
        S = self.antenna * np.eye(9)
        if self.translation:
            S += np.kron(np.full((3, 3), self.translation), np.eye(3))
        if self.rotation:
            Sk = skew(lever_arms(x)[0])  # (3, 3, 3): [rho_j]x
            S += self.rotation * np.einsum("iab,jcb->iajc", Sk, Sk).reshape(9, 9)
            if P is not None:
                # "Uncertain lever arms": E[[d_i]x [d_j]x^T] = tr(C_ij) I - C_ji, C = L P L^T
                C = (LEVER_ARMS_JACOBIAN @ P[:9, :9] @ LEVER_ARMS_JACOBIAN.T).reshape(3, 3, 3, 3)
                S += self.rotation * (np.einsum("iaja->ij", C)[:, None, :, None] * np.eye(3)[None, :, None, :]
                                      - C.transpose(2, 1, 0, 3)).reshape(9, 9)
        return S


def process_noise(dt: float, q: float | ProcessNoise = DEFAULT_Q, x: np.ndarray | None = None,
                  P: np.ndarray | None = None) -> np.ndarray:
    """Process noise Q (18, 18) of the CV model over dt s.

    q: a density per antenna axis (m^2/s^3), Q = q [[dt^3/3 I9, dt^2/2 I9], [dt^2/2 I9, dt I9]]
    (eq. 14's Q_k), or a ProcessNoise, Q = [[dt^3/3 S, dt^2/2 S], [dt^2/2 S, dt S]] with S its
    density at the state x (18,) the interval starts from, averaged over its covariance P (18, 18)
    when given (module docstring, "Uncertain lever arms").
    """
    S = ProcessNoise(antenna=q).density(None) if not isinstance(q, ProcessNoise) else q.density(x, P)
    return np.kron(white_acceleration_q(dt), S)


def rigid_transition(x: np.ndarray, dt: float) -> np.ndarray:
    """Prediction (18,) of the antenna state x (18,) over dt s: eq. 24 plus the centripetal
    acceleration a = phase_model.centripetal_acceleration(x) (9,) of the turning rigid body, held
    over dt (module docstring, "Rigid rotation"): x_j' = x_j + dt v_j + dt^2/2 a_j,  v_j' = v_j + dt a_j
    (time_update's mean)."""
    a = centripetal_acceleration(x)
    return transition(dt) @ x + np.concatenate([0.5 * dt * dt * a, dt * a])


def time_update(belief: Gaussian, dt: float, q: float | ProcessNoise = DEFAULT_Q, rigid: bool = False) -> Gaussian:
    """EKF time update over dt s (eq. 15, 18, 23): x' = Phi x, P' = Phi P Phi^T + Q (Q with the
    belief's lever-arm uncertainty, module docstring "Uncertain lever arms"); with rigid,
    x' = rigid_transition(x, dt) and P' = Phi P Phi^T + Q + G J_a P J_a^T G^T, the centripetal
    term's uncertainty as an input noise (module docstring, "Rigid rotation")."""
    # eq. 22 (first two lines) with f linear: eq. 23-24
    F, Q = transition(dt), process_noise(dt, q, belief.mean, belief.cov)
    if not rigid:
        return kf_predict(belief, F, Q)
    a, Ja = centripetal_acceleration(belief.mean, jacobian=True)
    # "Rigid rotation": the centripetal acceleration a as the known input G a, G = [dt^2/2 I9; dt I9]
    # (rigid_transition), its uncertainty J_a P J_a^T as an input noise
    GJ = np.concatenate([0.5 * dt * dt * Ja, dt * Ja])
    return kf_predict(belief, F, Q + GJ @ belief.cov @ GJ.T, u=np.concatenate([0.5 * dt * dt * a, dt * a]))


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


def measurement_update(belief: Gaussian, measurement: PhaseMeasurement, gate: Gate = Gate(),
                       iterations: int = 1) -> tuple[Gaussian, UpdateInfo]:
    """EKF measurement update with the M-master carrier-phase model (eq. 16-22, 25-28).

    belief: prior over the 18-state (phase_model docstring); measurement: one epoch.
    iterations: 1 = the paper's EKF. n > 1 = iterated EKF (Gauss-Newton): the model is
    relinearized n - 1 more times at the latest estimate x_i, with the rows kept by the gate in
    the first pass, z_lin = z - h(x_i) + H_i x_i; it removes the linearization error of the first
    epochs when the prior is metres wide (tests/test_phase_ekf.py measures it).
    Returns the posterior and an UpdateInfo (rows in the eq. 12/25 order, gate decisions, gain and
    Jacobian of the first pass). `PhaseEkf.update` is this without the UpdateInfo.
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
# Initialization, body state
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


# ------------------------------------------------------------------------------------------------
# The filter on the estimator interface (core.Filter)
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class PhaseEkf:
    """The seed 003 EKF as a core.Filter: predict(belief, dt, u) and update(belief, measurement).

    q: white-acceleration density per antenna axis (m^2/s^3) or a ProcessNoise; gate: the
    innovation gate; iterations: 1 = the paper's EKF, > 1 iterated EKF (`measurement_update`);
    rigid: False = eq. 24's constant velocity per antenna, True = plus the centripetal
    acceleration of the turning rigid body (rigid_transition). The filter has no input: u is ignored.
    """

    q: float | ProcessNoise = DEFAULT_Q
    gate: Gate = Gate()
    iterations: int = 1
    rigid: bool = False

    def predict(self, belief: Gaussian, dt: float, u: None = None) -> Gaussian:
        """Time update over dt s (eq. 18, 22-24; with rigid, rigid_transition)."""
        return time_update(belief, dt, self.q, self.rigid)

    def update(self, belief: Gaussian, measurement: PhaseMeasurement) -> Gaussian:
        """Measurement update with one epoch (eq. 16-22, 25-28); gate rejections are tallied."""
        return measurement_update(belief, measurement, self.gate, self.iterations)[0]


@dataclass(frozen=True, slots=True)
class AnalyzedGaussian(Gaussian):
    """A belief that also carries the ACTUAL error covariance of the filter that produced it.

    actual: (n, n) covariance of this filter's error if the motion had no random acceleration
    (`PhaseEkfCovarianceAnalysis`); info: the UpdateInfo of the update that produced the belief
    (None after a predict); mean and cov as in core.Gaussian.
    """

    actual: np.ndarray
    info: UpdateInfo | None = None


class PhaseEkfCovarianceAnalysis(PhaseEkf):
    """PhaseEkf that also propagates its actual error covariance for a motion without process noise.

    Covariance analysis of a suboptimal filter (Gelb 1974, ch. 7): with the filter's own gains K_k
    and Jacobians H_k, the error for a motion with zero process noise has covariance
        P_act,k|k-1 = Phi P_act Phi^T,   P_act,k = (I - K H) P_act,k|k-1 (I - K H)^T + K R K^T.
    The filter's P (with Q = q ...) is >= P_act, so its NEES is low on the eq. 31 motion, whose
    body has no acceleration at all; NEES against P_act is the consistency check that accounts for
    it. Beliefs are AnalyzedGaussian (start from AnalyzedGaussian(mean, P0, P0)); the filter's own
    mean and cov are exactly PhaseEkf's.
    """

    __slots__ = ()

    def predict(self, belief: AnalyzedGaussian, dt: float, u: None = None) -> AnalyzedGaussian:
        bel = time_update(belief, dt, self.q, self.rigid)
        F = transition(dt)
        return AnalyzedGaussian(bel.mean, bel.cov, F @ belief.actual @ F.T)

    def update(self, belief: AnalyzedGaussian, measurement: PhaseMeasurement) -> AnalyzedGaussian:
        post, info = measurement_update(belief, measurement, self.gate, self.iterations)
        Pa = belief.actual
        if info.dof:
            _, r_var, _ = measurement.stacked()
            K, ru = info.gain, r_var[info.used]
            IKH = np.eye(N_STATE) - K @ info.jacobian
            # Joseph form of eq. 21 with the filter's gain, on the actual covariance
            Pa = symmetrize(IKH @ Pa @ IKH.T + (K * ru[None, :]) @ K.T)
        return AnalyzedGaussian(post.mean, post.cov, Pa, info)


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
    Same timing as the filter under core.drive: measurements at every step including k = 0:
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
    "DEFAULT_Q", "AnalyzedGaussian", "PhaseEkf", "PhaseEkfCovarianceAnalysis", "PhaseMeasurement",
    "ProcessNoise", "body_state", "initial_belief", "measurement_update", "pcrb", "pcrb_position_rmse",
    "process_noise", "rigid_transition", "time_update", "transition", "ROWS_PER_MASTER",
]
