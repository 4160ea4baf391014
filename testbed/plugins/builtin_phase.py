"""The seed 003 carrier-phase EKF (phase-ekf pipeline) as a protocol estimator: `phase.ekf`.

It collects the `phase` rows of one output epoch (every master antenna to every follower antenna,
with the measured extras master_pos, master_vel, rate_periods) and, when a phase row of a later
time arrives (or at finish), turns them into the filter's inputs (`phase_inputs` on that epoch
alone, `measurement_epochs`) and steps the filter (estimators.phase_ekf.PhaseEkfCovarianceAnalysis)
with the library's online driver (estimators.core.Stepper). `prepare` does the same for a whole
run log at once (the prior of testbed.plugins.priors.priors, the PCRB of
testbed.plugins.phase_scores).

Inputs (nothing else): the `phase` stream: per output epoch and link (master m, slot i, follower
antenna j) the ambiguity-resolved range r_hat (m), the eq. 7 range rate (m/s) and its
`rate_periods`; the masters' own navigation solution `master_pos`, `master_vel` (world, m, m/s);
the settings (the phase-ekf [pipeline] keys) and the sensor's phase period T = 1 /
sensors.phase.phase_rate_hz (an instrument setting, not truth). Every master antenna is moved to
the navigation frame N (estimators.phase_frames) with the nav master's pose from its own antennas.

Start: Context.prior["uavF"], the 18-state the pipeline starts from (planned state + initial
error, testbed.plugins.priors.priors); the filter settings are the phase-ekf [pipeline] keys
(params; the scenario's by default; the init keys act through the prior only). The process
noise is q or q_flown by Context.motion, as in the pipeline.

Estimates at every epoch, world frame: the follower body's position and velocity as one
EstimateBatch with their covariances and their (6, 6) joint covariance (cov_joint, the 6-dof
ANEES of testbed.plugins.phase_scores), and its attitude (no covariance), mapped from the
navigation frame N with the nav master's pose measured at that epoch (from its own antennas, as
the pipeline does): p_W = p + R p_N, v_W = v + R v_N + dR/dt p_N (R, dR/dt: N to world).
`navigation_states()` (the optional method of testbed.plugins.api.NavigationStates): every
epoch's 18-state in N (frame "phase-N", layout "phase-18": estimators.phase_model's antenna
state), the filter's covariance and the actual covariance of the covariance analysis.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from estimators.core import Epoch, Gate, Gaussian, Stepper
from estimators.phase_ekf import AnalyzedGaussian, PhaseEkfCovarianceAnalysis, PhaseMeasurement, ProcessNoise, initial_belief
from estimators.phase_frames import BODY_POS, BODY_PV, nav_pose_from_antennas, to_nav
from estimators.phase_model import antenna_state_from_body, rotation_from_antennas
from estimators.so3 import skew
from testbed.errors import ConfigError
from testbed.config.pipelines import PhasePipelineConfig
from testbed.plugins.api import Context, Estimate, EstimateBatch, Measurement, NavigationStates
from testbed.plugins.settings import settings
from testbed.reference import evaluate
from testbed.rng import stream_rng

_COLUMNS = ("master_pos", "master_vel", "rate_periods", "slip")


@dataclass(frozen=True, slots=True)
class PhaseInputs:
    """Per-epoch inputs in N. times (K,) s; state_index (K,) into the log; ranges, rates, windows
    (K, M, 3, 3) m, m/s, s; master_pos, master_vel (K, M, 3, 3) m, m/s; slip (K, M, 3, 3) bool
    (sensor's repaired-slip flag); nav pose (p, v, R, Rd) from the nav master's own antennas."""

    times: np.ndarray
    state_index: np.ndarray
    masters: tuple[int, ...]
    follower: int
    ranges: np.ndarray
    rates: np.ndarray
    windows: np.ndarray
    master_pos: np.ndarray
    master_vel: np.ndarray
    slip: np.ndarray
    nav_pose: tuple


def phase_inputs(log: dict, phase_period: float, nav_master: int) -> PhaseInputs:
    """Reshape the `phase` stream (rows: epoch, master, slot i, antenna j) and move it to N.

    phase_period: T = 1 / phase_rate_hz (s). Raises ValueError if the stream's layout is not the
    documented one or the nav master is not among the masters.
    """
    times_all = log["phase/time"]
    times, first = np.unique(times_all, return_index=True)
    K = times.size
    L = times_all.size // K
    if L * K != times_all.size or L % 9:
        raise ValueError(f"phase stream has {times_all.size} rows, not a whole number of epochs of 9 M links")
    M = L // 9
    src = log["phase/src"].reshape(K, M, 3, 3)[0]
    dst = log["phase/dst"].reshape(K, M, 3, 3)[0]
    masters = tuple(int(s.split("/")[0][3:]) for s in src[:, 0, 0])
    follower = int(dst[0, 0, 0].split("/")[0][3:])
    for m in range(M):
        for i in range(3):
            for j in range(3):
                if src[m, i, j] != f"uav{masters[m]}/ant{i + 1}" or dst[m, i, j] != f"uav{follower}/ant{j + 1}":
                    raise ValueError("phase stream rows are not in (master, slot, antenna) order")
    if nav_master not in masters:
        raise ValueError(f"nav_master {nav_master} is not one of the phase masters {masters}")
    val = log["phase/value"].reshape(K, M, 3, 3, 3)
    periods = log["phase/rate_periods"].reshape(K, M, 3, 3).astype(float)
    Xw = log["phase/master_pos"].reshape(K, M, 3, 3, 3)[:, :, :, 0]  # (K, M, slot, xyz)
    Vw = log["phase/master_vel"].reshape(K, M, 3, 3, 3)[:, :, :, 0]
    n = masters.index(nav_master)
    pose = nav_pose_from_antennas(Xw[:, n], Vw[:, n])
    XN, VN = to_nav(Xw, Vw, *pose)
    windows = np.where(periods > 0, periods * phase_period, np.nan)
    return PhaseInputs(times, log["phase/state_index"][first], masters, follower, val[..., 1], val[..., 2],
                       windows, XN, VN, log["phase/slip"].reshape(K, M, 3, 3), pose)


def measurement_epochs(cfg: PhasePipelineConfig, inp: PhaseInputs) -> list:
    """One PhaseMeasurement per epoch with the configured rate-row model and noise."""
    out = []
    for k in range(inp.times.size):
        W = inp.windows[k]
        sig_rate = np.where(np.isfinite(W), np.sqrt(2.0) * cfg.range_sigma / np.where(np.isfinite(W), W, 1.0), np.inf)
        use_rate = np.isfinite(W) & (cfg.rate_rows != "off")
        out.append(PhaseMeasurement(
            inp.ranges[k], inp.rates[k], inp.master_pos[k], inp.master_vel[k], cfg.range_sigma, sig_rate,
            valid_range_rate=use_rate,
            rate_window=np.where(use_rate, W, 1.0) if cfg.rate_rows == "window" else None,
        ))
    return out


def process_noise_model(cfg: PhasePipelineConfig, motion: str) -> ProcessNoise:
    """The filter's ProcessNoise: per-antenna q of the motion mode plus the rigid-body terms."""
    return ProcessNoise(cfg.q_flown if motion == "flown" else cfg.q, cfg.q_translation, cfg.q_rotation)


def initial_prior(cfg: PhasePipelineConfig, scenario, inp: PhaseInputs, rng: np.random.Generator):
    """Prior on the 18-state at the first epoch: the planned (reference) follower state in N plus
    the initial error (drawn from the prior covariance, or the paper's fixed error).
    Returns (Gaussian prior, P0 (18, 18), error added (18,))."""

    ref = evaluate(scenario.trajectory, inp.times[0])
    f = inp.follower - 1
    p0, v0, R0, Rd0 = (x[:1] for x in inp.nav_pose)
    pN, vN = to_nav(ref.pos[:, f], ref.vel[:, f], p0, v0, R0, Rd0)
    Rw = Rotation.from_quat(ref.quat[0, f], scalar_first=True).as_matrix()
    RN = R0[0].T @ Rw
    RNd = Rd0[0].T @ Rw + R0[0].T @ Rw @ skew(ref.omega[0, f])
    a, b = cfg.antenna_a + cfg.antenna_error, cfg.antenna_b + cfg.antenna_error
    base = initial_belief(pN[0], vN[0], RN, RNd, np.diag(cfg.init_pos_var), np.diag(cfg.init_vel_var), a, b)
    if cfg.init == "paper":
        mean = antenna_state_from_body(pN[0] + np.array(cfg.init_pos_error), vN[0] + np.array(cfg.init_vel_error), RN, RNd, a, b)
    else:
        mean = base.mean + np.linalg.cholesky(base.cov) @ rng.standard_normal(base.mean.size)
    return Gaussian(mean, base.cov), base.cov, mean - base.mean


def prepare(scenario, log: dict) -> tuple:
    """The filter's inputs for a whole run log with the scenario's [pipeline] settings: (cfg,
    PhaseInputs, q, prior Gaussian, P0 (18, 18), measurements). The prior is the one phase.ekf
    starts from (testbed.plugins.priors.priors); the rest is what the PCRB assumes
    (testbed.plugins.phase_scores)."""
    cfg: PhasePipelineConfig = scenario.pipeline
    ph = scenario.sensors.phase
    if ph is None or "phase/time" not in log:
        raise ConfigError(f"{scenario.name}: pipeline phase-ekf needs the [sensors.phase] stream")
    try:
        inp = phase_inputs(log, 1.0 / ph.phase_rate_hz, cfg.nav_master)
    except ValueError as e:
        raise ConfigError(f"{scenario.name}: pipeline.nav_master: {e}") from None
    q = process_noise_model(cfg, scenario.motion)
    prior, P0, _ = initial_prior(cfg, scenario, inp, stream_rng(scenario.seed, "init"))
    return cfg, inp, q, prior, P0, measurement_epochs(cfg, inp)


class PhaseEkf:
    """seed 003: carrier-phase EKF of the follower (18-state, nav frame of a master), body pose in world."""

    Params = PhasePipelineConfig  # its parameters (testbed.plugins.settings)

    def __init__(self, context: Context, params: dict):
        self.cfg = settings(PhasePipelineConfig, context, params, "phase.ekf")
        ph = context.sensors.get("phase")
        if ph is None:
            raise ValueError("phase.ekf needs the carrier-phase stream ([sensors.phase])")
        self.period = 1.0 / ph["phase_rate_hz"]
        self.target = f"uav{ph['follower']}"
        if self.target not in context.prior:
            raise ValueError(f"phase.ekf needs the prior of {self.target} (a scenario whose [pipeline] kind is phase-ekf)")
        mean, cov = context.prior[self.target]
        q = process_noise_model(self.cfg, context.motion)
        filt = PhaseEkfCovarianceAnalysis(q, Gate(alpha=self.cfg.gate_alpha, enabled=self.cfg.gate), self.cfg.iterations,
                                          self.cfg.rigid)
        self.stepper = Stepper(filt, AnalyzedGaussian(mean, cov, cov))
        self.rows: list[Measurement] = []
        self.states: list[tuple[float, AnalyzedGaussian]] = []  # every epoch's belief: navigation_states()

    def _epoch(self) -> list[Estimate]:
        """Filter the buffered epoch; its estimates in the world frame (module docstring)."""
        rows, self.rows = self.rows, []
        t = rows[0].time
        log = {"phase/time": np.full(len(rows), t), "phase/state_index": np.zeros(len(rows), int),
               "phase/src": np.array([m.src for m in rows]), "phase/dst": np.array([m.dst for m in rows]),
               "phase/value": np.stack([m.value for m in rows]),
               **{f"phase/{c}": np.stack([m.extra[c] for m in rows]) for c in _COLUMNS}}
        inp = phase_inputs(log, self.period, self.cfg.nav_master)
        b = self.stepper.step(Epoch(t, measurement_epochs(self.cfg, inp)[0]))
        self.states.append((t, b))
        p, v, R, Rd = (a[0] for a in inp.nav_pose)
        pN, vN = BODY_POS @ b.mean, BODY_PV[3:] @ b.mean
        J = np.vstack([R @ BODY_POS, R @ BODY_PV[3:] + Rd @ BODY_POS])  # d(p_W, v_W) / d(18-state), (6, 18)
        P = J @ b.cov @ J.T
        att = Rotation.from_matrix(R @ rotation_from_antennas(b.mean)).as_quat(scalar_first=True)
        return [EstimateBatch(time=np.full(2, t), target=(self.target,) * 2, quantity=("position", "velocity"),
                              value=[p + R @ pN, v + R @ vN + Rd @ pN], cov=np.stack([P[:3, :3], P[3:, 3:]]), cov_joint=P),
                Estimate(time=t, target=self.target, quantity="attitude", value=att)]

    def process(self, m: Measurement) -> list[Estimate]:
        if m.stream != "phase":
            return []
        out = self._epoch() if self.rows and m.time > self.rows[0].time else []
        self.rows.append(m)
        return out

    def finish(self) -> list[Estimate]:
        return self._epoch() if self.rows else []

    def health(self) -> dict[str, int]:
        """The driver's counts (core.Track.health) and `gate_epochs_with_rejection`, the epochs
        whose gate rejected at least one row."""
        track = self.stepper.track()
        return {**track.health(), "gate_epochs_with_rejection": int((np.asarray(track.rejected_measurements) > 0).sum())}

    def navigation_states(self) -> NavigationStates:
        """Every epoch's 18-state in N, its filter covariance and its actual covariance (module docstring)."""
        beliefs = [b for _, b in self.states]
        return NavigationStates(time=np.array([t for t, _ in self.states]), mean=np.stack([b.mean for b in beliefs]),
                                cov=np.stack([b.cov for b in beliefs]), actual=np.stack([b.actual for b in beliefs]),
                                frame="phase-N", layout="phase-18")
