"""How a distributed estimator's messages travel: the transport protocols (no testbed import).

Two ways of sending, each a protocol the runtime implements over its network model
(testbed.sim.network) and hands to the estimator; anything with these methods works, so a
recorded or synthetic channel can be replayed here too.

- `Transport`: synchronous rounds of one solve. A distributed solver of this library calls
  `deliver` once per round with the directed messages it sends; the transport says which of them
  reach their receiver in time for that round's local step. None (the default of every solver)
  is the ideal channel: everything sent arrives.
- `Links`: timed broadcasts between n nodes (0-based), received when they have arrived, for an
  estimator that keeps its own clock of messages (a filter that hears its neighbours'
  broadcasts); `rounds` gives a `Transport` over the same links.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np


class Transport(Protocol):
    def deliver(self, rnd: int, src: np.ndarray, dst: np.ndarray, nbytes: int) -> np.ndarray:
        """(L,) bool: whether the message of sender src[l] to receiver dst[l] ((L,) 0-based node
        indices), nbytes bytes, sent at the start of round rnd (0-based) of the current solve,
        arrives before that round's local step."""


class Links(Protocol):
    """The directed links between n nodes (0-based), on the sender's clock (s)."""

    def set_geometry(self, t: float, pos: np.ndarray, los: np.ndarray | None = None) -> None:
        """Node positions pos (n, 3) m world and line of sight los (n, n) bool (None: all) for the
        messages sent from time t (s) on (the range limit and the NLOS loss read them)."""

    def broadcast_all(self, t: float, srcs: np.ndarray, nbytes: int, payloads: list) -> np.ndarray:
        """Each node of srcs (k,) (distinct) sends payloads[i] (nbytes bytes) to every other node at
        t (s); (k,) how many of each one's messages are under way (not dropped)."""

    def receive(self, t: float, dst: int) -> list:
        """The messages for node dst that have arrived by t (s), in arrival order, each handed over
        once: objects with sent, arrival (s), src, dst (0-based nodes), nbytes and payload (as sent)."""

    def rounds(self, t0: float, round_s: float) -> Transport:
        """A Transport for one solve over these links: round r starts at t0 + r round_s (s)."""

    def stats(self) -> dict[str, float]:
        """Counts so far (sent, delivered, dropped, bytes_sent, latency percentiles ...)."""
