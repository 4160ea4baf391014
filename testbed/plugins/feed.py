"""Measurements of a run log in order of arrival, and feeding them to one estimator.

Only the measured columns of each stream are fed (`NAME/time`, `arrival`, `value`, `src`, `dst`,
and the measured extras of MEASURED_EXTRA) with the declared sigma of the scenario's sensor table;
the truth columns of the log (`clean`, `nlos`, `outlier`, `span`, `state_index`, `bias`,
`slip_injected`, `truth/*`, `qpos`) never reach an estimator.
Order: by arrival time, then time of validity, then stream name, then log row (deterministic).
"""
from __future__ import annotations

import time as wallclock
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from testbed.errors import PluginError
from testbed.plugins.api import Context, Measurement, MeasurementBatch, NavigationStates
from testbed.plugins.collect import Collector, Track
from testbed.plugins.loading import Plugin
from testbed.config.scenario import Scenario
from testbed.stream import declared_sigma, stream_arrays, stream_names

# per stream, the other columns a receiver really reports (Measurement.extra); never truth
MEASURED_EXTRA: dict[str, tuple[str, ...]] = {
    "gnss": ("rtk",),
    "phase": ("master_pos", "master_vel", "rate_periods", "wavelength", "slip"),
}


def _read_only(a: np.ndarray) -> np.ndarray:
    a = np.array(a)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, slots=True)
class Columns:
    """The measured columns of one stream (rows of the log, or of one sample online): what
    `measurement(r)` turns row r into."""

    name: str
    time: np.ndarray
    arrival: np.ndarray
    value: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    sigma: np.ndarray | None
    extra: dict

    def measurement(self, r: int) -> Measurement:
        return Measurement(stream=self.name, time=float(self.time[r]), arrival=float(self.arrival[r]), value=self.value[r],
                           src=str(self.src[r]), dst=str(self.dst[r]), sigma=None if self.sigma is None else self.sigma[r],
                           extra={c: v[r] for c, v in self.extra.items()})


    def batch(self, lo: int, hi: int) -> MeasurementBatch:
        """Rows lo:hi as one MeasurementBatch (a stream without extra columns: batchable)."""
        return MeasurementBatch(stream=self.name, time=_read_only(self.time[lo:hi]), arrival=_read_only(self.arrival[lo:hi]),
                                value=self.value[lo:hi], src=_read_only(self.src[lo:hi]), dst=_read_only(self.dst[lo:hi]),
                                sigma=None if self.sigma is None else self.sigma[lo:hi])

    @property
    def batchable(self) -> bool:
        """Whether runs of rows may go as MeasurementBatches: no extra columns (a batch has none)
        and every row's sigma finite or none declared (a batch row with a non-finite sigma would
        reach process() as sigma None)."""
        return not self.extra and (self.sigma is None or bool(np.isfinite(self.sigma).all()))


def measurement_columns(name: str, arrays: dict[str, np.ndarray], scenario: Scenario) -> Columns:
    """The measured columns of stream `name` from its arrays keyed without the prefix
    (testbed.stream.stream_arrays), with the declared sigma; arrays read-only."""
    value = _read_only(np.asarray(arrays["value"], dtype=float))
    sigma = declared_sigma(name, arrays, scenario)
    if sigma is not None:
        sigma = _read_only(np.asarray(sigma, dtype=float))
    extra = {k: _read_only(arrays[k]) for k in MEASURED_EXTRA.get(name, ()) if k in arrays}
    return Columns(name, arrays["time"], arrays["arrival"], value, arrays["src"], arrays["dst"], sigma, extra)


def measurements(scenario: Scenario, log: dict[str, np.ndarray]) -> Iterator[Measurement]:
    """Every measurement of the log in feeding order (see the module docstring); arrays read-only."""
    cols = [measurement_columns(name, stream_arrays(name, log), scenario) for name in stream_names(log)]
    if not cols:
        return
    sid, row = _order(cols)
    for s, r in zip(sid.tolist(), row.tolist()):
        yield cols[s].measurement(r)


def batched(scenario: Scenario, log: dict[str, np.ndarray]) -> Iterator[Measurement | MeasurementBatch]:
    """The measurements of `measurements` in the same order, each run of consecutive rows of one
    batchable stream (Columns.batchable) as one MeasurementBatch (run_plugin feeds it whole to an
    estimator with process_batch, row by row to the others: the same Measurements)."""
    cols = [measurement_columns(name, stream_arrays(name, log), scenario) for name in stream_names(log)]
    if not cols:
        return
    sid, row = _order(cols)
    if not sid.size:  # streams in the log, none with a row (e.g. a swarm moved out of every range): nothing to feed
        return
    # a run ends where the stream changes or the rows of the stream are not consecutive
    cut = np.flatnonzero((np.diff(sid) != 0) | (np.diff(row) != 1)) + 1
    batchable = [c.batchable for c in cols]
    for lo, hi in zip([0, *cut.tolist()], [*cut.tolist(), len(sid)]):
        c, r = cols[sid[lo]], int(row[lo])
        if hi - lo > 1 and batchable[sid[lo]]:
            yield c.batch(r, r + hi - lo)
        else:
            yield from (c.measurement(k) for k in row[lo:hi].tolist())


def _order(cols: list[Columns]) -> tuple[np.ndarray, np.ndarray]:
    """Every row of cols in feeding order (module docstring): its stream's index in cols and its
    row in that stream, (K,) each."""
    arrival = np.concatenate([c.arrival for c in cols])
    tov = np.concatenate([c.time for c in cols])
    sid = np.concatenate([np.full(c.time.shape[0], i) for i, c in enumerate(cols)])
    row = np.concatenate([np.arange(c.time.shape[0]) for c in cols])
    order = np.lexsort((row, sid, tov, arrival))
    return sid[order], row[order]


def call(plugin: Plugin, what, fn, *args):
    """Call a plugin method; anything it raises becomes one PluginError line naming plugin and
    `what` (a string, or a Measurement or MeasurementBatch described by where)."""
    try:
        out = fn(*args)
        return [] if out is None else list(out)
    except Exception as e:
        msg = f"{type(e).__name__}: {e}".splitlines()[0]
        raise PluginError(f"estimator {plugin.key!r} ({plugin.entry}) {where(what)}: raised {msg}") from None


def where(what) -> str:
    """When, for an error message: a string as is, a measurement's time and link, a batch's span."""
    if isinstance(what, Measurement):
        return f"at t = {what.time:.6g} s ({what.stream} {what.src}{' -> ' + what.dst if what.dst else ''})"
    if isinstance(what, MeasurementBatch):
        return f"at t = {what.time[0]:.6g} .. {what.time[-1]:.6g} s ({what.stream}, a batch of {len(what)} rows)"
    return what


def run_plugin(plugin: Plugin, context: Context, feed: Iterable[Measurement | MeasurementBatch],
               diagnostics: dict | None = None, keep: list | None = None) -> tuple[Track, dict, float]:
    """Construct the estimator, feed every measurement (a MeasurementBatch whole to an estimator
    with process_batch, else row by row), finish; returns (estimates, health, wall ms). If
    `diagnostics` is a dict, it receives the estimator's optional per-epoch diagnostics()
    ({name: (K,) finite numbers}, one length), checked. If `keep` is a list, the finished
    estimator object is appended to it (a check that asks it more, testbed.plugins.graph_check).

    Raises PluginError (exit 1) on an exception in the plugin or an invalid estimate, with the
    time of the measurement (or the first of the batch) it was given then.
    """
    t0 = wallclock.perf_counter()
    est, col = start_plugin(plugin, context)
    for item in feed:
        try:
            if isinstance(item, MeasurementBatch):
                process_batch(plugin, est, col, item)
            else:
                process(plugin, est, col, item)
        except PluginError as e:
            e.time = float(item.time[0] if isinstance(item, MeasurementBatch) else item.time)
            raise
    health = finish_plugin(plugin, est, col)
    if keep is not None:
        keep.append(est)
    if diagnostics is not None and callable(getattr(est, "diagnostics", None)):
        diagnostics.update(_diagnostics(plugin, call(plugin, "in diagnostics()", lambda: [est.diagnostics()])[0]))
    track = col.track()
    if callable(getattr(est, "navigation_states", None)):
        track.navigation = _navigation(plugin, call(plugin, "in navigation_states()", lambda: [est.navigation_states()])[0])
    return track, health, (wallclock.perf_counter() - t0) * 1e3


def _navigation(plugin: Plugin, got: object) -> NavigationStates:
    """The estimator's navigation_states(), checked (api.NavigationStates: shapes, finite, times
    increasing); a PluginError naming the first problem."""
    if not isinstance(got, NavigationStates):
        raise PluginError(f"estimator {plugin.key!r} ({plugin.entry}) navigation_states() returned "
                          f"{type(got).__name__}, expected NavigationStates")
    t, x, P = (np.asarray(a, dtype=float) for a in (got.time, got.mean, got.cov))
    K = t.size
    n = x.shape[1] if x.ndim == 2 else -1
    reason = ("time must be (K,) increasing" if t.ndim != 1 or (K > 1 and np.any(np.diff(t) <= 0))
              else f"mean has shape {x.shape}, expected ({K}, n)" if x.ndim != 2 or x.shape[0] != K
              else f"cov has shape {P.shape}, expected {(K, n, n)}" if P.shape != (K, n, n)
              else f"actual has shape {np.shape(got.actual)}, expected {(K, n, n)}"
              if got.actual is not None and np.shape(got.actual) != (K, n, n)
              else "is not finite" if not all(np.isfinite(a).all() for a in (t, x, P, 0.0 if got.actual is None else got.actual))
              else None)
    if reason is not None:
        raise PluginError(f"estimator {plugin.key!r} ({plugin.entry}) navigation_states(): {reason}")
    return got


def finish_plugin(plugin: Plugin, est: object, col: Collector) -> dict[str, int]:
    """Call the estimator's optional finish() (its estimates into col) and health(); the checked counts."""
    if callable(getattr(est, "finish", None)):
        col.add(call(plugin, "in finish()", est.finish), "in finish()")
    health = {}
    if callable(getattr(est, "health", None)):
        raw = call(plugin, "in health()", lambda: [est.health()])[0]
        if not isinstance(raw, dict) or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in raw.values()):
            raise PluginError(f"estimator {plugin.key!r} ({plugin.entry}) health(): expected {{name: int}}, got {raw!r}"[:300])
        health = {str(k): int(v) for k, v in raw.items()}
    return health


def start_plugin(plugin: Plugin, context: Context) -> tuple[object, Collector]:
    """Construct the estimator and the Collector of its estimates."""
    est = call(plugin, "constructor", lambda: [plugin.cls(context, dict(plugin.params))])[0]
    return est, Collector(plugin, set(context.vehicles) | set(context.sites), context.duration, {"world", *context.vehicles})


def process(plugin: Plugin, est: object, col: Collector, m: Measurement) -> list:
    """Feed one measurement; its estimates, checked, go into col and are returned."""
    out = call(plugin, m, est.process, m)
    if out:
        col.add(out, where(m))
    return out


def process_batch(plugin: Plugin, est: object, col: Collector, b: MeasurementBatch) -> list:
    """Feed a batch: whole to an estimator with process_batch, else row by row; its estimates,
    checked, go into col and are returned."""
    fn = getattr(est, "process_batch", None)
    if not callable(fn):
        return [e for m in b.rows() for e in process(plugin, est, col, m)]
    out = call(plugin, b, fn, b)
    if out:
        col.add(out, where(b))
    return out


def _diagnostics(plugin: Plugin, raw) -> dict[str, np.ndarray]:
    """An estimator's diagnostics() checked: {name: (K,) finite numbers}, one K for all."""
    bad = f"estimator {plugin.key!r} ({plugin.entry}) diagnostics(): expected {{name: (K,) finite numbers}} of one length K"
    if not isinstance(raw, dict):
        raise PluginError(bad + f", got {type(raw).__name__}")
    out = {}
    for k, v in raw.items():
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            raise PluginError(bad + f": {k!r} is not numeric") from None
        if a.ndim != 1 or not np.all(np.isfinite(a)):
            raise PluginError(bad + f": {k!r} has shape {a.shape} or non-finite values")
        out[str(k)] = a
    if len({a.size for a in out.values()}) > 1:
        raise PluginError(bad + f": lengths {sorted({k: a.size for k, a in out.items()}.items())}")
    return out
