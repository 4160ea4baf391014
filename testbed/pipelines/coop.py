"""Seed 001 estimator pipeline (kind "coop-fg"): run log -> estimates, metrics, plots.

Must not import testbed.scenario, testbed.world or testbed.simulate at module level (the scenario
module imports this one for its configuration dataclass).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from testbed.pipelines import register


@dataclass(frozen=True, kw_only=True, slots=True)
class CoopConfig:
    """[pipeline] table of a seed 001 scenario."""

    kind: Literal["coop-fg"]


@register("coop-fg")
def run(scenario, log, plots_dir):
    raise NotImplementedError("the seed 001 pipeline is being written")
