"""The seed 001 estimators (gnss_only, one_shot, iterated, centralized) as protocol estimators.

Each is a per-epoch solver and naturally online: it collects the GNSS fixes and the tag-to-tag
UWB ranges of one time of validity (an epoch: the instant of the GNSS fixes) and solves that
epoch when a measurement of a later time arrives (or at finish), with the per-epoch code below
(`solve_epoch`, which the coop-fg pipeline also runs); estimates are each vehicle's
`uav{i}/uwb` site position with its covariance. Ranges at instants without GNSS fixes are not
part of an epoch and are ignored, as in the pipeline. Under a [network] table, the broadcasts of
one_shot and iterated travel through the network the runtime hands them (Context.channel,
testbed.plugins.channel). `factor_graphs()` gives the epoch graphs an estimator was given to solve
(the GTSAM check of the centralized solver, testbed.plugins.graph_check).

params: the coop-fg [pipeline] keys (the known noise model and solver settings); a key not given
takes the scenario's own [pipeline] value on a coop-fg scenario (testbed.plugins.settings). The fix type (SPP or RTK) is read from the declared sigma of the fix, which the testbed
sets by the fix type the receiver reports. Message loss (params message_loss > 0) draws from the
estimator's own Context.rng (stream "estimator/NAME").
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from estimators.factor_graph import CoopProblem, solve_centralized, solve_distributed
from estimators.sensor_models import gnss_sigma, twr_range_covariance, twr_range_variance
from estimators.transport import Transport
from testbed.config.pipelines import CoopPipelineConfig
from testbed.plugins.api import Context, EstimateBatch, Measurement
from testbed.plugins.epochs import EpochGrouping
from testbed.plugins.settings import settings


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
    terms of the known model, shared by the links of one radio (estimators.sensor_models.
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
                transport: Transport | None = None):
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




NETWORKED = ("one_shot", "iterated")  # the variants whose messages travel over [network]


class _CoopEpochs(EpochGrouping):
    """Base: one epoch's fixes and ranges (testbed.plugins.epochs); subclasses name the variant."""

    variant = ""

    Params = CoopPipelineConfig  # its parameters (testbed.plugins.settings)

    def __init__(self, context: Context, params: dict):
        self.cfg = settings(CoopPipelineConfig, context, params, f"coop.{self.variant}")
        self.n = len(context.vehicles)
        self.index = {f"{v}/uwb": i for i, v in enumerate(context.vehicles)}
        gnss = context.sensors.get("gnss", {})
        self.rtk_sigma = gnss_sigma(gnss["rtk"]) if "rtk" in gnss else None
        self.rng = context.rng
        self.channel = context.channel  # the runtime's network under [network] (None: ideal)
        self.t = None
        # health(): the per-epoch solver counts the coop scores read (testbed.plugins.coop_scores.SOLVER_COUNTS)
        self.counts = dict.fromkeys(("epochs", "rounds_total", "rounds_max", "messages_total", "bytes_total",
                                     "nonconverged_epochs"), 0)
        self.solved: list[tuple] = []  # (t, fixes, fix types, edges, ranges) of every epoch: factor_graphs()
        self._reset()

    def _reset(self) -> None:
        self.fix = np.full((self.n, 3), np.nan)
        self.is_rtk = np.zeros(self.n, bool)
        self.edges: list[tuple[int, int]] = []
        self.ranges: list[float] = []

    def _close(self) -> list[EstimateBatch]:
        if np.isnan(self.fix).all():  # only ranges at this instant: not an epoch
            return []
        missing = [f"uav{i + 1}" for i in np.flatnonzero(np.isnan(self.fix[:, 0]))]
        if missing:
            raise ValueError(f"epoch at t = {self.t:g} s has no GNSS fix of {', '.join(missing)}")
        edges = np.array(self.edges, dtype=np.int64).reshape(-1, 2)
        ranges = np.array(self.ranges, float)
        self.solved.append((self.t, self.fix.copy(), self.is_rtk.copy(), edges, ranges))
        prob = epoch_problem(self.cfg, self.fix, gnss_covariances(self.cfg, self.is_rtk), edges, ranges)
        transport = self.channel.transport(self.t) if self.channel is not None and self.variant in NETWORKED else None
        res, rounds, converged, messages, nbytes = solve_epoch(self.cfg, self.variant, prob, self.t, self.rng, transport)
        c = self.counts
        c["epochs"] += 1
        c["rounds_total"] += int(rounds)
        c["rounds_max"] = max(c["rounds_max"], int(rounds))
        c["messages_total"] += int(messages)
        c["bytes_total"] += int(nbytes)
        c["nonconverged_epochs"] += int(not converged)
        sites = list(self.index)  # vehicle order: site i is res row i
        # the centralized solver has the cross-covariances of the whole epoch: its joint covariance too
        return [EstimateBatch(time=np.full(self.n, self.t), target=sites, quantity="position", value=res.positions, cov=res.cov,
                              cov_joint=getattr(res, "cov_full", None))]

    def _take(self, i: int, m: Measurement) -> None:
        if m.stream == "gnss":
            self.fix[i] = m.value
            self.is_rtk[i] = self.rtk_sigma is not None and m.sigma is not None and np.allclose(m.sigma, self.rtk_sigma)
        elif m.stream == "uwb" and m.dst in self.index:
            self.edges.append((i, self.index[m.dst]))
            self.ranges.append(float(m.value[0]))

    def factor_graphs(self) -> list[tuple[float, CoopProblem]]:
        """(t s, the epoch's CoopProblem) of every epoch solved, in time order: the graph this
        estimator was given (fixes with their known covariances, ranges with the known model)."""
        return [(t, epoch_problem(self.cfg, fix, gnss_covariances(self.cfg, rtk), e, d)) for t, fix, rtk, e, d in self.solved]

    def health(self) -> dict[str, int]:
        """Epochs solved; solver rounds (iterations) in total and at most; messages and bytes sent
        in total; epochs whose solver stopped at its cap unconverged."""
        return dict(self.counts)


class GnssOnly(_CoopEpochs):
    """seed 001: each UAV's GNSS fix with the known GNSS covariance (no cooperation)."""

    variant = "gnss_only"


class OneShot(_CoopEpochs):
    """seed 001: one broadcast of the fixes, one local Gauss-Newton step per UAV (distributed)."""

    variant = "one_shot"


class Iterated(_CoopEpochs):
    """seed 001: message iteration between neighbours until convergence or the round cap."""

    variant = "iterated"


class Centralized(_CoopEpochs):
    """seed 001: Gauss-Newton on the whole epoch's factor graph (GNSS + UWB), full covariance."""

    variant = "centralized"
