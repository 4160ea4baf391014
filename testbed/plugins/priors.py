"""The priors the runtime hands the papers' built-in estimators (Context.prior), by scenario kind.

Drawn from the scenario's streams and, where the paper starts from the truth plus a drawn error,
from the run log's truth: so this module is the workflow's (tests/test_architecture.py), beside
testbed.plugins.run that calls it; the estimators only ever see the result.
"""
from __future__ import annotations

import numpy as np

from testbed.plugins import builtin_phase
from testbed.plugins.builtin_bandwidth import initial_estimate
from testbed.plugins.relnav_scores import start_prior
from testbed.config.scenario import Scenario


def priors(scenario: Scenario, log: dict[str, np.ndarray] | None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The prior the scenario's built-in estimators get, by target, in their own state (the
    runtime's: drawn here from the scenario streams and, where the paper starts from the truth
    plus a drawn error, the log's truth; the estimators never read it):

    coop-fg: none (every epoch is anchored by its GNSS fixes alone);
    phase-ekf: {"uavF": (18,), (18, 18)} the follower's antenna state of estimators.phase_ekf in
      the navigation frame N at the first phase epoch (planned state + the drawn initial error);
    visnav: {"uavF": (22,), (21, 21)} the follower's state relative to the leader
      (estimators.visnav layout) at the first IMU sample (truth + the drawn initial error);
    bandwidth: {"formation": (3,), (3, 3)} every node's initial estimate of the formation point
      (m, world) and M(0).
    Empty without a log or a pipeline.
    """
    kind = getattr(scenario.pipeline, "kind", None)
    if log is None or kind not in ("phase-ekf", "visnav", "bandwidth"):
        return {}
    if kind == "phase-ekf":
        _, inp, _, prior, _, _ = builtin_phase.prepare(scenario, log)
        return {f"uav{inp.follower}": (prior.mean, prior.cov)}
    if kind == "visnav":
        prior = start_prior(scenario, log)
        return {f"uav{scenario.sensors.camera.follower}": (prior.mean, prior.cov)}
    cfg = scenario.pipeline
    return {"formation": (initial_estimate(cfg, scenario.seed), np.diag(cfg.M0))}
