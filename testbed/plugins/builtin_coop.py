"""The seed 001 estimators (gnss_only, one_shot, iterated, centralized) as protocol estimators.

Each is a per-epoch solver and naturally online: it collects the GNSS fixes and the tag-to-tag
UWB ranges of one time of validity (an epoch: the instant of the GNSS fixes) and solves that
epoch when a measurement of a later time arrives (or at finish), with the same per-epoch code
as the coop-fg pipeline (testbed.pipelines.coop.solve_epoch); estimates are each vehicle's
`uav{i}/uwb` site position with its covariance. Ranges at instants without GNSS fixes are not
part of an epoch and are ignored, as in the pipeline.

params: the coop-fg [pipeline] keys (the known noise model and solver settings); a key not given
takes the scenario's own [pipeline] value on a coop-fg scenario (testbed.plugins.settings). The fix type (SPP or RTK) is read from the declared sigma of the fix, which the testbed
sets by the fix type the receiver reports. Message loss (params message_loss > 0) draws from the
estimator's own Context.rng, not the pipeline's shared "links" stream, so only loss-free runs
match the pipeline number for number (a test checks that they do).
"""
from __future__ import annotations

import numpy as np

from estimators.sensor_models import gnss_sigma
from testbed.pipelines.coop import epoch_problem, gnss_covariances, solve_epoch
from testbed.pipelines.config import CoopPipelineConfig
from testbed.plugins.api import Context, Estimate, Measurement
from testbed.plugins.epochs import EpochGrouping
from testbed.plugins.settings import settings


class _CoopEpochs(EpochGrouping):
    """Base: one epoch's fixes and ranges (testbed.plugins.epochs); subclasses name the variant."""

    variant = ""

    Params = CoopPipelineConfig  # its parameters (testbed.plugins.settings)

    def __init__(self, context: Context, params: dict):
        self.cfg = settings(CoopPipelineConfig, "coop-fg", context, params, f"coop.{self.variant}")
        self.n = len(context.vehicles)
        self.index = {f"{v}/uwb": i for i, v in enumerate(context.vehicles)}
        gnss = context.sensors.get("gnss", {})
        self.rtk_sigma = gnss_sigma(gnss["rtk"]) if "rtk" in gnss else None
        self.rng = context.rng
        self.t = None
        self.nonconverged = 0
        self._reset()

    def _reset(self) -> None:
        self.fix = np.full((self.n, 3), np.nan)
        self.is_rtk = np.zeros(self.n, bool)
        self.edges: list[tuple[int, int]] = []
        self.ranges: list[float] = []

    def _close(self) -> list[Estimate]:
        if np.isnan(self.fix).all():  # only ranges at this instant: not an epoch
            return []
        missing = [f"uav{i + 1}" for i in np.flatnonzero(np.isnan(self.fix[:, 0]))]
        if missing:
            raise ValueError(f"epoch at t = {self.t:g} s has no GNSS fix of {', '.join(missing)}")
        edges = np.array(self.edges, dtype=np.int64).reshape(-1, 2)
        prob = epoch_problem(self.cfg, self.fix, gnss_covariances(self.cfg, self.is_rtk), edges, np.array(self.ranges, float))
        res, _, converged, _, _ = solve_epoch(self.cfg, self.variant, prob, self.t, self.rng)
        self.nonconverged += int(not converged)
        return [Estimate(time=self.t, target=site, quantity="position", value=res.positions[i], cov=res.cov[i])
                for site, i in self.index.items()]

    def _take(self, i: int, m: Measurement) -> None:
        if m.stream == "gnss":
            self.fix[i] = m.value
            self.is_rtk[i] = self.rtk_sigma is not None and m.sigma is not None and np.allclose(m.sigma, self.rtk_sigma)
        elif m.stream == "uwb" and m.dst in self.index:
            self.edges.append((i, self.index[m.dst]))
            self.ranges.append(float(m.value[0]))

    def health(self) -> dict[str, int]:
        return {"nonconverged_epochs": self.nonconverged}


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
