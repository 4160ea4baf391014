"""Which pipeline runs each `[pipeline]` kind, and `run_pipeline`, the runner's one entry point.

A pipeline is a function `run(scenario, log, plots_dir) -> dict` returning the `estimators` object
of metrics.json (keyed by estimator name). A new kind adds its config dataclass to
testbed.pipelines.config (and to its `PipelineConfig` union) and its `run` here.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from testbed.pipelines import bandwidth, coop, phase, visnav
from testbed.scenario import Scenario

Pipeline = Callable[[Scenario, dict[str, np.ndarray], Path | None], dict]

PIPELINES: dict[str, Pipeline] = {
    "phase-ekf": phase.run,
    "visnav": visnav.run,
    "bandwidth": bandwidth.run,
    "coop-fg": coop.run,
}


def run_pipeline(scenario: Scenario, log: dict[str, np.ndarray], plots_dir: Path | None) -> dict:
    """Run the scenario's pipeline; a scenario without one scores nothing but tracking.

    log: the run log (stream name -> array); plots_dir: where to write figures (None: no plots).
    """
    if scenario.pipeline is None or scenario.pipeline.kind == "tracking":
        return {}
    return PIPELINES[scenario.pipeline.kind](scenario, log, plots_dir)
