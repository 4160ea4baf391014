"""Plugin estimators for tests/test_loop.py (loaded by path: `tests/loop_plugins.py:Name`)."""
from __future__ import annotations

import numpy as np

from testbed.plugins import Estimate

SEEN: list = []  # every Measurement a Recording instance was fed, in order (this process)


class GnssEcho:
    """Each GNSS fix minus the antenna lever arm (attitude ignored) as the body position."""

    def __init__(self, context, params):
        self.sites = context.sites

    def process(self, m):
        if m.stream != "gnss":
            return []
        body, arm = self.sites.get(m.src, (m.src.partition("/")[0], np.zeros(3)))
        return [Estimate(time=m.time, target=body, quantity="position", value=np.asarray(m.value) - arm)]


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
