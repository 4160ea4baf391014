"""The interface every simulated sensor implements, and the stream buffer they share.

A sensor samples the MuJoCo state at its own instants (every `period_ticks` controller ticks),
draws its errors from its own generator (testbed.rng.stream_rng(seed, name)), and at the end
hands its arrays to the run log under the data-contract keys `NAME/time`, `NAME/value`,
`NAME/clean`, `NAME/state_index` and, for links, `NAME/src`, `NAME/dst`.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np

from testbed.world import Physics


class Sensor(Protocol):
    name: str
    period_ticks: int

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        """Measure at time t (s) from the current physics state; state_index into log `time`."""

    def arrays(self) -> dict[str, np.ndarray]:
        """Everything measured, keyed `NAME/...` as in the data contract."""
