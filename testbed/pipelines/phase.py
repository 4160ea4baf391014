"""Seed 003 estimator pipeline (kind "phase-ekf"): run log -> estimates, metrics, plots.

Inputs the estimator gets (nothing else):
- the `phase` stream: per output epoch and link (master m, slot i, follower antenna j) the
  ambiguity-resolved range r_hat (m) and the eq. 7 range rate (m/s), `phase/rate_periods`;
- the masters' own navigation solution `phase/master_pos`, `phase/master_vel` (world, m, m/s);
- configured knowns from this [pipeline] table (filter noise, q, initial-error model, the
  follower's antenna lever arms for the prior spread) and the sensor's phase period
  T = 1 / sensors.phase.phase_rate_hz (an instrument setting, not truth);
- the planned initial state of the follower: the scenario's reference trajectory at the first
  epoch (testbed.reference; the plan, not the MuJoCo state), to which the initial error is added.

Navigation frame N = body frame (FLU) of master `nav_master` (3, on the symmetry axis). Its pose is
derived every epoch from ITS OWN antennas in the master_pos/master_vel stream (eq. 29-30 applied
to the master: origin = mid wing tips, axes from the antenna triangle, Euler rates from the antenna
velocities), and every master antenna is expressed in N:
    X_N = R^T (X_W - p),   V_N = d/dt X_N = R^T (V_W - v) + (dR/dt)^T (X_W - p).
Ranges are frame-free. The truth for scoring is expressed the same way with master 3's TRUE pose
(truth/pos, truth/vel, truth/quat, truth/omega). In prescribed mode master 3 hovers level with yaw
0 at trajectory.nav_origin, so N is the world frame shifted; in flown mode it is the frame of the
hovering quadrotor (its small motion, if any, is carried by R, p and their rates).

Range-rate rows (eq. 7 as the sensor really measures it): the reported rate is the mean over the
window W = rate_periods T (0.7 s by default) ending at the epoch, i.e. (r(t) - r(t - W)) / W; it
lags the instantaneous rate by ~W / 2. `rate_rows = "window"` predicts exactly that mean
from the constant-velocity state (phase_model.measurement_model, rate_window), `"instantaneous"`
is the paper's eq. 10 (biased by the lag), `"off"` (default) uses ranges only. The rate noise is
sqrt(2) range_sigma / W per row (W shorter during the first 0.7 s).
Correlation: because the phase tracker telescopes, the reported rate equals
(r_hat(t) - r_hat(t - W)) / W to round-off (checked in tests/test_phase_scenario.py): its error is
the difference of the range errors at t and t - W. So a rate row is correlated with the same
epoch's range row (rho = +0.71) and with the range row W earlier (rho = -0.71), and consecutive
rates are NOT correlated with each other (the window's inner phase samples cancel). The paper's
EKF treats all 90 rows as independent, which counts the range information twice in velocity:
with ranges at every epoch the rate rows carry no information the ranges do not, and `"off"` is
the consistent choice, hence the default (derivation: docs/models.md, "Seed 003 range-rate
rows"). Measured on the model-matched truth of
tests/test_phase_scenario.py (phase-cross-h000 with the follower's [disturbance] equal to the
filter's q_translation / q_rotation, 30 runs, 20 s, final epoch): body ANEES 5.78 with `"off"`,
9.65 with `"window"` (over-confident), 99 % interval [4.50, 7.75] (9.64 under the former q = 1e-7).

Scores (estimators.ekf in metrics.json), body = mean of wing tips (eq. 29), frame N:
rmse_position_m, rmse_velocity_mps, rmse_attitude_deg over t >= score_start;
window scores over the last W = last_window seconds (default 100), named by W:
rmse_position_last_<W>s_m, pcrb_rmse_position_last_<W>s_m; max_abs_position_error_last_<W>s_m,
max_abs_velocity_error_last_<W>s_mps (per axis x, y, z of N: x forward, y left, z up). A window
score exists only when the run covers its window (t_last - t_first >= W): on a shorter run they are
omitted (`last_window_s` and `last_window_omitted_reason` say so), never computed over a shorter
span under the longer name (`window_keys` gives the names for a W); anees: mean over t >= score_start of the NEES
of the body position and velocity (6 dof, linear in the state, so its covariance is exact);
anees_state18: the same for the 18-state; each with its dof (`anees_dof`, ...) and its 99 %
interval (`anees_interval_99`, ...) over its effective samples (`n_eff`, ...: the epochs' errors
are correlated, docs/consistency.md); nees_final, nees_body6_final, nees_attitude6_final: the
final epoch's NEES of the 18-state, of the body position and velocity (6 dof) and of the attitude
and its rates (yaw, pitch, roll and their rates, 6 dof, eq. 30 linearized: `attitude_nees`);
pcrb_rmse_position_m: sqrt of the mean over the same
epochs of trace(body-position block of the PCRB) along the true trajectory (Tichavsky 1998, same
measurement model, same rows, same q and P0 as the filter); gate statistics; the driver's health
counts (core.Track.health: covariance_repairs, rejected_measurements, nonconverged_steps).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from estimators.core import Epoch, Gate, Gaussian, Track, drive, nees
from estimators.phase_ekf import (
    AnalyzedGaussian,
    PhaseEkfCovarianceAnalysis,
    PhaseMeasurement,
    ProcessNoise,
    initial_belief,
    pcrb,
)
from estimators.phase_model import antenna_state_from_body, body_from_antennas, rotation_from_antennas
from estimators.so3 import euler_from_rotation, rot_zyx, rot_zyx_dot, skew
from testbed.errors import ConfigError
from testbed.pipelines.config import PhasePipelineConfig
from testbed.reference import evaluate
from testbed.rng import stream_rng


# ------------------------------------------------------------------------------------------------
# Frames
# ------------------------------------------------------------------------------------------------
def nav_pose_from_antennas(X: np.ndarray, V: np.ndarray) -> tuple[np.ndarray, ...]:
    """Pose of the navigation master from its own antennas, per epoch.

    X, V: (K, 3, 3) world positions / velocities of its ant1..3 (m, m/s). Returns p, v (K, 3)
    (origin = mid wing tips, eq. 29), R (K, 3, 3) R_world_from_N, Rd (K, 3, 3) dR/dt (1/s).
    """
    K = X.shape[0]
    p, v = np.empty((K, 3)), np.empty((K, 3))
    R, Rd = np.empty((K, 3, 3)), np.empty((K, 3, 3))
    for k in range(K):
        y, _ = body_from_antennas(np.concatenate([X[k].ravel(), V[k].ravel()]))
        p[k], v[k] = y[0:3], y[3:6]
        R[k], Rd[k] = rot_zyx(*y[6:9]), rot_zyx_dot(y[6:9], y[9:12])
    return p, v, R, Rd


def to_nav(X: np.ndarray, V: np.ndarray, p, v, R, Rd) -> tuple[np.ndarray, np.ndarray]:
    """World points X (K, ..., 3) and their velocities V to N: R^T (X - p), R^T (V - v) + Rd^T (X - p)."""
    extra = X.ndim - 2
    sl = (slice(None),) + (None,) * extra
    dX = X - p[sl]
    XN = np.einsum("k...i,kij->k...j", dX, R)
    VN = np.einsum("k...i,kij->k...j", V - v[sl], R) + np.einsum("k...i,kij->k...j", dX, Rd)
    return XN, VN


# ------------------------------------------------------------------------------------------------
# Streams -> estimator inputs
# ------------------------------------------------------------------------------------------------
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


def truth_in_nav(log: dict, idx: np.ndarray, nav_master: int, follower: int, a: float, b: float):
    """Truth at log rows idx (K,) in N from master nav_master's TRUE pose (scoring only).

    Returns body (K, 12) [p, v, yaw, pitch, roll, their rates], R_N_follower (K, 3, 3) and the
    18-state (K, 18) with the true lever arms a, b (m).
    """
    def pose(u):
        R = Rotation.from_quat(log["truth/quat"][idx, u - 1], scalar_first=True).as_matrix()
        om = log["truth/omega"][idx, u - 1]
        return log["truth/pos"][idx, u - 1], log["truth/vel"][idx, u - 1], R, R @ skew(om)

    p3, v3, R3, R3d = pose(nav_master)
    p6, v6, R6, R6d = pose(follower)
    pN, vN = to_nav(p6, v6, p3, v3, R3, R3d)
    RN = np.einsum("kji,kjl->kil", R3, R6)
    RNd = np.einsum("kji,kjl->kil", R3d, R6) + np.einsum("kji,kjl->kil", R3, R6d)
    K = idx.size
    states = np.array([antenna_state_from_body(pN[k], vN[k], RN[k], RNd[k], a, b) for k in range(K)])
    eul = np.array([euler_from_rotation(R) for R in RN])
    # Euler rates are not scored (left 0)
    body = np.concatenate([pN, vN, eul, np.zeros_like(eul)], axis=1)
    return body, RN, states


# ------------------------------------------------------------------------------------------------
# Filter
# ------------------------------------------------------------------------------------------------
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


def run_filter(cfg: PhasePipelineConfig, q: float | ProcessNoise, prior: Gaussian, meas: list,
               times: np.ndarray) -> Track:
    """The seed 003 EKF over all epochs through the library's driver (core.drive): one epoch per
    measurement, the prior at the first one. The beliefs are AnalyzedGaussian: besides the
    filter's mean and cov they carry the ACTUAL error covariance of this filter if the truth had
    no random acceleration (phase_ekf.PhaseEkfCovarianceAnalysis), for the NEES against it.
    Gate rejections per epoch are the track's rejected_measurements.
    """
    filt = PhaseEkfCovarianceAnalysis(q, Gate(alpha=cfg.gate_alpha, enabled=cfg.gate), cfg.iterations)
    epochs = [Epoch(float(t), m) for t, m in zip(times, meas)]
    return drive(filt, AnalyzedGaussian(prior.mean, prior.cov, prior.cov), epochs)


def phase_pcrb(cfg: PhasePipelineConfig, q: float | ProcessNoise, states: np.ndarray, inp: PhaseInputs, meas: list, P0: np.ndarray) -> np.ndarray:
    """PCRB (K, 18, 18) along the true 18-state trajectory with the filter's own rows and model."""
    valid = np.array([m.stacked()[2] for m in meas])
    sig_rate = np.array([np.broadcast_to(m.sigma_range_rate, (len(inp.masters), 3, 3)) for m in meas])
    sig_rate = np.where(np.isfinite(sig_rate), sig_rate, 1.0)
    W = np.where(np.isfinite(inp.windows), inp.windows, 1.0) if cfg.rate_rows == "window" else None
    return pcrb(states, inp.times, inp.master_pos, inp.master_vel, P0, cfg.range_sigma, sig_rate, q,
                valid=valid, rate_window=W)


# ------------------------------------------------------------------------------------------------
# Scores
# ------------------------------------------------------------------------------------------------
BODY_POS = np.zeros((3, 18))
BODY_POS[:, 3:6] = BODY_POS[:, 6:9] = 0.5 * np.eye(3)
BODY_PV = np.zeros((6, 18))
BODY_PV[:3] = BODY_POS
BODY_PV[3:, 12:15] = BODY_PV[3:, 15:18] = 0.5 * np.eye(3)


def attitude_nees(x: np.ndarray, P: np.ndarray, x_true: np.ndarray) -> float:
    """NEES of the follower's attitude and attitude rates (yaw, pitch, roll and their rates, 6 dof)
    at one epoch: x, x_true (18,) estimated and true antenna states in N, P (18, 18) the filter's
    covariance. Eq. 30 from the antennas (phase_model.body_from_antennas), covariance J P J^T
    linearized at the estimate, angle errors wrapped to [-pi, pi)."""
    (y, J), (y_true, _) = body_from_antennas(x), body_from_antennas(x_true)
    e = y[6:] - y_true[6:]
    e[:3] = (e[:3] + np.pi) % (2 * np.pi) - np.pi
    return float(nees(e, J[6:] @ P @ J[6:].T))


def window_keys(window_s: float) -> dict[str, str]:
    """metrics.json names of the window scores over the last `window_s` seconds:
    {"rmse", "pcrb_rmse", "max_abs_position", "max_abs_velocity"} -> key (e.g. window 100:
    "rmse_position_last_100s_m")."""
    w = f"last_{window_s:g}s"
    return {"rmse": f"rmse_position_{w}_m", "pcrb_rmse": f"pcrb_rmse_position_{w}_m",
            "max_abs_position": f"max_abs_position_error_{w}_m", "max_abs_velocity": f"max_abs_velocity_error_{w}_mps"}


def score(cfg: PhasePipelineConfig, track: Track, states_true, body_true, R_true, bound) -> dict:
    """metrics.json `estimators.ekf` (module docstring) and the series the plots need."""
    # lazy: testbed.metrics imports scipy.stats (seconds on a cold cache); only scoring needs it
    from testbed.metrics import anees_keys, attitude_error_vector, rmse

    t, means, covs = track.t, track.mean, track.cov
    acts = np.stack([b.actual for b in track.beliefs])
    pv = means @ BODY_PV.T
    Ppv = BODY_PV @ covs @ BODY_PV.T
    e = pv - body_true[:, :6]
    R_est = np.array([rotation_from_antennas(x) for x in means])
    att = np.degrees(np.linalg.norm(attitude_error_vector(R_est, R_true), axis=-1))
    sc = t >= t[0] + cfg.score_start
    if not sc.any():  # a run shorter than score_start: score every epoch
        sc[:] = True
    last = t >= t[-1] - cfg.last_window + 1e-9
    nees6 = nees(e, Ppv)
    nees18 = nees(means - states_true, covs)
    nees6_act = nees(e, BODY_PV @ acts @ BODY_PV.T)
    Bp = BODY_POS @ bound @ BODY_POS.T
    rejected = track.rejected_measurements
    mid = int(np.argmin(np.abs(t - (t[0] + 0.5 * (t[-1] - t[0])))))
    out = {
        "rmse_position_m": rmse(e[sc, :3]),
        "rmse_velocity_mps": rmse(e[sc, 3:]),
        "rmse_attitude_deg": float(np.sqrt(np.mean(att[sc] ** 2))),
        "position_error_mid_m": e[mid, :3].tolist(),
        "position_error_final_m": e[-1, :3].tolist(),
        "sigma_position_final_m": np.sqrt(np.diag(Ppv[-1])[:3]).tolist(),
        **anees_keys(nees6[sc], 6),
        **anees_keys(nees18[sc], 18, "anees_state18"),
        **anees_keys(nees6_act[sc], 6, "anees_body6_actual_cov"),
        "nees_final": float(nees18[-1]),
        "nees_body6_final": float(nees6[-1]),
        "nees_attitude6_final": attitude_nees(means[-1], covs[-1], states_true[-1]),
        "nees_body6_actual_cov_final": float(nees6_act[-1]),
        "pcrb_rmse_position_m": float(np.sqrt(np.mean(np.trace(Bp[sc], axis1=1, axis2=2)))),
        "pcrb_sigma_position_final_m": np.sqrt(np.diag(Bp[-1])).tolist(),
        "gate_rejected_rows": int(rejected.sum()),
        "gate_epochs_with_rejection": int((rejected > 0).sum()),
        "epochs": int(t.size),
        "score_start_s": float(t[sc][0]),
        **track.health(),
        "last_window_s": float(cfg.last_window),
    }
    if t[-1] - t[0] >= cfg.last_window - 1e-9:
        k = window_keys(cfg.last_window)
        out[k["rmse"]] = rmse(e[last, :3])
        out[k["max_abs_position"]] = np.abs(e[last, :3]).max(axis=0).tolist()
        out[k["max_abs_velocity"]] = np.abs(e[last, 3:]).max(axis=0).tolist()
        out[k["pcrb_rmse"]] = float(np.sqrt(np.mean(np.trace(Bp[last], axis1=1, axis2=2))))
    else:
        out["last_window_omitted_reason"] = (f"the run covers {t[-1] - t[0]:g} s, shorter than last_window = "
                                             f"{cfg.last_window:g} s: no window scores")
    series = {"t": t, "err": e, "sigma": np.sqrt(np.diagonal(Ppv, axis1=1, axis2=2)), "att_deg": att}
    return out, series


def plot(series: dict, plots_dir, name: str) -> None:
    """Figures like the paper's figs. 4-15: position and velocity error per axis, +/-3 sigma."""
    # lazy: matplotlib, only when plots are written
    from testbed.plots import error_envelope

    t, e, s = series["t"], series["err"], series["sigma"]
    lab = ("x (fwd)", "y (left)", "z (up)")
    error_envelope(t, e[:, :3], s[:, :3], plots_dir / "position_error.png", title=f"{name}: body position error (nav frame)", ylabel="m", labels=lab)
    error_envelope(t, e[:, 3:], s[:, 3:], plots_dir / "velocity_error.png", title=f"{name}: body velocity error (nav frame)", ylabel="m/s", labels=lab)


def prepare(scenario, log: dict) -> tuple:
    """What the filter starts from on a run log: (cfg, inputs, q, prior Gaussian, P0 (18, 18),
    measurements); the prior is also the one the phase.ekf plugin gets (testbed.plugins.context)."""
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


def true_states(scenario, log: dict, cfg: PhasePipelineConfig, inp: PhaseInputs):
    """truth_in_nav at the phase epochs (scoring only): body (K, 12), R_N_follower, 18-states."""
    return truth_in_nav(log, inp.state_index, cfg.nav_master, inp.follower, scenario.world.antenna_a, scenario.world.antenna_b)


def position_bound(scenario, log: dict) -> tuple[np.ndarray, np.ndarray, int]:
    """The PCRB of the follower's body position for plugin scores (scoring only): epoch times
    (K,) s, bound (K, 3, 3) m^2 in world axes (N rotated by the nav master's true attitude), the
    follower's number."""
    cfg, inp, q, _, P0, meas = prepare(scenario, log)
    bound = BODY_POS @ phase_pcrb(cfg, q, true_states(scenario, log, cfg, inp)[2], inp, meas, P0) @ BODY_POS.T
    R = Rotation.from_quat(log["truth/quat"][inp.state_index, cfg.nav_master - 1], scalar_first=True).as_matrix()
    return inp.times, R @ bound @ np.swapaxes(R, 1, 2), inp.follower


def estimate(scenario, log: dict) -> tuple[dict, dict]:
    """Run the seed 003 EKF on a run log and score it: (estimators.ekf metrics, plot series)."""
    cfg, inp, q, prior, P0, meas = prepare(scenario, log)
    track = run_filter(cfg, q, prior, meas, inp.times)
    body, RN, states = true_states(scenario, log, cfg, inp)
    bound = phase_pcrb(cfg, q, states, inp, meas, P0)
    metrics, series = score(cfg, track, states, body, RN, bound)
    metrics = {"q_m2ps3": q.antenna, "q_translation_m2ps3": q.translation, "q_rotation_rad2ps3": q.rotation, "rate_rows": cfg.rate_rows, "init": cfg.init, **metrics}
    return metrics, series


def run(scenario, log, plots_dir):
    metrics, series = estimate(scenario, log)
    if plots_dir is not None:
        plot(series, plots_dir, scenario.name)
    return {"ekf": metrics}
