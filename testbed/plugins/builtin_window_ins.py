"""Built-in `coop.window_ins` and `coop.window_distributed_ins`: the cascade that makes the
cooperative estimate flyable. Per vehicle an IMU-propagated error-state EKF (nav.eskf's filter,
estimators.eskf, driven exactly as `nav.eskf` drives it) whose only position updates are the
cooperative solution: the sliding-window factor graph's (`coop.window`, or
`coop.window_distributed`) per-vehicle antenna position at each epoch, with its marginal
covariance. GNSS fixes and UWB ranges go to the window graph, not to the filters; IMU samples go
to both (to the window they only close epochs).

Why: the window solves 5 Hz epochs of position and velocity without an IMU; held between
epochs, its velocity is off by metres per second at the start (docs/denied.md), and the
controller answers each epoch's step. The filter integrates the IMU at 100 Hz between epochs,
so the controller gets a smooth state (position, velocity, attitude, every `output_every`-th IMU
sample) and the epoch's information enters as a correction weighted against the IMU prediction.

Position update per epoch and vehicle: z = the window's antenna position (its body output plus
the lever arm of the `uwb` site, undoing the window's level-attitude conversion), h(x) = the
antenna position of the filter's state (estimators.eskf.site_position, attitude of the filter),
R = the window's marginal position covariance. The window's epoch closes when the next sample
of a later time arrives (the IMU's, 10 ms later in coop-denied) and the filter is then at the
epoch's time (the closing sample is handed to the window before the filter); an epoch older than
the filter updates its current state, as nav.eskf does with late measurements. The filter
starts at the vehicle's first window position (roll and pitch levelled from the IMU, velocity
0 with vel0_sigma), as nav.eskf starts at its first fix.

The approximation (stated, not corrected): the window's newest-epoch marginal already holds the
measurements of the earlier epochs (through the window and its marginalized prior), which the
filter has received before; feeding each epoch's marginal as an independent measurement counts
that shared information again, so the filter's position covariance is optimistic (it is at most
the window's own, which is already the right uncertainty of the window estimate) and the
filter follows the window more closely than an exact fusion would. The IMU information is what
the cascade adds between epochs; the UWB and GNSS information is the window's alone.

params: those of the window (testbed.plugins.builtin_window: window, q, huber, max_iter,
max_rounds, tol, init_sigma_v, network) and of the filter (testbed.plugins.builtin_eskf: yaw0,
yaw0_sigma, tilt0_sigma, vel0_sigma, gate_prob, output_every), in one table. gate_prob defaults
to 0 here (no innovation gate): the window's position is the filters' only position information,
and a filter that rejects it runs on its IMU alone; measured on a 6 s diagnostic of coop-denied
flown on this estimate (seed 18), the nav.eskf gate (1e-4) rejected 204 of 522 window updates
and the estimates drifted to 10-22 m of error.
"""
from __future__ import annotations

import numpy as np

from estimators import eskf
from testbed.plugins import builtin_eskf, builtin_window
from testbed.plugins.api import Context, Estimate, Measurement
from testbed.plugins.collect import cov_problem


class _Epoch:
    """The window's position of one vehicle as the measurement that starts its filter
    (NavEskf._start reads value and sigma)."""

    __slots__ = ("time", "value", "sigma")

    def __init__(self, time: float, value: np.ndarray, cov: np.ndarray):
        self.time, self.value, self.sigma = time, value, np.sqrt(np.diag(cov))


class _WindowIns(builtin_eskf.NavEskf):
    """nav.eskf's per-vehicle filters, position-updated by a window estimator (module docstring)."""

    window_class: type = builtin_window.Window

    def __init__(self, context: Context, params: dict):
        own = set(builtin_eskf.DEFAULTS)
        unknown = set(params) - own - set(builtin_window.DEFAULTS)
        if unknown:
            raise ValueError(f"unknown params {sorted(unknown)}; known: {sorted(own | set(builtin_window.DEFAULTS))}")
        super().__init__(context, {"gate_prob": 0.0, **{k: v for k, v in params.items() if k in own}})
        self.window = self.window_class(context, {k: v for k, v in params.items() if k not in own})
        self.delay_var = np.zeros(0)  # no UWB range reaches the filters: no antenna-delay states
        self.lever = {v: context.sites[f"{v}/uwb"][1] for v in context.vehicles}  # (3,) m body
        self.counts.update(window_updates=0, invalid_window_updates=0, filter_restarts=0)

    def process(self, m: Measurement) -> list[Estimate]:
        for e in self.window.process(m):
            if e.quantity == "position":
                self._epoch(e)
        return self._imu(m) if m.stream == "imu" else []

    def _imu(self, m: Measurement) -> list[Estimate]:
        """nav.eskf's propagation and output; a filter whose covariance is no longer finite and
        positive definite (after a vehicle tumbled: measured at 48 s of a 60 s flight of seed 18
        on the distributed cascade) is dropped and restarts at the next epoch (counted)."""
        out = super()._imu(m)
        if any(cov_problem(e.cov.tolist()) for e in out):
            self.v[out[0].target].x = None
            self.counts["filter_restarts"] += 1
            return []
        return out

    def finish(self) -> list[Estimate]:
        self.window.finish()  # the last epoch: no IMU sample follows to fly on it
        return []

    def health(self) -> dict[str, int]:
        return {**self.window.health(), **self.counts}

    def _epoch(self, e: Estimate) -> None:
        """The window's body position e of one vehicle: start or update its filter."""
        f, lever = self.v[e.target], self.lever[e.target]
        z = np.asarray(e.value, float) + lever  # the antenna (the window's level conversion undone)
        if f.imu is None:
            self.counts["skipped_updates"] += 1
            return
        if cov_problem(np.asarray(e.cov, float).tolist()):
            self.counts["invalid_window_updates"] += 1
            return
        if f.x is None:
            self._start(f, _Epoch(e.time, z, e.cov), lever)
            return
        self._to(f, e.time)
        self._apply(f, z, lambda x: eskf.site_position(x, lever), np.asarray(e.cov, float))
        self.counts["window_updates"] += 1


class WindowIns(_WindowIns):
    description = "IMU error-state EKF per vehicle, position-updated by coop.window (cascade); flies in the loop"


class WindowDistributedIns(_WindowIns):
    description = "IMU error-state EKF per vehicle, position-updated by coop.window_distributed (cascade)"
    window_class = builtin_window.WindowDistributed
