"""The network between vehicles: latency, loss, range and bandwidth, delivered by the simulation clock.

`Network(cfg, n, rng)` carries messages between n vehicles (0-based indices; time in s, the
simulation clock). The model of every key is in testbed.config.network.NetworkConfig and
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

from testbed.config.network import NetworkConfig
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


class _Links:
    """Draws and chain states of the directed links that have carried a message, one row each.

    A link's row holds its block of BLOCK draws, four uniforms (loss, chain step, chain loss,
    NLOS loss) and one standard normal (latency) per message, fetched from its own generator
    when the block is used up; `take` gives the next draw of several links at once."""

    def __init__(self, rng: np.random.Generator, n: int, pi_bad: float):
        self.rng, self.pi_bad = rng, pi_bad
        self.row = np.full((n, n), -1, dtype=np.intp)  # row of link src -> dst; -1: none yet
        self.rngs: list[np.random.Generator] = []
        self.bad = np.zeros(0, bool)  # (L,) the chain is in its bad state
        self.k = np.zeros(0, np.intp)  # (L,) draws of the block used
        self.u = np.zeros((0, BLOCK, 4))
        self.z = np.zeros((0, BLOCK))

    def rows(self, src: np.ndarray, dsts: np.ndarray) -> np.ndarray:
        """(k,) rows of the links src -> dsts (k,), created in order where missing: the child
        "link{src}-{dst}", its first draw the chain's stationary initial state."""
        rows = self.row[src, dsts]
        for s, d in zip(src[rows < 0].tolist(), dsts[rows < 0].tolist()):
            rng = device_rng(self.rng, f"link{s}-{d}")
            self.row[s, d] = len(self.rngs)
            self.rngs.append(rng)
            self.bad = np.append(self.bad, rng.random() < self.pi_bad)
            self.k = np.append(self.k, BLOCK)
            if len(self.rngs) > len(self.u):  # capacity doubles
                grow = max(len(self.u), 16)
                self.u = np.concatenate([self.u, np.zeros((grow, BLOCK, 4))])
                self.z = np.concatenate([self.z, np.zeros((grow, BLOCK))])
        return self.row[src, dsts]

    def take(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The next draw of each link of `rows` (distinct): uniforms (k, 4), normals (k,)."""
        for r in rows[self.k[rows] == BLOCK].tolist():  # a used-up block: the link's next BLOCK draws
            rng = self.rngs[r]
            self.u[r], self.z[r], self.k[r] = rng.random((BLOCK, 4)), rng.standard_normal(BLOCK), 0
        k = self.k[rows]
        self.k[rows] = k + 1
        return self.u[rows, k], self.z[rows, k]


class Network:
    """Messages between n vehicles over the links of `cfg` (module docstring); cfg None: ideal.
    An estimators.transport.Links; the runtime hands the class to the estimators as
    Context.open_network.

    rng: the network's generator (testbed.rng.stream_rng(seed, "network") or a name of the
    caller's choosing); every link spawns its own child from it.
    """

    def __init__(self, cfg: NetworkConfig | None, n: int, rng: np.random.Generator):
        self.cfg, self.n, self.rng = cfg, int(n), rng
        self.ideal = cfg is None or cfg == NetworkConfig()
        self.pos: np.ndarray | None = None
        self.los: np.ndarray | None = None
        self._links = _Links(rng, self.n, 0.0 if cfg is None else cfg.ge_p / (cfg.ge_p + cfg.ge_r))
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

    def _latency_draw(self, z: np.ndarray) -> np.ndarray:
        """Latencies (k,) s of standard normals z (k,) (NetworkConfig: jitter_model)."""
        cfg = self.cfg
        if cfg.jitter_model == "normal":
            return np.maximum(0.0, cfg.latency + cfg.jitter * z)
        # math.exp (the C library's), not numpy's: numpy picks an exp by the CPU's instruction set
        return cfg.latency + cfg.jitter * np.array([math.exp(cfg.jitter_shape * x) for x in z.tolist()])

    # ------------------------------------------------------------------------------ sending
    def multicast(self, t: float, src: int, dsts: np.ndarray, nbytes: int, payload: object) -> np.ndarray:
        """One transmission of src at t (s) to the vehicles dsts (k,): (k,) arrival times (s),
        inf where dropped. With budget_on "send" the sender pays nbytes once."""
        dsts = np.asarray(dsts, dtype=int).reshape(-1)
        return self._transmit(float(t), np.full(len(dsts), int(src)), dsts, int(nbytes), [payload], np.zeros(len(dsts), int))

    def broadcast_all(self, t: float, srcs: np.ndarray, nbytes: int, payloads: list) -> np.ndarray:
        """broadcast() of each vehicle of srcs (k,) (distinct) at t (s) in turn, payloads[i] from
        srcs[i], in one pass over their messages (the same draws, drops and queue order); (k,)
        how many of each were queued."""
        srcs = np.asarray(srcs, dtype=int).reshape(-1)
        k, others = len(srcs), np.arange(self.n - 1)
        dst = (others[None] + (others[None] >= srcs[:, None])).ravel()  # each sender's others, ascending
        which = np.repeat(np.arange(k), self.n - 1)
        arrival = self._transmit_grouped(float(t), srcs[which], dst, int(nbytes), payloads, which)
        return np.isfinite(arrival).reshape(k, self.n - 1).sum(axis=1)

    def _transmit_grouped(self, t: float, src: np.ndarray, dst: np.ndarray, nbytes: int, payloads: list,
                          which: np.ndarray, handed: float = -math.inf) -> np.ndarray:
        """The transmissions of several senders in turn: messages src -> dst (m,) grouped by
        sender (each sender's contiguous), sender group which (m,) (0, 1, .. in order) carrying
        payloads[which]; (m,) arrival times, inf where dropped. In one pass (`_transmit`: the
        same draws, drops and queue order as one multicast per sender) unless a receiver's
        bucket pays, which pays the senders one after the other (one `_transmit` each). handed:
        as `_transmit`'s."""
        if not (self.cfg is not None and self.cfg.bandwidth > 0 and self.cfg.budget_on == "receive"):
            return self._transmit(t, src, dst, nbytes, payloads, which, handed)
        cuts = np.flatnonzero(np.diff(which)) + 1
        return np.concatenate([np.zeros(0)] + [
            self._transmit(t, src[a:b], dst[a:b], nbytes, [payloads[which[a]]], np.zeros(b - a, int), handed)
            for a, b in zip([0, *cuts.tolist()], [*cuts.tolist(), len(which)]) if b > a])

    def _transmit(self, t: float, src: np.ndarray, dst: np.ndarray, nbytes: int, payloads: list, which: np.ndarray,
                  handed: float = -math.inf) -> np.ndarray:
        """Messages src -> dst (m,) at t (s) carrying payloads[which] (m,), grouped by sender (one
        transmission each), queued unless dropped: (m,) arrival times, inf where dropped.
        Those arriving by `handed` (s) are handed over at once instead, counted as a receive at
        that time would count them, never queued: for a caller that drains every receiver's queue
        then and discards what it gets (RoundTransport, which reads the arrival times)."""
        m = len(dst)
        self._count["sent"] += m
        self._bytes["bytes_sent"] += m * nbytes
        arrival = np.full(m, t) if self.ideal else self._channel(t, src, dst, nbytes)
        queued = np.flatnonzero(arrival < math.inf)
        self._latency.extend((arrival[queued] - t).tolist())
        now = arrival[queued] <= handed
        self._count["delivered"] += int(now.sum())
        self._bytes["bytes_delivered"] += int(now.sum()) * nbytes
        queues, seq = self._queues, self._seq
        late = queued[~now]
        for s, d, a, w in zip(src[late].tolist(), dst[late].tolist(), arrival[late].tolist(), which[late].tolist()):
            heapq.heappush(queues[d], (a, next(seq), Message(sent=t, arrival=a, src=s, dst=d, nbytes=nbytes, payload=payloads[w])))
        return arrival

    def _channel(self, t: float, src: np.ndarray, dsts: np.ndarray, nbytes: int) -> np.ndarray:
        """Arrival times (m,) of messages src -> dsts (m,), one transmission per sender (inf:
        dropped), steps 1-3 of the module docstring; with budget_on "receive", one sender."""
        cfg = self.cfg
        arrival = np.full(len(dsts), math.inf)
        live = np.ones(len(dsts), bool)
        if cfg.max_range > 0 and self.pos is not None:
            live &= np.linalg.norm(self.pos[dsts] - self.pos[src], axis=1) <= cfg.max_range
            self._count["dropped_range"] += int((~live).sum())
        if cfg.budget_on == "send":
            senders = np.unique(src[live])  # those with a receiver in range pay once
            unpaid = senders[~self._pay(t, senders, nbytes)] if senders.size else senders
            if unpaid.size:
                cut = live & np.isin(src, unpaid)
                self._count["dropped_budget"] += int(cut.sum())
                live &= ~cut
        elif live.any():
            paid = self._pay(t, dsts[live], nbytes)
            self._count["dropped_budget"] += int((~paid).sum())
            live[np.flatnonzero(live)[~paid]] = False
        sl, dl = src[live], dsts[live]
        if dl.size:
            rows = self._links.rows(sl, dl)
            u, z = self._links.take(rows)
            # the chain steps once per message on the link, then its state sets the loss
            bad = np.where(self._links.bad[rows], u[:, 1] >= cfg.ge_r, u[:, 1] < cfg.ge_p)
            self._links.bad[rows] = bad
            lost = (u[:, 0] < cfg.loss_prob) | (u[:, 2] < np.where(bad, cfg.ge_loss_bad, cfg.ge_loss_good))
            if self.los is not None:
                lost |= ~self.los[sl, dl] & (u[:, 3] < cfg.nlos_loss)
            self._count["dropped_loss"] += int(lost.sum())
            j = np.flatnonzero(live)[~lost]
            arrival[j] = t + self._latency_draw(z[~lost])
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

    def rounds(self, t0: float, round_s: float) -> RoundTransport:
        """The transport of one solve of synchronous rounds over these links (RoundTransport)."""
        return RoundTransport(self, t0, round_s)

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
        # every sender's multicast, in sender order (Network._transmit_grouped); what arrives by
        # the round's end is handed over at once (the receive below would drain it, unread)
        order = np.argsort(src, kind="stable")
        senders, which = np.unique(src[order], return_inverse=True)
        arrival = self.network._transmit_grouped(float(t), np.asarray(src[order], int), np.asarray(dst[order], int), int(nbytes),
                                                 [(rnd, s) for s in senders.tolist()], which, handed=end)
        ok[order] = arrival <= end
        self.late += int((np.isfinite(arrival) & (arrival > end)).sum())
        for d in np.unique(dst).tolist():
            self.network.receive(end, d)
        return ok
