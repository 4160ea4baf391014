"""Sensor configuration of a scenario: one optional table per stream."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, kw_only=True, slots=True)
class SensorsConfig:
    """Which sensors a scenario carries; a missing table means the stream is off."""
