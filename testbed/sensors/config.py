"""Sensor configuration of a scenario: one optional table per stream, `[sensors.NAME]`.

A missing table means the stream is off; an empty table turns it on with its defaults. Each table
has `rate_hz` (must divide the scenario's control_rate; checked by `cross_check`), `latency` (s:
`NAME/arrival = NAME/time + latency`, `NAME/time` being the time of validity) and a `preset` that
fills every error key the table leaves out (presets in testbed.sensors.presets). Keys given
explicitly override the preset; the resolved scenario writes every value out. Units SI (m, s,
rad); see docs/sensors.md for every key. Every table validates itself in `__post_init__` (after
the preset filled it in), so `dataclasses.replace` re-checks.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Literal

from testbed.config import from_dict, in_range, join_key, key, require, to_dict, whole_ratio
from testbed.sensors.presets import CAMERA_PRESETS, GNSS_PRESETS, IMU_PRESETS, PHASE_PRESETS, UWB_PRESETS


def _fill(obj: object, table: dict) -> None:
    """Set every None field of a frozen dataclass that the preset table names."""
    for f in fields(obj):
        if getattr(obj, f.name) is None and f.name in table:
            object.__setattr__(obj, f.name, table[f.name])


def _check_rate(cfg: object) -> None:
    in_range(cfg, "rate_hz", 0, lo_open=True, unit="Hz")
    in_range(cfg, "latency", 0, unit="s")


# --------------------------------------------------------------------------------------- IMU


@dataclass(frozen=True, kw_only=True, slots=True)
class InertialErrors:
    """Error model of one triad (accelerometer or gyro), per axis, SI units.

    accel: m/s^2 (noise_density m/s^2/sqrt(Hz), bias_walk m/s^3/sqrt(Hz)); gyro: rad/s
    (rad/s/sqrt(Hz), rad/s^2/sqrt(Hz)). gm_tau in s (0 = no Gauss-Markov bias). scale_sigma
    dimensionless, misalign_sigma rad. Omitted keys come from the IMU preset.
    """

    noise_density: float | None = None
    bias: float | None = None
    bias_sigma: float | None = None
    bias_walk: float | None = None
    gm_sigma: float | None = None
    gm_tau: float | None = None
    scale_sigma: float | None = None
    misalign_sigma: float | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name != "bias" and getattr(self, f.name) is not None:
                in_range(self, f.name, 0)


@dataclass(frozen=True, kw_only=True, slots=True)
class Vibration:
    """[sensors.imu.vibration]: rotor vibration seen by the IMU in flown motion (testbed.sensors.vibration).

    enabled: on in flown runs (prescribed motion has no rotor speeds: always off). thrust_coefficient
    k (N s^2): the airframe's rotor thrust T = k f^2 at rotation frequency f (rev/s).
    accel_xy, accel_z (m/s^2 per N of rotor thrust): acceleration amplitude of one rotor at its
    harmonics 1, 2, .. (one entry per harmonic), in the rotor plane (a vector turning with the rotor)
    and along body z; proportional to the thrust because an imbalance force m e omega^2 is.
    cutoff_ratio: the IMU's anti-alias low-pass (-3 dB, second-order Butterworth) as a fraction of
    rate_hz. Omitted keys come from the IMU preset.
    """

    enabled: bool | None = None
    thrust_coefficient: float | None = key(None, unit="N s^2", range="> 0")
    accel_xy: tuple[float, ...] | None = key(None, unit="m/s^2/N", range=">= 0")
    accel_z: tuple[float, ...] | None = key(None, unit="m/s^2/N", range=">= 0")
    cutoff_ratio: float | None = key(None, unit="-", range="> 0")

    def __post_init__(self) -> None:
        for name in ("thrust_coefficient", "cutoff_ratio"):
            if getattr(self, name) is not None:
                in_range(self, name, 0, lo_open=True)
        for name in ("accel_xy", "accel_z"):
            if getattr(self, name) is not None:
                in_range(self, name, 0, unit="m/s^2/N")


@dataclass(frozen=True, kw_only=True, slots=True)
class ImuConfig:
    """[sensors.imu]: accelerometer + gyro of every vehicle's `imu` site (seed 004 eqs. 1-4).

    vehicles: 1-based vehicle numbers carrying an IMU (empty = all). vibration: the rotors'
    vibration in flown runs (Vibration).
    """

    preset: Literal["paper004", "bmi088", "mpu9250", "ideal"] = "paper004"
    rate_hz: float = 200.0
    latency: float = 0.0
    vehicles: tuple[int, ...] = ()
    accel: InertialErrors | None = None
    gyro: InertialErrors | None = None
    vibration: Vibration | None = None

    def __post_init__(self) -> None:
        table = IMU_PRESETS[self.preset]
        for name, kind in (("accel", InertialErrors), ("gyro", InertialErrors), ("vibration", Vibration)):
            cur = getattr(self, name) or kind()
            filled = replace(cur)
            _fill(filled, table[name])
            object.__setattr__(self, name, filled)
        vib = self.vibration
        require(len(vib.accel_xy) == len(vib.accel_z), "vibration.accel_z", list(vib.accel_z),
                f"needs one amplitude per harmonic, as many as vibration.accel_xy ({len(vib.accel_xy)})")
        _check_rate(self)
        in_range(self, "vehicles", 1)


def declared_imu(table: dict, bodies: tuple[str, ...], at: str) -> dict:
    """A recorded dataset's [sensors.imu] resolved as a scenario's is (its preset fills every error
    key left out, ImuConfig), as Context.sensors["imu"].

    table: the spec's free table; a sub-table named after a body (`[sensors.imu.uav2]`) overrides
    the shared keys for that body (merged key by key, accel/gyro/vibration one level down, then
    resolved on its own: its `preset` fills only the keys neither table gives). Returns the shared
    table resolved, with each overridden body's whole resolved table under its name
    (estimators.sensor_models.vehicle_imu picks a body's). at: the dotted key of `table` (FieldError
    names the full key).
    """
    names = {f.name for f in fields(ImuConfig)}
    shared = {k: v for k, v in table.items() if k in names or k not in bodies}
    out = to_dict(from_dict(ImuConfig, shared, "", at))
    for body in (k for k in table if k not in names and k in bodies):
        own = table[body]
        require(isinstance(own, dict), join_key(at, body), own, f"expected a table of [sensors.imu] keys for body {body!r}")
        merged = {**shared, **own}
        for sub in ("accel", "gyro", "vibration"):
            if isinstance(shared.get(sub), dict) and isinstance(own.get(sub), dict):
                merged[sub] = {**shared[sub], **own[sub]}
        out[body] = to_dict(from_dict(ImuConfig, merged, "", join_key(at, body)))
    return out


# --------------------------------------------------------------------------------------- UWB


#: the antenna sites of the vehicle model (models/quadrotor.xml) a UWB tag may sit on: the mast's
#: `uwb`, and the three antenna tips `ant1..3` (world.antenna_a, world.antenna_b)
TAG_SITES = ("uwb", "ant1", "ant2", "ant3")


@dataclass(frozen=True, kw_only=True, slots=True)
class UwbSchedule:
    """[sensors.uwb.schedule]: which links are ranged at each UWB sample (testbed.sensors.uwb).

    policy "all" (default): every candidate link at every sample. Otherwise one two-way exchange
    takes slot_s seconds, so a cycle of 1 / rate_hz s serves S = floor(1 / (rate_hz slot_s))
    links: "round_robin" the next S in-range links in a fixed order (tag-anchor and tag-tag
    links by source, then destination), continuing after the last one served; "nearest" the S
    in-range links of smallest true distance (far links may never be served).
    """

    policy: Literal["all", "round_robin", "nearest"] = "all"
    slot_s: float = key(0.001, unit="s")

    def __post_init__(self) -> None:
        in_range(self, "slot_s", 0, lo_open=True, unit="s")


@dataclass(frozen=True, kw_only=True, slots=True)
class UwbConfig:
    """[sensors.uwb]: two-way ranging between `uwb` sites (tags) and `anchor{k}` sites.

    tags: the sites of each vehicle that range (default ["uwb"]; any sites of the vehicle model,
    e.g. ["ant2", "ant3"] for two tags a vehicle). anchor_links: tag-to-anchor ranges;
    tag_links: tag-to-tag (every pair of tags of different vehicles once). max_range (m):
    true distance beyond which no range is made. link_search: "all-pairs" (every link fixed at
    the start, random draws for all of them at every sample: O(N^2)) or "in-range" (tag pairs
    within max_range found at every sample with a k-d tree, draws only for those: large swarms;
    testbed.sensors.uwb). noise (m, 1 sigma, white); loss_prob: packet
    loss per measurement; clock_ppm: 1 sigma of each device's clock frequency offset (ppm);
    mode: how the clocks enter the range (testbed.sensors.uwb): "scale" (range x
    (1 + (k_src + k_dst)/2 1e-6)), "ss-twr" (single-sided two-way ranging, the responder replies
    after reply_time (s) on its own clock) or "ds-twr" (asymmetric double-sided);
    antenna_delay_sigma: 1 sigma (m of range) of each device's constant antenna-delay residual;
    link_bias_sigma: constant per-link bias, 1 sigma (m).
    LOS by mj_ray between the two sites through geoms of groups `los_groups` (0: obstacles and
    floor, 3: vehicle collision boxes), ignoring both end vehicles. nlos: what a blocked link does
    ("bias": + nlos_bias_per_m x blocked span + Exp(mean nlos_bias_mean), noise x
    nlos_noise_factor; "drop": not reported; "ignore": only flagged). Gross outliers: probability
    outlier_prob, N(0, outlier_sigma^2) added. schedule: which links each sample serves
    ([sensors.uwb.schedule]; default all).
    """

    preset: Literal["paper001", "dw1000", "ideal"] = "paper001"
    rate_hz: float = 10.0
    latency: float = 0.0
    tags: tuple[str, ...] = ("uwb",)
    anchor_links: bool = True
    tag_links: bool = True
    max_range: float = 100.0
    link_search: Literal["all-pairs", "in-range"] = "all-pairs"
    los_groups: tuple[int, ...] = (0, 3)
    noise: float | None = None
    loss_prob: float | None = None
    clock_ppm: float | None = None
    mode: Literal["scale", "ss-twr", "ds-twr"] | None = None
    reply_time: float | None = None
    antenna_delay_sigma: float | None = None
    link_bias_sigma: float | None = None
    nlos: Literal["bias", "drop", "ignore"] | None = None
    nlos_bias_mean: float | None = None
    nlos_bias_per_m: float | None = None
    nlos_noise_factor: float | None = None
    outlier_prob: float | None = None
    outlier_sigma: float | None = None
    schedule: UwbSchedule = field(default_factory=UwbSchedule)

    def __post_init__(self) -> None:
        _fill(self, UWB_PRESETS[self.preset])
        _check_rate(self)  # first: the slot's message divides by rate_hz
        require(self.schedule.policy == "all" or self.schedule.slot_s * self.rate_hz <= 1, "schedule.slot_s", self.schedule.slot_s,
                f"one slot must fit in the {1 / self.rate_hz:g} s cycle of rate_hz = {self.rate_hz:g} Hz")
        in_range(self, "max_range", 0, lo_open=True, unit="m")
        require(len(self.tags) > 0 and len(set(self.tags)) == len(self.tags) and all(t in TAG_SITES for t in self.tags),
                "tags", list(self.tags), f"expected distinct antenna sites of the vehicle model, of {list(TAG_SITES)}")
        require(all(0 <= g <= 5 for g in self.los_groups), "los_groups", self.los_groups, f"geom groups are 0..5, got {list(self.los_groups)}")
        for k in ("noise", "clock_ppm", "reply_time", "antenna_delay_sigma", "link_bias_sigma", "nlos_bias_mean", "nlos_bias_per_m", "outlier_sigma"):
            in_range(self, k, 0)
        in_range(self, "nlos_noise_factor", 1)
        for k in ("loss_prob", "outlier_prob"):
            in_range(self, k, 0, 1, hi_open=True)


# ------------------------------------------------------------------------------------- phase


@dataclass(frozen=True, kw_only=True, slots=True)
class PhaseConfig:
    """[sensors.phase]: carrier phase between the masters' and the follower's ant1..3 (seed 003).

    Every master antenna i (slot 1..3, wavelength wavelengths[i-1], m) to every follower antenna
    j. The receiver samples the wrapped phase every T = 1/phase_rate_hz s; every 1/rate_hz s it
    reports the phase, the ambiguity-resolved range and the eq. 7 range rate averaged over
    rate_periods = N + 1 periods. phase_noise: white, 1 sigma in range terms (m);
    coarse_noise: 1 sigma of the coarse range used to fix integers (m); slip_prob: injected cycle
    slip probability per link per phase sample, +/-1..slip_max_cycles cycles;
    master_pos_noise / master_vel_noise: 1 sigma white error (m, m/s) of the masters' own
    navigation solution logged in phase/master_pos, phase/master_vel.
    """

    preset: Literal["paper003", "ideal"] = "paper003"
    rate_hz: float = 10.0
    phase_rate_hz: float = 50.0
    rate_periods: int = 35
    latency: float = 0.0
    masters: tuple[int, ...] = (1, 2, 3, 4, 5)
    follower: int = 6
    wavelengths: tuple[float, float, float] = (1.0, 2.0, 3.0)
    slip_max_cycles: int = 3
    phase_noise: float | None = None
    coarse_noise: float | None = None
    slip_prob: float | None = None
    master_pos_noise: float | None = None
    master_vel_noise: float | None = None

    def __post_init__(self) -> None:
        _fill(self, PHASE_PRESETS[self.preset])
        _check_rate(self)
        require(self.phase_rate_hz > 0 and whole_ratio(self.phase_rate_hz, self.rate_hz), "phase_rate_hz", self.phase_rate_hz,
                f"must be a whole multiple of rate_hz = {self.rate_hz} Hz, got {self.phase_rate_hz}")
        in_range(self, "rate_periods", 1)
        require(len(self.masters) >= 1 and all(m >= 1 for m in self.masters), "masters", self.masters,
                f"need vehicle numbers >= 1, got {list(self.masters)}")
        require(self.follower >= 1 and self.follower not in self.masters, "follower", self.follower,
                f"must be a vehicle number that is not a master, got {self.follower}")
        in_range(self, "wavelengths", 0, lo_open=True, unit="m")
        in_range(self, "slip_max_cycles", 1)
        for k in ("phase_noise", "coarse_noise", "master_pos_noise", "master_vel_noise"):
            in_range(self, k, 0)
        in_range(self, "slip_prob", 0, 1, hi_open=True)
        lam = min(self.wavelengths)
        # Integer fixing rounds (coarse - phase range)/lambda: a 5 sigma total error must stay
        # inside half a cycle of the shortest wavelength.
        tot = (self.coarse_noise**2 + self.phase_noise**2) ** 0.5
        require(5 * tot < lam / 2, "coarse_noise", self.coarse_noise,
                f"coarse/phase noise {tot:.3f} m (1 sigma, with phase_noise) too large to fix integers of the {lam} m wavelength "
                "(need 5 sigma < lambda/2)")


# -------------------------------------------------------------------------------------- GNSS


@dataclass(frozen=True, kw_only=True, slots=True)
class GnssErrors:
    """Error model of one receiver class: white noise_h/noise_v (m, 1 sigma, east/north and up)
    plus a first-order Gauss-Markov bias bias_h/bias_v (m, steady-state 1 sigma) with time
    constant bias_tau (s; 0 = no bias)."""

    preset: Literal["spp", "spp-correlated", "rtk", "ideal"] = "spp"
    noise_h: float | None = None
    noise_v: float | None = None
    bias_h: float | None = None
    bias_v: float | None = None
    bias_tau: float | None = None

    def __post_init__(self) -> None:
        _fill(self, GNSS_PRESETS[self.preset])
        for k in ("noise_h", "noise_v", "bias_h", "bias_v", "bias_tau"):
            in_range(self, k, 0)
        require(self.bias_tau > 0 or (self.bias_h == 0 and self.bias_v == 0), "bias_tau", self.bias_tau,
                "a Gauss-Markov bias needs bias_tau > 0")


@dataclass(frozen=True, kw_only=True, slots=True)
class SkyConfig:
    """[sensors.gnss.sky]: GNSS availability and accuracy by sky visibility (testbed.sensors.sky).

    enabled: off by default (the receivers then always have a fix with the tables' sigmas).
    satellites: constellation size, all above elevation_mask_deg at t = 0 (deg). Each satellite
    moves along a great circle of the sky at rate_deg_s (deg/s; 0.0083 deg/s = 30 deg/h, the
    apparent motion of a GPS satellite); it is used only above the mask. Drawn from the stream
    "constellation". A satellite is blocked when the ray from the antenna towards it meets a geom
    of `groups` (0: obstacles and floor; 3 adds the other airframes) within ray_length (m).
    Accuracy: the receiver tables' noise and bias hold at the reference geometry hdop_ref,
    vdop_ref; a fix of the visible set scales them by HDOP / hdop_ref (east, north) and
    VDOP / vdop_ref (up). Fewer than min_satellites visible (4: three position coordinates and
    the clock) means no fix: no row.
    """

    enabled: bool = False
    satellites: int = 10
    elevation_mask_deg: float = 10.0
    rate_deg_s: float = 0.0083
    hdop_ref: float = 1.0
    vdop_ref: float = 1.5
    groups: tuple[int, ...] = (0,)
    ray_length: float = 1000.0
    min_satellites: int = 4

    def __post_init__(self) -> None:
        in_range(self, "satellites", 1, 64)
        in_range(self, "elevation_mask_deg", 0, 90, hi_open=True, unit="deg")
        in_range(self, "rate_deg_s", 0, 1, unit="deg/s")
        in_range(self, "hdop_ref", 0, lo_open=True)
        in_range(self, "vdop_ref", 0, lo_open=True)
        require(all(0 <= g <= 5 for g in self.groups), "groups", self.groups, f"geom groups are 0..5, got {list(self.groups)}")
        in_range(self, "ray_length", 0, lo_open=True, unit="m")
        in_range(self, "min_satellites", 4)


@dataclass(frozen=True, kw_only=True, slots=True)
class GnssConfig:
    """[sensors.gnss]: position of each vehicle's antenna in the world (ENU) frame.

    antenna: "uwb" (the uwb site on the mast, default) or "body" (the body origin / CoM).
    vehicles: 1-based numbers with a receiver (empty = all). rtk_vehicles: those using the `rtk`
    error table (empty: the swarm-box trajectory's `rtk` list if any). receiver / rtk: error
    tables [sensors.gnss.receiver], [sensors.gnss.rtk]. sky: visibility of a seeded
    constellation, DOP-scaled accuracy and no fix under cover ([sensors.gnss.sky], off by default).
    outages: scripted outage windows [[start, end], ...] (s): no receiver has a fix (no rows) at
    a sample time t with start <= t < end (the random draws are made all the same).
    """

    rate_hz: float = 5.0
    latency: float = 0.0
    antenna: Literal["uwb", "body"] = "uwb"
    vehicles: tuple[int, ...] = ()
    rtk_vehicles: tuple[int, ...] = ()
    receiver: GnssErrors = field(default_factory=lambda: GnssErrors(preset="spp"))
    rtk: GnssErrors = field(default_factory=lambda: GnssErrors(preset="rtk"))
    sky: SkyConfig = field(default_factory=SkyConfig)
    outages: tuple[tuple[float, float], ...] = key((), unit="s")

    def __post_init__(self) -> None:
        _check_rate(self)
        in_range(self, "vehicles", 1)
        in_range(self, "rtk_vehicles", 1)
        for k, w in enumerate(self.outages):
            require(len(w) == 2 and 0 <= w[0] < w[1] and all(math.isfinite(x) for x in w), f"outages[{k}]", list(w),
                    f"must be [start, end] with 0 <= start < end (s), got {list(w)}")


# ------------------------------------------------------------------------------------ camera


@dataclass(frozen=True, kw_only=True, slots=True)
class CameraConfig:
    """[sensors.camera]: the leader's `cam` camera sees the follower's LED beacons (seed 004).

    mode "geometric": projection of the LED centres (eqs. 5-6, 9-10) with eq. 8 / eq. 13 noise of
    sigma (rad) and d (eq. 8), glint contamination (probability glint_prob, std x glint_factor);
    "pixels": offscreen render + OpenCV detection (no added noise). focal_length (m) scales
    alpha, beta (paper: 1 m). min_depth (m): LEDs closer than this along the optical axis are
    not seen.
    """

    preset: Literal["paper004", "gaussian", "ideal"] = "paper004"
    mode: Literal["geometric", "pixels"] = "geometric"
    rate_hz: float = 10.0
    latency: float = 0.0
    leader: int = 1
    follower: int = 2
    focal_length: float = 1.0
    min_depth: float = 0.05
    sigma: float | None = None
    d: float | None = None
    glint_prob: float | None = None
    glint_factor: float | None = None

    def __post_init__(self) -> None:
        _fill(self, CAMERA_PRESETS[self.preset])
        _check_rate(self)
        in_range(self, "leader", 1)
        in_range(self, "follower", 1)
        require(self.leader != self.follower, "follower", self.follower, f"must differ from the leader {self.leader}")
        in_range(self, "focal_length", 0, lo_open=True, unit="m")
        in_range(self, "sigma", 0)
        in_range(self, "d", 0)
        in_range(self, "glint_prob", 0, 1, hi_open=True)
        in_range(self, "glint_factor", 1)


# ------------------------------------------------------------------------------------- table


@dataclass(frozen=True, kw_only=True, slots=True)
class SensorsConfig:
    """Which sensors a scenario carries; a missing table means the stream is off."""

    imu: ImuConfig | None = None
    uwb: UwbConfig | None = None
    phase: PhaseConfig | None = None
    gnss: GnssConfig | None = None
    camera: CameraConfig | None = None

    def streams(self) -> dict[str, object]:
        """The configured streams by name, in a fixed order."""
        return {n: getattr(self, n) for n in ("imu", "uwb", "phase", "gnss", "camera") if getattr(self, n) is not None}

    def cross_check(self, control_rate: float, vehicles: int, at: str) -> None:
        """Every stream's sampling rate must divide the control rate; vehicle numbers must exist.

        control_rate: world.control_rate (Hz); vehicles: the scenario's vehicle count; at: the
        dotted path of this table (`sensors`). Raises FieldError naming the full key.
        """
        for name, cfg in self.streams().items():
            key = "phase_rate_hz" if name == "phase" else "rate_hz"
            rate = getattr(cfg, key)
            require(whole_ratio(control_rate, rate), join_key(at, f"{name}.{key}"), rate,
                    f"{rate:g} Hz does not divide the control rate {control_rate:g} Hz (world.control_rate); use {_divisors(control_rate)} Hz")
            for key in _VEHICLE_KEYS[name]:
                nums = getattr(cfg, key)
                require(all(1 <= v <= vehicles for v in (nums if isinstance(nums, tuple) else (nums,))),
                        join_key(at, f"{name}.{key}"), nums, f"vehicle numbers must be in 1..{vehicles}, got {nums}")


# The keys of each stream that hold 1-based vehicle numbers.
_VEHICLE_KEYS = {"imu": ("vehicles",), "uwb": (), "phase": ("masters", "follower"), "gnss": ("vehicles", "rtk_vehicles"),
                 "camera": ("leader", "follower")}


def _divisors(rate: float) -> str:
    r = int(round(rate))
    return ", ".join(str(r // k) for k in range(1, r + 1) if r % k == 0 and r // k >= 1)[:80]
