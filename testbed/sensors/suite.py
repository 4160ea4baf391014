"""The sensor suite of a scenario: `make_sensors(scenario, physics)`.

Builds the streams a scenario's [sensors.*] tables switch on, each with its own generator
`stream_rng(scenario.seed, NAME)`, so adding a stream never changes another stream's numbers.
Rates and vehicle numbers were checked when the scenario was built (SensorsConfig.cross_check).
"""
from __future__ import annotations

from testbed.rng import stream_rng
from testbed.config.scenario import Scenario, SwarmBox, SwarmGrid
from testbed.sensors.base import Sensor
from testbed.sensors.camera import Camera
from testbed.sensors.gnss import Gnss
from testbed.sensors.imu import Imu
from testbed.sensors.phase import Phase
from testbed.sensors.uwb import Uwb
from testbed.sim.world import Physics


def make_sensors(scenario: Scenario, physics: Physics) -> list[Sensor]:
    """The sensors a scenario carries, each with its own seeded generator, in stream order."""
    rate = scenario.world.control_rate
    tick = 1.0 / rate
    cfg = scenario.sensors
    seed = scenario.seed

    def ticks(hz: float) -> int:
        return int(round(rate / hz))

    out: list[Sensor] = []
    if cfg.imu is not None:
        out.append(Imu(cfg.imu, physics, stream_rng(seed, "imu"), ticks(cfg.imu.rate_hz), tick, scenario.motion == "flown"))
    if cfg.uwb is not None:
        out.append(Uwb(cfg.uwb, physics, stream_rng(seed, "uwb"), ticks(cfg.uwb.rate_hz), len(scenario.world.anchors)))
    if cfg.phase is not None:
        out.append(Phase(cfg.phase, physics, stream_rng(seed, "phase"), ticks(cfg.phase.phase_rate_hz), tick))
    if cfg.gnss is not None:
        rtk = scenario.trajectory.rtk if isinstance(scenario.trajectory, (SwarmBox, SwarmGrid)) else ()
        out.append(Gnss(cfg.gnss, physics, stream_rng(seed, "gnss"), ticks(cfg.gnss.rate_hz), tick, rtk,
                        stream_rng(seed, "constellation")))
    if cfg.camera is not None:
        out.append(Camera(cfg.camera, physics, stream_rng(seed, "camera"), ticks(cfg.camera.rate_hz)))
    return out
