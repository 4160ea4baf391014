"""Seeded synthetic epochs of the factor-graph cooperative navigation problem (seed 001), pure numpy.

Used by the tests and by `testbed bench estimators`
(`epoch_factory`). No physics: for the physics-in-the-loop epochs run the scenario coop-fg.

Geometry: n UAVs uniformly in a box (default 200 m east x 200 m north x 100 m up, the paper's
18-UAV volume); each new UAV is accepted only if it is within `max_range` of an earlier one (so the
range graph is connected by construction) and at least `min_sep` from all (no collisions).
Measurements:
- GNSS fix z_i = p_i + N(0, diag(s_h^2, s_h^2, s_v^2)): SPP 1.5 / 3.0 m, RTK 0.02 / 0.03 m
  (the first `n_rtk` UAVs of a random permutation have RTK);
- UWB range for every pair within `max_range`: d = |p_i - p_j| (1 + (k_i + k_j)/2) + N(0, sigma_d^2),
  k_i ~ N(0, (scale_ppm 1e-6)^2) a per-device clock scale factor (two-way ranging: the mean of
  both ends' scale factors), sigma_d = 0.10 m; optional NLOS: a positive bias on chosen links.
The estimators absorb the scale factor into sigma_d (|k d| <= ~2 mm at 100 m).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.factor_graph import CoopProblem

BOX = (200.0, 200.0, 100.0)


@dataclass(frozen=True, slots=True)
class SyntheticEpoch:
    """truth: (n, 3) m ENU; problem: the measurements; is_rtk: (n,) bool; range_error: (m,) m."""

    truth: np.ndarray
    problem: CoopProblem
    is_rtk: np.ndarray
    range_error: np.ndarray


def connected_positions(n: int, rng: np.random.Generator, box=BOX, max_range: float = 100.0,
                        min_sep: float = 5.0, max_tries: int = 100000) -> np.ndarray:
    """(n, 3) positions in [0, box] whose graph of pairs within max_range is connected."""
    box = np.asarray(box, float)
    pts = [rng.uniform(0.0, 1.0, 3) * box]
    tries = 0
    while len(pts) < n:
        tries += 1
        if tries > max_tries:
            raise RuntimeError("connected_positions: could not place the UAVs; box too large or sparse")
        p = rng.uniform(0.0, 1.0, 3) * box
        dist = np.linalg.norm(np.asarray(pts) - p, axis=1)
        if dist.min() >= min_sep and dist.min() <= max_range:
            pts.append(p)
    return np.asarray(pts)


def is_connected(n: int, edges: np.ndarray) -> bool:
    """True if the undirected graph (n nodes, edges (m, 2)) is connected."""
    adj = [[] for _ in range(n)]
    for a, b in edges:
        adj[a].append(b)
        adj[b].append(a)
    seen = {0}
    stack = [0]
    while stack:
        for v in adj[stack.pop()]:
            if v not in seen:
                seen.add(v)
                stack.append(v)
    return len(seen) == n


def make_epoch(n: int = 18, seed: int = 0, *, n_rtk: int = 3, box=BOX, max_range: float = 100.0,
               spp_sigma=(1.5, 3.0), rtk_sigma=(0.02, 0.03), range_sigma: float = 0.10,
               scale_ppm: float = 20.0, nlos: dict | None = None, truth: np.ndarray | None = None,
               is_rtk: np.ndarray | None = None, scale_box_to_density: bool = False) -> SyntheticEpoch:
    """One epoch. nlos: {edge_index: bias_m} added to those ranges. truth/is_rtk: reuse a geometry
    (fresh noise from `seed`). scale_box_to_density: scale the box by (n/18)^(1/3) (same density)."""
    rng = np.random.default_rng(seed)
    box = np.asarray(box, float)
    if scale_box_to_density:
        box = box * (n / 18.0) ** (1.0 / 3.0)
    if truth is None:
        truth = connected_positions(n, rng, box, max_range)
    truth = np.asarray(truth, float)
    n = truth.shape[0]
    if is_rtk is None:
        is_rtk = np.zeros(n, bool)
        is_rtk[rng.permutation(n)[:n_rtk]] = True
    sig = np.where(is_rtk[:, None], np.asarray(rtk_sigma)[[0, 0, 1]], np.asarray(spp_sigma)[[0, 0, 1]])
    gnss_cov = np.zeros((n, 3, 3))
    gnss_cov[:, [0, 1, 2], [0, 1, 2]] = sig ** 2
    z = truth + sig * rng.standard_normal((n, 3))
    iu, ju = np.triu_indices(n, 1)
    dtrue = np.linalg.norm(truth[iu] - truth[ju], axis=1)
    keep = dtrue <= max_range
    edges = np.stack([iu[keep], ju[keep]], axis=1)
    dtrue = dtrue[keep]
    k = scale_ppm * 1e-6 * rng.standard_normal(n)
    scale = 0.5 * (k[edges[:, 0]] + k[edges[:, 1]])
    err = dtrue * scale + range_sigma * rng.standard_normal(dtrue.shape[0])
    for e, bias in (nlos or {}).items():
        err[e] += bias
    prob = CoopProblem(gnss_pos=z, gnss_cov=gnss_cov, edges=edges, ranges=dtrue + err, range_sigma=range_sigma)
    return SyntheticEpoch(truth, prob, is_rtk, err)


def epoch_factory(n_rtk: int = 3):
    """make_epoch(n, seed) -> (truth (n, 3) m, CoopProblem) for testbed.bench.estimators.bench_factor_graph:
    a random connected swarm with the box scaled to the density of 18 UAVs in 200 x 200 x 100 m."""

    def factory(n: int, seed: int):
        ep = make_epoch(n=n, seed=seed, n_rtk=n_rtk, scale_box_to_density=True)
        return ep.truth, ep.problem

    return factory


def nlos_epoch(seed: int, bias: float = 5.0) -> tuple[SyntheticEpoch, int]:
    """An 18-UAV epoch (make_epoch seed 2000 + seed) whose range k between two SPP UAVs (drawn
    with Generator(seed)) carries a +bias metres NLOS error. Returns (epoch, k)."""
    ep0 = make_epoch(18, seed=2000 + seed)
    e0 = ep0.problem.edges
    cand = np.flatnonzero(~ep0.is_rtk[e0[:, 0]] & ~ep0.is_rtk[e0[:, 1]])
    k = int(np.random.default_rng(seed).choice(cand))
    return make_epoch(18, seed=2000 + seed, nlos={k: bias}), k
