"""Scenarios: frozen dataclasses loaded strictly from TOML.

A scenario names the world (vehicles, anchors, obstacles), the motion (a reference trajectory
flown `prescribed` or `flown`), the sensors and the estimator pipeline. Built-in scenarios live in
`testbed/scenarios/*.toml`; a file is named by a path (see `resolve`). Units: metres, seconds, radians unless a key
says `_deg` or `_hz`. Frames: world ENU (x east, y north, z up); vehicle bodies FLU.
"""
from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Literal

import numpy as np
import tomli_w

from testbed import trajectories
from testbed.config import from_dict, in_range, key, require, set_dotted, to_dict, whole_ratio
from testbed.errors import ConfigError
from testbed.config.network import NetworkConfig
from testbed.config.pipelines import PipelineConfig
from testbed.config.estimators import EstimatorSpec
from testbed.sensors.config import SensorsConfig

Vec3 = tuple[float, float, float]
# Most physics steps (duration / world.timestep) a run may take: ~1e9 steps is hours of compute
# and the per-tick log arrays grow with it; beyond that a value is a mistake (a duration of 1e12 s).
MAX_STEPS = 1e9

# ------------------------------------------------------------------------------------- world


@dataclass(frozen=True, kw_only=True, slots=True)
class Obstacle:
    """A static obstacle that blocks line of sight (mj_ray) and can be flown into.

    box: size = half extents (m); cylinder (pillar): size = (radius, half height, unused).
    pos: centre, world frame (m); yaw_deg: rotation about world z.
    """

    type: Literal["box", "cylinder"]
    pos: Vec3 = key(unit="m")
    size: Vec3 = key(unit="m")
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        require(all(s > 0 for s in self.size[:2]) and (self.type == "cylinder" or self.size[2] > 0), "size", self.size,
                f"must be positive, got {list(self.size)}")


@dataclass(frozen=True, kw_only=True, slots=True)
class World:
    """Physics and scene settings.

    timestep: MuJoCo step (s); control_rate: controller and sensor tick rate (Hz), a multiple of
    every sensor rate; truth_rate: rate (Hz) at which truth is logged even when no sensor samples;
    antenna_a, antenna_b: nose and wing-tip antenna lever arms (m, seed 003); anchors: UWB anchor
    positions (m, world); obstacles: static obstacles.
    clearance: what a reference path that comes closer than the airframe radius to the floor, an
    obstacle or another vehicle does (checked before simulating, testbed.reference.clearance):
    "error" (default: the run is refused), "warn" (one line on stderr, the run goes on), "off".
    """

    timestep: float = key(0.0025, unit="s")
    control_rate: float = key(200.0, unit="Hz")
    truth_rate: float = key(10.0, unit="Hz")
    antenna_a: float = key(1.0, unit="m")
    antenna_b: float = key(1.0, unit="m")
    anchors: tuple[Vec3, ...] = key((), unit="m")
    obstacles: tuple[Obstacle, ...] = ()
    clearance: Literal["error", "warn", "off"] = "error"

    def __post_init__(self) -> None:
        in_range(self, "timestep", 1e-6, 0.01, unit="s")
        in_range(self, "control_rate", 0, lo_open=True)
        require(whole_ratio(1.0, self.control_rate * self.timestep), "control_rate", self.control_rate,
                f"{self.control_rate} Hz is not a whole number of {self.timestep} s steps")
        in_range(self, "truth_rate", 0, self.control_rate, lo_open=True, unit="Hz (world.control_rate)")
        in_range(self, "antenna_a", 0, lo_open=True)
        in_range(self, "antenna_b", 0, lo_open=True)


# --------------------------------------------------------------------------------- trajectories


@dataclass(frozen=True, kw_only=True, slots=True)
class PhaseFormation:
    """Seed 003: five masters in a formation observe a follower flying eq. 31.

    Vehicles uav1..uav5 are the masters (uav3 on the symmetry axis; its body frame is the
    navigation frame), uav6 is the follower. Everything here is in the navigation frame (FLU of
    master 3); `nav_origin` places that frame in the world. The paper's frame (x fwd, y up,
    z right) maps to ours as (x, y, z)_ours = (x, -z, y)_paper.
    formation: line (lateral), cross, vobtuse (120 deg V), vacute (30 deg V), apex forward.
    heights: master heights h1..h5 (m, Table 1). spacing: adjacent masters (m).
    master_velocity: common velocity of the masters (m/s; 0 = hovering).
    follower_start, follower_velocity: eq. 31 position at t = 0 and velocity (m, m/s).
    *_amp_deg, attitude_freq_hz, attitude_phase: eq. 31 attitude a * sin(2 pi f t + phase).
    """

    kind: Literal["phase-formation"]
    formation: Literal["line", "cross", "vobtuse", "vacute"]
    heights: tuple[float, float, float, float, float] = key((0.0, 0.0, 0.0, 0.0, 0.0), unit="m")
    spacing: float = key(100.0, unit="m")
    nav_origin: Vec3 = key((0.0, 0.0, 100.0), unit="m")
    master_velocity: Vec3 = key((0.0, 0.0, 0.0), unit="m/s")
    follower_start: Vec3 = key((-200.0, 200.0, 150.0), unit="m")
    follower_velocity: Vec3 = key((4.0, -4.0, 3.0), unit="m/s")
    yaw_amp_deg: float = -5.0
    pitch_amp_deg: float = -10.0
    roll_amp_deg: float = 2.5
    attitude_freq_hz: float = 0.005
    attitude_phase: float = key(math.pi / 2, unit="rad")

    def __post_init__(self) -> None:
        in_range(self, "spacing", 0, lo_open=True)
        # eq. 31 Euler angles (ZYX): a pitch of 90 deg is the gimbal singularity
        in_range(self, "pitch_amp_deg", -90, 90, lo_open=True, hi_open=True, unit="deg")
        in_range(self, "yaw_amp_deg", -180, 180, unit="deg")
        in_range(self, "roll_amp_deg", -180, 180, unit="deg")
        in_range(self, "attitude_freq_hz", 0, 1, unit="Hz")

    @property
    def vehicles(self) -> int:
        return 6


@dataclass(frozen=True, kw_only=True, slots=True)
class StraightLine:
    """Seed 000: a formation point moving at constant velocity, vehicles at fixed offsets.

    start: formation point at t = 0 (m, world); velocity (m/s); offsets: one per vehicle (m).
    """

    kind: Literal["straight-line"]
    start: Vec3 = key(unit="m")
    velocity: Vec3 = key(unit="m/s")
    offsets: tuple[Vec3, ...] = key(unit="m")

    def __post_init__(self) -> None:
        require(len(self.offsets) > 0, "offsets", self.offsets, "at least one vehicle is needed")

    @property
    def vehicles(self) -> int:
        return len(self.offsets)


@dataclass(frozen=True, kw_only=True, slots=True)
class SwarmBox:
    """Seed 001: vehicles hovering around base points in a box with smooth oscillations.

    p_i(t) = base_i + amplitude * sin(2 pi t / T_i + phi_i), per axis, with
    T_i = period_min + (period_max - period_min) * i / (n - 1) and phases phi_i,axis =
    (i * 2.39996 + axis * 1.0) rad (golden-angle spread), i = 0..n-1. Bases at least
    `min_separation` apart and amplitude small enough never collide (checked).
    rtk: 1-based numbers of the vehicles with RTK receivers.
    """

    kind: Literal["swarm-box"]
    bases: tuple[Vec3, ...] = key(unit="m")
    amplitude: Vec3 = key((6.0, 6.0, 3.0), unit="m")
    period_min: float = key(60.0, unit="s")
    period_max: float = key(120.0, unit="s", range=">= period_min")
    rtk: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        _check_swarm(self, "bases")

    @property
    def vehicles(self) -> int:
        return len(self.bases)


def _check_swarm(tr: "SwarmBox | SwarmGrid", key: str) -> None:
    """Checks shared by the swarm trajectories: vehicles, separation of the bases (all pairs, in
    blocks of rows so that memory stays small; no scipy here: the schema loads without it), rtk
    numbers, periods. key: the field reported for the bases."""
    b = np.asarray(tr.bases, dtype=float).reshape(-1, 3)
    n = len(b)
    require(n > 0, key, getattr(tr, key), "at least one vehicle is needed")
    if n > 1:
        reach = 2 * float(np.linalg.norm(tr.amplitude)) + 2.5
        d = np.inf
        for r0 in range(0, n, 256):
            block = np.linalg.norm(b[r0 : r0 + 256, None] - b[None], axis=-1)
            block[np.arange(len(block)), r0 + np.arange(len(block))] = np.inf
            d = min(d, float(block.min()))
        require(d > reach, key, getattr(tr, key),
                f"two bases are {d:.1f} m apart, closer than 2|amplitude| + 2.5 m = {reach:.1f} m: vehicles could collide")
    require(all(1 <= r <= n for r in tr.rtk), "rtk", tr.rtk, f"vehicle numbers must be in 1..{n}, got {list(tr.rtk)}")
    in_range(tr, "period_min", 1, unit="s")
    in_range(tr, "period_max", tr.period_min, unit="s (period_min)")


@dataclass(frozen=True, kw_only=True, slots=True)
class SwarmGrid:
    """A large swarm in formation: `count` vehicles on a grid, each oscillating as in swarm-box.

    Base of vehicle i (0-based): origin + spacing * (i mod columns, (i // columns) mod rows,
    i // (columns rows)) (m, world): rows of `columns` along x, layers of `rows` rows along y,
    layers stacked along z. columns = 0: ceil(sqrt(count)); rows = 0: as many as one layer needs.
    Scale it with `--set trajectory.count=N`. Motion about the bases, amplitude and periods as
    SwarmBox. rtk_corners: the vehicles at the corners of the first layer carry RTK receivers
    (`rtk`, 1-based, whatever the count).
    """

    kind: Literal["swarm-grid"]
    count: int
    spacing: Vec3 = (40.0, 40.0, 30.0)
    origin: Vec3 = (20.0, 20.0, 30.0)
    columns: int = 0
    rows: int = 0
    amplitude: Vec3 = (6.0, 6.0, 3.0)
    period_min: float = 60.0
    period_max: float = 120.0
    rtk_corners: bool = True

    def __post_init__(self) -> None:
        require(self.count >= 1, "count", self.count, f"at least one vehicle is needed, got {self.count}")
        require(self.columns >= 0 and self.rows >= 0, "columns", (self.columns, self.rows), "columns and rows must be >= 0 (0: automatic)")
        _check_swarm(self, "spacing")

    @property
    def vehicles(self) -> int:
        return self.count

    @property
    def _shape(self) -> tuple[int, int]:
        cols = self.columns or math.ceil(math.sqrt(self.count))
        return cols, self.rows or math.ceil(self.count / cols)

    @property
    def rtk(self) -> tuple[int, ...]:
        """1-based numbers of the RTK vehicles: the corners of the first layer (rtk_corners)."""
        if not self.rtk_corners:
            return ()
        cols, rows = self._shape
        last_row = (min(self.count, cols * rows) - 1) // cols * cols  # 0-based first of the last row
        corners = {0, min(cols, self.count) - 1, last_row, min(last_row + cols, self.count) - 1}
        return tuple(sorted(i + 1 for i in corners))

    @property
    def bases(self) -> np.ndarray:
        """(count, 3) base points, world, m (class docstring)."""
        cols, rows = self._shape
        i = np.arange(self.count)
        ijk = np.stack([i % cols, (i // cols) % rows, i // (cols * rows)], axis=1)
        return np.array(self.origin) + np.array(self.spacing) * ijk


@dataclass(frozen=True, kw_only=True, slots=True)
class LeaderFollower:
    """Seed 004: a leader flying straight and a follower weaving behind it, yawing.

    leader_start (m), leader_velocity (m/s), world frame; the leader's yaw follows its velocity.
    follower_offset: nominal follower position in the leader's heading frame (m, FLU: negative x
    is behind). weave_amp (m) and weave_period (s): lateral sinusoid of the follower;
    yaw_amp_deg, yaw_period (s): follower yaw oscillation about the leader's heading;
    heave_amp (m): vertical sinusoid at 0.7 x the weave period.
    """

    kind: Literal["leader-follower"]
    leader_start: Vec3 = key((0.0, 0.0, 30.0), unit="m")
    leader_velocity: Vec3 = key((5.0, 0.0, 0.0), unit="m/s")
    follower_offset: Vec3 = key((-20.0, 0.0, 0.0), unit="m")
    weave_amp: float = key(3.0, unit="m")
    weave_period: float = key(40.0, unit="s")
    heave_amp: float = key(1.0, unit="m")
    yaw_amp_deg: float = 10.0
    yaw_period: float = key(30.0, unit="s")

    def __post_init__(self) -> None:
        in_range(self, "weave_period", 1, unit="s")
        in_range(self, "yaw_period", 1, unit="s")

    @property
    def vehicles(self) -> int:
        return 2


@dataclass(frozen=True, kw_only=True, slots=True)
class Waypoints:
    """Generic minimum-jerk path: rest-to-rest quintic segments through waypoints.

    points (m, world) reached at times (s, increasing, first 0); every vehicle flies the same path
    shifted by its offset (m); yaw_deg constant.
    """

    kind: Literal["waypoints"]
    points: tuple[Vec3, ...] = key(unit="m")
    times: tuple[float, ...] = key(unit="s", range="from 0, increasing")
    offsets: tuple[Vec3, ...] = key(((0.0, 0.0, 0.0),), unit="m")
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        require(len(self.points) >= 2, "points", self.points, "need at least two waypoints")
        require(len(self.times) == len(self.points), "times", self.times,
                f"need one time per waypoint ({len(self.points)}), got {len(self.times)}")
        require(self.times[0] == 0 and all(b >= a + 0.01 for a, b in zip(self.times, self.times[1:])), "times", self.times,
                f"must start at 0 and increase by at least 0.01 s, got {list(self.times)}")
        require(len(self.offsets) > 0, "offsets", self.offsets, "at least one vehicle is needed")

    @property
    def vehicles(self) -> int:
        return len(self.offsets)


def _check_limits(key: str, value: object, t: np.ndarray, vel: np.ndarray, acc: np.ndarray) -> None:
    """Refuse a reference beyond the airframe (testbed.trajectories.limit_violation), naming `key`."""
    problem = trajectories.limit_violation(t, vel, acc)
    require(problem is None, key, value, f"{_plain(value)}: {problem}")


def _plain(value: object) -> str:
    return f"{value:g}" if isinstance(value, float) else str(list(value) if isinstance(value, tuple) else value)


@dataclass(frozen=True, kw_only=True, slots=True)
class Spline:
    """A minimum-snap spline through waypoints, flown without stopping (testbed/trajectories.py).

    points (m, world) are passed in order; between them, per axis, degree-7 polynomials whose
    integrated squared snap is least, with velocity, acceleration, jerk and snap continuous at
    every point (the optimum is continuous to the 6th derivative). Open (closed = false): from
    rest at the first point to rest at the last, then held there. Closed: back to the first point
    and round again, periodic, with no stop anywhere. times: when each point is reached (s, from
    0, increasing; closed: one more, the return to the first point); empty: allocated at the
    cruise `speed` (m/s): segment i lasts max(|P_i+1 - P_i| / speed, 0.5 s), the first and last
    segments of an open path twice that (they start or end at rest). Refused at load if the
    reference is faster than the airframe's 23 m/s or needs more than 80 % of its thrust
    (models/quadrotor.xml: 4 x 40 N for 6.9 kg; |a + g| at most 18.6 m/s^2): the key named is
    `times`, or `speed` when the times are allocated. Every vehicle flies the path shifted by its
    offset (m): a formation of len(offsets) vehicles; yaw_deg constant.
    """

    kind: Literal["spline"]
    points: tuple[Vec3, ...] = key(unit="m", range="2 to 256 points")
    times: tuple[float, ...] = key((), unit="s", range="empty, or one per point (closed: one more) from 0, increasing")
    speed: float = key(5.0, unit="m/s", range="> 0 (used when times is empty)")
    closed: bool = False
    offsets: tuple[Vec3, ...] = key(((0.0, 0.0, 0.0),), unit="m")
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        most = trajectories.MAX_POINTS
        require(2 <= len(self.points) <= most, "points", self.points, f"need 2 to {most} waypoints, got {len(self.points)}")
        in_range(self, "speed", 0, lo_open=True, unit="m/s")
        if self.times:
            need = len(self.points) + self.closed
            require(len(self.times) == need, "times", self.times,
                    f"need one time per waypoint{' and one for the return to the first' if self.closed else ''} ({need}), got {len(self.times)}")
            require(self.times[0] == 0 and all(b >= a + 0.01 for a, b in zip(self.times, self.times[1:])), "times", self.times,
                    f"must start at 0 and increase by at least 0.01 s, got {list(self.times)}")
        require(len(self.offsets) > 0, "offsets", self.offsets, "at least one vehicle is needed")
        knots = self.path.knots
        t = np.concatenate([np.linspace(a, b, trajectories.SAMPLES_PER_SEGMENT + 1) for a, b in zip(knots, knots[1:])])
        d = self.path.derivatives(t)
        _check_limits("times" if self.times else "speed", self.times or self.speed, t, d[1], d[2])

    @property
    def durations(self) -> np.ndarray:
        """(S,) s: segment durations, from `times` or allocated at `speed` (class docstring)."""
        if self.times:
            return np.diff(self.times)
        return trajectories.allocate(np.array(self.points, float), self.speed, self.closed)

    @property
    def path(self) -> trajectories.PiecewisePolynomial:
        """The minimum-snap spline of the formation point (cached on points and times)."""
        return trajectories.min_snap(np.array(self.points, float), self.durations, self.closed)

    @property
    def vehicles(self) -> int:
        return len(self.offsets)


def _check_curve(tr: "Circle | Lemniscate") -> None:
    """Checks shared by the closed curves: count, period, the airframe's limits over one period."""
    require(tr.count >= 1, "count", tr.count, f"at least one vehicle is needed, got {tr.count}")
    in_range(tr, "period", 0.1, unit="s")
    t = np.linspace(0.0, tr.period, trajectories.SAMPLES_PER_PERIOD, endpoint=False)
    _, vel, acc = tr.pva(t, 1)
    _check_limits("period", tr.period, t, vel, acc)


@dataclass(frozen=True, kw_only=True, slots=True)
class Circle:
    """Vehicles round a horizontal circle at constant speed: a ring formation.

    Vehicle i (0-based) at center + radius (cos theta_i, sin theta_i, 0) + i layer e_z (m, world),
    theta_i = 2 pi t / period + 2 pi i / count (anticlockwise from above; clockwise = true turns
    it the other way): `count` vehicles evenly spread round the circle, each `layer` m above the
    previous. Speed 2 pi radius / period, centripetal acceleration radius (2 pi / period)^2:
    refused (key `period`) beyond the airframe's speed or 80 % of its thrust (see spline).
    yaw_deg constant.
    """

    kind: Literal["circle"]
    center: Vec3 = key(unit="m")
    radius: float = key(unit="m", range="> 0")
    period: float = key(unit="s", range=">= 0.1")
    clockwise: bool = False
    count: int = key(1, range=">= 1")
    layer: float = key(0.0, unit="m")
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        in_range(self, "radius", 0, lo_open=True, unit="m")
        _check_curve(self)

    def pva(self, t: np.ndarray, count: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """pos, vel, acc (K, N, 3) at t (K,) s of the first `count` vehicles (all when None)."""
        phases, heights = trajectories.spread(self.count, self.layer)
        n = count or self.count
        sign = -1.0 if self.clockwise else 1.0
        return trajectories.circle(t, np.array(self.center), self.radius, sign * self.period, phases[:n], heights[:n])

    @property
    def vehicles(self) -> int:
        return self.count


@dataclass(frozen=True, kw_only=True, slots=True)
class Lemniscate:
    """Vehicles round a horizontal figure-eight (lemniscate of Gerono).

    Vehicle i (0-based) at center + i layer e_z + R(heading) (A sin theta_i, B sin theta_i
    cos theta_i, 0) (m, world), theta_i = 2 pi t / period + 2 pi i / count; size = (A, B) (m): the
    figure spans +/- A along its axis (heading_deg from world x) and +/- B / 2 across it. The
    path crosses itself at the centre: with an even count two vehicles meet there unless
    `layer` separates them (the clearance check refuses the run). Refused (key `period`) beyond
    the airframe's speed or 80 % of its thrust, checked at 1024 instants of a period (see
    spline). yaw_deg constant.
    """

    kind: Literal["lemniscate"]
    center: Vec3 = key(unit="m")
    size: tuple[float, float] = key(unit="m", range="> 0")
    period: float = key(unit="s", range=">= 0.1")
    heading_deg: float = 0.0
    count: int = key(1, range=">= 1")
    layer: float = key(0.0, unit="m")
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        in_range(self, "size", 0, lo_open=True, unit="m")
        _check_curve(self)

    def pva(self, t: np.ndarray, count: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """pos, vel, acc (K, N, 3) at t (K,) s of the first `count` vehicles (all when None)."""
        phases, heights = trajectories.spread(self.count, self.layer)
        n = count or self.count
        return trajectories.lemniscate(t, np.array(self.center), self.size, self.period, math.radians(self.heading_deg),
                                       phases[:n], heights[:n])

    @property
    def vehicles(self) -> int:
        return self.count


@dataclass(frozen=True, kw_only=True, slots=True)
class Hover:
    """Vehicles holding still: every vehicle at point + its offset (m, world), yaw_deg constant."""

    kind: Literal["hover"]
    point: Vec3 = key(unit="m")
    offsets: tuple[Vec3, ...] = key(((0.0, 0.0, 0.0),), unit="m")
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        require(len(self.offsets) > 0, "offsets", self.offsets, "at least one vehicle is needed")

    @property
    def vehicles(self) -> int:
        return len(self.offsets)


Trajectory = PhaseFormation | StraightLine | SwarmBox | SwarmGrid | LeaderFollower | Waypoints | Spline | Circle | Lemniscate | Hover

# ----------------------------------------------------------------------------------- scenario


@dataclass(frozen=True, kw_only=True, slots=True)
class Disturbance:
    """Random body accelerations: the white-noise-acceleration motion model made physical.

    Each disturbed vehicle gets, per controller tick (1 / world.control_rate s), an independent
    Gaussian linear acceleration (world axes) and angular acceleration (body axes), held over the
    tick: the piecewise-constant sampling of continuous white noise whose spectral densities are
    accel_density (m^2/s^3, per axis) and angular_accel_density (rad^2/s^3, per axis). So the
    velocity (angular velocity) is a random walk and, over any logged interval dt, increments by
    N(0, density * dt). prescribed: added to the reference motion (position, velocity,
    acceleration; attitude, body rate, angular acceleration), so the truth IS that process and every
    sensor sees it. flown: applied as an external force m a and torque I alpha (a gust), which the
    controller then fights. Stream "disturbance". vehicles: 1-based numbers; empty = all.
    Zero densities (the default) = no disturbance: the run is bit-identical to one without it.
    Prescribed, nothing pulls the vehicle back: after t seconds its position has wandered
    sqrt(accel_density t^3 / 3) m per axis (1.6 m at 1e-3 m^2/s^3 and 20 s, 95 m at 300 s, through
    floors and obstacles alike), so choose the density for the horizon, or fly it (`flown`).
    """

    accel_density: float = 0.0
    angular_accel_density: float = 0.0
    vehicles: tuple[int, ...] = key((), range="distinct vehicle numbers; empty = all")

    def __post_init__(self) -> None:
        in_range(self, "accel_density", 0, unit="m^2/s^3")
        in_range(self, "angular_accel_density", 0, unit="rad^2/s^3")
        require(all(v >= 1 for v in self.vehicles) and len(set(self.vehicles)) == len(self.vehicles), "vehicles", self.vehicles,
                f"must be distinct vehicle numbers >= 1, got {list(self.vehicles)}")

    @property
    def active(self) -> bool:
        return self.accel_density > 0 or self.angular_accel_density > 0


@dataclass(frozen=True, kw_only=True, slots=True)
class Control:
    """Geometric tracking controller gains (Lee, Leok, McClamroch 2010), per unit mass/inertia,
    and where a flown controller takes its state from (docs/control.md).

    kx (1/s^2), kv (1/s) position and velocity; kr (1/s^2), kw (1/s) attitude and rate.
    feedback: "truth" (the MuJoCo state) or "estimate:NAME", the position and velocity of the
    `[[estimators]]` table named NAME, run online inside the loop (flown motion; a prescribed
    one flies nothing and the estimator runs on the log);
    feedback_vehicles: the vehicles (1-based) flown on that estimate, the others on truth
    (empty: every vehicle). attitude: "truth"; "mahony", the onboard complementary filter on
    each vehicle's IMU with gains mahony_kp (1/s) and mahony_ki (1/s^2); or "estimate", the
    attitude of the feedback estimator (its latest "attitude" estimate) with the body rate of the
    latest gyro sample (needs feedback = "estimate:NAME"); both need [sensors.imu] on every
    vehicle. max_tilt_deg: the safety limit on the commanded thrust direction's tilt
    from the vertical (deg; 0 = off), docs/control.md. release_sigmas: n > 0 holds each
    fed-back vehicle on its reference (the initialization phase) until the covariance its
    estimator declares says an n-sigma error asks no more than the tilt limit,
    n (kx sigma_p + kv sigma_v) <= g tan(max_tilt_deg) (sigma: the RMS of the position and
    velocity errors, sqrt of the covariance's trace), or, flown on the estimated attitude, until
    sigma_p is no larger than the drift of its open-loop hold; from then on it flies on the
    estimate (needs max_tilt_deg > 0; 0 = off: flown on the first estimate; with feedback =
    "truth" nothing is fed back and it has no effect, so that flying a scenario on truth is the one
    key feedback). release_blend_s: tau > 0 makes the release bumpless: the difference between
    the estimate and the reference at the release (position and velocity) is subtracted from what
    the controller gets and faded out as exp(-(t - t_release) / tau), so the error it answers
    starts at zero (s; 0 = off: the whole difference at once; needs release_sigmas > 0).
    """

    kx: float = key(4.0, unit="1/s^2")
    kv: float = key(3.0, unit="1/s")
    kr: float = key(60.0, unit="1/s^2")
    kw: float = key(14.0, unit="1/s")
    feedback: str = key("truth", range='"truth" or "estimate:NAME"')
    feedback_vehicles: tuple[int, ...] = key((), range="vehicle numbers >= 1; empty = all")
    attitude: Literal["truth", "mahony", "estimate"] = "truth"
    mahony_kp: float = key(0.3, unit="1/s")
    mahony_ki: float = key(0.02, unit="1/s^2")
    max_tilt_deg: float = key(0.0, unit="deg", range="0 (off) or in (0, 90)")
    release_sigmas: float = key(0.0, range="0 (off) or > 0")
    release_blend_s: float = key(0.0, unit="s", range="0 (off) or > 0")

    def __post_init__(self) -> None:
        for gain in ("kx", "kv", "kr", "kw", "mahony_kp"):
            in_range(self, gain, 0, lo_open=True)
        in_range(self, "mahony_ki", 0)
        in_range(self, "max_tilt_deg", 0, 90, hi_open=True, unit="deg")
        require(self.feedback == "truth" or (self.feedback.startswith("estimate:") and len(self.feedback) > 9),
                "feedback", self.feedback, f'must be "truth" or "estimate:NAME" (NAME: an [[estimators]] name), got {self.feedback!r}')
        require(all(v >= 1 for v in self.feedback_vehicles), "feedback_vehicles", list(self.feedback_vehicles),
                f"vehicle numbers start at 1, got {list(self.feedback_vehicles)}")
        require(not self.feedback_vehicles or self.feedback != "truth", "feedback_vehicles", list(self.feedback_vehicles),
                f'{list(self.feedback_vehicles)}: only with feedback = "estimate:NAME"')
        in_range(self, "release_sigmas", 0)
        require(not self.release_sigmas or self.feedback == "truth" or self.max_tilt_deg > 0, "release_sigmas",
                self.release_sigmas, f'{self.release_sigmas:g}: only with max_tilt_deg > 0')
        in_range(self, "release_blend_s", 0, unit="s")
        require(not self.release_blend_s or self.release_sigmas > 0, "release_blend_s", self.release_blend_s,
                f'{self.release_blend_s:g}: only with release_sigmas > 0')

    @property
    def feedback_estimator(self) -> str:
        """NAME of feedback "estimate:NAME", "" for truth."""
        return self.feedback.partition("estimate:")[2]


@dataclass(frozen=True, kw_only=True, slots=True)
class Scenario:
    """A complete, resolved scenario. `vehicles` is derived from the trajectory."""

    name: str
    description: str
    paper: Literal["003", "004", "000", "001", "none"] = "none"
    seed: int = key(0, range=">= 0")
    duration: float = key(unit="s")
    motion: Literal["prescribed", "flown"] = "prescribed"
    world: World = field(default_factory=World)
    control: Control = field(default_factory=Control)
    trajectory: Trajectory
    disturbance: Disturbance = field(default_factory=Disturbance)
    sensors: SensorsConfig = field(default_factory=SensorsConfig)
    network: NetworkConfig | None = None  # [network]: the links between vehicles; none = ideal
    pipeline: PipelineConfig | None = None
    estimators: tuple[EstimatorSpec, ...] = ()  # plugin estimators scored beside the pipeline

    def __post_init__(self) -> None:
        in_range(self, "duration", 0, lo_open=True, unit="s")
        steps = self.duration / self.world.timestep
        require(steps <= MAX_STEPS, "duration", self.duration,
                f"{self.duration:g} s is {steps:.3g} physics steps of world.timestep {self.world.timestep:g} s, "
                f"more than the {MAX_STEPS:.0e} a run may take")
        require(self.seed >= 0, "seed", self.seed, f"must be a non-negative integer, got {self.seed}")
        bad = [v for v in self.disturbance.vehicles if v > self.vehicles]
        require(not bad, "disturbance.vehicles", self.disturbance.vehicles,
                f"vehicle {bad[0] if bad else 0} does not exist (the scenario has {self.vehicles})")
        # cross-checks: sensor rates divide the control rate, vehicle numbers exist, the
        # pipeline has the sensors it needs (keys dotted from the scenario root)
        self.sensors.cross_check(self.world.control_rate, self.vehicles, "sensors")
        if self.pipeline is not None:
            # the sensor-model keys the estimators assume, unless given, are the declared ones
            assumed = self.pipeline.assumed({name: to_dict(cfg) for name, cfg in self.sensors.streams().items()})
            object.__setattr__(self, "pipeline", assumed)
            self.pipeline.cross_check(self)
        self._check_feedback()

    def _check_feedback(self) -> None:
        """[control] feedback and attitude: flown motion, a known estimator, existing vehicles, an IMU."""
        c = self.control
        name = c.feedback_estimator
        # feedback = "estimate:NAME" with a prescribed motion: nothing is flown, the estimator runs on the log
        # (so that --motion prescribed plays back a scenario written to fly on its estimate)
        if c.attitude != "truth":
            require(self.motion == "flown", "control.attitude", c.attitude,
                    f'{c.attitude!r} needs motion = "flown" (a prescribed motion has no controller)')
        if name:
            names = [e.key for e in self.estimators]
            require(name in names, "control.feedback", c.feedback,
                    f"{c.feedback!r}: no [[estimators]] named {name!r} (names: {', '.join(names) or 'none'})")
            bad = [v for v in c.feedback_vehicles if v > self.vehicles]
            require(not bad, "control.feedback_vehicles", list(c.feedback_vehicles),
                    f"vehicle {bad[0] if bad else 0} does not exist (the scenario has {self.vehicles})")
        if c.attitude == "estimate":
            require(bool(name), "control.attitude", c.attitude, """'estimate' needs feedback = "estimate:NAME" (the estimator it takes the attitude from)""")
        if c.attitude != "truth":
            imu = self.sensors.imu
            require(imu is not None and set(imu.vehicles or range(1, self.vehicles + 1)) == set(range(1, self.vehicles + 1)),
                    "control.attitude", c.attitude, f"{c.attitude!r} needs [sensors.imu] on every vehicle")

    @property
    def vehicles(self) -> int:
        return self.trajectory.vehicles


# ------------------------------------------------------------------------------------ loading


def builtin_names() -> list[str]:
    """Names of the scenarios shipped with the package."""
    return sorted(p.name[:-5] for p in resources.files("testbed.scenarios").iterdir() if p.name.endswith(".toml"))


def resolve(name_or_path: str) -> tuple[bool, str]:
    """Which scenario `name_or_path` names: (built-in?, label for messages).

    Unambiguous by its spelling, never by what happens to exist in the working directory: a path
    contains a `/` or ends in `.toml` (`./bandwidth`, `my.toml`); anything else is the name of a
    built-in scenario (`bandwidth`), even if a file or directory of that name is here too.
    """
    if "/" in name_or_path or os.sep in name_or_path or name_or_path.endswith(".toml"):
        return False, name_or_path
    return True, f"{name_or_path}.toml"


def _read_table(name_or_path: str) -> tuple[dict, str]:
    builtin, label = resolve(name_or_path)
    if builtin:
        res = resources.files("testbed.scenarios") / label
        if not name_or_path or not res.is_file():
            hint = f"; a scenario file is named by a path: ./{name_or_path}" if name_or_path and Path(name_or_path).exists() else ""
            raise ConfigError(f"unknown scenario {name_or_path!r}; built-in: {', '.join(builtin_names())}{hint}")
        raw = res.read_bytes()
    else:
        path = Path(name_or_path)
        if not path.is_file():
            raise ConfigError(f"{label}: {'is a directory, not' if path.is_dir() else 'no such'} scenario file")
        try:
            raw = path.read_bytes()
        except OSError as e:
            raise ConfigError(f"{label}: cannot read: {e.strerror or e}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(f"{label}: not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start}); TOML files are UTF-8") from None
    try:
        return tomllib.loads(text), label
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{label}: malformed TOML: {e}") from None


def load(name_or_path: str, overrides: dict[str, object] | None = None, **top: object) -> Scenario:
    """Load a built-in scenario by name or a TOML file by path, apply overrides, validate.

    overrides: dotted key -> raw TOML value, as from `--set key=value`, or a Python value (the
    key must exist once defaults are written out; list elements `world.obstacles[0].size`). top: seed, motion, duration given on the command line (None = keep).
    Raises ConfigError with one line naming the file, key and value.
    """
    data, label = _read_table(name_or_path)
    scenario = from_dict(Scenario, data, label)
    if overrides:
        resolved = to_dict(scenario)
        for dotted, raw in overrides.items():
            set_dotted(resolved, dotted, raw, label)
        # an assumed sensor-model key of the pipeline given neither in the file nor here follows
        # the (overridden) declared sensor model: derived again, never kept equal by hand
        given = set(data.get("pipeline", {})) | {str(k).partition(".")[2].partition(".")[0] for k in overrides
                                                  if str(k).startswith("pipeline.")}
        for k in scenario.pipeline.derived() - given if scenario.pipeline is not None else ():
            resolved["pipeline"].pop(k, None)
        scenario = from_dict(Scenario, resolved, label)
    changes = {k: v for k, v in top.items() if v is not None}
    if changes:
        scenario = from_dict(Scenario, {**to_dict(scenario), **changes}, label + " (command line)")
    return scenario


def dumps(scenario: Scenario) -> str:
    """The fully resolved scenario as TOML, every default written out: enough to rerun."""
    return tomli_w.dumps(to_dict(scenario))

