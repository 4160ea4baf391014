"""`testbed bench replay`: recorded-data throughput of the centralized factor graph (graph.poses).

Synthetic multi-robot ranging data like a multi-robot UWB dataset (issue #16): three robots, each
with six antennas on a flat 0.6 m hexagon (so a height aid is needed against the mirror
ambiguity), every antenna of one robot ranging every antenna of another (36 antenna pairs per robot
pair, 108 ranges an epoch) at 10 Hz, robot 1 known by motion capture (fixed), robots 2 and 3
estimated as poses with a height measurement each. The measurements go through the plugin path of
`testbed replay` (testbed.plugins.feed.run_plugin: Measurement objects one at a time, estimates
checked and collected), so the figure is what a replay of such a recording costs. CPU time
(time.process_time) of generating the data and of the replay, reported separately.
"""
from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np

from estimators.so3 import rotmat_to_quat
from testbed.plugins.api import Context, Measurement
from testbed.plugins.feed import run_plugin
from testbed.plugins.loading import Plugin
from testbed.replay.graph import PoseGraph
from testbed.rng import stream_rng

RATE_HZ = 10.0
RANGE_SIGMA = 0.05  # m
HEIGHT_SIGMA = 0.05  # m


def robots(duration: float, rate: float = RATE_HZ, n: int = 3, antennas: int = 6, seed: int = 0) -> dict:
    """Synthetic truth and measurements: time (E,) s; pos (E, n, 3) m world; rot (E, n, 3, 3)
    body-to-world (yaw along the velocity, level); arms (antennas, 3) m body frame (a flat
    hexagon); ranges (E, P) m for the pairs (P, 4) = (robot a, antenna i, robot b, antenna j), a < b;
    height (E, n) m, the measured up coordinate of each robot's body origin."""
    rng = stream_rng(seed, "bench/replay")
    t = np.arange(int(round(duration * rate)) + 1) / rate
    centre = np.array([[0.0, 0.0], [3.0, 1.0], [-1.0, 3.0]])[:n]
    radius, omega = np.array([1.0, 1.2, 0.8])[:n], np.array([0.20, -0.15, 0.25])[:n]  # m, rad/s
    ang = omega[None, :] * t[:, None] + np.arange(n)[None, :]
    pos = np.stack([centre[:, 0] + radius * np.cos(ang), centre[:, 1] + radius * np.sin(ang),
                    1.0 + 0.5 * np.arange(n) + 0.2 * np.sin(0.1 * t[:, None] + np.arange(n))], axis=-1)
    yaw = ang + np.sign(omega) * np.pi / 2
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.zeros(yaw.shape + (3, 3))
    rot[..., 0, 0], rot[..., 0, 1], rot[..., 1, 0], rot[..., 1, 1], rot[..., 2, 2] = c, -s, s, c, 1.0
    k = 2 * np.pi * np.arange(antennas) / antennas
    arms = 0.3 * np.stack([np.cos(k), np.sin(k), np.zeros(antennas)], axis=1)  # flat ring, radius 0.3 m
    pairs = np.array([(a, i, b, j) for a in range(n) for b in range(a + 1, n) for i in range(antennas) for j in range(antennas)])
    ea = pos[:, pairs[:, 0]] + np.einsum("epij,pj->epi", rot[:, pairs[:, 0]], arms[pairs[:, 1]])
    eb = pos[:, pairs[:, 2]] + np.einsum("epij,pj->epi", rot[:, pairs[:, 2]], arms[pairs[:, 3]])
    ranges = np.linalg.norm(ea - eb, axis=-1) + RANGE_SIGMA * rng.standard_normal((t.size, pairs.shape[0]))
    height = pos[..., 2] + HEIGHT_SIGMA * rng.standard_normal(pos.shape[:2])
    return {"time": t, "pos": pos, "rot": rot, "arms": arms, "pairs": pairs, "ranges": ranges, "height": height}


def _yaw(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def context(data: dict, seed: int = 0) -> Context:
    """The Context of the synthetic recording: robots r1..rn with sites a1..a6."""
    n = data["pos"].shape[1]
    sites = {f"r{a + 1}/a{i + 1}": (f"r{a + 1}", data["arms"][i]) for a in range(n) for i in range(len(data["arms"]))}
    return Context(vehicles=tuple(f"r{a + 1}" for a in range(n)), sites=sites, anchors={}, sensors={},
                   duration=float(data["time"][-1]), seed=seed, rng=stream_rng(seed, "estimator/graph.poses"))


def feed(data: dict, known: tuple[int, ...] = (0,)) -> Iterator[Measurement]:
    """Measurements in feeding order (per epoch: heights, mocap of the known robots, ranges)."""
    n = data["pos"].shape[1]
    src = [f"r{a + 1}/a{i + 1}" for a, i in data["pairs"][:, :2]]
    dst = [f"r{b + 1}/a{j + 1}" for b, j in data["pairs"][:, 2:]]
    sig_r, sig_h = np.array([RANGE_SIGMA]), np.array([HEIGHT_SIGMA])
    quat = {(e, a): rotmat_to_quat(data["rot"][e, a]) for e in range(data["time"].size) for a in known}
    for e, t in enumerate(data["time"].tolist()):
        for a in range(n):
            if a not in known:
                yield Measurement(stream="height", time=t, arrival=t, value=data["height"][e, a:a + 1], src=f"r{a + 1}", sigma=sig_h)
        for a in known:
            yield Measurement(stream="mocap", time=t, arrival=t, value=np.concatenate([data["pos"][e, a], quat[(e, a)]]),
                              src=f"r{a + 1}")
        row = data["ranges"][e]
        for k in range(len(src)):
            yield Measurement(stream="uwb", time=t, arrival=t, value=row[k:k + 1], src=src[k], dst=dst[k], sigma=sig_r)


def bench_replay(duration: float = 3600.0, batch: int = 64) -> dict:
    """Replay `duration` s of the synthetic recording through graph.poses; CPU seconds and accuracy."""
    c0 = time.process_time()
    data = robots(duration)
    ctx = context(data)
    n = data["pos"].shape[1]
    # the robots' starting poses are known to 0.5 m and 0.2 rad of yaw (an experiment's set-up)
    start = {f"r{a + 1}": [*(data["pos"][0, a] + 0.5).tolist(), *rotmat_to_quat(data["rot"][0, a] @ _yaw(0.2)).tolist()]
             for a in range(1, n)}
    params = {"batch": batch, "initial": start}
    c1 = time.process_time()
    track, health, _ = run_plugin(Plugin("graph.poses", "graph.poses", PoseGraph, params), ctx, feed(data))
    c2 = time.process_time()
    err = []
    for a in range(1, n):
        s = track[(f"r{a + 1}", "position")]
        idx = np.rint(s.time * RATE_HZ).astype(int)
        err.append(s.value - data["pos"][idx, a])
    e = np.concatenate(err)
    return {
        "duration_s": duration, "rate_hz": RATE_HZ, "robots": n, "antennas_per_robot": len(data["arms"]),
        "epochs": int(data["time"].size), "ranges": int(data["ranges"].size), "batch": batch,
        "generate_cpu_s": c1 - c0, "replay_cpu_s": c2 - c1, "target_cpu_s": 60.0,
        "position_rmse_m": float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))), "health": health,
    }
