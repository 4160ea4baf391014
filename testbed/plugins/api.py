"""The estimator protocol: what the testbed gives a plugin, and what a plugin gives back.

A plugin is a class (see docs/estimators.md)

    class MyEstimator:
        description = "one line"                         # optional, shown by `testbed estimators`
        def __init__(self, context: Context, params: dict): ...
        def process(self, m: Measurement) -> Iterable[Estimate]: ...
        def process_batch(self, b: MeasurementBatch) -> Iterable[Estimate]: ...  # optional, see below
        def finish(self) -> Iterable[Estimate]: ...      # optional
        def health(self) -> dict[str, int]: ...          # optional counts, e.g. covariance_repairs

The testbed constructs it once per run with the `Context` (everything an estimator may know:
geometry, declared sensor models, prior, its params, a random generator), then calls `process`
with every `Measurement` in order of arrival (time of validity + latency), one at a time, and
`finish` once at the end. Runs of consecutive rows of one stream (a recorded dataset's, or one
sensor sample of a whole swarm: the IMUs of every vehicle at one instant) are fed as
`MeasurementBatch`es, as columns: an estimator with `process_batch` gets each batch whole, and
must treat it exactly as its rows one at a time; one without gets the rows one by one through
`process`. Any of these methods may return `EstimateBatch`es (many estimates of one time or
frame, as columns) among its `Estimate`s; they are checked and scored exactly as their rows. Nothing else
is given: never truth, never the simulator's state. The same class therefore runs offline on a
log, on recorded data, or online inside a simulation.

Frames and units: world frame ENU (m), bodies FLU; quaternions wxyz, body-to-world, as MuJoCo.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from estimators.transport import Links

Quantity = Literal["position", "velocity", "attitude"]

# value length of each estimated quantity
VALUE_SIZE: dict[str, int] = {"position": 3, "velocity": 3, "attitude": 4}


@dataclass(frozen=True, kw_only=True, slots=True)
class Measurement:
    """One sensor sample, as the receiving estimator sees it.

    stream: log stream name ("gnss", "uwb", "imu", "phase", "camera"); time: time of validity (s);
    arrival: time + the stream's latency (s), the feeding order; value: (d,) in the stream's units
    (uwb: range m; gnss: antenna position m world; see docs/sensors.md); src, dst: site names
    ("uav3/uwb", "anchor2"), dst "" for a per-vehicle stream; sigma: the declared 1-sigma noise
    (d,) in the units of value, or None when the stream declares none; extra: the stream's other
    measured columns of this row by name (feed.MEASURED_EXTRA: gnss `rtk` (fix type); phase
    `master_pos`, `master_vel` (3,) m, m/s world (the src master antenna from the master's own
    navigation solution), `rate_periods` (periods in the eq. 7 window), `wavelength` m, `slip`;
    empty for the other streams). Arrays are read-only.
    """

    stream: str
    time: float
    arrival: float
    value: np.ndarray
    src: str
    dst: str = ""
    sigma: np.ndarray | None = None
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True, kw_only=True, slots=True)
class MeasurementBatch:
    """Consecutive measurements of one stream in feeding order, as columns (a recorded dataset's
    runs of rows, testbed.replay): what `Estimator.process_batch` receives, or, for an estimator
    without it, one `Measurement` per row (`rows()`), so both see the same data in the same order.

    stream: the stream name; time, arrival: (n,) s; value: (n, d); src, dst: (n,) str (dst "" for a
    per-vehicle stream); sigma: (n, d) declared 1-sigma, NaN in a row that declares none (its
    Measurement has sigma None), or None when no row declares one. Arrays are read-only.
    """

    stream: str
    time: np.ndarray
    arrival: np.ndarray
    value: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    sigma: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.time.shape[0])

    def has_sigma(self) -> np.ndarray:
        """(n,) bool: the rows that declare a sigma."""
        if self.sigma is None:
            return np.zeros(len(self), bool)
        return np.all(np.isfinite(self.sigma), axis=1)

    def rows(self) -> list[Measurement]:
        """One Measurement per row, in order."""
        has = self.has_sigma()
        return [Measurement(stream=self.stream, time=t, arrival=a, value=self.value[i], src=str(self.src[i]),
                            dst=str(self.dst[i]), sigma=self.sigma[i] if has[i] else None)
                for i, (t, a) in enumerate(zip(self.time.tolist(), self.arrival.tolist()))]


@dataclass(frozen=True, kw_only=True, slots=True)
class Estimate:
    """One estimate produced by an estimator.

    time: time of validity (s); target: a body ("uav3") or a site ("uav3/uwb");
    quantity: "position" (m), "velocity" (m/s) or "attitude" (quaternion wxyz, body-to-world);
    frame: "world" (ENU), or a vehicle body "uavJ" for a state relative to that vehicle, in its
    body axes: position R_J^T (p - p_J), velocity R_J^T (v - v_J), attitude R_J^T R (one frame
    per target and quantity); value: (3,) or (4,) for attitude; cov: optional (3, 3) covariance
    (m^2, (m/s)^2; attitude: rad^2 in the body tangent space, the error being log(R_true^T R_est)).
    """

    time: float
    target: str
    quantity: Quantity
    value: np.ndarray
    cov: np.ndarray | None = None
    frame: str = "world"


@dataclass(frozen=True, kw_only=True, slots=True)
class EstimateBatch:
    """Estimates in one frame for several targets, as columns: what an estimator that outputs a
    whole swarm at once may return in place of one `Estimate` per row (the testbed checks and
    scores it exactly as its rows, `rows()`, without a Python object per row).

    time: (n,) s; target: (n,) str; frame: as Estimate, the same for every row; quantity: as
    Estimate, the same for every row, or a sequence of n, one per row (rows of several quantities,
    e.g. the position, velocity and attitude of one target: then value is a sequence of n arrays,
    each its row's (3,) or (4,)); value: (n, 3), or (n, 4) for attitude; cov: optional (n, 3, 3),
    for every row; cov_joint: optional (3n, 3n) joint covariance of all the rows' errors (rows in
    order, of one time of validity, with cov its (3, 3) diagonal blocks; attitude rows in their
    body tangent space as Estimate.cov), for an estimator that has the cross-covariances (a
    centralized solver; a filter's full navigation covariance): scored by the hooks that use it
    (the joint ANEES of testbed.plugins.coop_scores and testbed.plugins.relnav_scores), kept out
    of estimates.npz.
    """

    time: np.ndarray
    target: Sequence[str]
    quantity: Quantity | Sequence[Quantity]
    value: np.ndarray | Sequence[np.ndarray]
    cov: np.ndarray | None = None
    frame: str = "world"
    cov_joint: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.target)

    def quantities(self) -> tuple[str, ...]:
        """The quantity of each row (n,)."""
        return (self.quantity,) * len(self) if isinstance(self.quantity, str) else tuple(self.quantity)

    def parts(self) -> list[EstimateBatch]:
        """The rows as batches of one quantity each (in order of first appearance; no
        cov_joint): the batch itself when it has one quantity."""
        if isinstance(self.quantity, str):
            return [self]
        qs = self.quantities()
        out = []
        for q in dict.fromkeys(qs):
            i = [r for r, x in enumerate(qs) if x == q]
            out.append(EstimateBatch(time=np.asarray(self.time)[i], target=[self.target[r] for r in i], quantity=q,
                                     value=np.stack([np.asarray(self.value[r], float) for r in i]),
                                     cov=None if self.cov is None else np.asarray(self.cov)[i], frame=self.frame))
        return out

    def rows(self) -> list[Estimate]:
        """One Estimate per row, in order."""
        return [Estimate(time=float(t), target=str(k), quantity=q, value=self.value[i],
                         cov=None if self.cov is None else self.cov[i], frame=self.frame)
                for i, (t, k, q) in enumerate(zip(np.asarray(self.time).tolist(), self.target, self.quantities()))]


@dataclass(frozen=True, kw_only=True, slots=True)
class NavigationStates:
    """An estimator's whole navigation state over a run, returned by its OPTIONAL method
    `navigation_states()` (called once, after finish()), for the scoring hooks that judge the full
    state rather than the estimates (the seed 003 18-state ANEES, testbed.plugins.phase_scores).

    time: (K,) s, increasing; mean: (K, n) the state means; cov: (K, n, n) the filter's own
    covariances; actual: optional (K, n, n), the actual error covariance of a covariance-analysis
    filter (estimators.phase_ekf.PhaseEkfCovarianceAnalysis); frame: the frame of the state
    (e.g. "phase-N", the seed 003 navigation frame N, estimators.phase_frames); layout: the name of
    the state's order (e.g. "phase-18", the antenna state of estimators.phase_model). A hook uses
    the states only when it knows their frame and layout.
    """

    time: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    actual: np.ndarray | None = None
    frame: str
    layout: str


@dataclass(frozen=True, kw_only=True, slots=True)
class Context:
    """What an estimator may legitimately know about a run, given to its constructor.

    vehicles: body names ("uav1", ...); sites: {site: (body, lever arm (3,) m body frame)} for every
    vehicle site; anchors: {name: (3,) m world}; sensors: {stream: declared model: rate_hz (Hz),
    latency (s) and the noise parameters of the scenario's [sensors.NAME] table};
    prior: {target: (mean, cov)} the prior the built-in estimators get, in their own state
    (empty when they get none; testbed.plugins.priors.priors lists them per pipeline kind);
    pipeline: the scenario's [pipeline] table with every default written out ({} without one):
    the built-in estimators' settings, their defaults when `params` does not override them;
    params: this estimator's params table; duration: run length (s); motion: "prescribed"
    (kinematic) or "flown" (closed loop); seed: the scenario seed; rng: numpy Generator seeded from the scenario seed under the name "estimator/NAME";
    channel: the network of a distributed estimator's messages when the scenario has [network]
    and the estimator runs on a log (testbed.plugins.channel.Channel: `transport(t)` gives an
    estimators.transport.Transport for the rounds of one solve starting at t s), else None (ideal);
    open_network: the runtime's network model, for an estimator that carries its own broadcasts over
    a [network] table of its params: open_network(cfg, n, rng) -> estimators.transport.Links, cfg a
    testbed.config.network.NetworkConfig (None: ideal), n nodes, drawing from rng
    (testbed.sim.network.Network); None where no runtime made the Context.
    """

    vehicles: tuple[str, ...]
    sites: dict[str, tuple[str, np.ndarray]]
    anchors: dict[str, np.ndarray]
    sensors: dict[str, dict]
    prior: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    pipeline: dict = field(default_factory=dict)
    params: dict = field(default_factory=dict)
    duration: float
    motion: str = "prescribed"
    seed: int
    rng: np.random.Generator
    channel: object | None = None
    open_network: Callable[..., Links] | None = None

    def links(self, cfg: object | None, n: int) -> Links:
        """The links of n nodes of an estimator's own broadcasts under cfg (a NetworkConfig; None:
        ideal), drawn from this Context's rng: open_network(cfg, n, rng)."""
        if self.open_network is None:
            raise ValueError("needs the runtime's network model (Context.open_network), which this Context lacks")
        return self.open_network(cfg, n, self.rng)


@runtime_checkable
class Estimator(Protocol):
    """The protocol a plugin implements (`process_batch`, `finish`, `health` and `description` are
    optional)."""

    def __init__(self, context: Context, params: dict) -> None: ...

    def process(self, m: Measurement) -> Iterable[Estimate] | None: ...
