"""Seed 001 estimator pipeline (kind "coop-fg"): run log -> epochs -> four estimators -> scores.

Epochs. One epoch per GNSS sample instant (`gnss/time`; 1 Hz in coop-fg). The UWB ranges of an
epoch are the `uwb` rows taken at the same controller tick (same `state_index`), i.e. the same
physics state: the UWB rate must be a multiple of the GNSS rate (both divide the control rate),
otherwise a GNSS epoch has no ranges and the pipeline refuses the scenario (ConfigError). Only
tag-to-tag links (`uav{i}/uwb` - `uav{j}/uwb`) are used.

The variable of UAV i is the position of its `uav{i}/uwb` site (ENU, m). The GNSS antenna must be
that same site (`sensors.gnss.antenna = "uwb"`): then the fix and the ranges refer to one point
and there is no lever arm (the estimator knows no attitude to rotate one). Truth for scoring is
`gnss/clean` (the physics position of that site at the epoch); the estimators never see it.

Inputs of the estimators, nothing else: `gnss/value` with the receiver's solution type
`gnss/rtk` (a real receiver reports its fix type), `uwb/value`, `uwb/src`, `uwb/dst`, and the
"known" noise model of [pipeline] (gnss_sigma_*, rtk_sigma_*, range_sigma, clock_ppm, twr_mode,
reply_time, antenna_delay_sigma): a mismatch between these and the sensor tables is the
configurable error of the known quantities. The two-way ranging clock and antenna-delay errors
are per device, shared by every link of a radio: the centralized estimator whitens an epoch's
ranges with their joint covariance range_sigma^2 I + twr_range_covariance (range_covariance;
testbed.sensors.noise, docs/sensors.md); the distributed ones (the paper's scheme, ranges
independent) use its diagonal sigma_k^2 = range_sigma^2 + twr_range_variance(d_k) (range_sigmas):
(clock_ppm 1e-6 d_k)^2 / 2 + 2 antenna_delay_sigma^2 for "scale" and "ds-twr" (<= 1.4 mm of clock
at 100 m), plus the reply-time term for "ss-twr". With robust = "huber" the centralized estimator
uses the diagonal too (the Huber loss is defined on independent whitened ranges).
`uwb/nlos` is truth (scoring only).

Estimators (metrics.json `estimators.*`):
- gnss_only: the fix itself, covariance = the known GNSS covariance;
- one_shot: the paper's distributed scheme, one broadcast of the GNSS fixes + one local step;
- iterated: message iteration until every position change < tol or max_rounds (cap);
- centralized: Gauss-Newton on the whole graph (estimators.factor_graph.solve_centralized).
Each has `nonconverged_steps`: epochs whose solver stopped at its iteration or round cap
unconverged (counted, never hidden; converged_fraction is the complement over the epochs).
Faults (item 7): `silent_uav` stops broadcasting from `silent_from_s` on (it still receives,
computes and ranges); each directed delivery is lost with probability `message_loss`, drawn from
`stream_rng(seed, "links")`; receivers keep a neighbour's last message for `max_age` rounds
(-1 = for the whole epoch). Tables start empty at every epoch.
Network ([network] set; testbed.network, docs/network.md): the broadcasts of one_shot and
iterated go through a network of their own (streams "network/one_shot", "network/iterated"),
round r of the epoch at t_k starting at t_k + r round_s; a message is used in its round only if
it arrives within the round (testbed.network.RoundTransport). The channel uses the physical
geometry of the epoch: the uwb sites' positions (`gnss/clean`) for the range limit and the
epoch's ranged pairs' `uwb/nlos` for NLOS (pairs not ranged count as LOS). metrics.json then
has `network` (messages sent / dropped / bytes, latency percentiles, late) under each of the two.
Without [network] nothing changes (ideal channel).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from estimators.core import nees
from estimators.factor_graph import CoopProblem, solve_centralized, solve_distributed
from estimators.sensor_models import twr_range_covariance, twr_range_variance
from testbed.errors import ConfigError
from testbed.interrupt import poll
from testbed.network import Network, NetworkConfig, RoundTransport
from testbed.pipelines.config import CoopPipelineConfig
from testbed.rng import stream_rng

ESTIMATORS = ("gnss_only", "one_shot", "iterated", "centralized")




# ----------------------------------------------------------------------------------------------
# Log -> epochs
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Epochs:
    """The measurements of a run grouped by GNSS epoch (K epochs, N UAVs, UAV order 1..N).

    time: (K,) s; gnss: (K, N, 3) m ENU fixes; is_rtk: (N,) bool (receiver fix type);
    truth: (K, N, 3) m ENU physics position of the uwb sites (scoring only);
    edges: list of K (m_k, 2) int arrays (0-based UAV indices); ranges: list of K (m_k,) m;
    nlos: list of K (m_k,) bool (truth flag, diagnostics only).
    """

    time: np.ndarray
    gnss: np.ndarray
    is_rtk: np.ndarray
    truth: np.ndarray
    edges: list
    ranges: list
    nlos: list


def _uav_index(names: np.ndarray, label: str) -> np.ndarray:
    """'uav7/uwb' -> 6 (0-based). Raises ConfigError on a site that is not a UAV tag."""
    out = np.empty(len(names), dtype=np.int64)
    for k, s in enumerate(names):
        head, _, site = str(s).partition("/")
        if not head.startswith("uav") or site != "uwb":
            raise ConfigError(f"pipeline coop-fg: {label} site {s!r} is not a UAV uwb tag")
        out[k] = int(head[3:]) - 1
    return out


def epochs_from_log(log: dict[str, np.ndarray], n: int) -> Epochs:
    """Group the gnss and uwb streams of a run log into epochs (see Epochs). n: number of UAVs."""
    gi = log["gnss/state_index"]
    ticks = np.unique(gi)
    K = ticks.size
    gnss = np.full((K, n, 3), np.nan)
    truth = np.full((K, n, 3), np.nan)
    veh = log["gnss/vehicle"] - 1
    row = np.searchsorted(ticks, gi)
    gnss[row, veh] = log["gnss/value"]
    truth[row, veh] = log["gnss/clean"]
    if np.isnan(gnss).any():
        raise ConfigError("pipeline coop-fg: every UAV needs a GNSS fix at every epoch (sensors.gnss.vehicles = [] : all)")
    is_rtk = np.zeros(n, bool)
    is_rtk[veh] = log["gnss/rtk"]
    ui = log["uwb/state_index"]
    tag = np.char.endswith(log["uwb/src"].astype(str), "/uwb") & np.char.startswith(log["uwb/src"].astype(str), "uav") \
        & np.char.startswith(log["uwb/dst"].astype(str), "uav")
    src = _uav_index(log["uwb/src"][tag], "uwb/src")
    dst = _uav_index(log["uwb/dst"][tag], "uwb/dst")
    ui, val, nl = ui[tag], log["uwb/value"][tag, 0], log["uwb/nlos"][tag]
    order = np.argsort(ui, kind="stable")
    bounds = np.searchsorted(ui[order], np.concatenate([ticks, [np.iinfo(np.int64).max]]))
    edges, ranges, nlos = [], [], []
    for k in range(K):
        sel = order[bounds[k]:bounds[k + 1]]
        edges.append(np.stack([src[sel], dst[sel]], axis=1))
        ranges.append(val[sel].astype(float))
        nlos.append(nl[sel].astype(bool))
    t = log["time"][ticks]
    return Epochs(t, gnss, is_rtk, truth, edges, ranges, nlos)


# ----------------------------------------------------------------------------------------------
# Estimation
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class CoopEstimates:
    """Per-epoch results of the four estimators (K epochs, N UAVs).

    pos, cov: {name: (K, N, 3) m ENU, (K, N, 3, 3) m^2}; rounds, messages, bytes: {name: (K,)};
    converged: {name: (K,) bool}; joint_nees: (K,) centralized NEES of all 3N coordinates with
    the full covariance (3N dof); epochs: the input; network: {name: Network.stats() plus `late`}
    of the estimators whose messages went through [network] (empty without it).
    """

    epochs: Epochs
    pos: dict
    cov: dict
    rounds: dict
    messages: dict
    bytes: dict
    converged: dict
    joint_nees: np.ndarray
    network: dict = field(default_factory=dict)


def gnss_covariances(cfg: CoopPipelineConfig, is_rtk: np.ndarray) -> np.ndarray:
    """Known GNSS covariances (N, 3, 3) m^2, diagonal (s_h^2, s_h^2, s_v^2) by fix type."""
    sig = np.where(is_rtk[:, None], [cfg.rtk_sigma_h, cfg.rtk_sigma_h, cfg.rtk_sigma_v],
                   [cfg.gnss_sigma_h, cfg.gnss_sigma_h, cfg.gnss_sigma_v])
    cov = np.zeros((is_rtk.size, 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = sig ** 2
    return cov


def range_sigmas(cfg: CoopPipelineConfig, d: np.ndarray) -> np.ndarray:
    """Range standard deviations (m) the estimators assume for ranges d (m): the white noise plus the
    two-way ranging clock and antenna-delay variance of the known model, absorbed as white."""
    return np.sqrt(cfg.range_sigma ** 2 + twr_range_variance(cfg.twr_mode, d, cfg.clock_ppm, cfg.reply_time, cfg.antenna_delay_sigma))


def range_covariance(cfg: CoopPipelineConfig, edges: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Joint covariance (m, m) m^2 the centralized estimator assumes for one epoch's ranges d (m,)
    m on edges (m, 2): the white noise range_sigma^2 I plus the per-device clock and antenna-delay
    terms of the known model, shared by the links of one radio (testbed.sensors.noise.
    twr_range_covariance); its diagonal is range_sigmas(cfg, d)^2."""
    twr = twr_range_covariance(cfg.twr_mode, d, edges[:, 0], edges[:, 1], cfg.clock_ppm, cfg.reply_time, cfg.antenna_delay_sigma)
    return cfg.range_sigma ** 2 * np.eye(d.size) + twr


def epoch_problem(cfg: CoopPipelineConfig, gnss: np.ndarray, gnss_cov: np.ndarray, edges: np.ndarray,
                  ranges: np.ndarray) -> CoopProblem:
    """One epoch's problem: fixes (N, 3) m with known covariances (N, 3, 3), edges (m, 2), ranges (m,) m;
    with the joint range covariance (range_covariance) when the known model has per-device terms."""
    cov = range_covariance(cfg, edges, ranges) if cfg.clock_ppm > 0 or cfg.antenna_delay_sigma > 0 else None
    return CoopProblem(gnss_pos=gnss, gnss_cov=gnss_cov, edges=edges, ranges=ranges, range_sigma=range_sigmas(cfg, ranges),
                       range_cov=cov)


def solve_epoch(cfg: CoopPipelineConfig, w: str, prob: CoopProblem, t: float, rng: np.random.Generator,
                transport: RoundTransport | None = None):
    """Estimator `w` on one epoch at time t (s): (result, rounds, converged, messages, bytes).

    result has positions (N, 3), cov (N, 3, 3) and, for "centralized", cov_full (3N, 3N); rng: the
    message-loss draws (used only when cfg.message_loss > 0 and w is a distributed variant);
    transport: the channel of a distributed variant's broadcasts (None: ideal)."""
    n = prob.gnss_pos.shape[0]
    huber = cfg.huber_delta if cfg.robust == "huber" else None
    if w == "centralized":
        if huber is not None:  # the Huber loss is defined on independent whitened ranges
            prob = replace(prob, range_cov=None)
        res = solve_centralized(prob, huber=huber, covariance="full")
        # every UAV uploads its fix + covariance (9 floats) and the ranges it initiated
        # (value + neighbour id): n messages, 8 (9 n + 2 m) bytes
        return res, res.iterations, res.converged, n, 8 * (9 * n + 2 * prob.m)
    silent = {cfg.silent_uav - 1: 0} if cfg.silent_uav and t >= cfg.silent_from_s else None
    mode = {"gnss_only": "gnss", "one_shot": "single", "iterated": "iterate"}[w]
    loss = cfg.message_loss if mode != "gnss" else 0.0
    res = solve_distributed(prob, mode=mode, neighbour_model=cfg.neighbour_model, max_rounds=cfg.max_rounds,
                            tol=cfg.tol, huber=huber, silent_from=silent, loss_prob=loss,
                            rng=rng if loss > 0 else None, max_age=None if cfg.max_age < 0 else cfg.max_age,
                            damping=cfg.damping, transport=transport)
    return res, res.rounds, res.converged, res.messages, res.bytes_sent


NETWORKED = ("one_shot", "iterated")  # the estimators whose messages travel over [network]


def epoch_los(epochs: Epochs, k: int, n: int) -> np.ndarray:
    """(n, n) bool line of sight at epoch k: False for the pairs ranged NLOS, True otherwise."""
    los = np.ones((n, n), bool)
    e = epochs.edges[k][epochs.nlos[k]]
    los[e[:, 0], e[:, 1]] = los[e[:, 1], e[:, 0]] = False
    return los


def estimate(cfg: CoopPipelineConfig, epochs: Epochs, seed: int, *, which=ESTIMATORS,
             network: NetworkConfig | None = None) -> CoopEstimates:
    """Run the estimators `which` on every epoch. seed: the scenario seed (message-loss and
    network streams); network: the scenario's [network] (None: ideal, module docstring)."""

    K, n = epochs.gnss.shape[:2]
    rng = stream_rng(seed, "links")
    Sg = gnss_covariances(cfg, epochs.is_rtk)
    pos = {w: np.empty((K, n, 3)) for w in which}
    cov = {w: np.empty((K, n, 3, 3)) for w in which}
    rounds = {w: np.zeros(K, dtype=np.int64) for w in which}
    messages = {w: np.zeros(K, dtype=np.int64) for w in which}
    nbytes = {w: np.zeros(K, dtype=np.int64) for w in which}
    conv = {w: np.ones(K, dtype=bool) for w in which}
    joint = np.full(K, np.nan)
    nets = {} if network is None else {w: Network(network, n, stream_rng(seed, f"network/{w}")) for w in which if w in NETWORKED}
    late = dict.fromkeys(nets, 0)
    for k in range(K):
        poll()  # a worker asked to stop does so between epochs (testbed.interrupt)
        prob = epoch_problem(cfg, epochs.gnss[k], Sg, epochs.edges[k], epochs.ranges[k])
        for w in which:
            transport = None
            if w in nets:
                nets[w].set_geometry(epochs.time[k], epochs.truth[k], epoch_los(epochs, k, n))
                transport = RoundTransport(nets[w], epochs.time[k], network.round_s)
            res, rounds[w][k], conv[w][k], messages[w][k], nbytes[w][k] = solve_epoch(cfg, w, prob, epochs.time[k], rng, transport)
            if transport is not None:
                late[w] += transport.late
            pos[w][k], cov[w][k] = res.positions, res.cov
            if w == "centralized":
                joint[k] = float(nees((res.positions - epochs.truth[k]).reshape(-1), res.cov_full))
    stats = {w: {**nw.stats(), "late": float(late[w])} for w, nw in nets.items()}
    return CoopEstimates(epochs, pos, cov, rounds, messages, nbytes, conv, joint, stats)


# ----------------------------------------------------------------------------------------------
# Scores
# ----------------------------------------------------------------------------------------------
def score(est: CoopEstimates) -> dict:
    """The `estimators` object of metrics.json (see the module docstring for the keys)."""
    # lazy: testbed.metrics imports scipy.stats (seconds on a cold cache); only scoring needs it
    from testbed.metrics import anees_keys, effective_samples, network_summary, rmse

    ep = est.epochs
    K, n = ep.gnss.shape[:2]
    spp = ~ep.is_rtk
    out = {}
    for w in est.pos:
        err = est.pos[w] - ep.truth  # (K, N, 3)
        per_uav = rmse(err, axis=0)  # (N,)
        ne = nees(err, est.cov[w])  # (K, N)
        # the epochs of a run are correlated (shared radios, slow GNSS errors), and so are the
        # vehicles of one epoch: the interval counts the effective samples (docs/consistency.md)
        s = {
            "rmse_position_m": [float(x) for x in per_uav],
            "rmse_position_mean_m": float(np.mean(per_uav)),
            "rmse_position_spp_mean_m": _masked_mean(per_uav, spp),
            "rmse_position_rtk_mean_m": _masked_mean(per_uav, ~spp),
            "iterations_mean": float(np.mean(est.rounds[w])),
            "iterations_max": int(np.max(est.rounds[w])),
            "converged_fraction": float(np.mean(est.converged[w])),
            "nonconverged_steps": int(np.count_nonzero(~est.converged[w])),
            "messages_per_epoch": float(np.mean(est.messages[w])),
            "bytes_per_epoch": float(np.mean(est.bytes[w])),
            **anees_keys(ne, 3),
            "anees_spp": _masked_mean(ne, spp),
            "anees_rtk": _masked_mean(ne, ~spp),
            "n_eff_spp": effective_samples(ne[:, spp]) if spp.any() else None,
            "epochs": int(K),
        }
        # strict JSON: a score that cannot exist is null, with the reason beside it
        why = {f"{k}_{g}{u}": f"no {g.upper()} vehicle in this scenario" for g, m in (("spp", spp), ("rtk", ~spp)) if not m.any()
               for k, u in (("rmse_position", "_mean_m"), ("anees", ""))}
        if not spp.any():
            why["n_eff_spp"] = "no SPP vehicle in this scenario"
        if why:
            s["null_reasons"] = why
        if w in est.network:
            s["network"] = network_summary(est.network[w])
        if w == "centralized":
            s.update(anees_keys(est.joint_nees, 3 * n, "anees_joint"))
        out[w] = s
    nl = np.concatenate(ep.nlos) if ep.nlos else np.zeros(0, bool)
    out["iterated"]["nlos_fraction"] = float(nl.mean()) if nl.size else 0.0
    return out


def _masked_mean(x: np.ndarray, mask: np.ndarray) -> float | None:
    """Mean of x[..., mask] (mask: (N,) bool over vehicles, the last axis of x); None if mask is empty."""
    return float(np.mean(x[..., mask])) if mask.any() else None


def neighbour_counts(epochs: Epochs) -> tuple[np.ndarray, np.ndarray]:
    """Mean over epochs of each UAV's number of UWB neighbours and of RTK neighbours: (N,), (N,)."""
    K, n = epochs.gnss.shape[:2]
    nb = np.zeros(n)
    nr = np.zeros(n)
    for e in epochs.edges:
        np.add.at(nb, e[:, 0], 1.0)
        np.add.at(nb, e[:, 1], 1.0)
        np.add.at(nr, e[:, 0], epochs.is_rtk[e[:, 1]].astype(float))
        np.add.at(nr, e[:, 1], epochs.is_rtk[e[:, 0]].astype(float))
    return nb / K, nr / K


def choose_four(epochs: Epochs) -> list[int]:
    """Four SPP UAVs (1-based) with different neighbour counts, like the paper's UAVs 1, 7, 12, 13:
    the SPP UAVs sorted by (mean neighbours, RTK neighbours, number), taken at the 0, 1/3, 2/3 and
    1 quantiles of that order."""
    nb, nr = neighbour_counts(epochs)
    spp = np.flatnonzero(~epochs.is_rtk)
    order = spp[np.lexsort((spp, nr[spp], nb[spp]))]
    picks = np.round(np.linspace(0, order.size - 1, 4)).astype(int)
    return [int(order[p]) + 1 for p in picks]


# ----------------------------------------------------------------------------------------------
# Plots
# ----------------------------------------------------------------------------------------------
def plot_error_vs_time(est: CoopEstimates, uavs: list[int], path: Path, title: str) -> Path:
    """Figure 6: position error norm (m) against time for four UAVs (1-based), every estimator."""
    from testbed.plots import figure, save

    nb, nr = neighbour_counts(est.epochs)
    fig = figure(figsize=(8, 2.0 * len(uavs) + 0.6))
    axes = fig.subplots(len(uavs), 1, sharex=True)
    for ax, u in zip(np.atleast_1d(axes), uavs):
        for c, w in enumerate(est.pos):
            e = np.linalg.norm(est.pos[w][:, u - 1] - est.epochs.truth[:, u - 1], axis=1)
            ax.plot(est.epochs.time, e, lw=0.8, color=f"C{c}", label=w)
        ax.set_yscale("log")
        ax.set_ylabel("|error| [m]")
        ax.set_title(f"UAV {u}: {nb[u - 1]:.1f} neighbours, {nr[u - 1]:.1f} RTK neighbours", fontsize=9)
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].legend(fontsize=7, ncol=4, loc="upper right")
    np.atleast_1d(axes)[-1].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=10)
    return save(fig, path)


def write_plots(est: CoopEstimates, scores: dict, uavs: list[int], plots_dir: Path) -> None:
    """Figure 6, the iterated error of the first chosen UAV with its own 3-sigma envelope (shows
    the over-confidence), the centralized one likewise, and the mean RMSE per estimator."""
    # lazy: matplotlib, only when plots are written
    from testbed.plots import compare_bars, error_envelope

    plot_error_vs_time(est, uavs, plots_dir / "fig6_error_vs_time.png", "Position error of four UAVs")
    u = uavs[0] - 1
    for w in ("iterated", "centralized"):
        if w in est.pos:
            err = est.pos[w][:, u] - est.epochs.truth[:, u]
            sig = np.sqrt(np.diagonal(est.cov[w][:, u], axis1=1, axis2=2))
            error_envelope(est.epochs.time, err, sig, plots_dir / f"{w}_uav{u + 1}_envelope.png",
                           title=f"{w}: UAV {u + 1} position error and its own 3-sigma", ylabel="m", labels=("E", "N", "U"))
    names = list(scores)
    means = np.array([scores[w]["rmse_position_mean_m"] for w in names])
    compare_bars(names, means, means, means, plots_dir / "rmse_mean.png", title="Mean per-UAV position RMSE",
                 ylabel="RMSE [m]")


def run(scenario, log, plots_dir):
    """Pipeline entry: (scenario, run log, plots dir or None) -> metrics.json `estimators`."""
    ep = epochs_from_log(log, scenario.vehicles)
    est = estimate(scenario.pipeline, ep, scenario.seed, network=scenario.network)
    scores = score(est)
    uavs = list(scenario.pipeline.plot_uavs) or choose_four(ep)
    if plots_dir is not None:
        write_plots(est, scores, uavs, Path(plots_dir))
    return scores
