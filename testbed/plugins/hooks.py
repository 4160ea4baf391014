"""The scoring hooks of a run (testbed.plugins.score.Hook): which extra scores its scenario and log
make possible, given to every estimator whose outputs fit.

`scenario_hooks(scenario, log)` builds them once per run, before the estimators are scored:
- on a seed 003 phase-ekf scenario (testbed.plugins.phase_scores.phase_hooks): `Bound`, the PCRB
  of the follower's body position, `PhaseWindow`, the scores in the navigation frame, and
  `PhaseScored`, the scores from score_start on (6-dof and 18-state ANEES);
- `CoopHook`, the seed 001 scores and figures of every vehicle's uwb site position at the GNSS
  epochs, on a coop-fg scenario (testbed.plugins.coop_scores);
- `FusionBound`, the seed 000 fusion bound (eqs. 12, 16) of every vehicle's uwb site position, on a
  bandwidth scenario (testbed.plugins.fusion_bound);
- `RelNav`, the seed 004 relative-frame scores and figures of the camera's follower relative to
  its leader, on a visnav scenario (testbed.plugins.relnav_scores).
A new hook is a Hook subclass (testbed.plugins.score) built here from what the scenario and log
hold; it must not depend on which estimator is scored, only on the outputs it is given.
"""
from __future__ import annotations

import numpy as np

from testbed.plugins.score import Hook
from testbed.config.scenario import Scenario


def scenario_hooks(scenario: Scenario, log: dict[str, np.ndarray]) -> list[Hook]:
    """The hooks of this run (possibly none). log: the run log (stream name -> array)."""
    hooks: list[Hook] = []
    if getattr(scenario.pipeline, "kind", None) == "phase-ekf":
        from testbed.plugins.phase_scores import phase_hooks  # lazy: the phase model, only for its scenarios

        hooks += phase_hooks(scenario, log)
    if getattr(scenario.pipeline, "kind", None) == "coop-fg":
        from testbed.plugins.coop_scores import coop_hook

        hooks.append(coop_hook(scenario, log))
    if getattr(scenario.pipeline, "kind", None) == "bandwidth":
        from testbed.plugins.fusion_bound import fusion_bound

        hooks.append(fusion_bound(scenario))
    if getattr(scenario.pipeline, "kind", None) == "visnav":
        from testbed.plugins.relnav_scores import relnav_hook

        hooks.append(relnav_hook(scenario))
    return hooks
