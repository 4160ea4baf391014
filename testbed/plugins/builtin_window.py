"""Built-in `coop.window` and `coop.window_distributed`: seed 001's factor graph over a sliding
window of epochs (estimators.window), online, usable in the control loop ([control] feedback).

An epoch is the set of GNSS fixes and UWB ranges of one time of validity; it closes when a
measurement of a later time arrives (the next IMU sample, 10 ms later in coop-denied, or the
next epoch), and is then added to the window and solved: no look-ahead. Each closed epoch gives,
per vehicle "uavI", the body position (the `uwb` antenna's estimate minus its lever arm, taken
level: the window has no attitude; at 10 deg of tilt the 0.17 m mast moves 3 cm) and velocity,
with their marginal covariances. Ranges: tag to tag (the graph's range factors) and tag to
anchor (known anchor positions from the Context). GNSS: the fix's declared sigma. An epoch
before the first with a GNSS fix is skipped (counted).

Range weights. The window takes ranges as independent; their errors are not: every radio's
antenna delay (constant over the run) enters each range it takes part in, at every epoch, and
the window and its prior, which add the epochs up, cannot average it out. `antenna_delays`:
"consider" (coop.window's default): a range's variance is the declared noise, the two-way-ranging
clock term and the link bias (estimators.sensor_models.range_variances without the delays), and
the delays are consider parameters of the centralized window (estimators.window_delays): the
estimate is not corrected for them, its covariance gains what they move it by (docs/estimators.md,
"The window's antenna delays"); "white": each range's variance also holds the two delays as
white noise, 2 sigma_ad^2 (coop.window_distributed, whose message iteration has no consider term,
and the cascades, whose filters take the window's tracklets; docs/denied.md: the centralized
window's position ANEES 3.6-4.1 on 3 dof that way).

params (defaults): window (5 epochs), q (2.0 m^2/s^3, the white acceleration density of the
motion factors), range_scale (1: the factor on every range's 1-sigma; the declared variance
treats the constant antenna delays and the NLOS biases as white, so a window that sees the same
links epoch after epoch is overconfident: position ANEES 19 on 3 dof on coop-denied flown on the
truth, seed 1000; 2.5 with range_scale = 3, docs/denied.md), huber (0: least squares, the seed 001 default; > 0: threshold of a Huber range
loss in sigmas. Measured in the loop on coop-denied, the window alone flown on (no IMU, an
early commit): Huber 1.345 with 5 steps per epoch let the estimate run away, 36 m of vertical
error in 6 s; least squares 2.2 m on the same log. In the cascade coop.window_ins, which flies
on Huber 1.345 by default, the reverse: docs/denied.md),
max_iter (5, Gauss-Newton steps per epoch, centralized), max_rounds (10, message rounds per
epoch, distributed), tol (1e-3 m, the distributed rounds' stopping rule,
estimators.window.Distributed; docs/denied.md, "Stopping the distributed rounds early"), tol_sigma (0.01: the
centralized stopping rule, the newest states' estimated distance to the optimum within that many
of their marginal sigmas; estimators.window, docs/denied.md), init_sigma_v (10 m/s, the first epoch's velocity prior),
network (distributed: a [network] table, docs/network.md, through which the broadcasts travel:
links the runtime opens (Context.links) drawn from the plugin's own rng, one
estimators.transport.Transport of rounds per epoch; absent: ideal). The channel's geometry
(range limit, NLOS loss) is taken from the estimator's own positions and the epoch's ranged
links (the estimator cannot see the truth).
mirrors (true): after each epoch's solve, a vehicle is replaced by its mirror image through the
plane of what it ranged to when the window's measurements favour it 100 to 1 (estimators.window;
health `mirrored` counts them).
The cascade (testbed.plugins.builtin_window_ins, imu_motion) may set `motion`: each vehicle's
known motion over the interval an epoch closes, the input of the window's motion factor
(estimators.window.Epoch.motion).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from estimators import window as sw
from estimators.sensor_models import range_variances
from testbed.config import check_fields, from_dict, key
from testbed.config.network import NetworkConfig
from testbed.plugins.api import Context, Estimate, Measurement
from testbed.plugins.epochs import EpochGrouping
from testbed.plugins.params import fields_of, read


@dataclass(frozen=True, kw_only=True)
class WindowParams:
    """Parameters of coop.window and coop.window_distributed ([[estimators]] params; module docstring)."""

    window: int = key(5, lo=1, doc="epochs in the window")
    q: float = key(2.0, lo=0, unit="m^2/s^3", doc="white acceleration density of the motion factors")
    range_scale: float = key(1.0, lo=0, lo_open=True, doc="factor on every range's 1-sigma")
    antenna_delays: Literal["consider", "white"] = key("consider", doc="the radios' constant antenna delays: consider parameters of the centralized window (estimators.window_delays), or white noise in each range's variance")
    huber: float = key(0.0, lo=0, unit="sigma", doc="Huber range loss threshold (0: least squares)")
    max_iter: int = key(5, lo=1, doc="Gauss-Newton steps per epoch (centralized)")
    max_rounds: int = key(10, lo=1, doc="message rounds per epoch (distributed)")
    tol: float = key(1e-3, lo=0, lo_open=True, unit="m", doc="distributed: rounds stop when every newest position moved less than this")
    tol_sigma: float = key(0.01, lo=0, lo_open=True, unit="sigma", doc="centralized: Gauss-Newton stops when the newest states' estimated distance to the optimum is below this many of their marginal sigmas")
    init_sigma_v: float = key(10.0, lo=0, lo_open=True, unit="m/s", doc="the first epoch's velocity prior, 1 sigma")
    network: dict | None = key(None, range="a [network] table (docs/network.md)", doc="distributed: the channel of the broadcasts (none: ideal)")
    mirrors: bool = key(True, doc="test each vehicle's mirror image through its neighbours' plane after every solve")

    def __post_init__(self) -> None:
        check_fields(self)
        if self.network is not None:
            from_dict(NetworkConfig, self.network, "", "network")


@dataclass(frozen=True, kw_only=True)
class WindowDistributedParams(WindowParams):
    """Parameters of coop.window_distributed: as coop.window's; the antenna delays white only."""

    antenna_delays: Literal["white"] = key("white", doc="the radios' constant antenna delays: white noise in each range's variance (consider parameters: centralized only)")


class _WindowPlugin(EpochGrouping):
    """One epoch's fixes and ranges (testbed.plugins.epochs) and the output; subclasses make the solver."""

    Params = WindowParams

    def __init__(self, context: Context, params: dict):
        self.p = fields_of(read(self.Params, params, type(self).__name__))
        self.vehicles = context.vehicles
        self.n = len(self.vehicles)
        self.index = {f"{v}/uwb": i for i, v in enumerate(self.vehicles)}
        self.lever = np.array([context.sites[f"{v}/uwb"][1] for v in self.vehicles])  # (n, 3) m body
        self.anchors = dict(context.anchors)
        self.anchor_id = {a: k for k, a in enumerate(self.anchors)}  # an anchor's device: n + k
        self.uwb = context.sensors.get("uwb")
        self.solver = self._solver(context)
        self.solver.mirrors = bool(self.p["mirrors"])
        self.t = None
        self.last: sw.WindowEstimate | None = None  # the newest epoch's solution
        # t (s) -> (n, 6) the vehicles' known motion since the window's previous epoch (Epoch.motion;
        # the cascade's IMU filters, testbed.plugins.builtin_window_ins); None: none
        self.motion = None
        self.counts = {"epochs": 0, "skipped_epochs": 0, "nonconverged_epochs": 0, "mirrored": 0, "messages": 0, "bytes_sent": 0}
        self._reset()

    def _solver(self, context: Context):
        raise NotImplementedError

    def _add(self, ep: sw.Epoch) -> sw.WindowEstimate:
        raise NotImplementedError

    def _reset(self) -> None:
        self.fix = np.full((self.n, 3), np.nan)
        self.fix_sigma = np.ones((self.n, 3))
        self.tag: list[tuple[int, int, float, float]] = []  # vehicle, vehicle, range m, declared sigma m
        self.anchor: list[tuple[int, int, np.ndarray, float, float]] = []  # vehicle, anchor k, its position, range, sigma

    def _range_sigmas(self, rows: list[tuple[int, int, float, float]]) -> np.ndarray:
        """(L,) m: the 1-sigma the window gives each range of one epoch, rows (vehicle, other
        device, range m, declared sigma m) (devices: vehicles 0 .. n-1, anchors n + k), by the rule
        of the module docstring ("Range weights")."""
        if not rows:
            return np.zeros(0)
        _, _, d, sigma = (np.array(c) for c in zip(*rows))
        var = range_variances(self.uwb, sigma, d, antenna_delays=self.p["antenna_delays"] == "white")
        return self.p["range_scale"] * np.sqrt(var)

    def _epoch(self) -> sw.Epoch:
        sig = self._range_sigmas(self.tag + [(i, self.n + k, d, s) for i, k, _, d, s in self.anchor])
        tag = np.array(self.tag, float).reshape(-1, 4)
        tag[:, 3] = sig[:len(tag)]
        anc = [(i, pos, d, s) for (i, _, pos, d, _), s in zip(self.anchor, sig[len(tag):])]
        return sw.Epoch(t=self.t, fix=self.fix, fix_sigma=self.fix_sigma, edges=tag[:, :2].astype(np.int64),
                        ranges=tag[:, 2], range_sigma=tag[:, 3],
                        anchor_vehicle=np.array([a[0] for a in anc], np.int64),
                        anchor_pos=np.array([a[1] for a in anc], float).reshape(-1, 3),
                        anchor_range=np.array([a[2] for a in anc], float), anchor_sigma=np.array([a[3] for a in anc], float),
                        anchor_device=np.array([self.n + k for _, k, _, _, _ in self.anchor], np.int64),
                        motion=None if self.motion is None or not self.solver.epochs else self.motion(self.t))

    def _close(self) -> list[Estimate]:
        if np.isnan(self.fix).all() and not self.tag and not self.anchor:
            return []  # an IMU-only instant: not an epoch
        if not self.solver.epochs and np.isnan(self.fix).all():
            self.counts["skipped_epochs"] += 1  # nothing fixes the window yet
            return []
        est = self.last = self._add(self._epoch())
        self.counts["epochs"] += 1
        self.counts["nonconverged_epochs"] += int(not est.converged)
        self.counts["mirrored"] += est.mirrored
        self.counts["messages"] += est.messages
        self.counts["bytes_sent"] += est.bytes_sent
        body = est.pos - self.lever  # level attitude assumed (module docstring)
        out = []
        for i, v in enumerate(self.vehicles):
            out.append(Estimate(time=est.t, target=v, quantity="position", value=body[i], cov=est.pos_cov[i]))
            out.append(Estimate(time=est.t, target=v, quantity="velocity", value=est.vel[i], cov=est.vel_cov[i]))
        return out

    def _take(self, i: int, m: Measurement) -> None:
        if m.stream == "gnss":
            self.fix[i] = m.value
            self.fix_sigma[i] = m.sigma
        elif m.stream == "uwb":
            sigma = float(np.asarray(m.sigma, float)[0])
            if m.dst in self.index:
                self.tag.append((i, self.index[m.dst], float(m.value[0]), sigma))
            elif m.dst in self.anchors:
                self.anchor.append((i, self.anchor_id[m.dst], self.anchors[m.dst], float(m.value[0]), sigma))

    def health(self) -> dict[str, int]:
        return dict(self.counts)


class Window(_WindowPlugin):
    description = "seed 001 factor graph over a sliding window, centralized (GNSS + UWB + anchors); flies in the loop"

    def _solver(self, context):
        p = self.p
        consider = p["antenna_delays"] == "consider" and self.uwb is not None
        return sw.Centralized(self.n, window=int(p["window"]), q=float(p["q"]), huber=float(p["huber"]) or None,
                              max_iter=int(p["max_iter"]), tol=float(p["tol_sigma"]), init_sigma_v=float(p["init_sigma_v"]),
                              delay_sigma=self.uwb["antenna_delay_sigma"] if consider else 0.0,
                              devices=self.n + len(self.anchors))

    def _add(self, ep):
        return self.solver.add(ep)


class WindowDistributed(_WindowPlugin):
    description = "seed 001 sliding-window factor graph, distributed message iteration (optionally over [network])"
    Params = WindowDistributedParams

    def _solver(self, context):
        p = self.p
        net = p["network"]
        cfg = None if net is None else from_dict(NetworkConfig, dict(net), "estimator params network")
        self.network = None if cfg is None else context.links(cfg, self.n)
        self.round_s = 0.0 if cfg is None else cfg.round_s
        return sw.Distributed(self.n, window=int(p["window"]), q=float(p["q"]), huber=float(p["huber"]) or None,
                              max_rounds=int(p["max_rounds"]), tol=float(p["tol"]),
                              init_sigma_v=float(p["init_sigma_v"]))

    def _add(self, ep):
        transport = None
        if self.network is not None:
            pos = self.solver.X[:, -1].reshape(self.n, 6)[:, :3] if self.solver.epochs else np.nan_to_num(ep.fix)
            self.network.set_geometry(ep.t, pos)
            transport = self.network.rounds(ep.t, self.round_s)
        return self.solver.add(ep, transport)

    def health(self):
        out = super().health()
        if self.network is not None:
            out.update({k: int(v) for k, v in self.network.stats().items()
                        if k in ("sent", "delivered", "dropped_loss", "dropped_range")})
        return out
