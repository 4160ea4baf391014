"""Seed 000 batch filter for `testbed reproduce bandwidth`: many runs' logs filtered at once, for any
selection and weights (vectorized over a leading run axis), with the same filter, known values
and streams as the `bandwidth.fusion` estimator (testbed.plugins.builtin_bandwidth, which runs
one log online and is what a run scores). This module is the reproduction's Monte Carlo tool, not
an estimator runtime: it reads the truth of the formation point for its scores.

The common state x (3,) is the formation's reference point (m, world ENU). UAV i flies at a known
offset from it; its UWB tag sits at a known offset o_i (m, world) from it. The filter step is `dt`
(s); epoch k is the instant t_k = k dt, k = 0..K, K = floor(duration / dt). Model (paper eqs. 1-3
with eq. 22's known input): x(k+1) = x(k) + v dt + w, A = I3, B = v dt.

Measurements: node i's measurement at epoch k comes from the `uwb` stream only: its four ranges
to its anchor group (`groups`, last anchor = reference) at t_k, turned into a position by the
subtraction of eqs. 21-23 (estimators.bandwidth.uwb_pseudo_measurement) with the *known* anchor
positions, minus the known tag offset o_i: y_i = x + v_i, C = I3. V_i(k) comes from the configured
range noise `range_sigma` by linear error propagation at the measured ranges, so it varies with k.
An epoch needs all four ranges of a group at t_k: if one is missing (packet loss, out of range,
NLOS "drop"), node i has no measurement at k and predicts only (L_i = 0, lambda_i = A xhat_i + B;
the bound uses eq. 15 with L_i = 0). No interpolation. (The paper's synthetic measurements:
testbed.reproduce.bandwidth_paper.)
W: diag(process_noise); `w_reading` "rate" reads it in m^2/s (per step W dt), "per-step" as the
covariance per step as printed by the paper.

Known configuration with error and the initial estimate: testbed.plugins.builtin_bandwidth
(known_config, initial_estimate: the streams "known-config" and "init").
No link faults (drop_prob, fail_node) and no [network]: the reproduction's runs have none (a
run's bandwidth.fusion draws its faults from its own Context.rng and gets its network from the
runtime, Context.channel: testbed.plugins.builtin_bandwidth); both are refused here.

Truth (scoring only): x_true(t_k) = mean_i (truth/pos_i(t_k) - d_i), d_i the scenario's vehicle
offsets; prescribed: exactly start + velocity t.
"""
from __future__ import annotations

import numpy as np

from estimators import bandwidth as bw
from estimators.bandwidth import uwb_pseudo_measurement
from estimators.core import Epoch, drive
from testbed.errors import ConfigError
from testbed.interrupt import poll
from testbed.config.pipelines import N_NODES, BandwidthPipelineConfig
from testbed.plugins.builtin_bandwidth import initial_estimate, known_config
from testbed.synthetic.bandwidth import P_SETS, T_SETS



# ---------------------------------------------------------------------------------- helpers


def _epoch_index(times: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Epoch number round(t/dt) of each time and whether t is on an epoch (1 microsecond)."""
    e = np.rint(times / dt).astype(int)
    return e, np.abs(times - e * dt) < 1e-6


def truth_formation_point(scenario, log: dict, t: np.ndarray) -> np.ndarray:
    """Scoring only: x_true (K+1, 3) at epoch times t, mean over UAVs of truth/pos - vehicle offset."""
    idx = np.searchsorted(log["time"], t - 1e-9)
    idx = np.minimum(idx, log["time"].size - 1)
    if np.any(np.abs(log["time"][idx] - t) > 1e-6):
        raise ConfigError(f"{scenario.name}.toml: pipeline.dt: {scenario.pipeline.dt} s epochs are not logged instants "
                          f"(world.truth_rate {scenario.world.truth_rate} Hz); use a multiple of the truth period")
    d = np.asarray(scenario.trajectory.offsets, float)
    return (log["truth/pos"][idx] - d[None]).mean(1)


def uwb_epochs(cfg: BandwidthPipelineConfig, log: dict, K: int, anchors: np.ndarray, offsets: np.ndarray):
    """Pseudo-measurements from the `uwb` stream. Returns y (K+1, N, 3) m (NaN where unavailable),
    V (K+1, N, 3, 3) m^2 (identity where unavailable), available (K+1, N) bool, ranges (K+1, N, 4)."""

    ranges = np.full((K + 1, N_NODES, 4), np.nan)
    e, on = _epoch_index(log["uwb/time"], cfg.dt)
    src, dst, val = log["uwb/src"], log["uwb/dst"], log["uwb/value"][:, 0]
    for i, g in enumerate(cfg.groups):
        for slot, a in enumerate(g):
            sel = on & (src == f"uav{i + 1}/uwb") & (dst == f"anchor{a}") & (e <= K)
            ranges[e[sel], i, slot] = val[sel]
    avail = np.isfinite(ranges).all(-1)
    y = np.full((K + 1, N_NODES, 3), np.nan)
    V = np.broadcast_to(np.eye(3), (K + 1, N_NODES, 3, 3)).copy()
    for i, g in enumerate(cfg.groups):
        ok = avail[:, i]
        if ok.any():
            p, Vi = uwb_pseudo_measurement(ranges[ok, i], anchors[np.array(g) - 1], cfg.range_sigma)
            # eq. 23 plus the known offset: y_i = p_tag,i - o_i measures the formation point (C = I3)
            y[ok, i] = p - offsets[i]
            V[ok, i] = Vi
    return y, V, avail, ranges


def measurements(scenario, log: dict) -> dict:
    """Everything the filter needs from a run log, for any selection and weights.

    Returns t (K+1,) s; truth (K+1, 3) m (scoring only); y (K+1, N, 3) m and V (K+1, N, 3, 3) m^2
    the pseudo-measurements and their covariances; available (K+1, N) bool; K; x_init (3,) m the
    initial estimate x0 + N(0, M0) (stream "init").
    """
    cfg: BandwidthPipelineConfig = scenario.pipeline
    label = f"{scenario.name}.toml"
    K = int(np.floor(scenario.duration / cfg.dt + 1e-9))
    t = np.arange(K + 1) * cfg.dt
    anchors, offsets = known_config(cfg, scenario.seed)
    truth = truth_formation_point(scenario, log, t)
    if cfg.measurements != "uwb" or "uwb/value" not in log:
        raise ConfigError(f"{label}: pipeline.measurements: the batch filter reads the [sensors.uwb] stream "
                          f"(measurements = \"uwb\"), got {cfg.measurements!r}")
    period = 1.0 / scenario.sensors.uwb.rate_hz
    ratio = cfg.dt / period
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ConfigError(f"{label}: pipeline.dt: {cfg.dt} s is not a multiple of the UWB period {period:g} s")
    if len(anchors) != len(scenario.world.anchors):
        raise ConfigError(f"{label}: pipeline.anchors: {len(anchors)} known anchors but the world has "
                          f"{len(scenario.world.anchors)} (world.anchors)")
    y, V, avail, _ = uwb_epochs(cfg, log, K, anchors, offsets)
    return dict(t=t, truth=truth, y=y, V=V, available=avail, K=K, x_init=initial_estimate(cfg, scenario.seed))


def stack_runs(metas: list[dict]) -> dict:
    """Stack :func:`measurements` of several runs (same K) along a leading run axis R."""
    out = {k: np.stack([m[k] for m in metas]) for k in ("truth", "y", "V", "available", "x_init")}
    return dict(out, t=metas[0]["t"], K=metas[0]["K"])


def estimate(scenario, log: dict | None = None, *, meas: dict | None = None, select: np.ndarray | None = None,
             weights: np.ndarray | None = None) -> dict:
    """Run the seed 000 estimator on a run log (or on precomputed :func:`measurements`).

    select (4, 4, 3) masks / weights (4, 4) override the configured selection / weights. meas may
    carry a leading run axis R (:func:`stack_runs`): the runs are filtered together (vectorized);
    every output below gains that axis.
    Returns the arrays of :func:`measurements` plus xhat (K+1, N, 3) m; M (K+1, N, 3, 3) m^2;
    comm: estimators.bandwidth.CommLog; S, P: nominal masks and weights; W (3, 3) per step;
    health: the driver's health counts (core.Track.health).
    """
    cfg: BandwidthPipelineConfig = scenario.pipeline
    label = f"{scenario.name}.toml"
    meas = measurements(scenario, log) if meas is None else meas
    K, y, V, avail = meas["K"], meas["y"], meas["V"], meas["available"]
    batch = y.shape[:-3]  # () or (R,)
    y, V, avail = (np.moveaxis(a, len(batch), 0) for a in (y, V, avail))  # step axis first
    n = 3
    W = np.diag(cfg.process_noise) * (cfg.dt if cfg.w_reading == "rate" else 1.0)
    A, B = np.eye(n), np.asarray(cfg.velocity, float) * cfg.dt
    P = P_SETS[cfg.weights] if weights is None else np.asarray(weights, float)
    M0 = np.diag(cfg.M0)
    budget = [cfg.budget] * N_NODES
    if select is not None:
        S = select
    elif cfg.selection == "search":
        # design-time V: the first epoch where every node measured (first run when batched)
        av0 = avail.reshape(K + 1, -1, N_NODES)[:, 0].all(-1)
        k0 = int(np.argmax(av0)) if av0.any() else 0
        V0 = V.reshape(K + 1, -1, N_NODES, n, n)[k0, 0]
        model0 = bw.NetworkModel.create(A=A, B=B, C=np.eye(n), W=W, V=list(V0), N=N_NODES)
        S = bw.search_selection(model0, P, M0, K, budget, objective="bound").best
    else:
        S = T_SETS[cfg.selection]
        if cfg.budget != 5:
            raise ConfigError(f"{label}: pipeline.budget: the paper's {cfg.selection} is for budget 5, got "
                              f"{cfg.budget}; use selection = \"search\"")
    net = bw.FusionNetwork(select=S, weights=P, budget=budget)
    if cfg.drop_prob > 0 or cfg.fail_node or scenario.network is not None:
        raise ConfigError(f"{label}: pipeline.drop_prob / pipeline.fail_node / network: the reproduction's batch "
                          "filter has no link faults and no network; run the scenario (bandwidth.fusion has both)")
    x_init = meas["x_init"]
    prior = bw.FusionState(xhat=np.broadcast_to(x_init[..., None, :], batch + (N_NODES, n)).copy(),
                           M=np.broadcast_to(M0, batch + (N_NODES, n, n)).copy())
    C = (np.eye(n),) * N_NODES
    # what arrives at each step: the nominal design
    delivered = []
    t = meas["t"]
    for k in range(K):
        poll()  # a worker asked to stop does so between epochs (testbed.interrupt)
        delivered.append(net.at(k))
    # V_i(k) of each run (batched V broadcasts through eqs. 15 and 18)
    epochs = [Epoch(float(t[k]), bw.NodeMeasurements(y=tuple(y[k][..., i, :] for i in range(N_NODES)),
                                                     V=tuple(V[k][..., i, :, :] for i in range(N_NODES)),
                                                     available=avail[k]),
                    [(cfg.dt, delivered[k - 1])] if k else [])
              for k in range(K + 1)]
    track = drive(bw.FusionFilter(A=A, B=B, C=C, W=W), prior, epochs)
    comps = [bw.link_components(Se) for Se, _ in delivered]
    comm = bw.CommLog(components=np.stack(comps) if comps else np.zeros((0, N_NODES, N_NODES)),
                      budget=np.asarray(budget))
    ax = len(batch)
    xh = [b.xhat for b in track.beliefs]
    Ms = [b.M for b in track.beliefs]
    return dict(meas, xhat=np.stack(xh, ax), M=np.stack(Ms, ax), comm=comm, S=S, P=P, W=W, health=track.health())
