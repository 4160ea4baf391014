"""Seed 004 estimator pipeline (kind "visnav"): run log -> estimates, metrics, plots.

Inputs the filters see (and nothing else):
- the `imu` stream of the leader and the follower (200 Hz, body FLU = imu site frame),
- the `camera` stream (leader camera -> follower LEDs, unit LOS in the MuJoCo camera frame, or
  the focal-plane alpha/beta with `measurement = "focal"`),
- the "known" quantities of the [pipeline] table: camera mounting on the leader, LED positions on
  the follower (each with a configurable survey error drawn once from stream "known"), the IMU
  noise figures, the LOS noise, the initial uncertainty.
Truth (truth/*, imu/bias) is read only by `score_track`, after the filters ran.

Discretisation (the filters' time step). The IMU samples at 200 Hz; the filters predict at
`predict_rate_hz` (default 20 Hz, dt = 0.05 s): the n + 1 = 11 readings of both IMUs at
t_j, t_j + h, ..., t_j + dt (h = 5 ms) are averaged with trapezoidal weights (1/2, 1, ..., 1, 1/2)/n,
the mean rate and specific force over the step (pre-integrated increment / dt), and that input
drives one step of the model (estimators.visnav: exact for constant rates, second order in dt).
Measured on the visnav trajectory with error-free readings, 60 s of dead reckoning end 0.3 mm
(prescribed) / 17 mm (flown) from the truth; a box-car mean of the 10 readings in [t_j, t_j + dt)
(centred 2.5 ms early) ended 33 / 50 mm off. Noise: the trapezoidal mean of white readings has
variance 0.95 N^2/dt and consecutive steps share one end reading (correlation 2.6 %); the model's
Q assumes N^2/dt, white: 5 % conservative. Camera epochs (10 Hz) fall on the predict grid; at each
epoch the filter updates with all LEDs seen, then predicts on.

Initial estimate: the relative navigation state at t = 0 is truth + a draw from the initial
covariance (stream "init", the same draw for every filter); the biases start at their nominal 0
with the configured prior std. Scores (per filter, at every camera epoch after the update):
RMSE of the relative position (m), velocity (m/s) and attitude (deg, on SO(3) by
testbed.scoring.metrics), ANEES of the 9-dim navigation error (p, v, theta; truth = est (+) e;
`anees_dof` 9) with its 99 % interval over its effective samples (`anees_interval_99`, `n_eff`:
docs/consistency.md), and the wall time per camera epoch (one update and its predicts). The wall
time is the only part of metrics.json that is not bit-identical between two runs of the same seed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimators.core import Epoch, Track, drive, nees
from estimators.sigma_filters import ManifoldGaussian, make_filter
from estimators.so3 import quat_conj, quat_exp, quat_mul, quat_to_rotmat
from estimators.visnav import (
    CameraFilter,
    CameraFrame,
    ImuNoise,
    RelNavModel,
    VisNavConfig,
)
from testbed.errors import ConfigError
from testbed.pipeline_config import VisNavPipelineConfig
from testbed.rng import stream_rng

_DEG = math.pi / 180.0


# --------------------------------------------------------------------------------------------
# Known quantities -> estimator configuration
# --------------------------------------------------------------------------------------------
def xyaxes_to_rotation(xyaxes) -> np.ndarray:
    """R_L_from_C (3, 3) of MJCF `xyaxes` (camera x and y axes in the body frame; z = x cross y;
    y is orthogonalised against x, as MuJoCo does)."""
    x = np.asarray(xyaxes[:3], float)
    x = x / np.linalg.norm(x)
    y = np.asarray(xyaxes[3:], float)
    y = y - (y @ x) * x
    y = y / np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


def estimator_config(cfg: VisNavPipelineConfig, seed: int, focal_length: float):
    """The VisNavConfig the filters get: configured camera/LED values plus their survey errors
    (stream "known"), configured IMU and vision noise figures."""

    rng = stream_rng(seed, "known")
    led = np.array(cfg.led_pos, float)
    d_cam = rng.standard_normal(3) * cfg.cam_pos_sigma
    d_att = rng.standard_normal(3) * cfg.cam_att_sigma_deg * _DEG
    d_led = rng.standard_normal(led.shape) * cfg.led_pos_sigma
    imu = ImuNoise(gyro_noise=cfg.gyro_noise, accel_noise=cfg.accel_noise, gyro_bias_rw=cfg.gyro_bias_rw,
                   accel_bias_rw=cfg.accel_bias_rw, gyro_bias_sigma=cfg.gyro_bias_sigma,
                   accel_bias_sigma=cfg.accel_bias_sigma)
    cam_rot = xyaxes_to_rotation(cfg.cam_xyaxes) @ quat_to_rotmat(quat_exp(d_att))
    return VisNavConfig(cam_pos=np.array(cfg.cam_pos) + d_cam, cam_rot=cam_rot, led_pos=led + d_led,
                        los_sigma=cfg.los_sigma, focal_length=focal_length,
                        focal_sigma=cfg.los_sigma * focal_length, focal_d=cfg.focal_d,
                        imu_leader=imu, imu_follower=imu)


# --------------------------------------------------------------------------------------------
# Streams -> filter inputs
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class Inputs:
    """What the filters consume.

    dt: predict step (s); u: (J, 12) step-averaged [w_L, f_L, w_F, f_F] per step (rad/s,
    m/s^2, body frames); t: (J + 1,) step boundaries (s); cam_step: (E,) step index of each camera
    epoch (update before predicting step cam_step); cam_time: (E,) s; cam_state: (E,) index into
    the log's time; cam_leds: list of (K_e,) 0-based LED indices; cam_b: list of (K_e, 3) unit LOS
    (camera frame); cam_ab: list of (K_e, 2) focal-plane coordinates (m).
    """

    dt: float
    u: np.ndarray
    t: np.ndarray
    cam_step: np.ndarray
    cam_time: np.ndarray
    cam_state: np.ndarray
    cam_leds: list
    cam_b: list
    cam_ab: list


def build_inputs(cfg: VisNavPipelineConfig, log: dict, leader: int, follower: int, imu_rate: float) -> Inputs:
    """Pre-integrate both IMUs to the predict rate and group the camera rows by epoch."""
    n_sub = imu_rate / cfg.predict_rate_hz
    if abs(n_sub - round(n_sub)) > 1e-9 or round(n_sub) < 1:
        raise ConfigError(f"pipeline.predict_rate_hz: {cfg.predict_rate_hz} Hz must divide the IMU rate {imu_rate:g} Hz")
    n_sub = int(round(n_sub))
    dt = n_sub / imu_rate
    veh, val, tim = log["imu/vehicle"], log["imu/value"], log["imu/time"]
    mL, mF = veh == leader, veh == follower
    if not mL.any() or not mF.any():
        raise ConfigError(f"sensors.imu.vehicles: the visnav pipeline needs IMUs on vehicles {leader} and {follower}")
    if not np.array_equal(tim[mL], tim[mF]):
        raise ValueError("visnav: leader and follower IMU samples are not simultaneous")
    # per reading: [w_L, f_L, w_F, f_F] (imu/value is [f, w])
    u_fast = np.concatenate([val[mL][:, 3:6], val[mL][:, 0:3], val[mF][:, 3:6], val[mF][:, 0:3]], axis=1)
    J = (u_fast.shape[0] - 1) // n_sub
    # trapezoidal mean of the n_sub + 1 readings spanning [t_j, t_j + dt] (see module docstring)
    w = np.full(n_sub + 1, 1.0 / n_sub)
    w[[0, -1]] = 0.5 / n_sub
    idx = n_sub * np.arange(J)[:, None] + np.arange(n_sub + 1)[None, :]
    u = np.einsum("k,jkc->jc", w, u_fast[idx])
    t0 = float(tim[mL][0])
    t = t0 + dt * np.arange(J + 1)

    ct, led = log["camera/time"], log["camera/led"]
    epochs, first = np.unique(ct, return_index=True)
    if led.size and int(led.max()) > len(cfg.led_pos):
        raise ConfigError(f"pipeline.led_pos: the camera reports LED {int(led.max())} but only {len(cfg.led_pos)} LED positions are configured")
    steps = np.rint((epochs - t0) / dt).astype(int)
    if np.any(np.abs(steps * dt + t0 - epochs) > 1e-9):
        raise ConfigError(f"pipeline.predict_rate_hz: camera epochs must fall on the {cfg.predict_rate_hz} Hz predict grid")
    keep = steps <= J
    leds, bs, abs_ = [], [], []
    bounds = np.append(first, ct.size)
    for i in np.flatnonzero(keep):
        rows = slice(bounds[i], bounds[i + 1])
        leds.append(led[rows].astype(int) - 1)
        bs.append(log["camera/value"][rows, 2:5])
        abs_.append(log["camera/value"][rows, 0:2])
    return Inputs(dt, u, t, steps[keep], epochs[keep], log["camera/state_index"][first][keep], leds, bs, abs_)


# --------------------------------------------------------------------------------------------
# Filters
# --------------------------------------------------------------------------------------------
def initial_belief(cfg: VisNavPipelineConfig, model, truth0: np.ndarray, seed: int):
    """Prior at t0: the true relative navigation state (+) a draw from P0 (stream "init"), biases 0.

    truth0: (22,) true state (only its p, v, q are used)."""
    P0 = model.initial_cov(cfg.init_sigma_pos, cfg.init_sigma_vel, cfg.init_sigma_att_deg * _DEG)
    d = np.zeros(P0.shape[0])
    d[:9] = stream_rng(seed, "init").standard_normal(9) * np.sqrt(np.diag(P0)[:9])
    x0 = truth0.copy()
    x0[10:] = 0.0
    return ManifoldGaussian(model.boxplus(x0[None], d[None])[0], P0)


def camera_epochs(inputs: Inputs) -> list[Epoch]:
    """The driver's epochs: one per camera epoch, with the predict steps (dt, IMU input) since the
    previous one and the camera frame (None if no LED was seen: predict only)."""
    epochs, j = [], 0
    for e in range(inputs.cam_step.size):
        controls = [(inputs.dt, inputs.u[i]) for i in range(j, int(inputs.cam_step[e]))]
        j = max(j, int(inputs.cam_step[e]))
        leds = inputs.cam_leds[e]
        frame = CameraFrame(leds, inputs.cam_b[e], inputs.cam_ab[e]) if leds.size else None
        epochs.append(Epoch(float(inputs.cam_time[e]), frame, controls))
    return epochs


def run_filter(name: str, cfg: VisNavPipelineConfig, model, epochs: list[Epoch], prior) -> Track:
    """Run one filter of the family over the camera epochs through the library's driver
    (core.drive); returns its core.Track (beliefs at every camera epoch after the update, health
    counts, wall time of the predicts and updates per epoch)."""
    filt = CameraFilter(make_filter(name, model, kernel_sigma=cfg.kernel_sigma, tol=cfg.mc_tol,
                                    max_iter=cfg.mc_max_iter), cfg.measurement)
    # repairs warn (SpdRepairWarning, not silenced) and are counted: metrics_of's covariance_repairs
    return drive(filt, prior, epochs)


def true_relative_state(log: dict, leader: int, follower: int, idx: np.ndarray) -> np.ndarray:
    """True relative state (len(idx), 22) at log rows idx: p, v in the leader frame, q = q_L^* q_F,
    biases from imu/bias at the nearest IMU sample (scoring only)."""
    L, F = leader - 1, follower - 1
    qL, qF = log["truth/quat"][idx, L], log["truth/quat"][idx, F]
    RL = quat_to_rotmat(qL)
    dp = log["truth/pos"][idx, F] - log["truth/pos"][idx, L]
    dv = log["truth/vel"][idx, F] - log["truth/vel"][idx, L]
    X = np.zeros((idx.size, 22))
    X[:, 0:3] = np.einsum("nji,nj->ni", RL, dp)
    X[:, 3:6] = np.einsum("nji,nj->ni", RL, dv)
    q = quat_mul(quat_conj(qL), qF)
    X[:, 6:10] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return X


@dataclass(frozen=True, slots=True, eq=False)
class Scored:
    """Errors of a Track against truth: err (E, 9) = estimate minus truth (p m, v m/s, theta rad,
    theta = Log(R_true^T R_est) in the follower frame), sigma (E, 9) filter stds, nees (E,) of
    the 9 navigation states, att_deg (E,) attitude error angle (deg)."""

    err: np.ndarray
    sigma: np.ndarray
    nees: np.ndarray
    att_deg: np.ndarray


def score_track(model, track: Track, truth: np.ndarray) -> Scored:
    """Score a Track against the true states truth (E, 22) (see Scored)."""
    # lazy: testbed.scoring.metrics imports scipy.stats (seconds on a cold cache); only scoring needs it
    from testbed.scoring.metrics import attitude_error_deg

    est = track.mean
    e_true = model.boxminus(truth, est)[:, :9]          # truth = est (+) e
    err = model.boxminus(est, truth)[:, :9]             # estimate minus truth
    P = track.cov[:, :9, :9]
    sig = np.sqrt(np.einsum("nii->ni", P))
    return Scored(err, sig, nees(e_true, P), attitude_error_deg(est[:, 6:10], truth[:, 6:10]))


def metrics_of(track: Track, sc: Scored) -> dict:
    """The metrics.json entry of one filter."""
    # lazy: see score_track
    from testbed.scoring.metrics import anees_keys, rmse

    E = track.t.size
    predict_s, update_s = float(track.predict_s.sum()), float(track.update_s.sum())
    finite = bool(np.all(np.isfinite(sc.err)) and np.all(np.isfinite(sc.nees)))
    return {
        "rmse_position_m": rmse(sc.err[:, 0:3]),
        "rmse_velocity_mps": rmse(sc.err[:, 3:6]),
        "rmse_attitude_deg": float(np.sqrt(np.mean(sc.att_deg ** 2))),
        **anees_keys(sc.nees, 9),
        "time_per_step_ms": 1e3 * (predict_s + update_s) / max(E, 1),
        "predict_per_epoch_ms": 1e3 * predict_s / max(E, 1),
        "update_ms": 1e3 * update_s / max(E, 1),
        "final_position_error_m": float(np.linalg.norm(sc.err[-1, 0:3])),
        "final_nees": float(sc.nees[-1]),
        "epochs": int(E),
        "finite": finite,
        **track.health(),
    }


def prepare(scenario, log: dict) -> tuple:
    """What the filters start from on a run log: (model, inputs, prior ManifoldGaussian at the
    first IMU sample); the prior is also the one the visnav.* plugins get (testbed.plugins.context)."""
    cfg: VisNavPipelineConfig = scenario.pipeline
    cam, imu = scenario.sensors.camera, scenario.sensors.imu
    if cam is None or imu is None:
        raise ConfigError(f"sensors: the visnav pipeline needs [sensors.imu] and [sensors.camera] (scenario {scenario.name})")
    model = RelNavModel(estimator_config(cfg, scenario.seed, cam.focal_length))
    inputs = build_inputs(cfg, log, cam.leader, cam.follower, imu.rate_hz)
    truth0 = true_relative_state(log, cam.leader, cam.follower, np.array([int(np.argmin(np.abs(log["time"] - inputs.t[0])))]))[0]
    return model, inputs, initial_belief(cfg, model, truth0, scenario.seed)


def run_all(scenario, log: dict) -> tuple[dict[str, Track], dict[str, Scored], object]:
    """Run every configured filter on the log; returns tracks, their scores and the model."""
    cfg: VisNavPipelineConfig = scenario.pipeline
    cam = scenario.sensors.camera
    model, inputs, prior = prepare(scenario, log)
    truth = true_relative_state(log, cam.leader, cam.follower, inputs.cam_state)
    if inputs.cam_step.size == 0 or inputs.cam_step[0] != 0:  # a scenario the filters cannot start on: one line, exit 2
        raise ConfigError(f"{scenario.name}: sensors.camera: the leader's camera sees no LED of the follower at t = {inputs.t[0]:g} s; "
                          "the visnav filters start from a camera epoch at the first IMU sample")
    epochs = camera_epochs(inputs)
    tracks, scores = {}, {}
    for name in cfg.filters:
        tracks[name] = run_filter(name, cfg, model, epochs, prior)
        scores[name] = score_track(model, tracks[name], truth)
    return tracks, scores, model


def plot_track(name: str, track: Track, sc: Scored, plots_dir: Path, prefix: str = "") -> list[Path]:
    """Error curves with +/-3 sigma envelopes (position, velocity, attitude) of filter `name`."""
    # lazy: matplotlib, only when plots are written
    from testbed.outputs.plots import error_envelope

    n = name.upper()
    return [
        error_envelope(track.t, sc.err[:, 0:3], sc.sigma[:, 0:3], plots_dir / f"{prefix}{name}_position.png",
                       title=f"{n} relative position error (leader frame)", ylabel="m"),
        error_envelope(track.t, sc.err[:, 3:6], sc.sigma[:, 3:6], plots_dir / f"{prefix}{name}_velocity.png",
                       title=f"{n} relative velocity error (leader frame)", ylabel="m/s"),
        error_envelope(track.t, np.degrees(sc.err[:, 6:9]), np.degrees(sc.sigma[:, 6:9]),
                       plots_dir / f"{prefix}{name}_attitude.png",
                       title=f"{n} relative attitude error (follower frame)", ylabel="deg"),
    ]


def run(scenario, log, plots_dir):
    """The seed 004 pipeline: every configured filter on the log; one metrics entry per filter."""
    tracks, scores, _ = run_all(scenario, log)
    if plots_dir is not None:
        for name in tracks:
            plot_track(name, tracks[name], scores[name], Path(plots_dir))
    return {name: metrics_of(tracks[name], scores[name]) for name in tracks}
