"""Epoch grouping shared by the per-epoch protocol estimators (coop.*, coop.window*).

An epoch is every measurement of one time of validity. `EpochGrouping.process` closes the open
epoch when a measurement of a later time arrives (no look-ahead: the epoch is complete once time
has moved past it), then hands the measurement to `_take` if its src site is one the estimator
indexes; `finish` closes the last epoch. Subclasses define `index` ({src site: vehicle index}),
`_reset()` (empty epoch), `_take(i, m)` (add one measurement of vehicle i) and `_close()` (solve
the open epoch, return its estimates), and set `self.t = None` before the first measurement.
`equal_time_runs` cuts a batch's rows into instants (rows of one time).
"""
from __future__ import annotations

import numpy as np

from testbed.plugins.api import Estimate, Measurement


def equal_time_runs(t: np.ndarray) -> list[tuple[int, int]]:
    """(lo, hi) of each run of equal times in t (k,), in order."""
    cuts = (np.flatnonzero(np.diff(t)) + 1).tolist()
    return list(zip([0, *cuts], [*cuts, len(t)]))


class EpochGrouping:
    index: dict[str, int]
    t: float | None

    def _reset(self) -> None:
        raise NotImplementedError

    def _take(self, i: int, m: Measurement) -> None:
        raise NotImplementedError

    def _close(self) -> list[Estimate]:
        raise NotImplementedError

    def process(self, m: Measurement) -> list[Estimate]:
        out = []
        if self.t is not None and m.time > self.t:
            out = self._close()
            self._reset()
        self.t = m.time
        i = self.index.get(m.src)
        if i is not None:
            self._take(i, m)
        return out

    def finish(self) -> list[Estimate]:
        return self._close() if self.t is not None else []
