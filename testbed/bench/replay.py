"""`testbed bench replay`: recorded-data throughput of the centralized factor graph (graph.poses).

Synthetic multi-robot ranging data like a multi-robot UWB dataset (docs/replay.md): three robots, each
with six antennas on a flat 0.6 m hexagon (so a height aid is needed against the mirror
ambiguity), every antenna of one robot ranging every antenna of another (36 antenna pairs per robot
pair, 108 ranges an epoch) at 10 Hz, robot 1 known by motion capture (fixed), robots 2 and 3
estimated as poses with a height measurement each. The measurements go through the factor graph
alone (solve_direct: the batched solver on prebuilt factor arrays) and through the plugin path of
`testbed replay` (testbed.plugins.feed.run_plugin: per epoch the height and mocap Measurements and
the ranges as one MeasurementBatch, as a recorded dataset's run of link rows is fed; estimates
checked and collected), so the second figure is what a replay of such a recording costs once it is
read. CPU time (time.process_time) of generating the data and of the replay, reported separately.
"""
from __future__ import annotations

import os
import time
from collections.abc import Iterator

import numpy as np

from estimators.graph.batch import EpochFactors, solve_epochs
from estimators.graph.warmstart import fit_motion
from estimators.so3 import rotmat_to_quat
from testbed.plugins.api import Context, Measurement, MeasurementBatch
from testbed.plugins.feed import run_plugin
from testbed.plugins.loading import Plugin
from testbed.replay.graph import GraphParams, PoseGraph
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
                    1.0 + 1.5 * np.arange(n) + 0.2 * np.sin(0.1 * t[:, None] + np.arange(n))], axis=-1)
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


def feed(data: dict, known: tuple[int, ...] = (0,), batched: bool = True) -> Iterator[Measurement | MeasurementBatch]:
    """Measurements in feeding order (per epoch: heights, mocap of the known robots, ranges); the
    ranges of an epoch as one MeasurementBatch (as testbed.replay feeds a run of rows of one
    stream), or one Measurement each (batched False)."""
    n = data["pos"].shape[1]
    P = data["pairs"].shape[0]
    src = np.array([f"r{a + 1}/a{i + 1}" for a, i in data["pairs"][:, :2]])
    dst = np.array([f"r{b + 1}/a{j + 1}" for b, j in data["pairs"][:, 2:]])
    sig_r, sig_h = np.full((P, 1), RANGE_SIGMA), np.array([HEIGHT_SIGMA])
    for a in (src, dst, sig_r):
        a.flags.writeable = False
    quat = {(e, a): rotmat_to_quat(data["rot"][e, a]) for e in range(data["time"].size) for a in known}
    for e, t in enumerate(data["time"].tolist()):
        for a in range(n):
            if a not in known:
                yield Measurement(stream="height", time=t, arrival=t, value=data["height"][e, a:a + 1], src=f"r{a + 1}", sigma=sig_h)
        for a in known:
            yield Measurement(stream="mocap", time=t, arrival=t, value=np.concatenate([data["pos"][e, a], quat[(e, a)]]),
                              src=f"r{a + 1}")
        tt = np.full(P, t)
        b = MeasurementBatch(stream="uwb", time=tt, arrival=tt, value=data["ranges"][e][:, None], src=src, dst=dst, sigma=sig_r)
        if batched:
            yield b
        else:
            yield from b.rows()


def _batch_factors(data: dict, epochs: np.ndarray) -> EpochFactors:
    """The factors of some epochs, robot 0 known (its antennas fixed points), robots 1.. free poses."""
    pairs, arms, E = data["pairs"], data["arms"], epochs.size
    P = pairs.shape[0]
    ep = np.repeat(np.arange(E), P)
    a, i, b, j = (np.tile(pairs[:, c], E) for c in range(4))
    world = data["pos"][epochs][ep, a] + np.einsum("nij,nj->ni", data["rot"][epochs][ep, a], arms[i])
    known = a == 0
    n = data["pos"].shape[1]
    return EpochFactors(
        kinds=("pose",) * (n - 1), r_epoch=ep, r_a=np.where(known, -1, a - 1), r_b=b - 1,
        r_arm_a=np.where(known[:, None], world, arms[i]), r_arm_b=arms[j], r_d=data["ranges"][epochs].ravel(),
        r_sigma=np.full(ep.size, RANGE_SIGMA), h_epoch=np.repeat(np.arange(E), n - 1), h_var=np.tile(np.arange(n - 1), E),
        h_arm=np.zeros((E * (n - 1), 3)), h_z=data["height"][epochs, 1:].ravel(), h_sigma=np.full(E * (n - 1), HEIGHT_SIGMA),
        q_epoch=np.zeros(0, np.int64), q_var=np.zeros(0, np.int64), q_arm=np.zeros((0, 3)), q_z=np.zeros((0, 3)),
        q_cov=np.zeros((0, 3, 3)),
    )


def solve_direct(data: dict, start: tuple[np.ndarray, np.ndarray], batch: int,
                 window: float | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """The factor graph alone (no Measurement objects): epochs in batches, each batch started from
    the constant-velocity and body-rate fit to the solutions of the last `window` s
    (estimators.graph.warmstart), as graph.poses does; returns positions (E, n - 1, 3), converged
    (E,) and iteration statistics."""
    p = GraphParams()  # graph.poses' defaults
    window = p.motion_window if window is None else window
    E, t = data["time"].size, data["time"]
    V = start[0].shape[0]
    pos, rot = np.zeros((E, V, 3)), np.zeros((E, V, 3, 3))
    conv, iters = np.zeros(E, bool), np.zeros(E, np.int64)
    for b0 in range(0, E, batch):
        epochs = np.arange(b0, min(E, b0 + batch))
        if b0 == 0:
            p0, R0 = np.broadcast_to(start[0], (epochs.size, V, 3)), np.broadcast_to(start[1], (epochs.size, V, 3, 3))
        else:
            recent = np.arange(np.searchsorted(t[:b0], t[b0 - 1] - window - 1e-9), b0)
            p0, R0 = fit_motion(t[recent], pos[recent], rot[recent]).predict(t[epochs])
        res = solve_epochs(_batch_factors(data, epochs), p0, R0, step_tol=p.step_tol, cost_tol=p.cost_tol,
                           step_sigma=p.step_sigma)
        pos[epochs], rot[epochs], conv[epochs], iters[epochs] = res.p, res.R, res.converged, res.iterations
    return pos, conv, {"iterations_mean": float(iters.mean()), "iterations_max": int(iters.max())}


def bench_replay(duration: float = 3600.0, batch: int = 16, plugin_duration: float | None = None) -> dict:
    """`duration` s of the synthetic recording through the factor graph alone (solve_direct), and
    `plugin_duration` s (default: the same) of it through graph.poses on the plugin path; CPU
    seconds, accuracy and the load average of the machine before and after (it may be shared)."""
    load0 = os.getloadavg()
    c0 = time.process_time()
    data = robots(duration)
    n = data["pos"].shape[1]
    start = (data["pos"][0, 1:] + 0.5, data["rot"][0, 1:] @ _yaw(0.2))
    c1 = time.process_time()
    pos, conv, stats = solve_direct(data, start, batch)
    c2 = time.process_time()
    err = (pos - data["pos"][:, 1:]).reshape(-1, 3)
    direct = {"duration_s": duration, "epochs": int(data["time"].size), "ranges": int(data["ranges"].size),
              "generate_cpu_s": c1 - c0, "solve_cpu_s": c2 - c1, "nonconverged_epochs": int((~conv).sum()), **stats,
              "position_rmse_m": float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))}
    plugin = bench_plugin(duration if plugin_duration is None else plugin_duration, batch)
    return {"robots": n, "antennas_per_robot": len(data["arms"]), "rate_hz": RATE_HZ, "batch": batch, "target_cpu_s": 60.0,
            "factor_graph": direct, "plugin_path": plugin, "load_average_1_5_15_min": {"before": list(load0), "after": list(os.getloadavg())}}


def bench_plugin(duration: float, batch: int) -> dict:
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
        "duration_s": duration, "epochs": int(data["time"].size), "ranges": int(data["ranges"].size),
        "generate_cpu_s": c1 - c0, "replay_cpu_s": c2 - c1, "iterations_mean": health["lm_iterations"] / max(health["epochs"], 1),
        "position_rmse_m": float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))), "health": health,
    }
