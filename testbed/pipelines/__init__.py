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


def register(kind: str) -> Callable[[Pipeline], Pipeline]:
    def deco(fn: Pipeline) -> Pipeline:
        _REGISTRY[kind] = fn
        return fn

    return deco


def run_pipeline(scenario, log: dict[str, np.ndarray], plots_dir: Path | None) -> dict:
    """Run the scenario's pipeline; a scenario without one scores nothing but tracking."""
    if scenario.pipeline is None or scenario.pipeline.kind == "tracking":
        return {}
    return _REGISTRY[scenario.pipeline.kind](scenario, log, plots_dir)
