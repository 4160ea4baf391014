"""Which pipeline runs each `[pipeline]` kind not yet converted to plugins (testbed.plugins.defaults),
and `run_pipeline`, the runner's entry point for them (shrinking as each kind is converted).

A pipeline is a function `run(scenario, log, plots_dir) -> dict` returning the `estimators` object
of metrics.json (keyed by estimator name). A new kind adds its config dataclass to
testbed.config.pipelines (and to its `PipelineConfig` union) and its `run` here.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from testbed.pipelines import phase
from testbed.config.scenario import Scenario

Pipeline = Callable[[Scenario, dict[str, np.ndarray], Path | None], dict]

PIPELINES: dict[str, Pipeline] = {
    "phase-ekf": phase.run,
}


def run_pipeline(scenario: Scenario, log: dict[str, np.ndarray], plots_dir: Path | None) -> dict:
    """Run the scenario's pipeline; a scenario without one, or of a kind whose estimators run as
    plugins (testbed.plugins.defaults: coop-fg), has nothing to run here.

    log: the run log (stream name -> array); plots_dir: where to write figures (None: no plots).
    """
    if scenario.pipeline is None or scenario.pipeline.kind not in PIPELINES:
        return {}
    return PIPELINES[scenario.pipeline.kind](scenario, log, plots_dir)
