"""Typed access to one sensor stream of a run log (`Run.stream(name)`).

A stream's rows are what `log.npz` holds under `NAME/...` (the data contract, docs/usage.md
"Run directory"); `Stream` gives them names, shapes and units, and adds the sigma the scenario declares
for each row (`declared_sigma`), which the log does not store. Rows are in time order; row m was
measured from the MuJoCo state of log instant `state_index[m]` (so the truth of a measurement is
`run.truth(name).pos[stream.state_index]`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.sensor_models import gnss_sigma
from testbed.config import to_dict
from testbed.config.scenario import Scenario

_COMMON = ("time", "arrival", "state_index", "value", "clean", "src", "dst")


@dataclass(frozen=True, kw_only=True, slots=True)
class Stream:
    """One sensor stream, M rows of d-dimensional values.

    name: stream name (imu, uwb, phase, gnss, camera).
    time: (M,) s, time of validity; arrival: (M,) s, time + the declared latency.
    value: (M, d) measured; clean: (M, d) the same quantity computed from the physics without
      errors (truth, for scoring only). Units and frames per stream (docs/sensors.md): uwb (M, 1)
      range m; gnss (M, 3) antenna position m, world ENU; imu (M, 6) specific force m/s^2 and
      angular rate rad/s, imu site frame; phase (M, 3) wrapped phase rad, range m, eq. 7 range
      rate m/s; camera (M, 5) alpha, beta (focal-plane units) and unit line of sight (camera frame).
    state_index: (M,) int, the log instant (row of `Run.time`) the row was measured at.
    src, dst: (M,) str, site names of the link ends ("uav3/uwb", "anchor2"); dst is "" for a
      single-site stream (imu, gnss).
    sigma: (M, d) the 1-sigma white noise the scenario declares for each component (same units
      as value), or None where the stream has no single declared sigma (camera). Declared, not
      realised: NLOS, outliers, biases and clock errors come on top.
    nlos: (M,) bool, the link was blocked (uwb only; truth from mj_ray, for analysis), else None.
    extra: every other array of the stream (`uwb/outlier`, `gnss/rtk`, `imu/vehicle`, ...) by its
      short name.
    """

    name: str
    time: np.ndarray
    arrival: np.ndarray
    value: np.ndarray
    clean: np.ndarray
    state_index: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    sigma: np.ndarray | None
    nlos: np.ndarray | None
    extra: dict[str, np.ndarray]

    @property
    def los(self) -> np.ndarray | None:
        """(M,) bool: line of sight (the complement of nlos), or None where not modelled."""
        return None if self.nlos is None else ~self.nlos

    @property
    def error(self) -> np.ndarray:
        """(M, d) value - clean, in the units of value."""
        return self.value - self.clean

    def __len__(self) -> int:
        return len(self.time)


def stream_names(log: dict[str, np.ndarray]) -> list[str]:
    """Names of the sensor streams present in a log (those with a `NAME/value` array)."""
    return sorted(k.partition("/")[0] for k in log if k.endswith("/value") and k.count("/") == 1)


def stream_arrays(name: str, log: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The arrays of stream `name` keyed without the prefix: {"time": ..., "value": ..., ...}."""
    return {k.partition("/")[2]: v for k, v in log.items() if k.startswith(f"{name}/")}


def make_stream(name: str, log: dict[str, np.ndarray], scenario: Scenario) -> Stream:
    """The Stream `name` of a log written for `scenario`; KeyError naming the streams present."""
    if f"{name}/value" not in log:
        raise KeyError(f"no stream {name!r} in this run; streams: {', '.join(stream_names(log)) or 'none'}")
    arrays = stream_arrays(name, log)
    return Stream(
        name=name, **{k: arrays[k] for k in _COMMON},
        sigma=declared_sigma(name, arrays, scenario), nlos=arrays.get("nlos") if name == "uwb" else None,
        extra={k: v for k, v in arrays.items() if k not in _COMMON},
    )


def declared_sigma(name: str, arrays: dict[str, np.ndarray], scenario: Scenario) -> np.ndarray | None:
    """(M, d) 1-sigma of each row as the scenario's [sensors.NAME] table declares it: what a
    Stream carries and what an estimator plugin is told (testbed.plugins.feed).

    uwb: `noise` (m). gnss: gnss_sigma of the row's receiver table (rtk or receiver), by the fix
    type the receiver reports; with [sensors.gnss.sky] the logged `gnss/sigma`, that sigma scaled
    by the DOP of the row's visible satellites (testbed.sensors.gnss). imu: noise_density / sqrt(dt), dt = 1 / rate_hz, accel then gyro. phase:
    phase_noise as a phase (2 pi phase_noise / lambda rad), as a range (m) and, for the eq. 7
    rate, sqrt(2) phase_noise / (rate_periods T) m/s with T = 1 / phase_rate_hz. camera: None.
    """
    cfg = getattr(scenario.sensors, name, None)
    m = len(arrays["time"])
    if cfg is None or name == "camera":
        return None
    if name == "uwb":
        return np.full((m, 1), cfg.noise)
    if name == "gnss":
        if "sigma" in arrays:  # sky visibility: the DOP-scaled sigma of each row, as logged
            return arrays["sigma"]
        rtk = arrays["rtk"][:, None]
        return np.where(rtk, gnss_sigma(to_dict(cfg.rtk)), gnss_sigma(to_dict(cfg.receiver)))
    if name == "imu":
        root_dt = np.sqrt(1.0 / cfg.rate_hz)
        return np.tile([cfg.accel.noise_density / root_dt] * 3 + [cfg.gyro.noise_density / root_dt] * 3, (m, 1))
    if name == "phase":
        period = 1.0 / cfg.phase_rate_hz
        with np.errstate(divide="ignore"):
            rate = np.sqrt(2.0) * cfg.phase_noise / (arrays["rate_periods"] * period)
        return np.stack([2 * np.pi * cfg.phase_noise / arrays["wavelength"], np.full(m, cfg.phase_noise), rate], axis=1)
    return None
