"""Plugin estimators for tests/test_loop.py (loaded by path: `tests/loop_plugins.py:Name`)."""
from __future__ import annotations

import numpy as np

from testbed.bench.loop import Hold as GnssEcho  # each GNSS fix minus the antenna lever arm as the position
from testbed.plugins import Estimate

SEEN: list = []  # every Measurement a Recording instance was fed, in order (this process)


class Recording(GnssEcho):
    """GnssEcho that keeps every measurement it is fed in SEEN."""

    def __init__(self, context, params):
        super().__init__(context, params)
        SEEN.clear()

    def process(self, m):
        SEEN.append(m)
        return super().process(m)


class Silent:
    """Produces nothing."""

    def __init__(self, context, params):
        pass

    def process(self, m):
        return []


class NotANumber(GnssEcho):
    """A NaN position from the first GNSS fix on."""

    def process(self, m):
        return [Estimate(time=e.time, target=e.target, quantity="position", value=np.full(3, np.nan)) for e in super().process(m)]
