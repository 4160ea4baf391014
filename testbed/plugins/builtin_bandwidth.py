"""The seed 000 bandwidth-constrained fusion (kind "bandwidth") as a protocol estimator:
`bandwidth.fusion`, the default estimator `bandwidth` of a bandwidth scenario (testbed.plugins.defaults).

The common state x (3,) is the formation's reference point (m, world ENU). UAV i's UWB tag sits at
a known offset o_i (m, world: the vehicle offset plus the tag's 0.17 m mast, level flight, yaw 0)
from it. Epoch k is the instant k dt, k = 0..K, K = floor(duration / dt). Model (paper eqs. 1-3
with eq. 22's known input): x(k+1) = x(k) + v dt + w, A = I3, B = v dt with the configured known
velocity v; W: diag(process_noise), `w_reading` "rate" reads it in m^2/s (per step W dt),
"per-step" as the covariance per step as printed by the paper.

Node i's measurement at epoch k is its four ranges to its anchor group (`groups`, last anchor =
reference) at k dt, turned into a position by the subtraction of eqs. 21-23
(estimators.bandwidth.uwb_pseudo_measurement) with the *known* anchor positions, minus the known
tag offset: y_i = x + v_i, C = I3, V_i(k) by linear error propagation of `range_sigma` at the
measured ranges. An epoch needs all four ranges of a group at k dt: otherwise node i predicts only
(L_i = 0). An epoch is complete when a UWB range of a later time arrives (or at finish); each is one
step of estimators.bandwidth.FusionFilter through the library's online driver
(estimators.core.Stepper), with the messages the selection delivers.

Known configuration with error: anchors get N(0, anchor_error^2) per axis and tag offsets
N(0, offset_error^2) per axis, drawn once from the scenario stream "known-config"
(`known_config`); the initial estimate is x0 + N(0, M0) from the stream "init"
(`initial_estimate`, so that Sigma_i(0) = M_i(0) as the bound assumes).
Faults: `drop_prob` loses each directed message with that probability per step (the estimator's
own Context.rng); `fail_node` (1-based, 0 = none) stops sending at `fail_time` s. A lost component
is compensated by the receiver's own prediction (eq. 6 with that T entry 0).
selection = "search" designs the bound-optimal set from the first epoch's V (every node must
measure then). measurements = "paper" (synthetic data drawn from the truth) is refused: an
estimator never reads the truth (testbed reproduce bandwidth runs the paper's setup itself).

Network ([network] set: Context.channel, testbed.plugins.channel): the messages of the step from
epoch k to k + 1 are sent at k dt, one per directed link j -> i of the delivered design (after the
faults), 8 bytes per selected component, each counting only if it arrives within the network's
round (network.round_s); the others are compensated as a loss. The paper's budget t_i is one
instance of the network's: budget_on = "receive", bandwidth = 8 t_i / dt bytes/s, burst_bytes =
8 t_i passes exactly the designs that respect t_i.

health(): the driver's counts plus `steps` (K), `measurements_used` and
`measurement_epochs_missing` (node-epochs with / without a pseudo-measurement),
`components_received_uav{i}` / `components_sent_uav{i}` (components delivered over the run) and
`steps_over_budget` (steps in which a node received more than its budget) and
`estimates_without_cov` (estimates given without M_i: the bound recursion of eq. 15 diverges for
some designs, and a covariance not finite or numerically singular (testbed.plugins.collect
.cov_problems) is no usable statement of uncertainty) and `estimates_not_finite` (node-epochs
with no estimate: once M_i overflows the fused state does too, from 151.8 s on the `bandwidth`
scenario); the fusion bound and
its scores are the hook testbed.plugins.fusion_bound's.

Estimates at every epoch: node i's estimate of its own UWB tag, `uav{i}/uwb` position =
xhat_i + o_i, with covariance M_i.
"""
from __future__ import annotations

import numpy as np

from estimators import bandwidth as bw
from estimators.bandwidth import BYTES_PER_COMPONENT, uwb_pseudo_measurement
from estimators.core import Epoch, Stepper
from testbed.config.pipelines import N_NODES, BandwidthPipelineConfig
from testbed.plugins.api import Context, Estimate, Measurement
from testbed.plugins.collect import cov_problems
from testbed.plugins.settings import settings
from testbed.rng import stream_rng
from testbed.synthetic.bandwidth import P_SETS, T_SETS


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


class Fusion:
    """seed 000: bandwidth-constrained distributed fusion of the formation point, each node's tag."""

    Params = BandwidthPipelineConfig  # its parameters (testbed.plugins.settings)

    def __init__(self, context: Context, params: dict):
        cfg = self.cfg = settings(BandwidthPipelineConfig, context, params, "bandwidth.fusion")
        if cfg.measurements != "uwb":
            raise ValueError("measurements = \"paper\" draws its data from the truth; a plugin gets the uwb stream: "
                             "use measurements = \"uwb\"")
        if len(context.vehicles) != N_NODES:
            raise ValueError(f"bandwidth.fusion fuses {N_NODES} UAVs, the scenario has {len(context.vehicles)}")
        self.anchors, self.offsets = known_config(cfg, context.seed)
        self.slot = {(f"uav{i + 1}/uwb", f"anchor{a}"): (i, s) for i, g in enumerate(cfg.groups) for s, a in enumerate(g)}
        self.K = int(np.floor(context.duration / cfg.dt + 1e-9))
        self.A, self.B = np.eye(3), np.asarray(cfg.velocity, float) * cfg.dt
        self.W = np.diag(cfg.process_noise) * (cfg.dt if cfg.w_reading == "rate" else 1.0)
        self.P, self.M0, self.budget = P_SETS[cfg.weights], np.diag(cfg.M0), [cfg.budget] * N_NODES
        failed = {cfg.fail_node - 1: int(np.ceil(cfg.fail_time / cfg.dt - 1e-9))} if cfg.fail_node else {}
        self.faults = bw.LinkFaults(drop_prob=cfg.drop_prob, failed=failed) if (cfg.drop_prob > 0 or failed) else None
        self.rng, self.channel = context.rng, context.channel
        self.used = np.zeros(N_NODES, int)  # epochs with a pseudo-measurement, per node
        self.comps = np.zeros((N_NODES, N_NODES), int)  # components delivered j -> i over the run
        self.over = 0  # steps in which a node received more than its budget
        self.unusable = 0  # estimates given without their M (not finite or numerically singular)
        self.lost = 0  # node-epochs without an estimate (the state itself not finite)
        self.net = None if cfg.selection == "search" else bw.FusionNetwork(select=T_SETS[cfg.selection], weights=self.P,
                                                                            budget=self.budget)
        prior = bw.FusionState(xhat=np.tile(initial_estimate(cfg, context.seed), (N_NODES, 1)),
                               M=np.tile(self.M0, (N_NODES, 1, 1)))
        self.stepper = Stepper(bw.FusionFilter(A=self.A, B=self.B, C=(np.eye(3),) * N_NODES, W=self.W), prior)
        self.k = 0  # next epoch
        self.ranges = np.full((N_NODES, 4), np.nan)

    def _design(self, V: tuple, avail: np.ndarray) -> None:
        """selection = "search": the bound-optimal set for the horizon, from the first epoch's V."""
        if not avail.all():
            raise ValueError("selection = \"search\" needs every node's measurement at the first epoch")
        model0 = bw.NetworkModel.create(A=self.A, B=self.B, C=np.eye(3), W=self.W, V=list(V), N=N_NODES)
        S = bw.search_selection(model0, self.P, self.M0, self.K, self.budget, objective="bound").best
        self.net = bw.FusionNetwork(select=S, weights=self.P, budget=self.budget)

    def _epoch(self) -> list[Estimate]:
        k, dt = self.k, self.cfg.dt
        avail = np.isfinite(self.ranges).all(-1)
        y, V = [np.full(3, np.nan)] * N_NODES, [np.eye(3)] * N_NODES
        for i in np.flatnonzero(avail):
            p, Vi = uwb_pseudo_measurement(self.ranges[i][None], self.anchors[np.array(self.cfg.groups[i]) - 1], self.cfg.range_sigma)
            # eq. 23 plus the known offset: y_i = p_tag,i - o_i measures the formation point
            y[i], V[i] = p[0] - self.offsets[i], Vi[0]
        if self.net is None:
            self._design(V, avail)
        self.used += avail
        controls = []
        if k:
            Sn, Pk = self.net.at(k - 1)
            Se = self.faults.effective(Sn, k - 1, self.rng, 1)[0] if self.faults is not None else Sn
            if self.channel is not None:
                Se = self._through_network(Se, (k - 1) * dt)
            comps = bw.link_components(Se)
            self.comps += np.rint(comps).astype(int)
            self.over += int(np.any(comps.sum(0) > np.asarray(self.budget) + 1e-12))
            controls = [(dt, (Se, Pk))]
        # a diverging bound overflows (the paper's T1 on this geometry): detected below and counted, not warned
        with np.errstate(over="ignore", invalid="ignore"):
            b = self.stepper.step(Epoch(k * dt, bw.NodeMeasurements(y=tuple(y), V=tuple(V), available=avail), controls))
        self.k += 1
        self.ranges[:] = np.nan
        # a bound M_i that diverged (the design's recursion can be unstable) is no usable covariance:
        # the estimate goes without it; a state that overflowed with it is no estimate (both counted)
        bad = [p is not None for p in cov_problems(b.M)]
        finite = np.isfinite(b.xhat).all(-1)
        self.unusable += int(np.sum(bad & finite))
        self.lost += int(np.sum(~finite))
        return [Estimate(time=k * dt, target=f"uav{i + 1}/uwb", quantity="position", value=b.xhat[i] + self.offsets[i],
                         cov=None if bad[i] else b.M[i]) for i in np.flatnonzero(finite)]

    def _through_network(self, S: np.ndarray, t: float) -> np.ndarray:
        """Masks (N, N, n) of what arrives within the round of the step's messages sent at t (s):
        each directed message j -> i of design S, BYTES_PER_COMPONENT per selected component."""
        transport = self.channel.transport(t)
        comps = bw.link_components(S)
        Se = S.copy()
        for j, i in zip(*np.nonzero(comps)):
            if not transport.deliver(0, np.array([j]), np.array([i]), int(BYTES_PER_COMPONENT * comps[j, i]))[0]:
                Se[j, i] = 0.0
        return Se

    def _until(self, t: float) -> list[Estimate]:
        """Filter every epoch before time t (s): all their ranges are in."""
        out = []
        while self.k <= self.K and self.k * self.cfg.dt < t - 1e-6:
            out += self._epoch()
        return out

    def process(self, m: Measurement) -> list[Estimate]:
        if m.stream != "uwb":
            return []
        out = self._until(m.time)
        e = int(np.rint(m.time / self.cfg.dt))
        key = self.slot.get((m.src, m.dst))
        if key is not None and e == self.k and e <= self.K and abs(m.time - e * self.cfg.dt) < 1e-6:
            self.ranges[key] = m.value[0]
        return out

    def finish(self) -> list[Estimate]:
        return self._until(np.inf)

    def health(self) -> dict[str, int]:
        return {**self.stepper.track().health(), "steps": self.K, "measurements_used": int(self.used.sum()),
                "measurement_epochs_missing": int((self.K + 1) * N_NODES - self.used.sum()),
                **{f"components_received_uav{i + 1}": int(self.comps[:, i].sum()) for i in range(N_NODES)},
                **{f"components_sent_uav{i + 1}": int(self.comps[i].sum()) for i in range(N_NODES)},
                "steps_over_budget": self.over, "estimates_without_cov": self.unusable, "estimates_not_finite": self.lost}
