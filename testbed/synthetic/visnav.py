"""A tiny synthetic truth + IMU + LOS generator of seed 004 (INS + vision), pure numpy.

Independent of the filter's model code paths where it matters: the truth comes from analytic
world-frame trajectories of two vehicles (world z-up, bodies FLU), the IMU readings from their
analytic derivatives (specific force f = R^T (a - g_W), g_W = (0, 0, -9.80665) m/s^2; body rates
from central differences of the attitude), the lines of sight from world geometry. Only the
quaternion/rotation helpers (estimators.so3) are shared with estimators.visnav.

IMU readings are mid-interval samples (t_k + dt/2): the filter holds a reading over [t_k, t_k+1].
Noise: white densities N sampled as N / sqrt(dt) per reading; biases constant, drawn from their
prior. LOS noise: isotropic in the tangent plane of the true b, std los_sigma; with glint, each
LED sample is drawn with probability `glint_rate` from the component with `glint_scale` x std.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.so3 import quat_log, rotmat_to_quat
from estimators.visnav import RelNavModel, VisNavConfig, make_state, tangent_basis
from estimators.visnav_paper import G0, PAPER_GLINT_RATE, PAPER_GLINT_SCALE

G_W = np.array([0.0, 0.0, -G0])

# camera on the leader looking backwards: boresight -z_C = -x_L, image x right = +y_L, y up = +z_L
CAM_ROT = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
CAM_POS = np.array([-0.3, 0.0, 0.1])
LEDS = np.array([[1.0, 0.0, 0.0], [-0.5, 1.0, 0.0], [-0.5, -1.0, 0.0],
                 [0.0, 0.0, 0.5], [0.3, 0.4, -0.3], [-0.8, 0.0, 0.2]])


def default_config() -> VisNavConfig:
    """Paper sensor values (VisNavConfig/ImuNoise defaults), the camera and LEDs above."""
    return VisNavConfig(cam_pos=CAM_POS, cam_rot=CAM_ROT, led_pos=LEDS)


def _euler_zyx(yaw, pitch, roll) -> np.ndarray:
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
    Ry = np.array([[cp, 0, sp], [0, 1.0, 0], [-sp, 0, cp]])
    Rx = np.array([[1.0, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return Rz @ Ry @ Rx


def _sines(t, amp, omega, phase):
    """sum of a_j sin(w_j t + f_j) per axis and its first two derivatives: three (3,) arrays."""
    s = np.sin(omega * t + phase)
    c = np.cos(omega * t + phase)
    return amp * s, amp * omega * c, -amp * omega ** 2 * s


def leader(t: float):
    """Leader world position (3,), velocity, acceleration (m, m/s, m/s^2) and R_W_from_L."""
    base = np.array([5.0 * t, 0.0, 50.0])
    p, v, a = _sines(t, np.array([0.0, 2.0, 1.0]), np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 0.4]))
    R = _euler_zyx(0.2 * np.sin(0.15 * t), 0.05 * np.sin(0.3 * t + 0.5), 0.1 * np.sin(0.25 * t))
    return base + p, np.array([5.0, 0.0, 0.0]) + v, a, R


def follower(t: float):
    """Follower world position, velocity, acceleration and R_W_from_F (about 8 m behind)."""
    base = np.array([5.0 * t - 8.0, 1.0, 49.5])
    p, v, a = _sines(t, np.array([0.5, 2.5, 1.3]), np.array([0.4, 0.2, 0.3]), np.array([0.0, 0.3, 0.6]))
    R = _euler_zyx(0.2 * np.sin(0.15 * t) + 0.05 * np.sin(0.5 * t), 0.04 * np.sin(0.4 * t),
                   0.08 * np.sin(0.3 * t + 1.0))
    return base + p, np.array([5.0, 0.0, 0.0]) + v, a, R


def body_rate(pose, t: float, h: float = 1e-4) -> np.ndarray:
    """Body angular rate (3,) rad/s: Log(R(t-h)^T R(t+h)) / (2h)."""
    Rm, Rp = pose(t - h)[3], pose(t + h)[3]
    return quat_log(rotmat_to_quat(Rm.T @ Rp)) / (2.0 * h)


def relative_truth(t: float) -> np.ndarray:
    """True relative state (22,) at t, biases zero (filled in by simulate)."""
    pL, vL, _, RL = leader(t)
    pF, vF, _, RF = follower(t)
    return make_state(RL.T @ (pF - pL), RL.T @ (vF - vL), rotmat_to_quat(RL.T @ RF))


def true_los(t: float, config: VisNavConfig) -> np.ndarray:
    """True unit LOS (K, 3) in the camera frame, from world geometry."""
    pL, _, _, RL = leader(t)
    pF, _, _, RF = follower(t)
    r_W = pF + config.led_pos @ RF.T - (pL + RL @ config.cam_pos)
    r_C = r_W @ RL @ config.cam_rot
    return r_C / np.linalg.norm(r_C, axis=1, keepdims=True)


@dataclass(frozen=True)
class Run:
    """One synthetic run: truth (K+1, 22) at t_k = k dt; inputs (K, 12); camera frames at IMU steps
    cam_steps (J,) (the update follows predict number cam_steps[j] - 1), b_meas (J, nLED, 3);
    the initial belief mean (22,) and covariance (21, 21)."""

    dt: float
    truth: np.ndarray
    inputs: np.ndarray
    cam_steps: np.ndarray
    b_meas: np.ndarray
    mean0: np.ndarray
    cov0: np.ndarray


def simulate(seed: int, *, duration: float = 20.0, dt: float = 0.02, cam_every: int = 5,
             glint: bool = False, config: VisNavConfig | None = None,
             sigma_p: float = 0.3, sigma_v: float = 0.05, sigma_att: float = 2.0 * np.pi / 180) -> Run:
    """Generate one seeded run (see the module docstring). Camera at 1 / (cam_every dt) Hz."""
    config = default_config() if config is None else config
    model = RelNavModel(config)
    rng = np.random.default_rng(seed)
    K = int(round(duration / dt))
    cL, cF = config.imu_leader, config.imu_follower
    bgF, baF = rng.normal(0, cF.gyro_bias_sigma, 3), rng.normal(0, cF.accel_bias_sigma, 3)
    bgL, baL = rng.normal(0, cL.gyro_bias_sigma, 3), rng.normal(0, cL.accel_bias_sigma, 3)
    truth = np.array([relative_truth(k * dt) for k in range(K + 1)])
    truth[:, 10:22] = np.concatenate([bgF, baF, bgL, baL])
    inputs = np.empty((K, 12))
    for k in range(K):
        tm = (k + 0.5) * dt
        _, _, aL, RL = leader(tm)
        _, _, aF, RF = follower(tm)
        wL, wF = body_rate(leader, tm), body_rate(follower, tm)
        fL, fF = RL.T @ (aL - G_W), RF.T @ (aF - G_W)
        inputs[k] = np.concatenate([
            wL + bgL + cL.gyro_noise / np.sqrt(dt) * rng.normal(size=3),
            fL + baL + cL.accel_noise / np.sqrt(dt) * rng.normal(size=3),
            wF + bgF + cF.gyro_noise / np.sqrt(dt) * rng.normal(size=3),
            fF + baF + cF.accel_noise / np.sqrt(dt) * rng.normal(size=3),
        ])
    cam_steps = np.arange(cam_every, K + 1, cam_every)
    nled = config.led_pos.shape[0]
    b_meas = np.empty((cam_steps.size, nled, 3))
    for j, k in enumerate(cam_steps):
        b = true_los(k * dt, config)
        scale = np.ones(nled)
        if glint:
            scale = np.where(rng.random(nled) < PAPER_GLINT_RATE, PAPER_GLINT_SCALE, 1.0)
        n = rng.normal(size=(nled, 2)) * (config.los_sigma * scale)[:, None]
        bt = b + np.einsum("kij,kj->ki", tangent_basis(b), n)
        b_meas[j] = bt / np.linalg.norm(bt, axis=1, keepdims=True)
    cov0 = model.initial_cov(sigma_p, sigma_v, sigma_att)
    e0 = rng.multivariate_normal(np.zeros(21), cov0)
    mean0 = model.boxplus(truth[0][None], -e0[None])[0]   # truth = mean0 (+) e0
    return Run(dt, truth, inputs, cam_steps, b_meas, mean0, cov0)


__all__ = ["Run", "simulate", "default_config", "relative_truth", "true_los", "leader", "follower",
           "body_rate"]
