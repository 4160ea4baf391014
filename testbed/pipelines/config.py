"""Estimator-pipeline configuration of a scenario: a table discriminated by `kind`."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True, kw_only=True, slots=True)
class TrackingOnly:
    """No estimator: the run scores only how well the vehicles tracked their references."""

    kind: Literal["tracking"]


PipelineConfig = TrackingOnly
