"""UWB stream `uwb`: two-way ranging between tag sites of the vehicles and `anchor{k}` sites.

Tags: the sites `tags` of every vehicle (default ["uwb"]; e.g. ["ant2", "ant3"]: two tags a
vehicle), devices in the order uav1's tags, uav2's tags, ... Links, in this order: every tag to
every anchor (src = "uav{i}/uwb", dst = "anchor{k}"), then tag pairs of different vehicles once
(src = "uav{i}/uwb", dst = "uav{j}/uwb", by device order; tags of one vehicle never range). link_search
"all-pairs": every tag pair, fixed at the start; random draws are made for every link at every
sample (O(N^2) per sample). "in-range": at every sample only the tag pairs within max_range
(scipy cKDTree.query_pairs, O(N log N + links)), draws only for these, and a pair's constant
bias drawn when it first comes into range. At each sample, a link whose true distance exceeds
max_range makes no measurement.

Line of sight: one mj_multiRay per source tag towards its in-range link ends, through the geoms
of `los_groups` (default 0: obstacles and floor, 3: vehicle collision boxes; visual geoms and
anchor masts never block), excluding the source vehicle's body; a hit on the destination
vehicle's own body, or within 1 mm of the end point, does not block. Blocked links are NLOS.
MuJoCo's rays skip fully transparent geoms, so the vehicles' collision boxes have alpha 0.3 (they
are in group 3, which is not rendered): other airframes block. Only links whose segment meets the bounding box of a geom the rays can hit (or
reaches down to a plane) are ray-cast (Physics.segments_may_hit); the others are clear.
Blocked span: distance between the first hit seen from each end (a second ray from the
destination), i.e. the length of the segment inside/between blocking geoms.

Range model (m), per measurement, src = initiator A, dst = responder B:
  value = twr(d, k_A, k_B) + b_A + b_B + c_link + s e1 + [NLOS] (nlos_bias_per_m span +
          nlos_bias_mean E) + [outlier] outlier_sigma e2
with d the true distance between the sites, k per-device clock frequency offsets ~
N(0, clock_ppm^2) (ppm), twr the two-way ranging arithmetic of `mode`
(testbed.sensors.noise.twr_range: "scale" d (1 + 1e-6 (k_A + k_B)/2); "ss-twr" adds
c T_reply (e_A - e_B)/2; "ds-twr" the asymmetric double-sided formula), b per-device antenna-delay
residuals ~ N(0, antenna_delay_sigma^2) (constant), c_link ~ N(0, link_bias_sigma^2) constant per
link, s = noise (x nlos_noise_factor when NLOS), E ~ Exp(1), e1, e2 ~ N(0, 1); outlier with
probability outlier_prob; the measurement is lost with probability loss_prob; nlos = "drop" drops
NLOS links, "ignore" only flags them. The same number of random draws is made at every sample.

Seeding: the stream's generator draws, in order, D clock offsets ("scale" mode), L link biases,
then each sample's normals, exponentials and uniforms, in every mode. In "ss-twr" and "ds-twr"
each device's clock offset, and in every mode its antenna delay, come from the device's own child
stream device_rng(stream, device name) (its first and second normal): adding a device never
changes another device's clock or delay.

Scheduling ([sensors.uwb.schedule], policy not "all"): each two-way exchange takes slot_s, so a
sample serves S = floor(1 / (rate_hz slot_s)) of its in-range links (round robin in key order
src * D + dst continuing after the last key served, or the S nearest), chosen after the random
draws (the draws are the same under every policy) and before the ray casts; a served link may
still be lost or dropped as NLOS (it used its slot). Log: uwb/served_time (T,) s and
uwb/served (T,) links served at each of the T samples.

Log: uwb/value, uwb/clean (M, 1) m; uwb/nlos (M,) bool; uwb/outlier (M,) bool; uwb/span (M,)
m (0 when LOS); src/dst site names. Per device (D,): uwb/devices names, uwb/clock_ppm, and
uwb/antenna_delay (m) when mode is not "scale" or antenna_delay_sigma > 0.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from testbed.sensors.base import Recorder, common_keys
from testbed.sensors.config import UwbConfig
from testbed.sensors.noise import device_rng, twr_range
from testbed.sim.world import Physics

END_TOLERANCE = 1e-3  # m: hits this close to the far end (e.g. the floor under a ground anchor) do not block


class Uwb:
    name = "uwb"

    def __init__(self, cfg: UwbConfig, physics: Physics, rng: np.random.Generator, period_ticks: int, n_anchors: int):
        self.cfg, self.rng, self.period_ticks = cfg, rng, period_ticks
        T = len(cfg.tags)
        N = physics.n * T  # tag devices, vehicle by vehicle, each vehicle's tags in cfg.tags order
        names = [f"anchor{k}" for k in range(1, n_anchors + 1)] + [f"uav{i}/{tag}" for i in range(1, physics.n + 1)
                                                                   for tag in cfg.tags]
        self.devices = np.array(names)
        self.site_ids = physics.site_ids(names)
        A = n_anchors
        # body of each device (-1 for anchors: world body, never excluded)
        self.dev_body = np.concatenate([np.full(A, -1), np.repeat(physics.body_ids, T)]).astype(int)
        self.tag_vehicle = np.repeat(np.arange(physics.n), T)  # (N,) vehicle of each tag device
        src, dst = [], []
        if cfg.anchor_links:
            for i in range(N):
                for k in range(A):
                    src.append(A + i), dst.append(k)
        self.in_range = cfg.link_search == "in-range"
        if cfg.tag_links and not self.in_range:
            for i in range(N):
                for j in range(i + 1, N):
                    if self.tag_vehicle[i] != self.tag_vehicle[j]:  # tags of one vehicle never range
                        src.append(A + i), dst.append(A + j)
        self.n_anchors = A
        self.src, self.dst = np.array(src, dtype=int), np.array(dst, dtype=int)  # the fixed links
        D, L = len(names), len(src)
        self.ppm = cfg.clock_ppm * rng.standard_normal(D)
        self.link_bias = cfg.link_bias_sigma * rng.standard_normal(L)
        own = np.array([device_rng(rng, name).standard_normal(2) for name in names]).reshape(D, 2)  # (clock, delay)
        if cfg.mode != "scale":
            self.ppm = cfg.clock_ppm * own[:, 0]
        self.antenna_delay = cfg.antenna_delay_sigma * own[:, 1]  # (D,) m of range per device
        # in-range tag pairs seen so far: keys src * D + dst (sorted) and their constant biases
        self._pair_keys, self._pair_bias = np.empty(0, dtype=int), np.empty(0)
        self.groups = np.array([1 if g in cfg.los_groups else 0 for g in range(6)], dtype=np.uint8)
        self.geom_body = physics.model.geom_bodyid.copy()
        self.blockers = physics.ray_targets(self.groups)  # geoms the LOS rays can hit
        self.rec = Recorder("uwb", {**common_keys(1), "nlos": ((), "?"), "outlier": ((), "?"), "span": ((), "f8")})
        sched = cfg.schedule
        self.slots = None if sched.policy == "all" else int(np.floor(1.0 / (cfg.rate_hz * sched.slot_s) + 1e-9))
        self._rr_last = -1  # key of the last link served by round robin
        self._served: list[tuple[float, int]] = []  # (sample time s, links served)

    def links(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Candidate links of this sample: src, dst (L,) device indices and constant biases (L,)
        m, from device positions P (D, 3) world, m (module docstring: link order)."""
        if not (self.in_range and self.cfg.tag_links):
            return self.src, self.dst, self.link_bias
        A = self.n_anchors
        # pairs within max_range (a hair more: the exact test on the distance follows in sample)
        pairs = cKDTree(P[A:]).query_pairs(self.cfg.max_range * (1 + 1e-9), output_type="ndarray")
        if len(pairs):
            pairs = pairs[self.tag_vehicle[pairs[:, 0]] != self.tag_vehicle[pairs[:, 1]]]
        pairs = A + pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))] if len(pairs) else np.empty((0, 2), dtype=int)
        keys = pairs[:, 0] * len(self.devices) + pairs[:, 1]
        new = np.setdiff1d(keys, self._pair_keys, assume_unique=True)
        if len(new):  # pairs in range for the first time: their constant bias (in key order)
            keys_all = np.concatenate([self._pair_keys, new])
            bias_all = np.concatenate([self._pair_bias, self.cfg.link_bias_sigma * self.rng.standard_normal(len(new))])
            order = np.argsort(keys_all)
            self._pair_keys, self._pair_bias = keys_all[order], bias_all[order]
        bias = self._pair_bias[np.searchsorted(self._pair_keys, keys)]
        return (np.concatenate([self.src, pairs[:, 0]]), np.concatenate([self.dst, pairs[:, 1]]),
                np.concatenate([self.link_bias, bias]))

    def line_of_sight(self, physics: Physics, P: np.ndarray, src: np.ndarray, dst: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """NLOS flags and blocked spans (m) of links src -> dst (L,) (device indices), P (D, 3)."""
        # rays only where a blocking geom's bounding box meets the link (the rest are clear)
        cast = np.flatnonzero(physics.segments_may_hit(self.blockers, P[src], P[dst], self.dev_body[np.stack([src, dst], axis=1)]))
        first = np.full(len(src), np.inf)
        gid = np.full(len(src), -1)
        first[cast], gid[cast] = physics.rays(P, src[cast], P[dst[cast]], self.groups, self.dev_body)
        hit_body = np.where(gid >= 0, self.geom_body[np.maximum(gid, 0)], -2)
        nlos = np.isfinite(first) & (first < d - END_TOLERANCE) & (hit_body != self.dev_body[dst])
        span = np.zeros(len(src))
        if self.cfg.nlos_bias_per_m > 0:
            for k in np.flatnonzero(nlos):
                back, _ = physics.ray(P[dst[k]], P[src[k]], self.groups, self.dev_body[dst[k]])
                span[k] = max(0.0, d[k] - first[k] - (back if np.isfinite(back) else 0.0))
        return nlos, span

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        cfg = self.cfg
        P = physics.data.site_xpos[self.site_ids]
        src, dst, link_bias = self.links(P)
        L = len(src)
        dist = np.linalg.norm(P[dst] - P[src], axis=1)
        e = self.rng.standard_normal((2, L))
        expo = self.rng.exponential(1.0, L)
        u = self.rng.random((2, L))
        links = np.flatnonzero(dist <= cfg.max_range)
        if self.slots is not None:
            links = self.scheduled(links, src, dst, dist)
            self._served.append((t, len(links)))
        d = dist[links]
        src, dst = src[links], dst[links]
        nlos, span = self.line_of_sight(physics, P, src, dst, d)
        outlier = u[0, links] < cfg.outlier_prob
        keep = u[1, links] >= cfg.loss_prob
        sigma = np.full(len(links), cfg.noise)
        value = twr_range(cfg.mode, d, self.ppm[src], self.ppm[dst], cfg.reply_time) + (self.antenna_delay[src] + self.antenna_delay[dst] + link_bias[links])
        if cfg.nlos == "bias":
            sigma[nlos] *= cfg.nlos_noise_factor
            value = value + nlos * (cfg.nlos_bias_per_m * span + cfg.nlos_bias_mean * expo[links])
        elif cfg.nlos == "drop":
            keep &= ~nlos
        value = value + sigma * e[0, links] + outlier * cfg.outlier_sigma * e[1, links]
        M = int(keep.sum())
        self.rec.add(
            time=np.full(M, t), arrival=np.full(M, t + cfg.latency), state_index=np.full(M, state_index),
            value=value[keep][:, None], clean=d[keep][:, None], src=self.devices[src[keep]], dst=self.devices[dst[keep]],
            nlos=nlos[keep], outlier=outlier[keep], span=span[keep],
        )

    def scheduled(self, links: np.ndarray, src: np.ndarray, dst: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """The in-range candidate links (indices into src, dst, dist) this sample serves, in link
        order: at most self.slots of them by the schedule's policy (module docstring)."""
        S = self.slots
        if len(links) <= S:
            if len(links) and self.cfg.schedule.policy == "round_robin":
                self._rr_last = int((src[links] * len(self.devices) + dst[links]).max())
            return links
        if self.cfg.schedule.policy == "nearest":
            return np.sort(links[np.argsort(dist[links], kind="stable")[:S]])
        keys = src[links] * len(self.devices) + dst[links]
        order = np.argsort(keys, kind="stable")
        first = int(np.searchsorted(keys[order], self._rr_last, side="right"))
        take = order[(first + np.arange(S)) % len(links)]
        self._rr_last = int(keys[take[-1]])
        return np.sort(links[take])

    def arrays(self) -> dict[str, np.ndarray]:
        out = self.rec.arrays()
        if self.slots is not None:
            served = np.array(self._served, dtype=float).reshape(-1, 2)
            out["uwb/served_time"], out["uwb/served"] = served[:, 0], served[:, 1].astype(np.int64)
        out["uwb/devices"] = self.devices.astype(str)
        out["uwb/clock_ppm"] = self.ppm.copy()
        if self.cfg.mode != "scale" or self.cfg.antenna_delay_sigma > 0:
            out["uwb/antenna_delay"] = self.antenna_delay.copy()
        return out
