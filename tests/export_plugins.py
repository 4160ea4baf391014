"""A plugin estimator for tests/test_export_replay.py (loaded by path: `tests/export_plugins.py:Echo`)."""
from __future__ import annotations

import numpy as np

from testbed.plugins import Estimate


class Echo:
    """What it was given, folded into one estimate per vehicle at finish (time: Context.duration):
    position = [a draw of Context.rng, the sum of Context.prior's means and covariances plus 1 when
    Context.motion is "flown", an order-sensitive fold of every measurement fed (time, value,
    sigma) but those of the streams the format does not carry whole (testbed.replay.export.LEFT_OUT):
    the camera's, and the phase stream's, which the export splits into phase and range-rate rows].
    Equal estimates in a run and in the replay of its export: the same Context and the same feed."""

    def __init__(self, context, params):
        self.context, self.fold, self.n = context, 0.0, 0

    def process(self, m):
        if m.stream not in ("camera", "phase", "range-rate"):
            sigma = 0.0 if m.sigma is None else float(np.sum(m.sigma))
            self.fold = 0.5 * self.fold + m.time + float(np.sum(m.value)) + sigma
            self.n += 1
        return []

    def finish(self):
        c = self.context
        prior = sum(float(np.sum(mean)) + float(np.sum(cov)) for mean, cov in c.prior.values()) + (c.motion == "flown")
        return [Estimate(time=c.duration, target=v, quantity="position",
                         value=np.array([c.rng.standard_normal(), prior, self.fold + self.n])) for v in c.vehicles]
