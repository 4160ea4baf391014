"""Estimator-pipeline configuration of a scenario: the `[pipeline]` table, discriminated by `kind`.

Configuration only (dataclasses and their validation), so that the scenario schema loads without
the pipelines' compute modules, scipy or mujoco. Each table checks its own values in
`__post_init__` and, through `cross_check(scenario)`, what it needs from the rest of the
scenario (called by `Scenario.__post_init__`, so before anything is simulated; keys dotted from
the scenario root). The compute
side of each kind lives in the built-in plugins (testbed.plugins.builtin_*).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from collections.abc import Callable
from operator import itemgetter
from typing import Any, Literal

import numpy as np

from estimators.sensor_models import gnss_sigma
from estimators.visnav_paper import PAPER_ACCEL_BIAS, PAPER_ACCEL_NOISE, PAPER_GYRO_BIAS, PAPER_GYRO_NOISE, PAPER_VISION_SIGMA
from testbed.config import check_fields, key, require, whole_ratio
from testbed.sensors.config import SensorsConfig

Vec3 = tuple[float, float, float]


class _PipelineConfig:
    """What every [pipeline] table offers besides its fields.

    _assumed: {field: (sensor stream, its value from the stream's declared table)}: the
    sensor-model keys the estimators assume that default (None) to the scenario's declared model
    (`assumed`).
    """

    __slots__ = ()
    _assumed: dict[str, tuple[str, Callable[[dict], Any]]] = {}

    def assumed(self, sensors: dict):
        """This table with every assumed sensor-model key left unset (None) taken from the
        declared sensor tables `sensors` ({stream: table as a dict}, as Context.sensors gives them);
        one without its sensor stays None (the estimator cannot use that stream). Called by
        Scenario.__post_init__ and testbed.plugins.settings: the one place a default is derived."""
        fill = {k: value(sensors[s]) for k, (s, value) in self._assumed.items() if getattr(self, k) is None and s in sensors}
        return dataclasses.replace(self, **fill) if fill else self

    def derived(self) -> set[str]:
        """The keys `assumed` derives from the declared sensor model when not given."""
        return set(self._assumed)

    def cross_check(self, sc: Any) -> None:
        """Check what the pipeline needs from the rest of scenario `sc` (nothing here).

        sc: the testbed.config.scenario.Scenario being built (its sensors, world, trajectory and vehicle
        count; not imported: that module imports this one). Raises FieldError naming the key
        from the scenario root (`pipeline.silent_uav`)."""


def _needs(sensors: SensorsConfig, kind: str, *streams: str) -> None:
    for name in streams:
        require(getattr(sensors, name) is not None, f"sensors.{name}", None, f"pipeline {kind} needs the [sensors.{name}] stream")


@dataclass(frozen=True, kw_only=True, slots=True)
class TrackingPipelineConfig(_PipelineConfig):
    """No estimator: the run scores only how well the vehicles tracked their references."""

    kind: Literal["tracking"]


# ------------------------------------------------------------------------------ seed 003 phase
# seed 003 (docs/papers.md) initial error and covariance, paper frame (x fwd, y up, z right) mapped to ours
# (x fwd, y left, z up) as (x, -z, y).
PAPER_POS_ERROR = (-1.33500, 1.68219, -1.62100)  # m      (paper -1.33500, -1.62100, -1.68219)
PAPER_VEL_ERROR = (0.81860, -0.74150, 0.68610)  # m/s    (paper 0.81860, 0.68610, 0.74150)
PAPER_POS_VAR = (1.87306, 3.70352, 3.14771)  # m^2    (paper 1.87306, 3.14771, 3.70352)
PAPER_VEL_VAR = (0.69928, 0.50587, 0.46008)  # m^2/s^2 (paper 0.69928, 0.46008, 0.50587)


@dataclass(frozen=True, kw_only=True, slots=True)
class PhasePipelineConfig(_PipelineConfig):
    """[pipeline] table of a seed 003 scenario (its estimator: phase.ekf, testbed.plugins.builtin_phase).

    nav_master: the master whose body frame is the navigation frame (1-based).
    q, q_flown: white-acceleration density per antenna axis (m^2/s^3) in prescribed / flown mode.
      q is chosen by the stated rule of testbed.reproduce.phase_q (the grid q whose body ANEES
      over whole 200 s runs on calibration seeds 1000..1009 is closest to its dof); the default 1e-12 is
      the rule's q for phase-cross-h000, and every built-in scenario states its own, all printed by
      `python -m testbed.reproduce.phase_q`. q_flown (1e-6) was not calibrated.
    q_translation (m^2/s^3), q_rotation (rad^2/s^3): rigid-body white accelerations of the
      follower, common to its antennas (estimators.phase_ekf.ProcessNoise); 0 = the paper's Q.
      A scenario with a [disturbance] on the follower states its densities here (model-matched).
      The built-in phase scenarios' q_rotation is the rule's stage 2 (testbed.reproduce.phase_q:
      with q fixed, the grid value whose attitude ANEES over the same 200 s calibration runs is
      closest to 6; where the attitude is unobserved, at q = 1e-12 the value whose body ANEES is
      closest to its dof); it applies in both motion modes.
    rigid: the prediction adds the centripetal acceleration of the follower's turning rigid body to
      eq. 24's constant velocity per antenna, its uncertainty as an input noise
      (estimators.phase_ekf.rigid_transition, time_update; false: the paper's eq. 24 alone).
    range_sigma: filter range noise, 1 sigma (m; default: the declared [sensors.phase] phase_noise,
      in range terms); rate rows, if on, get sqrt(2) range_sigma / W.
    rate_rows: "off" (default: ranges only; the eq. 7 rates are differences of range rows already
      used, docs/models.md) | "window" | "instantaneous" (testbed.plugins.builtin_phase).
    init: "drawn" = initial 18-state error drawn from the initial covariance per run (stream
      "init"); "paper" = the paper's fixed body error on every antenna.
    init_pos_error, init_vel_error: the paper's fixed error (m, m/s, frame N);
    init_pos_var, init_vel_var: diagonal initial covariance per antenna (m^2, m^2/s^2).
    antenna_a, antenna_b: follower nose / wing-tip lever arms known to the estimator (m), used
      only to spread the body prior to the antennas; antenna_error: their error (m).
    gate, gate_alpha: w-test innovation gate on/off and its family-wise false-alarm rate.
    iterations: 1 = the paper's EKF, > 1 iterated EKF.
    score_start: scores skip t < score_start (s, initial convergence); last_window: the
      "last 100 s" window (s).
    """

    kind: Literal["phase-ekf"]
    nav_master: int = key(3, lo=1, doc="the master whose body frame is the navigation frame (1-based)")
    q: float = key(1e-12, lo=0, lo_open=True, unit="m^2/s^3", doc="white-acceleration density per antenna axis, prescribed motion")
    q_flown: float = key(1e-6, lo=0, lo_open=True, unit="m^2/s^3", doc="white-acceleration density per antenna axis, flown motion")
    q_translation: float = key(0.0, lo=0, unit="m^2/s^3", doc="rigid-body white acceleration of the follower (0: the paper's Q)")
    q_rotation: float = key(0.0, lo=0, unit="rad^2/s^3", doc="rigid-body white angular acceleration of the follower")
    rigid: bool = key(True, doc="prediction with the centripetal acceleration of the turning follower (false: the paper's eq. 24)")
    range_sigma: float | None = key(None, lo=0, lo_open=True, unit="m", doc="assumed range noise, 1 sigma (none: the declared [sensors.phase] phase_noise)")
    rate_rows: Literal["window", "instantaneous", "off"] = key("off", doc="eq. 7 range-rate rows: off, window or instantaneous")
    init: Literal["drawn", "paper"] = key("drawn", doc="initial error drawn per run, or the paper's fixed error")
    init_pos_error: Vec3 = key(PAPER_POS_ERROR, unit="m", doc="the paper's fixed initial position error, frame N")
    init_vel_error: Vec3 = key(PAPER_VEL_ERROR, unit="m/s", doc="the paper's fixed initial velocity error, frame N")
    init_pos_var: Vec3 = key(PAPER_POS_VAR, lo=0, lo_open=True, unit="m^2", doc="diagonal initial position covariance per antenna")
    init_vel_var: Vec3 = key(PAPER_VEL_VAR, lo=0, lo_open=True, unit="m^2/s^2", doc="diagonal initial velocity covariance per antenna")
    antenna_a: float = key(1.0, lo=0, lo_open=True, unit="m", doc="follower nose lever arm known to the estimator")
    antenna_b: float = key(1.0, lo=0, lo_open=True, unit="m", doc="follower wing-tip lever arm known to the estimator")
    antenna_error: float = key(0.0, unit="m", doc="error of the known lever arms")
    gate: bool = key(True, doc="w-test innovation gate on/off")
    gate_alpha: float = key(1e-3, lo=0, hi=1, lo_open=True, hi_open=True, doc="family-wise false-alarm rate of the gate")
    iterations: int = key(1, lo=1, doc="1: the paper's EKF; > 1: iterated EKF")
    score_start: float = key(10.0, lo=0, unit="s", doc="scores skip t < score_start (initial convergence)")
    last_window: float = key(100.0, lo=0, lo_open=True, unit="s", doc="the \"last 100 s\" window of the scores")

    def __post_init__(self) -> None:
        check_fields(self)

    _assumed = {"range_sigma": ("phase", itemgetter("phase_noise"))}

    def cross_check(self, sc: Any) -> None:
        """phase-ekf needs the carrier-phase stream, and its navigation frame is a master's."""
        _needs(sc.sensors, "phase-ekf", "phase")
        masters = sc.sensors.phase.masters
        require(self.nav_master in masters, "pipeline.nav_master", self.nav_master,
                f"{self.nav_master} is not one of the phase masters {list(masters)} (sensors.phase.masters)")


# ------------------------------------------------------------------------------ seed 004 visnav
FILTER_NAMES = ("ekf", "ckf", "hckf", "mckf", "rhcf")
N_LEDS = 4  # LED beacons led1..led4 of models/quadrotor.xml


@dataclass(frozen=True, kw_only=True, slots=True)
class VisNavPipelineConfig(_PipelineConfig):
    """[pipeline] table of a seed 004 scenario. Units SI unless the key says otherwise.

    filters: which of ekf, ckf, hckf, mckf, rhcf to run. measurement: "los" (unit LOS on the
    tangent plane, eqs. 9-13) or "focal" (alpha, beta with the eq. 8 covariance).
    predict_rate_hz: filter prediction rate (IMU readings trapezoid-averaged over each step).
    cam_pos (m, leader body FLU) and cam_xyaxes (MJCF convention: camera x and y axes in the
    leader body frame): the camera mounting known to the filter; cam_pos_sigma (m per axis) and
    cam_att_sigma_deg (per axis): its survey error, drawn once per run from stream "known".
    led_pos (K, 3) m in the follower body frame; led_pos_sigma (m per coordinate): survey error.
    los_sigma (rad): nominal LOS noise; focal_d: eq. 8 constant d.
    IMU figures known to the filter, the same for both vehicles: gyro_noise (rad/s/sqrt(Hz)),
    accel_noise (m/s^2/sqrt(Hz)), gyro_bias_sigma (rad/s), accel_bias_sigma (m/s^2) prior stds,
    gyro_bias_rw (rad/s^2/sqrt(Hz)), accel_bias_rw (m/s^3/sqrt(Hz)).
    init_sigma_pos (m), init_sigma_vel (m/s), init_sigma_att_deg: initial relative-state std per
    axis. kernel_sigma (whitened units), mc_tol, mc_max_iter: correntropy update of mckf/rhcf.
    """

    kind: Literal["visnav"]
    filters: tuple[str, ...] = key(FILTER_NAMES, range=f"non-empty subset of {', '.join(FILTER_NAMES)}", doc="the filters to run")
    measurement: Literal["los", "focal"] = key("los", doc="unit LOS on the tangent plane (eqs. 9-13) or focal alpha, beta (eq. 8)")
    predict_rate_hz: float = key(20.0, lo=0, lo_open=True, unit="Hz", doc="filter prediction rate")
    cam_pos: Vec3 = key((-0.645, 0.0, 0.0), unit="m", doc="camera position known to the filter, leader body FLU")
    cam_xyaxes: tuple[float, float, float, float, float, float] = key(
        (0.0, 1.0, 0.0, 0.0, 0.0, 1.0), range="x, y non-zero, not parallel", doc="camera x and y axes in the leader body frame (MJCF)")
    cam_pos_sigma: float = key(0.0, lo=0, unit="m", doc="survey error of cam_pos per axis, drawn once per run")
    cam_att_sigma_deg: float = key(0.0, lo=0, unit="deg", doc="survey error of the camera attitude per axis")
    led_pos: tuple[Vec3, ...] = key(((0.40, 0.30, 0.06), (0.40, -0.30, 0.06), (0.25, 0.0, 0.28), (0.60, 0.0, -0.12)),
                                    unit="m", range="at least one", doc="LED positions in the follower body frame")
    led_pos_sigma: float = key(0.0, lo=0, unit="m", doc="survey error of each LED coordinate")
    los_sigma: float = key(PAPER_VISION_SIGMA, lo=0, lo_open=True, unit="rad", doc="nominal LOS noise")
    focal_d: float = key(1.0, lo=0, doc="eq. 8 constant d")
    gyro_noise: float = key(PAPER_GYRO_NOISE, lo=0, unit="rad/s/sqrt(Hz)", doc="gyro white noise known to the filter")
    accel_noise: float = key(PAPER_ACCEL_NOISE, lo=0, unit="m/s^2/sqrt(Hz)", doc="accelerometer white noise known to the filter")
    gyro_bias_sigma: float = key(PAPER_GYRO_BIAS, lo=0, unit="rad/s", doc="gyro bias prior std")
    accel_bias_sigma: float = key(PAPER_ACCEL_BIAS, lo=0, unit="m/s^2", doc="accelerometer bias prior std")
    gyro_bias_rw: float = key(0.0, lo=0, unit="rad/s^2/sqrt(Hz)", doc="gyro bias random walk")
    accel_bias_rw: float = key(0.0, lo=0, unit="m/s^3/sqrt(Hz)", doc="accelerometer bias random walk")
    init_sigma_pos: float = key(0.5, lo=0, lo_open=True, unit="m", doc="initial relative position std per axis")
    init_sigma_vel: float = key(0.1, lo=0, lo_open=True, unit="m/s", doc="initial relative velocity std per axis")
    init_sigma_att_deg: float = key(2.0, lo=0, lo_open=True, unit="deg", doc="initial relative attitude std per axis")
    kernel_sigma: float = key(3.0, lo=0, lo_open=True, doc="correntropy kernel width of mckf / rhcf (whitened units)")
    mc_tol: float = key(1e-6, lo=0, lo_open=True, doc="convergence tolerance of the correntropy update")
    mc_max_iter: int = key(50, lo=1, hi=10_000, doc="iterations cap of the correntropy update")

    def __post_init__(self) -> None:
        require(len(self.filters) > 0 and all(f in FILTER_NAMES for f in self.filters), "filters", self.filters,
                f"must be a non-empty subset of {list(FILTER_NAMES)}, got {list(self.filters)}")
        require(len(set(self.filters)) == len(self.filters), "filters", self.filters, f"repeated names in {list(self.filters)}")
        check_fields(self)
        x, y = np.array(self.cam_xyaxes[:3]), np.array(self.cam_xyaxes[3:])
        require(np.linalg.norm(x) > 1e-9 and np.linalg.norm(np.cross(x, y)) > 1e-6 * np.linalg.norm(x) * np.linalg.norm(y),
                "cam_xyaxes", self.cam_xyaxes, f"x and y axes must be non-zero and not parallel, got {list(self.cam_xyaxes)}")
        require(len(self.led_pos) >= 1, "led_pos", self.led_pos, "at least one LED is needed")

    def cross_check(self, sc: Any) -> None:
        """visnav needs the IMU on both vehicles and the camera; the predict grid must divide the
        IMU rate and contain every camera epoch; every LED the camera can report needs a position."""
        _needs(sc.sensors, "visnav", "imu", "camera")
        imu, cam = sc.sensors.imu, sc.sensors.camera
        require(whole_ratio(imu.rate_hz, self.predict_rate_hz), "pipeline.predict_rate_hz", self.predict_rate_hz,
                f"{self.predict_rate_hz:g} Hz must divide the IMU rate {imu.rate_hz:g} Hz (sensors.imu.rate_hz)")
        require(whole_ratio(self.predict_rate_hz, cam.rate_hz), "pipeline.predict_rate_hz", self.predict_rate_hz,
                f"{self.predict_rate_hz:g} Hz must be a multiple of the camera rate {cam.rate_hz:g} Hz (sensors.camera.rate_hz)")
        missing = [v for v in (cam.leader, cam.follower) if imu.vehicles and v not in imu.vehicles]
        require(not missing, "sensors.imu.vehicles", imu.vehicles,
                f"{list(imu.vehicles)}: the visnav pipeline needs IMUs on the camera's leader {cam.leader} and follower {cam.follower}")
        require(len(self.led_pos) >= N_LEDS, "pipeline.led_pos", self.led_pos,
                f"{len(self.led_pos)} positions, but the follower carries {N_LEDS} LEDs (led1..led{N_LEDS}) the camera can report")


# --------------------------------------------------------------------------- seed 000 bandwidth
N_NODES = 4  # UAVs of the seed 000 formation


@dataclass(frozen=True, kw_only=True, slots=True)
class BandwidthPipelineConfig(_PipelineConfig):
    """[pipeline] table of a seed 000 scenario.

    measurements: "uwb" | "paper" (testbed.plugins.builtin_bandwidth). dt: filter step (s); in uwb mode a multiple
    of the UWB period. process_noise: diag W (m^2/s for w_reading "rate", m^2 for "per-step").
    paper_V: diag V of the paper mode (m^2). range_sigma: UWB range noise 1 sigma assumed by the
    estimator (m; default: the declared [sensors.uwb] noise). x0: initial estimate (m); M0: diag M_i(0) (m^2). velocity: known input v (m/s).
    selection: "T1" | "T2" | "T3" (the paper's sets) | "search" (bound-optimal set for the run's
    horizon, exhaustive over the 2430 admissible sets; in uwb mode with V from the first epoch).
    weights: "P1" | "P2" | "P3". budget: t_i, components each node receives per step.
    anchors: known anchor positions (m, world), 1-based numbering as `anchor{k}`; groups: the four
    anchor numbers of each UAV, the last one the reference of eq. 21; offsets: known tag position
    of each UAV relative to the formation point (m, world). anchor_error, offset_error: 1 sigma
    per axis (m) of the error of those known values. drop_prob: per directed message and step;
    fail_node (1-based, 0 = none) stops sending at fail_time (s).
    """

    kind: Literal["bandwidth"]
    measurements: Literal["uwb", "paper"] = key("uwb", doc="UWB pseudo-measurements, or the paper's (drawn from the truth)")
    dt: float = key(0.1, lo=0, lo_open=True, unit="s", doc="filter step; in uwb mode a multiple of the UWB period")
    process_noise: Vec3 = key((0.02, 0.05, 0.03), lo=0, unit="m^2/s or m^2", doc="diag W, per w_reading")
    w_reading: Literal["rate", "per-step"] = key("rate", doc="process_noise as a rate (m^2/s) or per step (m^2)")
    paper_V: Vec3 = key((0.03, 0.04, 0.02), lo=0, lo_open=True, unit="m^2", doc="diag V of the paper mode")
    range_sigma: float | None = key(None, lo=0, lo_open=True, unit="m", doc="assumed UWB range noise, 1 sigma (none: the declared [sensors.uwb] noise)")
    x0: Vec3 = key((10.0, 10.0, 10.0), unit="m", doc="initial estimate")
    M0: Vec3 = key((0.19, 0.09, 0.08), lo=0, lo_open=True, unit="m^2", doc="diag M_i(0)")
    velocity: Vec3 = key((0.5, 0.5, 0.5), unit="m/s", doc="known input v")
    selection: Literal["T1", "T2", "T3", "search"] = key("T1", doc="the paper's component sets, or the bound-optimal search")
    weights: Literal["P1", "P2", "P3"] = key("P1", doc="the paper's fusion weights")
    budget: int = key(5, lo=N_NODES - 1, hi=3 * (N_NODES - 1), doc="t_i, components each node receives per step")
    anchors: tuple[Vec3, ...] = key((), unit="m", doc="known anchor positions, world, numbered from 1")
    groups: tuple[tuple[int, int, int, int], ...] = key(((1, 2, 3, 4), (5, 6, 7, 8), (9, 10, 11, 12), (13, 14, 15, 16)),
                                                        range="1..len(anchors), spanning 3-D", doc="the four anchor numbers of each UAV, the last the reference of eq. 21")
    offsets: tuple[Vec3, ...] = key((), unit="m", range=f"{N_NODES} of them", doc="known tag position of each UAV from the formation point, world")
    anchor_error: float = key(0.0, lo=0, unit="m", doc="error of the known anchors, 1 sigma per axis")
    offset_error: float = key(0.0, lo=0, unit="m", doc="error of the known offsets, 1 sigma per axis")
    drop_prob: float = key(0.0, lo=0, hi=1, hi_open=True, doc="probability per directed message and step that it is lost")
    fail_node: int = key(0, lo=0, hi=N_NODES, doc="1-based node that stops sending at fail_time (0: none)")
    fail_time: float = key(0.0, lo=0, unit="s", doc="when fail_node stops sending")

    def __post_init__(self) -> None:
        check_fields(self)
        require(len(self.groups) == N_NODES, "groups", self.groups, f"need one anchor group per UAV ({N_NODES}), got {len(self.groups)}")
        require(len(self.offsets) == N_NODES, "offsets", self.offsets, f"need one tag offset per UAV ({N_NODES}), got {len(self.offsets)}")
        for i, g in enumerate(self.groups):
            require(all(1 <= a <= len(self.anchors) for a in g), f"groups[{i}]", g,
                    f"anchor numbers must be in 1..{len(self.anchors)} (pipeline.anchors), got {list(g)}")
            a = np.array([self.anchors[k - 1] for k in g])
            require(np.linalg.matrix_rank(a[:-1] - a[-1], tol=1e-6) == 3, f"groups[{i}]", g,
                    f"anchors {list(g)} do not span 3-D: eqs. 21-23 cannot be solved")
        # budget: t_ji >= 1 on every link needs budget >= N - 1; at most every component of every neighbour
        require(self.selection == "search" or self.budget == 5, "budget", self.budget,
                f"the paper's {self.selection} is for budget 5, got {self.budget}; use selection = \"search\"")

    _assumed = {"range_sigma": ("uwb", itemgetter("noise"))}

    def cross_check(self, sc: Any) -> None:
        """bandwidth estimates the point of a straight-line formation of N_NODES UAVs; its epochs
        must be logged instants; in uwb mode it needs the UWB stream and every world anchor known."""
        require(sc.trajectory.kind == "straight-line", "trajectory.kind", sc.trajectory.kind,
                "pipeline bandwidth estimates the point of a \"straight-line\" formation")
        require(sc.vehicles == N_NODES, "trajectory.offsets", sc.trajectory.offsets,
                f"pipeline bandwidth fuses {N_NODES} UAVs, the trajectory has {sc.vehicles}")
        rate = sc.world.control_rate
        step = self.dt * rate  # controller ticks per filter epoch
        periods = [rate / sc.world.truth_rate] + ([rate / sc.sensors.uwb.rate_hz] if sc.sensors.uwb else [])
        require(any(whole_ratio(step, round(p)) for p in periods), "pipeline.dt", self.dt,
                f"{self.dt:g} s epochs are not logged instants; use a multiple of the truth period 1/world.truth_rate "
                f"{1 / sc.world.truth_rate:g} s")
        if self.measurements == "uwb":
            _needs(sc.sensors, "bandwidth (measurements = \"uwb\")", "uwb")
            period = 1.0 / sc.sensors.uwb.rate_hz
            require(whole_ratio(self.dt, period), "pipeline.dt", self.dt, f"{self.dt:g} s is not a multiple of the UWB period {period:g} s")
            require(len(self.anchors) == len(sc.world.anchors), "pipeline.anchors", self.anchors,
                    f"{len(self.anchors)} known anchors but the world has {len(sc.world.anchors)} (world.anchors)")


# ------------------------------------------------------------------------------ seed 001 coop-fg
@dataclass(frozen=True, kw_only=True, slots=True)
class CoopPipelineConfig(_PipelineConfig):
    """[pipeline] table of a seed 001 scenario.

    gnss_sigma_h, gnss_sigma_v / rtk_sigma_h, rtk_sigma_v: the GNSS noise the estimators assume,
    1 sigma (m), horizontal (east, north) and up, for SPP and RTK fixes (by `gnss/rtk`); default:
    the declared [sensors.gnss.receiver] / [sensors.gnss.rtk] white noise and bias combined.
    range_sigma: assumed UWB range noise (m, 1 sigma); clock_ppm: assumed clock frequency offset
    (ppm, 1 sigma per device); twr_mode ("scale" | "ss-twr" | "ds-twr"), reply_time (s) and
    antenna_delay_sigma (m of range per device, 1 sigma): the assumed two-way ranging scheme;
    each of these five defaults to the declared [sensors.uwb] value (noise, clock_ppm, mode,
    reply_time, antenna_delay_sigma): set one only to study a mismatch;
    clock and antenna-delay errors enter the centralized estimator as the joint covariance of an
    epoch's ranges (shared by the links of one radio, plugins.builtin_coop.range_covariance) and the
    distributed ones as extra white variance (plugins.builtin_coop.range_sigmas).
    robust: "none" (least squares) or "huber" range factors, threshold huber_delta (in sigmas).
    neighbour_model: "prior" (the paper: neighbours' broadcasts as priors with their covariances)
    or "fixed" (neighbours fixed, block-Jacobi: converges to the centralized optimum, slower).
    damping: fraction of the local step applied (1 = the paper).
    max_rounds: cap on message-iteration rounds per epoch; tol: stop when every position change
    of a round is below tol (m).
    message_loss: probability that one directed delivery is lost (stream "links").
    max_age: rounds a receiver keeps a neighbour's last message (-1: the whole epoch).
    silent_uav: 1-based UAV that stops broadcasting (0: none) at time silent_from_s (s) on.
    plot_uavs: four 1-based UAVs for the error-vs-time figure (empty: chosen by neighbour count).
    """

    kind: Literal["coop-fg"]
    gnss_sigma_h: float | None = key(None, lo=0, lo_open=True, unit="m", doc="assumed SPP noise, horizontal, 1 sigma (none: [sensors.gnss.receiver])")
    gnss_sigma_v: float | None = key(None, lo=0, lo_open=True, unit="m", doc="assumed SPP noise, up, 1 sigma (none: [sensors.gnss.receiver])")
    rtk_sigma_h: float | None = key(None, lo=0, lo_open=True, unit="m", doc="assumed RTK noise, horizontal, 1 sigma (none: [sensors.gnss.rtk])")
    rtk_sigma_v: float | None = key(None, lo=0, lo_open=True, unit="m", doc="assumed RTK noise, up, 1 sigma (none: [sensors.gnss.rtk])")
    range_sigma: float | None = key(None, lo=0, lo_open=True, unit="m", doc="assumed UWB range noise, 1 sigma (none: [sensors.uwb] noise)")
    clock_ppm: float | None = key(None, lo=0, unit="ppm", doc="assumed clock frequency offset, 1 sigma per device (none: [sensors.uwb] clock_ppm)")
    twr_mode: Literal["scale", "ss-twr", "ds-twr"] | None = key(None, doc="assumed two-way ranging scheme (none: [sensors.uwb] mode)")
    reply_time: float | None = key(None, lo=0, unit="s", doc="assumed two-way ranging reply time (none: [sensors.uwb] reply_time)")
    antenna_delay_sigma: float | None = key(None, lo=0, unit="m", doc="assumed antenna delay, m of range per device, 1 sigma (none: [sensors.uwb] antenna_delay_sigma)")
    robust: Literal["none", "huber"] = key("none", doc="range factors: least squares or Huber")
    huber_delta: float = key(1.345, lo=0, lo_open=True, doc="Huber threshold, in sigmas")
    neighbour_model: Literal["prior", "fixed"] = key("prior", doc="neighbours' broadcasts as priors (the paper) or fixed (block-Jacobi)")
    damping: float = key(1.0, lo=0, hi=1, lo_open=True, doc="fraction of the local step applied (1: the paper)")
    max_rounds: int = key(300, lo=1, doc="cap on message-iteration rounds per epoch")
    tol: float = key(1e-3, lo=0, lo_open=True, unit="m", doc="stop when every position change of a round is below tol")
    message_loss: float = key(0.0, lo=0, hi=1, hi_open=True, doc="probability that one directed delivery is lost")
    max_age: int = key(-1, lo=-1, doc="rounds a receiver keeps a neighbour's last message (-1: the whole epoch)")
    silent_uav: int = key(0, lo=0, doc="1-based UAV that stops broadcasting (0: none)")
    silent_from_s: float = key(0.0, lo=0, unit="s", doc="when silent_uav stops broadcasting")
    plot_uavs: tuple[int, ...] = key((), range="empty or four UAV numbers >= 1", doc="UAVs of the error-vs-time figure (empty: by neighbour count)")

    def __post_init__(self) -> None:
        check_fields(self)
        require(len(self.plot_uavs) in (0, 4) and all(u >= 1 for u in self.plot_uavs), "plot_uavs", self.plot_uavs,
                f"must be empty or four 1-based UAV numbers, got {list(self.plot_uavs)}")

    _assumed = {"range_sigma": ("uwb", itemgetter("noise")), "clock_ppm": ("uwb", itemgetter("clock_ppm")),
                "twr_mode": ("uwb", itemgetter("mode")), "reply_time": ("uwb", itemgetter("reply_time")),
                "antenna_delay_sigma": ("uwb", itemgetter("antenna_delay_sigma")),
                # (east, north, up) declared sigmas of the receiver's and the RTK error tables
                "gnss_sigma_h": ("gnss", lambda g: float(gnss_sigma(g["receiver"])[0])),
                "gnss_sigma_v": ("gnss", lambda g: float(gnss_sigma(g["receiver"])[2])),
                "rtk_sigma_h": ("gnss", lambda g: float(gnss_sigma(g["rtk"])[0])),
                "rtk_sigma_v": ("gnss", lambda g: float(gnss_sigma(g["rtk"])[2]))}

    def cross_check(self, sc: Any) -> None:
        """coop-fg needs GNSS at the UWB tag on every UAV, UWB tag-to-tag links sampled at every
        GNSS epoch, and vehicle numbers that exist."""
        _needs(sc.sensors, "coop-fg", "gnss", "uwb")
        gnss, uwb, vehicles = sc.sensors.gnss, sc.sensors.uwb, sc.vehicles
        require(not gnss.vehicles or set(gnss.vehicles) >= set(range(1, vehicles + 1)), "sensors.gnss.vehicles", gnss.vehicles,
                f"{list(gnss.vehicles)}: coop-fg needs a GNSS fix of every UAV at every epoch (empty = all)")
        require(gnss.antenna == "uwb", "sensors.gnss.antenna", gnss.antenna,
                f"{gnss.antenna!r}; the coop-fg factor graph has one point per UAV, the UWB tag: set antenna = \"uwb\"")
        require(whole_ratio(uwb.rate_hz, gnss.rate_hz), "sensors.uwb.rate_hz", uwb.rate_hz,
                f"{uwb.rate_hz} Hz is not a multiple of sensors.gnss.rate_hz {gnss.rate_hz} Hz; every GNSS epoch needs its UWB sample")
        require(uwb.tag_links, "sensors.uwb.tag_links", uwb.tag_links, "false; coop-fg needs UAV-to-UAV ranges")
        require(self.silent_uav <= vehicles, "pipeline.silent_uav", self.silent_uav, f"{self.silent_uav}, the scenario has {vehicles} UAVs")
        require(all(u <= vehicles for u in self.plot_uavs), "pipeline.plot_uavs", self.plot_uavs,
                f"{list(self.plot_uavs)}, the scenario has {vehicles} UAVs")


PipelineConfig = TrackingPipelineConfig | PhasePipelineConfig | VisNavPipelineConfig | BandwidthPipelineConfig | CoopPipelineConfig
