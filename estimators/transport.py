"""How a distributed estimator's messages travel: the transport protocol (no testbed import).

A distributed estimator of this library calls `deliver` once per synchronous round with the
directed messages it sends; the transport says which of them reach their receiver in time for
that round's local step. None (the default of every solver) is the ideal channel: everything sent
arrives. The testbed implements it over its network model (testbed.sim.network.RoundTransport);
anything with this method works, so a recorded or synthetic channel can be replayed here too.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np


class Transport(Protocol):
    def deliver(self, rnd: int, src: np.ndarray, dst: np.ndarray, nbytes: int) -> np.ndarray:
        """(L,) bool: whether the message of sender src[l] to receiver dst[l] ((L,) 0-based node
        indices), nbytes bytes, sent at the start of round rnd (0-based) of the current solve,
        arrives before that round's local step."""
