"""The network a distributed estimator's messages travel through, handed to it by the runtime
(Context.channel) when the scenario has a [network] table (testbed.sim.network, docs/network.md).

The channel is the simulator's, not the estimator's: its geometry is the true one of the run (the
uwb sites' true positions at the solve's time for the range limit, and the NLOS flags of the pairs
ranged at that instant, pairs not ranged counting as line of sight), read from the log here. The
estimator only asks `transport(t)` for the rounds of one solve starting at t s and gets an
estimators.transport.Transport (testbed.sim.network.RoundTransport: round r starts at t + r round_s;
a message counts in its round only if it arrives within it). Each estimator has a network of its
own, drawn from the stream "network/NAME" of the seed; its counts (`stats`) go to metrics.json
under the estimator's `network` when it used it.
"""
from __future__ import annotations

import numpy as np

from testbed.sim.network import Network, NetworkConfig, RoundTransport
from testbed.plugins.truth import Truth
from testbed.rng import stream_rng


def uwb_rows(log: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The uwb rows of a run log a Channel reads: time, src, dst, nlos (none without a uwb stream)."""
    if "uwb/time" not in log:
        return {"time": np.zeros(0), "src": np.zeros(0, str), "dst": np.zeros(0, str), "nlos": np.zeros(0, bool)}
    return {k: log[f"uwb/{k}"] for k in ("time", "src", "dst", "nlos")}


class Channel:
    """One estimator's network in one run. config: the scenario's [network]; truth: the run's
    (testbed.plugins.truth.Truth, or a replay's testbed.replay.recording.RecordedTruth: `at` of a
    site's position); uwb: the run's uwb rows, for NLOS (`uwb_rows`: time (n,) s, src, dst (n,)
    site names, nlos (n,) bool); vehicles: body names in node order (node i is `vehicles[i]`, its
    radio the site `vehicles[i]/uwb`); seed, key: the scenario seed and the estimator's name (the
    network's random stream)."""

    def __init__(self, config: NetworkConfig, truth: Truth, uwb: dict[str, np.ndarray], vehicles: tuple[str, ...],
                 seed: int, key: str):
        self.config, self.truth, self.vehicles = config, truth, vehicles
        self.network = Network(config, len(vehicles), stream_rng(seed, f"network/{key}"))
        self.late = 0
        self.used = False  # a transport was asked for
        self._open: list[RoundTransport] = []
        node = {f"{v}/uwb": i for i, v in enumerate(vehicles)}
        src, dst = uwb["src"].astype(str), uwb["dst"].astype(str)
        tag = np.array([s in node and d in node for s, d in zip(src, dst)], bool)
        self._uwb_time = uwb["time"][tag]
        self._pairs = np.array([[node[s], node[d]] for s, d in zip(src[tag], dst[tag])], np.int64).reshape(-1, 2)
        self._nlos = uwb["nlos"][tag].astype(bool)

    def transport(self, t: float) -> RoundTransport:
        """The transport of one solve of synchronous rounds starting at t (s), the channel's
        geometry set to the true one at t."""
        n = len(self.vehicles)
        pos = np.concatenate([self.truth.at(f"{v}/uwb", "position", np.array([t])) for v in self.vehicles])
        los = np.ones((n, n), bool)
        e = self._pairs[(np.abs(self._uwb_time - t) < 1e-9) & self._nlos]
        los[e[:, 0], e[:, 1]] = los[e[:, 1], e[:, 0]] = False
        self.network.set_geometry(t, pos, los)
        self._collect()
        self.used = True
        self._open.append(self.network.rounds(t, self.config.round_s))
        return self._open[-1]

    def _collect(self) -> None:
        self.late += sum(tr.late for tr in self._open)
        self._open.clear()

    def stats(self) -> dict[str, float] | None:
        """Network.stats() plus `late` (messages that arrived after their round), or None when
        the estimator never asked for a transport."""
        self._collect()
        return {**self.network.stats(), "late": float(self.late)} if self.used else None
