"""Seed 004 estimator pipeline (kind "visnav"): run log -> estimates, metrics, plots.

Must not import testbed.scenario, testbed.world or testbed.simulate at module level (the scenario
module imports this one for its configuration dataclass).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from testbed.pipelines import register


@dataclass(frozen=True, kw_only=True, slots=True)
class VisnavConfig:
    """[pipeline] table of a seed 004 scenario."""

    kind: Literal["visnav"]


@register("visnav")
def run(scenario, log, plots_dir):
    raise NotImplementedError("the seed 004 pipeline is being written")
