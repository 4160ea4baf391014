"""Simulated sensors computed from the MuJoCo state: imu, uwb, phase, gnss, camera."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from testbed.scenario import Scenario
    from testbed.sensors.base import Sensor
    from testbed.world import Physics


def make_sensors(scenario: "Scenario", physics: "Physics") -> list["Sensor"]:
    """The sensors a scenario carries, each with its own seeded generator."""
    return []
