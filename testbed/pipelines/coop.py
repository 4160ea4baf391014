"""Seed 001 batch estimation over a run's epochs (kind "coop-fg"): epochs -> four estimators -> scores.

A run of coop-fg runs the four estimators as plugins (coop.gnss_only, coop.one_shot,
coop.iterated, coop.centralized: testbed.plugins.builtin_coop, the defaults of the kind,
testbed.plugins.defaults) and scores them with the seed 001 hook (testbed.plugins.coop_scores).
What is left here is the same per-epoch code run over a whole log at once, for the reproduction's
re-solves of a run (its round-cap and NLOS experiments, figure 6 of run 0) and the tests; given
the same names it gives the plugins' estimates number for number.

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
estimators.sensor_models, docs/sensors.md); the distributed ones (the paper's scheme, ranges
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
the estimator's own stream `stream_rng(seed, "estimator/NAME")` (its plugin's Context.rng);
receivers keep a neighbour's last message for `max_age` rounds (-1 = for the whole epoch). Tables start empty at every epoch.
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

from dataclasses import dataclass, field

import numpy as np

from estimators.core import nees
from testbed.interrupt import poll
from testbed.network import Network, NetworkConfig, RoundTransport
from testbed.pipelines.config import CoopPipelineConfig
from testbed.plugins.builtin_coop import NETWORKED, epoch_problem, gnss_covariances, solve_epoch
from testbed.plugins.coop_scores import Epochs
from testbed.rng import stream_rng

ESTIMATORS = ("gnss_only", "one_shot", "iterated", "centralized")




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
    rng = {w: stream_rng(seed, f"estimator/{w}") for w in which}  # the plugins' Context.rng
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
            res, rounds[w][k], conv[w][k], messages[w][k], nbytes[w][k] = solve_epoch(cfg, w, prob, epochs.time[k], rng[w], transport)
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
    from testbed.metrics import anees_keys, network_summary
    from testbed.plugins.coop_scores import position_scores

    ep = est.epochs
    n = ep.gnss.shape[1]
    out = {}
    for w in est.pos:
        p = position_scores(est.pos[w] - ep.truth, est.cov[w], ep.is_rtk)
        solver = {"iterations_mean": float(np.mean(est.rounds[w])), "iterations_max": int(np.max(est.rounds[w])),
                  "converged_fraction": float(np.mean(est.converged[w])), "nonconverged_steps": int(np.count_nonzero(~est.converged[w])),
                  "messages_per_epoch": float(np.mean(est.messages[w])), "bytes_per_epoch": float(np.mean(est.bytes[w]))}
        # metrics.json order of the pipeline: the per-vehicle RMSE is `rmse_position_m` here
        head = ("rmse_position_mean_m", "rmse_position_spp_mean_m", "rmse_position_rtk_mean_m")
        s = {"rmse_position_m": p.pop("rmse_position_per_vehicle_m"), **{k: p.pop(k) for k in head}, **solver, **p}
        if w in est.network:
            s["network"] = network_summary(est.network[w])
        if w == "centralized":
            s.update(anees_keys(est.joint_nees, 3 * n, "anees_joint"))
        out[w] = s
    nl = np.concatenate(ep.nlos) if ep.nlos else np.zeros(0, bool)
    out["iterated"]["nlos_fraction"] = float(nl.mean()) if nl.size else 0.0
    return out
