"""Estimator-pipeline configuration of a scenario: a `[pipeline]` table discriminated by `kind`."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from testbed.pipelines.bandwidth import BandwidthConfig
from testbed.pipelines.coop import CoopConfig
from testbed.pipelines.phase import PhaseEkfConfig
from testbed.pipelines.visnav import VisnavConfig


@dataclass(frozen=True, kw_only=True, slots=True)
class TrackingOnly:
    """No estimator: the run scores only how well the vehicles tracked their references."""

    kind: Literal["tracking"]


PipelineConfig = TrackingOnly | PhaseEkfConfig | VisnavConfig | BandwidthConfig | CoopConfig
