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


class Converging(GnssEcho):
    """GnssEcho with a position and a velocity (0) estimate whose declared covariances shrink:
    sigma^2 I with sigma = SIGMA0 / (1 + t) m and m/s (t s) (the initialization phase's release)."""

    SIGMA0 = 1.0

    def process(self, m):
        out = []
        for e in super().process(m):
            cov = (self.SIGMA0 / (1.0 + e.time)) ** 2 * np.eye(3)
            out += [Estimate(time=e.time, target=e.target, quantity="position", value=e.value, cov=cov),
                    Estimate(time=e.time, target=e.target, quantity="velocity", value=np.zeros(3), cov=cov)]
        return out


class ConvergingAttitude(Converging):
    """Converging, with an attitude estimate too (level, heading 0) declaring TILT rad of sigma
    about every axis: what [control] attitude = "estimate" flies on."""

    TILT = 0.05

    def process(self, m):
        out = super().process(m)
        return out + [Estimate(time=e.time, target=e.target, quantity="attitude", value=np.array([1.0, 0.0, 0.0, 0.0]),
                               cov=self.TILT ** 2 * np.eye(3)) for e in out if e.quantity == "position"]


class SiteEcho:
    """Each GNSS fix as the position of its antenna site ("uav1/uwb"): a site, where the
    controller needs the body."""

    def __init__(self, context, params):
        pass

    def process(self, m):
        return [Estimate(time=m.time, target=m.src, quantity="position", value=m.value)] if m.stream == "gnss" else []


class Sinking(GnssEcho):
    """GnssEcho HEIGHT m too high: the controller, believing it is above its path, flies the
    vehicle into the floor."""

    HEIGHT = 15.0

    def process(self, m):
        return [Estimate(time=e.time, target=e.target, quantity="position", value=e.value + [0.0, 0.0, self.HEIGHT])
                for e in super().process(m)]
