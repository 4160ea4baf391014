"""Simulated sensors computed from the MuJoCo state: imu, uwb, phase, gnss, camera.

`make_sensors(scenario, physics)` builds the streams a scenario's [sensors.*] tables switch on,
each with its own generator `stream_rng(scenario.seed, NAME)`, so adding a stream never changes
another stream's numbers. See docs/sensors.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from testbed.config import ConfigError
from testbed.rng import stream_rng

if TYPE_CHECKING:
    from testbed.scenario import Scenario
    from testbed.sensors.base import Sensor
    from testbed.world import Physics


def validate(scenario: "Scenario") -> None:
    """Cross-checks of [sensors.*] against the world: rates divide world.control_rate, vehicle
    numbers exist. Raises ConfigError naming the key."""
    try:
        scenario.sensors.check_rates(scenario.world.control_rate, scenario.vehicles)
    except ValueError as e:
        key, msg = e.args if len(e.args) == 2 else ("", e.args[0])
        raise ConfigError(f"{scenario.name}: sensors.{key}: {msg}") from None


def make_sensors(scenario: "Scenario", physics: "Physics") -> list["Sensor"]:
    """The sensors a scenario carries, each with its own seeded generator."""
    from testbed.scenario import SwarmBox
    from testbed.sensors.camera import Camera
    from testbed.sensors.gnss import Gnss
    from testbed.sensors.imu import Imu
    from testbed.sensors.phase import Phase
    from testbed.sensors.uwb import Uwb

    validate(scenario)
    rate = scenario.world.control_rate
    tick = 1.0 / rate
    cfg = scenario.sensors
    seed = scenario.seed

    def ticks(hz: float) -> int:
        return int(round(rate / hz))

    out: list = []
    if cfg.imu is not None:
        out.append(Imu(cfg.imu, physics, stream_rng(seed, "imu"), ticks(cfg.imu.rate_hz), tick))
    if cfg.uwb is not None:
        out.append(Uwb(cfg.uwb, physics, stream_rng(seed, "uwb"), ticks(cfg.uwb.rate_hz), len(scenario.world.anchors)))
    if cfg.phase is not None:
        out.append(Phase(cfg.phase, physics, stream_rng(seed, "phase"), ticks(cfg.phase.phase_rate_hz), tick))
    if cfg.gnss is not None:
        rtk = scenario.trajectory.rtk if isinstance(scenario.trajectory, SwarmBox) else ()
        out.append(Gnss(cfg.gnss, physics, stream_rng(seed, "gnss"), ticks(cfg.gnss.rate_hz), tick, rtk))
    if cfg.camera is not None:
        out.append(Camera(cfg.camera, physics, stream_rng(seed, "camera"), ticks(cfg.camera.rate_hz)))
    return out
