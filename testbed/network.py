"""The network between vehicles: latency, loss, range and bandwidth, delivered by the simulation clock.

`Network(cfg, n, rng)` carries messages between n vehicles (0-based indices; time in s, the
simulation clock). The model of every key is in testbed.network_config.NetworkConfig and
docs/network.md. Order of the checks of one message on the directed link src -> dst:

1. range: |p_src - p_dst| > max_range (positions of the last set_geometry) -> dropped ("range");
2. budget: the token bucket (sender's once per transmission, or the receiver's: budget_on)
   cannot pay nbytes -> dropped ("budget"). Buckets refill at `bandwidth` bytes/s up to the depth;
3. loss: the link's Gilbert-Elliott chain steps, then the message is lost if
   u1 < loss_prob or u2 < ge_loss(state) or (NLOS and u3 < nlos_loss) -> dropped ("loss");
4. otherwise it is queued with arrival = t + latency draw, and `receive(t, dst)` hands it over
   once arrival <= t, in arrival order (ties: send order).

Seeding: every directed link draws from its own generator, the child "link{src}-{dst}" of the
network's generator (testbed.sensors.noise.device_rng), created when the link first carries a
message: its first draw is the chain's initial state (stationary: bad with probability
ge_p / (ge_p + ge_r)), then per message four uniforms and one normal, whatever the outcome. So a
link's draws depend only on the seed, the stream and its own traffic. cfg None: ideal (no draws,
arrival = t, nothing dropped).
"""
from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass

import numpy as np

from testbed.network_config import NetworkConfig
from testbed.sensors.noise import device_rng

__all__ = ["Message", "Network", "NetworkConfig", "RoundTransport", "stationary_loss"]

BLOCK = 64  # draws fetched per link at a time


@dataclass(frozen=True, kw_only=True, slots=True)
class Message:
    """One delivered message: sent, arrival (s), src, dst (0-based), nbytes, payload (as sent)."""

    sent: float
    arrival: float
    src: int
    dst: int
    nbytes: int
    payload: object


def stationary_loss(cfg: NetworkConfig) -> float:
    """Loss probability of a LOS link in range with an unlimited budget: the independent loss
    and the Gilbert-Elliott chain's stationary loss pi_G ge_loss_good + pi_B ge_loss_bad,
    pi_B = ge_p / (ge_p + ge_r), combined as independent causes."""
    pi_b = cfg.ge_p / (cfg.ge_p + cfg.ge_r)
    ge = (1 - pi_b) * cfg.ge_loss_good + pi_b * cfg.ge_loss_bad
    return 1 - (1 - cfg.loss_prob) * (1 - ge)


class _Link:
    """Draws and chain state of one directed link."""

    __slots__ = ("rng", "bad", "u", "z", "k")

    def __init__(self, rng: np.random.Generator, pi_bad: float):
        self.rng = rng
        self.bad = bool(rng.random() < pi_bad)
        self.k = BLOCK

    def next(self) -> tuple[list[float], float]:
        """Four uniforms (loss, chain step, chain loss, NLOS loss) and one standard normal (latency)."""
        if self.k == BLOCK:  # as Python floats: compared one message at a time
            self.u, self.z, self.k = self.rng.random((BLOCK, 4)).tolist(), self.rng.standard_normal(BLOCK).tolist(), 0
        k = self.k
        self.k += 1
        return self.u[k], self.z[k]


class Network:
    """Messages between n vehicles over the links of `cfg` (module docstring); cfg None: ideal.

    rng: the network's generator (testbed.rng.stream_rng(seed, "network") or a name of the
    caller's choosing); every link spawns its own child from it.
    """

    def __init__(self, cfg: NetworkConfig | None, n: int, rng: np.random.Generator):
        self.cfg, self.n, self.rng = cfg, int(n), rng
        self.ideal = cfg is None or cfg == NetworkConfig()
        self.pos: np.ndarray | None = None
        self.los: np.ndarray | None = None
        self._links: dict[tuple[int, int], _Link] = {}
        self._pi_bad = 0.0 if cfg is None else cfg.ge_p / (cfg.ge_p + cfg.ge_r)
        depth = 0.0 if cfg is None else cfg.depth
        self._tokens = np.full(self.n, float(depth))  # bytes in each vehicle's bucket
        self._t_tokens = np.full(self.n, -math.inf)  # time of the last refill (s); -inf: full
        self._queues: list[list] = [[] for _ in range(self.n)]  # per dst: heap of (arrival, seq, Message)
        self._seq = itertools.count()
        self._count = dict(sent=0, dropped_range=0, dropped_budget=0, dropped_loss=0, delivered=0)
        self._bytes = dict(bytes_sent=0, bytes_delivered=0)
        self._latency: list[float] = []

    # ------------------------------------------------------------------------------ channel
    def set_geometry(self, t: float, pos: np.ndarray, los: np.ndarray | None = None) -> None:
        """Positions pos (n, 3) m world (the physical channel may use true positions) and line of
        sight los (n, n) bool (None: all LOS) for the messages sent from now on; t (s) unused
        by the model, kept for the record."""
        self.pos = np.asarray(pos, float).reshape(self.n, 3)
        self.los = None if los is None else np.asarray(los, bool).reshape(self.n, self.n)

    def _pay(self, t: float, who: np.ndarray, nbytes: int) -> np.ndarray:
        """Take nbytes from the buckets of vehicles `who` (k,) at time t: (k,) bool paid."""
        cfg = self.cfg
        if cfg is None or cfg.bandwidth == 0:
            return np.ones(len(who), bool)
        dt = np.maximum(t - self._t_tokens[who], 0.0)  # time never runs backwards for a bucket
        tokens = np.minimum(cfg.depth, self._tokens[who] + cfg.bandwidth * dt)
        ok = tokens >= nbytes - 1e-9 * nbytes  # refills that should add up exactly may round below
        self._tokens[who] = np.where(ok, tokens - nbytes, tokens)
        self._t_tokens[who] = np.maximum(self._t_tokens[who], t)
        return ok

    def _link(self, src: int, dst: int) -> _Link:
        link = self._links.get((src, dst))
        if link is None:
            link = self._links[(src, dst)] = _Link(device_rng(self.rng, f"link{src}-{dst}"), self._pi_bad)
        return link

    def _latency_draw(self, z: float) -> float:
        cfg = self.cfg
        if cfg.jitter_model == "normal":
            return max(0.0, cfg.latency + cfg.jitter * z)
        return cfg.latency + cfg.jitter * math.exp(cfg.jitter_shape * z)

    # ------------------------------------------------------------------------------ sending
    def multicast(self, t: float, src: int, dsts: np.ndarray, nbytes: int, payload: object) -> np.ndarray:
        """One transmission of src at t (s) to the vehicles dsts (k,): (k,) arrival times (s),
        inf where dropped. With budget_on "send" the sender pays nbytes once."""
        dsts = np.asarray(dsts, dtype=int).reshape(-1)
        k = len(dsts)
        self._count["sent"] += k
        self._bytes["bytes_sent"] += k * int(nbytes)
        arrival = np.full(k, float(t))
        if not self.ideal:
            arrival = self._channel(t, int(src), dsts, int(nbytes))
        t, src, nbytes = float(t), int(src), int(nbytes)
        queues, seq, latency = self._queues, self._seq, self._latency
        for d, a in zip(dsts.tolist(), arrival.tolist()):
            if a < math.inf:
                heapq.heappush(queues[d], (a, next(seq), Message(sent=t, arrival=a, src=src, dst=d, nbytes=nbytes, payload=payload)))
                latency.append(a - t)
        return arrival

    def _channel(self, t: float, src: int, dsts: np.ndarray, nbytes: int) -> np.ndarray:
        """Arrival times (k,) of one transmission (inf: dropped), steps 1-3 of the module docstring."""
        cfg = self.cfg
        arrival = np.full(len(dsts), math.inf)
        live = np.ones(len(dsts), bool)
        if cfg.max_range > 0 and self.pos is not None:
            live &= np.linalg.norm(self.pos[dsts] - self.pos[src], axis=1) <= cfg.max_range
            self._count["dropped_range"] += int((~live).sum())
        if cfg.budget_on == "send":
            if live.any() and not self._pay(t, np.array([src]), nbytes)[0]:
                self._count["dropped_budget"] += int(live.sum())
                live[:] = False
        elif live.any():
            paid = self._pay(t, dsts[live], nbytes)
            self._count["dropped_budget"] += int((~paid).sum())
            live[np.flatnonzero(live)[~paid]] = False
        los = None if self.los is None else self.los[src].tolist()
        links, dropped = self._links, 0
        for j, d in zip(np.flatnonzero(live).tolist(), dsts[live].tolist()):
            link = links.get((src, d)) or self._link(src, d)
            u, z = link.next()
            # the chain steps once per message on the link, then its state sets the loss
            link.bad = (u[1] >= cfg.ge_r) if link.bad else (u[1] < cfg.ge_p)
            nlos = los is not None and not los[d]
            if u[0] < cfg.loss_prob or u[2] < (cfg.ge_loss_bad if link.bad else cfg.ge_loss_good) or (nlos and u[3] < cfg.nlos_loss):
                dropped += 1
            else:
                arrival[j] = t + self._latency_draw(z)
        self._count["dropped_loss"] += dropped
        return arrival

    def send(self, t: float, src: int, dst: int, nbytes: int, payload: object) -> bool:
        """Queue a message src -> dst at t (s); False if dropped (range, budget, loss)."""
        return bool(np.isfinite(self.multicast(t, src, np.array([dst]), nbytes, payload)[0]))

    def broadcast(self, t: float, src: int, nbytes: int, payload: object) -> int:
        """Send to every other vehicle (one transmission); returns how many were queued."""
        others = np.delete(np.arange(self.n), src)
        return int(np.isfinite(self.multicast(t, src, others, nbytes, payload)).sum())

    # ---------------------------------------------------------------------------- receiving
    def receive(self, t: float, dst: int) -> list[Message]:
        """Messages for dst with arrival <= t, in arrival order, removed from the queue."""
        q = self._queues[dst]
        out = []
        while q and q[0][0] <= t:
            msg = heapq.heappop(q)[2]
            out.append(msg)
        self._count["delivered"] += len(out)
        self._bytes["bytes_delivered"] += sum(m.nbytes for m in out)
        return out

    def stats(self) -> dict[str, float]:
        """Counts and latencies so far: sent, dropped (and by cause: dropped_range, dropped_budget,
        dropped_loss), queued (not dropped), delivered (handed over by receive), in_flight,
        bytes_sent, bytes_delivered, drop_fraction, latency_mean_s / _p50_s / _p95_s / _max_s over the
        queued messages (NaN when none was queued)."""
        c = self._count
        dropped = c["dropped_range"] + c["dropped_budget"] + c["dropped_loss"]
        lat = np.asarray(self._latency)
        pct = np.percentile(lat, [50, 95]) if lat.size else [math.nan] * 2
        return {
            **{k: float(v) for k, v in c.items()}, "dropped": float(dropped), "queued": float(len(lat)),
            "in_flight": float(len(lat) - c["delivered"]),
            **{k: float(v) for k, v in self._bytes.items()},
            "drop_fraction": dropped / c["sent"] if c["sent"] else math.nan,
            "latency_mean_s": float(lat.mean()) if lat.size else math.nan,
            "latency_p50_s": float(pct[0]), "latency_p95_s": float(pct[1]),
            "latency_max_s": float(lat.max()) if lat.size else math.nan,
        }


class RoundTransport:
    """estimators.transport.Transport over a Network for one solve of synchronous rounds.

    Round r starts at t0 + r round_s (s); each sender transmits its messages of the round as one
    multicast (a radio broadcast) and a message counts for the round only if it arrives by the
    round's end, t0 + (r + 1) round_s. Later arrivals are drained from the queues (and counted in
    `late`), never used.
    """

    def __init__(self, network: Network, t0: float, round_s: float):
        self.network, self.t0, self.round_s = network, float(t0), float(round_s)
        self.late = 0

    def deliver(self, rnd: int, src: np.ndarray, dst: np.ndarray, nbytes: int) -> np.ndarray:
        t = self.t0 + rnd * self.round_s
        end = t + self.round_s
        ok = np.zeros(len(src), bool)
        for s in np.unique(src).tolist():
            sel = np.flatnonzero(src == s)
            arrival = self.network.multicast(t, s, dst[sel], nbytes, (rnd, s))
            ok[sel] = arrival <= end
            self.late += int((np.isfinite(arrival) & (arrival > end)).sum())
        for d in np.unique(dst).tolist():
            self.network.receive(end, d)
        return ok
