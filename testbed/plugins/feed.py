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

import numpy as np

from testbed.errors import PluginError
from testbed.plugins.api import Context, Measurement, MeasurementBatch
from testbed.plugins.collect import Collector, Track
from testbed.plugins.loading import Plugin
from testbed.scenario import Scenario
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


def measurements(scenario: Scenario, log: dict[str, np.ndarray]) -> Iterator[Measurement]:
    """Every measurement of the log in feeding order (see the module docstring); arrays read-only."""
    names = stream_names(log)
    cols = []
    for name in names:
        value = _read_only(np.asarray(log[f"{name}/value"], dtype=float))
        sigma = declared_sigma(name, stream_arrays(name, log), scenario)
        if sigma is not None:
            sigma = _read_only(np.asarray(sigma, dtype=float))
        extra = {k: _read_only(log[f"{name}/{k}"]) for k in MEASURED_EXTRA.get(name, ()) if f"{name}/{k}" in log}
        cols.append((name, log[f"{name}/time"], log[f"{name}/arrival"], value, log[f"{name}/src"], log[f"{name}/dst"], sigma,
                     extra))
    if not cols:
        return
    arrival = np.concatenate([c[2] for c in cols])
    tov = np.concatenate([c[1] for c in cols])
    sid = np.concatenate([np.full(c[1].shape[0], i) for i, c in enumerate(cols)])
    row = np.concatenate([np.arange(c[1].shape[0]) for c in cols])
    for k in np.lexsort((row, sid, tov, arrival)).tolist():
        name, t, a, value, src, dst, sigma, extra = cols[sid[k]]
        r = row[k]
        yield Measurement(stream=name, time=float(t[r]), arrival=float(a[r]), value=value[r], src=str(src[r]),
                          dst=str(dst[r]), sigma=None if sigma is None else sigma[r],
                          extra={c: v[r] for c, v in extra.items()})


def _call(plugin: Plugin, what, fn, *args):
    """Call a plugin method; anything it raises becomes one PluginError line naming plugin and
    `what` (a string, or a Measurement or MeasurementBatch described by _where)."""
    try:
        out = fn(*args)
        return [] if out is None else list(out)
    except Exception as e:
        msg = f"{type(e).__name__}: {e}".splitlines()[0]
        raise PluginError(f"estimator {plugin.key!r} ({plugin.entry}) {_where(what)}: raised {msg}") from None


def _where(what) -> str:
    """When, for an error message: a string as is, a measurement's time and link, a batch's span."""
    if isinstance(what, Measurement):
        return f"at t = {what.time:.6g} s ({what.stream} {what.src}{' -> ' + what.dst if what.dst else ''})"
    if isinstance(what, MeasurementBatch):
        return f"at t = {what.time[0]:.6g} .. {what.time[-1]:.6g} s ({what.stream}, a batch of {len(what)} rows)"
    return what


def run_plugin(plugin: Plugin, context: Context, feed: Iterable[Measurement | MeasurementBatch],
               diagnostics: dict | None = None) -> tuple[Track, dict, float]:
    """Construct the estimator, feed every measurement (a MeasurementBatch whole to an estimator
    with process_batch, else row by row), finish; returns (estimates, health, wall ms). If
    `diagnostics` is a dict, it receives the estimator's optional per-epoch diagnostics()
    ({name: (K,) finite numbers}, one length), checked.

    Raises PluginError (exit 1) on an exception in the plugin or an invalid estimate.
    """
    t0 = wallclock.perf_counter()
    est = _call(plugin, "constructor", lambda: [plugin.cls(context, dict(plugin.params))])[0]
    targets = set(context.vehicles) | set(context.sites)
    col = Collector(plugin, targets, context.duration, {"world", *context.vehicles})
    batch = getattr(est, "process_batch", None)
    batch = batch if callable(batch) else None
    for item in feed:
        if isinstance(item, MeasurementBatch) and batch is None:
            for m in item.rows():
                out = _call(plugin, m, est.process, m)
                if out:
                    col.add(out, _where(m))
            continue
        out = _call(plugin, item, batch if isinstance(item, MeasurementBatch) else est.process, item)
        if out:
            col.add(out, _where(item))
    if callable(getattr(est, "finish", None)):
        col.add(_call(plugin, "in finish()", est.finish), "in finish()")
    health = {}
    if callable(getattr(est, "health", None)):
        raw = _call(plugin, "in health()", lambda: [est.health()])[0]
        if not isinstance(raw, dict) or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in raw.values()):
            raise PluginError(f"estimator {plugin.key!r} ({plugin.entry}) health(): expected {{name: int}}, got {raw!r}"[:300])
        health = {str(k): int(v) for k, v in raw.items()}
    if diagnostics is not None and callable(getattr(est, "diagnostics", None)):
        diagnostics.update(_diagnostics(plugin, _call(plugin, "in diagnostics()", lambda: [est.diagnostics()])[0]))
    return col.track(), health, (wallclock.perf_counter() - t0) * 1e3


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
