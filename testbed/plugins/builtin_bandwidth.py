"""The seed 000 bandwidth-constrained fusion (bandwidth pipeline) as a protocol estimator:
`bandwidth.fusion`.

Online form of testbed.pipelines.bandwidth in "uwb" mode: epoch k is the instant k dt; node i's
measurement is its four ranges to its anchor group at that instant, turned into a position of the
formation point by eqs. 21-23 with the known anchors and tag offset. An epoch is complete when a
UWB range of a later time arrives (or at finish, up to K = floor(duration / dt)); epochs without
any range predict only. Each epoch is one step of the same filter (estimators.bandwidth
.FusionFilter) through the library's online driver (estimators.core.Stepper), with the messages
the nominal selection delivers, so the estimates equal the pipeline's number for number. Not
the pipeline's: message loss (drop_prob > 0) draws from the estimator's own Context.rng, not the
scenario stream "links"; selection = "search" is designed from the first epoch's measurements
(the pipeline's first epoch where every node measured: the same when that is epoch 0, refused
otherwise); measurements = "paper" (synthetic data drawn from the truth) is refused.

Settings: the bandwidth [pipeline] keys (params; the scenario's by default). Known anchors and
tag offsets with their survey errors and the initial estimate come from the scenario streams
"known-config" and "init", like the pipeline's.

Estimates at every epoch: node i's estimate of its own UWB tag, `uav{i}/uwb` position =
xhat_i + o_i (o_i the known tag offset), with covariance M_i.
"""
from __future__ import annotations

import numpy as np

from estimators import bandwidth as bw
from estimators.bandwidth import uwb_pseudo_measurement
from estimators.core import Epoch, Stepper
from testbed.pipelines.bandwidth import initial_estimate, known_config
from testbed.pipelines.config import N_NODES, BandwidthPipelineConfig
from testbed.plugins.api import Context, Estimate, Measurement
from testbed.plugins.settings import settings
from testbed.synthetic.bandwidth import P_SETS, T_SETS


class Fusion:
    """seed 000: bandwidth-constrained distributed fusion of the formation point, each node's tag."""

    Params = BandwidthPipelineConfig  # its parameters (testbed.plugins.settings)

    def __init__(self, context: Context, params: dict):
        cfg = self.cfg = settings(BandwidthPipelineConfig, "bandwidth", context, params, "bandwidth.fusion")
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
        self.rng = context.rng
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
        controls = []
        if k:
            Sn, Pk = self.net.at(k - 1)
            controls = [(dt, (self.faults.effective(Sn, k - 1, self.rng, 1)[0] if self.faults is not None else Sn, Pk))]
        b = self.stepper.step(Epoch(k * dt, bw.NodeMeasurements(y=tuple(y), V=tuple(V), available=avail), controls))
        self.k += 1
        self.ranges[:] = np.nan
        return [Estimate(time=k * dt, target=f"uav{i + 1}/uwb", quantity="position", value=b.xhat[i] + self.offsets[i],
                         cov=b.M[i]) for i in range(N_NODES)]

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
        return self.stepper.track().health()
