"""Seed 000 estimator pipeline (kind "bandwidth"): run log -> estimates, metrics, plots.

The common state x (3,) is the formation's reference point (m, world ENU). UAV i flies at a known
offset from it; its UWB tag sits at a known offset o_i (m, world: the vehicle offset plus the
tag's 0.17 m mast, level flight, yaw 0) from it. The filter step is `dt` (s); epoch k is the
instant t_k = k dt, k = 0..K, K = floor(duration / dt). Model (paper eqs. 1-3 with eq. 22's known
input): x(k+1) = x(k) + v dt + w, A = I3, B = v dt with the configured known velocity v.

Measurement modes (`measurements`):
- "uwb": node i's measurement at epoch k comes from the `uwb` stream only: its four ranges to
  its anchor group (`groups`, last anchor = reference) at t_k, turned into a position by the
  subtraction of eqs. 21-23 (estimators.bandwidth.uwb_pseudo_measurement) with the *known*
  anchor positions, minus the known tag offset o_i: y_i = x + v_i, C = I3. V_i(k) comes from
  the configured range noise `range_sigma` by linear error propagation at the measured ranges, so
  it varies with k. An epoch needs all four ranges of a group at t_k: if one is missing (packet
  loss, out of range, NLOS "drop"), node i has no measurement at k and predicts only
  (L_i = 0, lambda_i = A xhat_i + B; the bound uses eq. 15 with L_i = 0). No interpolation.
- "paper": synthetic y_i = x(k) + v_i, v_i ~ N(0, diag(paper_V)) drawn from the stream
  "paper-noise", with x the physics truth of the formation point (the paper's setup with the
  testbed's motion; its W is then a model parameter, the prescribed truth has no process noise).
W: diag(process_noise); `w_reading` "rate" reads it in m^2/s (per step W dt), "per-step" as the
covariance per step as printed by the paper.

Known configuration with error: anchors get N(0, anchor_error^2) per axis and tag offsets
N(0, offset_error^2) per axis, drawn once from the stream "known-config"; the initial estimate is
x0 + N(0, M0) from the stream "init" (so that Sigma_i(0) = M_i(0) as the bound assumes).
Faults (estimators.bandwidth.LinkFaults): `drop_prob` loses each directed message with that
probability per step (stream "links"); `fail_node` (1-based, 0 = none) stops sending at
`fail_time` s. A lost component is compensated by the receiver's own prediction (eq. 6 with that
T entry 0) and M follows the realised loss pattern.

Network ([network] set; testbed.sim.network, docs/network.md): at every step k each directed
message j -> i of the delivered design (after the faults above) is sent at t_k through a network
of N nodes (stream "network") with its size, 8 bytes per selected component; it is used at step
k only if it arrives by t_k + dt, else its components are compensated as a loss. The channel's
geometry is the vehicles' true positions at t_k (all LOS). The paper's budget t_i is one instance
of the network's: budget_on = "receive", bandwidth = 8 t_i / dt bytes/s, burst_bytes = 8 t_i
passes exactly the designs that respect t_i (every node receives 8 t_i bytes at each step and the
bucket refills that much per step); a smaller bandwidth drops what does not fit. metrics.json
then has `network` (messages sent / dropped / bytes, latency percentiles).

Truth (scoring only): x_true(t_k) = mean_i (truth/pos_i(t_k) - d_i), d_i the scenario's vehicle
offsets; prescribed: exactly start + velocity t.
"""
from __future__ import annotations

import numpy as np

from estimators import bandwidth as bw
from estimators.bandwidth import BYTES_PER_COMPONENT, uwb_pseudo_measurement
from estimators.core import Epoch, drive
from testbed.errors import ConfigError
from testbed.interrupt import poll
from testbed.sim.network import Network
from testbed.pipeline_config import N_NODES, BandwidthPipelineConfig
from testbed.rng import stream_rng
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
    n = 3
    anchors, offsets = known_config(cfg, scenario.seed)
    truth = truth_formation_point(scenario, log, t)

    if cfg.measurements == "uwb":
        if "uwb/value" not in log:
            raise ConfigError(f"{label}: pipeline.measurements: 'uwb' needs the [sensors.uwb] stream")
        period = 1.0 / scenario.sensors.uwb.rate_hz
        ratio = cfg.dt / period
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ConfigError(f"{label}: pipeline.dt: {cfg.dt} s is not a multiple of the UWB period {period:g} s")
        if len(anchors) != len(scenario.world.anchors):
            raise ConfigError(f"{label}: pipeline.anchors: {len(anchors)} known anchors but the world has "
                              f"{len(scenario.world.anchors)} (world.anchors)")
        y, V, avail, _ = uwb_epochs(cfg, log, K, anchors, offsets)
    else:
        Vp = np.diag(cfg.paper_V)
        rng = stream_rng(scenario.seed, "paper-noise")
        y = truth[:, None, :] + rng.standard_normal((K + 1, N_NODES, n)) @ np.linalg.cholesky(Vp).T
        V = np.broadcast_to(Vp, (K + 1, N_NODES, n, n)).copy()
        avail = np.ones((K + 1, N_NODES), bool)

    return dict(t=t, truth=truth, y=y, V=V, available=avail, K=K, x_init=initial_estimate(cfg, scenario.seed))


def known_config(cfg: BandwidthPipelineConfig, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The anchor positions (A, 3) m and tag offsets (N, 3) m the estimator knows, with their
    configured errors drawn once from the stream "known-config" (anchors first)."""
    rng_known = stream_rng(seed, "known-config")
    anchors = np.asarray(cfg.anchors, float)
    anchors = anchors + cfg.anchor_error * rng_known.standard_normal(anchors.shape)
    offsets = np.asarray(cfg.offsets, float)
    return anchors, offsets + cfg.offset_error * rng_known.standard_normal(offsets.shape)


def initial_estimate(cfg: BandwidthPipelineConfig, seed: int) -> np.ndarray:
    """x0 + N(0, M0) (3,) m, stream "init": every node's initial estimate of the formation point."""
    return np.asarray(cfg.x0, float) + np.linalg.cholesky(np.diag(cfg.M0)) @ stream_rng(seed, "init").standard_normal(3)


def stack_runs(metas: list[dict]) -> dict:
    """Stack :func:`measurements` of several runs (same K) along a leading run axis R."""
    out = {k: np.stack([m[k] for m in metas]) for k in ("truth", "y", "V", "available", "x_init")}
    return dict(out, t=metas[0]["t"], K=metas[0]["K"])


def estimate(scenario, log: dict | None = None, *, meas: dict | None = None, select: np.ndarray | None = None,
             weights: np.ndarray | None = None) -> dict:
    """Run the seed 000 estimator on a run log (or on precomputed :func:`measurements`).

    select (4, 4, 3) masks / weights (4, 4) override the configured selection / weights. meas may
    carry a leading run axis R (:func:`stack_runs`): the runs are filtered together (vectorized;
    faults need per-run generators and are refused then); every output below gains that axis.
    Returns the arrays of :func:`measurements` plus xhat (K+1, N, 3) m; M (K+1, N, 3, 3) m^2;
    comm: estimators.bandwidth.CommLog; S, P: nominal masks and weights; W (3, 3) per step;
    health: the driver's health counts (core.Track.health), also in metrics.json.
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
    failed = {cfg.fail_node - 1: int(np.ceil(cfg.fail_time / cfg.dt - 1e-9))} if cfg.fail_node else {}
    faults = bw.LinkFaults(drop_prob=cfg.drop_prob, failed=failed) if (cfg.drop_prob > 0 or failed) else None
    rng_links = stream_rng(scenario.seed, "links")

    if batch and (faults is not None or scenario.network is not None):
        raise ValueError("estimate: batched runs cannot use link faults or a [network] (per-run generators)")
    x_init = meas["x_init"]
    prior = bw.FusionState(xhat=np.broadcast_to(x_init[..., None, :], batch + (N_NODES, n)).copy(),
                           M=np.broadcast_to(M0, batch + (N_NODES, n, n)).copy())
    C = (np.eye(n),) * N_NODES
    # what actually arrives at each step: the nominal design with this step's dropped messages
    delivered = []
    t = meas["t"]
    network = None if scenario.network is None else Network(scenario.network, N_NODES, stream_rng(scenario.seed, "network"))
    for k in range(K):
        poll()  # a worker asked to stop does so between epochs (testbed.interrupt)
        Sn, Pk = net.at(k)
        Se = faults.effective(Sn, k, rng_links, 1)[0] if faults is not None else Sn
        if network is not None:
            if log is not None:  # the physical channel: true positions at t_k (no log: no range limit)
                network.set_geometry(t[k], log["truth/pos"][np.searchsorted(log["time"], t[k] - 1e-9)])
            Se = through_network(network, Se, float(t[k]), cfg.dt)
        delivered.append((Se, Pk))
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
    out = dict(meas, xhat=np.stack(xh, ax), M=np.stack(Ms, ax), comm=comm, S=S, P=P, W=W, health=track.health())
    if network is not None:
        out["network"] = network.stats()
    return out


def through_network(network: Network, S: np.ndarray, t: float, dt: float) -> np.ndarray:
    """Masks (N, N, n) of what arrives in time: each directed message j -> i of design S sent at
    t (s), BYTES_PER_COMPONENT per selected component, kept only if it arrives by t + dt."""
    comps = bw.link_components(S)
    Se = S.copy()
    for j, i in zip(*np.nonzero(comps)):
        arrival = network.multicast(t, int(j), np.array([i]), int(BYTES_PER_COMPONENT * comps[j, i]), None)[0]
        if not arrival <= t + dt:
            Se[j, i] = 0.0
    for i in range(len(S)):
        network.receive(t + dt, i)
    return Se


def scores(est: dict) -> dict:
    """The `estimators.bandwidth` object of metrics.json from :func:`estimate`'s arrays.

    J_empirical: realised eq. 12 of this run, sum_k sum_i |e_i(k)|^2 (m^2): one sample of the
    random variable whose mean is J; its Monte Carlo estimate is the mean over seeds (testbed sweep
    / testbed reproduce bandwidth). J_bound: eq. 16, sum_k sum_i tr M_i(k) (m^2, deterministic
    given the measured V and losses). bound_holds: a single run cannot estimate a covariance, so
    per node this is the time-averaged check mean_k |e_i(k)|^2 <= mean_k tr M_i(k) (errors are
    correlated in time: indicative); the per-node-and-step check needs a Monte Carlo
    (testbed reproduce bandwidth). bytes_per_step: per directed link "j->i" (float64 components),
    mean over steps as delivered, next to the budget.
    """

    e = est["truth"][:, None, :] - est["xhat"]  # eq. 10: e_i(k) = x(k) - xhat_i(k)
    se = (e ** 2).sum(-1)  # (K+1, N)
    trM = np.trace(est["M"], axis1=-2, axis2=-1)
    comm = est["comm"]
    mean_bytes = comm.bytes.mean(0) if comm.components.size else np.zeros((N_NODES, N_NODES))
    avail = est["available"]
    out = {
        "measurements_used": int(avail.sum()),
        "measurement_epochs_missing": int((~avail).sum()),
        "steps": int(est["K"]),
        "dt_s": float(est["t"][1] - est["t"][0]) if est["t"].size > 1 else 0.0,
        "J_empirical": float(se.sum()),
        "J_bound": float(trM.sum()),
        "rmse_position_m": [float(v) for v in np.sqrt(se.mean(0))],
        # null for a node that never had a pseudo-measurement (reason in null_reasons)
        "rms_pseudo_measurement_sigma_m": [float(np.sqrt(v / n)) if n else None for v, n in zip(
            np.where(avail, np.trace(est["V"], axis1=-2, axis2=-1), 0.0).sum(0), avail.sum(0))],
        "final_trace_M_m2": [float(v) for v in trM[-1]],
        "bound_holds": [bool(se[:, i].mean() <= trM[:, i].mean()) for i in range(N_NODES)],
        "bound_holds_basis": "single run: time-mean |e_i|^2 <= time-mean tr M_i; per step needs a Monte Carlo",
        "bytes_per_step": {f"{j + 1}->{i + 1}": float(mean_bytes[j, i])
                           for j in range(N_NODES) for i in range(N_NODES) if i != j},
        "bytes_received_per_step": [float(v) for v in mean_bytes.sum(0)],
        "budget_bytes_per_step": [float(BYTES_PER_COMPONENT * b) for b in comm.budget],
        "within_budget": comm.within_budget(),
        **est["health"],
    }
    reasons = {}
    if (~avail.any(0)).any():
        reasons["rms_pseudo_measurement_sigma_m"] = (
            f"nodes {[i + 1 for i in np.flatnonzero(~avail.any(0)).tolist()]}: no UWB pseudo-measurement in the run")
    finite = np.isfinite(se).all(0) & np.isfinite(trM).all(0)  # (N,) per node
    if not finite.all():
        # strict JSON: what a diverged estimate cannot give is null, with the reason beside it
        seen = est["t"][avail.any(1)]
        why = (f"not finite: the fusion diverged (no UWB pseudo-measurement after t = {seen[-1]:g} s)" if seen.size
               else "not finite: the fusion diverged (no UWB pseudo-measurement in the run)")
        for key in ("J_empirical", "J_bound"):
            out[key], reasons[key] = None, why
        for key in ("rmse_position_m", "final_trace_M_m2", "bound_holds"):
            out[key] = [v if ok else None for v, ok in zip(out[key], finite)]
            reasons[key] = f"nodes {[i + 1 for i in np.flatnonzero(~finite).tolist()]}: {why}"
    if reasons:
        out["null_reasons"] = reasons
    if "network" in est:
        from testbed.scoring.metrics import network_summary  # lazy: scipy.stats, only with a [network]

        out["network"] = network_summary(est["network"])
    return out


def run(scenario, log, plots_dir):
    """Pipeline entry: estimate, score, plot (errors of each node with +/- 3 sqrt(diag M))."""
    est = estimate(scenario, log)
    out = scores(est)
    if plots_dir is not None:
        # lazy: matplotlib, only when plots are written
        from testbed.outputs.plots import error_envelope

        e = est["xhat"] - est["truth"][:, None, :]
        for i in range(N_NODES):
            sig = np.sqrt(np.diagonal(est["M"][:, i], axis1=-2, axis2=-1))
            big = float(sig.max()) > 100 * max(float(np.abs(e[:, i]).max()), 1e-9)
            error_envelope(est["t"], e[:, i], None if big else sig, plots_dir / f"bandwidth_error_uav{i + 1}.png",
                           title=f"UAV {i + 1}: estimate - truth of the formation point"
                                 + (" (bound sqrt(diag M) off-scale, not drawn)" if big else ", ±3 sqrt(diag M)"),
                           ylabel="m")
    return {"bandwidth": out}
