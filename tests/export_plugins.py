"""A plugin estimator for tests/test_export_replay.py (loaded by path: `tests/export_plugins.py:Echo`)."""
from __future__ import annotations

import numpy as np

from testbed.plugins import Estimate


class Echo:
    """What it was given, folded into one estimate per vehicle at finish (time: Context.duration):
    position = [a draw of Context.rng, the sum of Context.prior's means and covariances plus 1 when
    Context.motion is "flown", an order-sensitive fold of every measurement fed (time, value,
    sigma, extra columns; a sigma that is not finite counts as none, as the export writes it:
    testbed.replay.export.left_out)].
    Equal estimates in a run and in the replay of its export: the same Context and the same feed."""

    def __init__(self, context, params):
        self.context, self.fold, self.n = context, 0.0, 0

    def process(self, m):
        finite = m.sigma is not None and bool(np.isfinite(m.sigma).all())
        extra = sum(float(np.sum(v)) for v in m.extra.values())
        self.fold = 0.5 * self.fold + m.time + float(np.nansum(m.value)) + (float(np.sum(m.sigma)) if finite else 0.0) + extra
        self.n += 1
        return []

    def finish(self):
        c = self.context
        prior = sum(float(np.sum(mean)) + float(np.sum(cov)) for mean, cov in c.prior.values()) + (c.motion == "flown")
        return [Estimate(time=c.duration, target=v, quantity="position",
                         value=np.array([c.rng.standard_normal(), prior, self.fold + self.n])) for v in c.vehicles]
