"""[network]: the communication model between vehicles (testbed.sim.network, docs/network.md).

A missing table means an ideal network (no latency, no loss, no limits): every existing run is
unchanged. Units SI: s, m, bytes, bytes/s. Probabilities are per message and directed link.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from testbed.config import in_range, key, require


@dataclass(frozen=True, kw_only=True, slots=True)
class NetworkConfig:
    """[network]: latency, loss, range and bandwidth of every directed link (testbed.sim.network).

    Latency of a message (s): latency + jitter term. jitter_model "normal": jitter * z,
    z ~ N(0, 1), the total clipped at 0 (the configured percentiles hold while latency >= 3
    jitter); "lognormal": jitter * exp(jitter_shape * z) (median jitter, always positive).
    Loss (independent draws; a message is lost when any says so): loss_prob; a Gilbert-Elliott
    chain per directed link (states good / bad, stepped once per message on the link before its
    loss draw: good -> bad with ge_p, bad -> good with ge_r; loss probability ge_loss_good,
    ge_loss_bad in the state; started from its stationary distribution; ge_p = 0: off);
    nlos_loss when the link has no line of sight. max_range (m, 0 = unlimited): a receiver
    farther than that gets nothing. Bandwidth: a token bucket of bandwidth bytes/s per vehicle
    (0 = unlimited), depth burst_bytes (0: one second of bandwidth), full at the start; a message
    the bucket cannot pay is dropped (never delayed). budget_on "send": the sender pays once per
    transmission (a broadcast is one radio transmission); "receive": every receiver pays for what
    reaches it (seed 000's per-node budget t_i). round_s: length of one synchronous message
    round of a distributed estimator (s): a message is used in its round only if it arrives
    within the round.
    """

    latency: float = key(0.0, unit="s")
    jitter: float = key(0.0, unit="s")
    jitter_model: Literal["normal", "lognormal"] = "normal"
    jitter_shape: float = 0.5
    loss_prob: float = 0.0
    ge_p: float = 0.0
    ge_r: float = 1.0
    ge_loss_good: float = 0.0
    ge_loss_bad: float = 1.0
    nlos_loss: float = 0.0
    max_range: float = key(0.0, unit="m", range=">= 0; 0 = unlimited")
    bandwidth: float = key(0.0, unit="bytes/s", range=">= 0; 0 = unlimited")
    burst_bytes: float = key(0.0, unit="bytes", range=">= 0; 0 = one second of bandwidth")
    budget_on: Literal["send", "receive"] = "send"
    round_s: float = key(0.01, unit="s")

    def __post_init__(self) -> None:
        for k in ("latency", "jitter", "max_range", "bandwidth", "burst_bytes"):
            in_range(self, k, 0)
        in_range(self, "jitter_shape", 0, 5, lo_open=True)
        for k in ("loss_prob", "nlos_loss", "ge_loss_good", "ge_loss_bad", "ge_p"):
            in_range(self, k, 0, 1)
        in_range(self, "ge_r", 0, 1, lo_open=True)
        in_range(self, "round_s", 0, lo_open=True, unit="s")
        require(self.burst_bytes == 0 or self.bandwidth > 0, "burst_bytes", self.burst_bytes,
                "a bucket depth needs a bandwidth > 0 (bandwidth = 0: unlimited)")

    @property
    def depth(self) -> float:
        """Token bucket depth (bytes): burst_bytes, or one second of bandwidth."""
        return self.burst_bytes or self.bandwidth
