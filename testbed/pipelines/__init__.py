"""Estimator pipelines: turn a run log into estimates, metrics and plots, one per paper.

A pipeline is a function `(scenario, log, plots_dir) -> dict` registered under the `kind` of its
`[pipeline]` table; it returns the `estimators` object of metrics.json (keyed by estimator name).
Pipelines read measurement streams and configured "known" quantities; truth only for scoring.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

Pipeline = Callable[..., dict]
_REGISTRY: dict[str, Pipeline] = {}
_CHECKS: dict[str, Callable[..., None]] = {}


def register(kind: str, check: Callable[..., None] | None = None) -> Callable[[Pipeline], Pipeline]:
    """Register a pipeline; `check(scenario)` (optional) cross-checks the scenario at load time
    (sensors the pipeline needs, vehicle numbers) and raises ConfigError."""

    def deco(fn: Pipeline) -> Pipeline:
        _REGISTRY[kind] = fn
        if check is not None:
            _CHECKS[kind] = check
        return fn

    return deco


def check_pipeline(scenario) -> None:
    """Run the scenario's pipeline cross-checks, if it has any (called by Scenario.check)."""
    if scenario.pipeline is not None and scenario.pipeline.kind in _CHECKS:
        _CHECKS[scenario.pipeline.kind](scenario)


def run_pipeline(scenario, log: dict[str, np.ndarray], plots_dir: Path | None) -> dict:
    """Run the scenario's pipeline; a scenario without one scores nothing but tracking."""
    if scenario.pipeline is None or scenario.pipeline.kind == "tracking":
        return {}
    return _REGISTRY[scenario.pipeline.kind](scenario, log, plots_dir)
