"""The seed 004 relative-navigation filters (kind "visnav") as protocol estimators: `visnav.ekf`,
`visnav.ckf`, `visnav.hckf`, `visnav.mckf`, `visnav.rhcf`, a visnav scenario's default estimators
ekf, ckf, hckf, mckf, rhcf (those its [pipeline] filters names: testbed.plugins.defaults), scored
with the relative-frame hook (testbed.plugins.relnav_scores).

Inputs: the `imu` stream of the leader and the follower (body FLU = imu site frame), the `camera`
stream (leader camera -> follower LEDs, unit LOS in the MuJoCo camera frame, or the focal-plane
alpha/beta with `measurement = "focal"`), and the known quantities of the [pipeline] table:
camera mounting on the leader, LED positions on the follower (each with a configurable survey
error drawn once from the scenario stream "known", `estimator_config`), the IMU noise figures,
the LOS noise.

Discretisation: the leader's and the follower's IMU readings are paired by
time; the predict step j uses the trapezoidal mean of the n + 1 readings spanning [t_j, t_j + dt]
(dt = 1 / predict_rate_hz, n = imu rate_hz * dt), so it can run once the reading at t_j + dt is
in. That input, the mean rate and specific force over the step, drives one step of the model
(estimators.visnav: exact for constant rates, second order in dt). Measured on the visnav
trajectory with error-free readings, 60 s of dead reckoning end 0.3 mm (prescribed) / 17 mm
(flown) from the truth; a box-car mean of the n readings in [t_j, t_j + dt) (centred h / 2 early)
ended 33 / 50 mm off. Noise: the trapezoidal mean of white readings has variance 0.95 N^2/dt and
consecutive steps share one end reading (correlation 2.6 %); the model's Q assumes N^2/dt,
white: 5 % conservative. A camera epoch (the LED rows of one time) is complete when a camera row
of a later time arrives (or at finish) and is filtered once the IMU has reached its time: the
predicts since the previous camera epoch, then the update with every LED seen, through the
library's online driver (estimators.core.Stepper). Camera epochs after the last complete predict
step are dropped. SPD repairs warn (SpdRepairWarning, not silenced) and are counted in health().

Start: Context.prior["uavF"] (testbed.plugins.relnav_scores.start_prior: the true relative state
plus a draw from the initial covariance, stream "init", given by the runtime). Settings: the
visnav [pipeline] keys (params; the scenario's by default); `filters` is ignored (the class is
the filter).

Estimates at every camera epoch: the follower relative to the leader, in the leader's body frame
(Estimate.frame "uavL"): position, velocity and attitude, each with its covariance block, as one
EstimateBatch whose cov_joint is the filter's (9, 9) covariance of the three (p m, v m/s, theta
rad), cross-covariances included (the relnav hook's 9-dof ANEES).
"""
from __future__ import annotations

import math

import numpy as np

from estimators.core import Epoch, Stepper
from estimators.sigma_filters import ManifoldGaussian, make_filter
from estimators.so3 import quat_exp, quat_to_rotmat
from estimators.visnav import CameraFilter, CameraFrame, ImuNoise, RelNavModel, VisNavConfig
from testbed.config.pipelines import VisNavPipelineConfig
from testbed.plugins.api import Context, EstimateBatch, Measurement
from testbed.plugins.settings import settings
from testbed.rng import stream_rng

_DEG = math.pi / 180.0


def xyaxes_to_rotation(xyaxes) -> np.ndarray:
    """R_L_from_C (3, 3) of MJCF `xyaxes` (camera x and y axes in the body frame; z = x cross y;
    y is orthogonalised against x, as MuJoCo does)."""
    x = np.asarray(xyaxes[:3], float)
    x = x / np.linalg.norm(x)
    y = np.asarray(xyaxes[3:], float)
    y = y - (y @ x) * x
    y = y / np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


def estimator_config(cfg: VisNavPipelineConfig, seed: int, focal_length: float) -> VisNavConfig:
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


class _VisNav:
    """Base: IMU pre-integration and camera-epoch bookkeeping; subclasses name the filter."""

    filter = ""

    Params = VisNavPipelineConfig  # its parameters (testbed.plugins.settings)

    def __init__(self, context: Context, params: dict):
        cfg = settings(VisNavPipelineConfig, context, params, f"visnav.{self.filter}")
        cam, imu = context.sensors.get("camera"), context.sensors.get("imu")
        if cam is None or imu is None:
            raise ValueError(f"visnav.{self.filter} needs the imu and camera streams ([sensors.imu], [sensors.camera])")
        self.leader, self.follower = f"uav{cam['leader']}", f"uav{cam['follower']}"
        if self.follower not in context.prior:
            raise ValueError(f"visnav.{self.filter} needs the prior of {self.follower} (a scenario whose [pipeline] kind is visnav)")
        n = imu["rate_hz"] / cfg.predict_rate_hz
        if abs(n - round(n)) > 1e-9 or round(n) < 1:
            raise ValueError(f"predict_rate_hz {cfg.predict_rate_hz} Hz must divide the IMU rate {imu['rate_hz']:g} Hz")
        self.n = int(round(n))
        self.dt = self.n / imu["rate_hz"]
        # trapezoidal weights of the n + 1 readings of one step (module docstring)
        self.w = np.full(self.n + 1, 1.0 / self.n)
        self.w[[0, -1]] = 0.5 / self.n
        model = RelNavModel(estimator_config(cfg, context.seed, cam["focal_length"]))
        filt = CameraFilter(make_filter(self.filter, model, kernel_sigma=cfg.kernel_sigma, tol=cfg.mc_tol,
                                        max_iter=cfg.mc_max_iter), cfg.measurement)
        self.stepper = Stepper(filt, ManifoldGaussian(*context.prior[self.follower]))
        self.t0: float | None = None
        self.imu: dict[str, tuple[float, np.ndarray]] = {}  # the latest reading of each vehicle
        self.u: list[np.ndarray] = []  # (12,) [w_L, f_L, w_F, f_F] per paired reading
        self.step = 0  # predict steps done
        self.camera: list[Measurement] = []  # rows of the camera epoch being collected
        self.ready: list[tuple[float, CameraFrame]] = []  # complete camera epochs: (t, frame)
        self.started = False

    def _pair(self, m: Measurement) -> None:
        body = m.src.partition("/")[0]
        if body not in (self.leader, self.follower):
            return
        self.imu[body] = (m.time, m.value)
        (tl, fl), (tf, ff) = self.imu.get(self.leader, (None, None)), self.imu.get(self.follower, (None, None))
        if tl is not None and tl == tf:
            self.t0 = tl if self.t0 is None else self.t0
            # imu value is [f, w]
            self.u.append(np.concatenate([fl[3:6], fl[0:3], ff[3:6], ff[0:3]]))
            self.imu.clear()

    def _close_camera(self) -> None:
        rows, self.camera = self.camera, []
        leds = np.array([int(m.dst.rpartition("/led")[2]) - 1 for m in rows])
        frame = CameraFrame(leds, np.stack([m.value[2:5] for m in rows]), np.stack([m.value[0:2] for m in rows]))
        self.ready.append((rows[0].time, frame))

    def _filter(self, final: bool = False) -> list[EstimateBatch]:
        """Filter every complete camera epoch whose predict steps have their readings."""
        out = []
        while self.ready and self.t0 is not None:
            t, frame = self.ready[0]
            s = int(np.rint((t - self.t0) / self.dt))
            if abs(s * self.dt + self.t0 - t) > 1e-9:
                raise ValueError(f"camera epoch at t = {t:g} s is not on the {1 / self.dt:g} Hz predict grid")
            if not self.started and s != 0:
                raise ValueError(f"the first camera epoch (t = {t:g} s) is not at the first IMU sample (t = {self.t0:g} s)")
            if len(self.u) < self.n * s + 1:  # the readings up to t are not all in yet
                if final:
                    self.ready.clear()  # after the last complete predict step: dropped, as in the pipeline
                break
            self.ready.pop(0)
            self.started = True
            controls = [(self.dt, self.w @ np.stack(self.u[self.n * j:self.n * j + self.n + 1])) for j in range(self.step, s)]
            self.step = max(self.step, s)
            b = self.stepper.step(Epoch(t, frame, controls))
            P = b.cov[:9, :9]  # the navigation error (p, v, theta) block: cov_joint
            out.append(EstimateBatch(time=np.full(3, t), target=(self.follower,) * 3, frame=self.leader,
                                     quantity=("position", "velocity", "attitude"),
                                     value=[b.mean[0:3], b.mean[3:6], b.mean[6:10]],
                                     cov=np.stack([P[c:c + 3, c:c + 3] for c in (0, 3, 6)]), cov_joint=P))
        return out

    def process(self, m: Measurement) -> list[EstimateBatch]:
        if m.stream == "imu":
            self._pair(m)
        elif m.stream == "camera":
            if self.camera and m.time > self.camera[0].time:
                self._close_camera()
            self.camera.append(m)
        return self._filter()

    def finish(self) -> list[EstimateBatch]:
        if self.camera:
            self._close_camera()
        return self._filter(final=True)

    def health(self) -> dict[str, int]:
        return self.stepper.track().health()


class Ekf(_VisNav):
    """seed 004: EKF of the leader-follower relative state (IMUs + LED camera), relative to the leader."""

    filter = "ekf"


class Ckf(_VisNav):
    """seed 004: cubature Kalman filter (third-degree rule) of the relative state, relative to the leader."""

    filter = "ckf"


class Hckf(_VisNav):
    """seed 004: high-degree cubature Kalman filter (fifth-degree rule), relative to the leader."""

    filter = "hckf"


class Mckf(_VisNav):
    """seed 004: maximum-correntropy Kalman filter on the EKF linearization, relative to the leader."""

    filter = "mckf"


class Rhcf(_VisNav):
    """seed 004: the paper's robust high-degree cubature filter (correntropy update), relative to the leader."""

    filter = "rhcf"
