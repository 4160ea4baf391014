"""`testbed replay SPEC.toml --out DIR`: run estimators on a recorded dataset and score them.

The estimators are the spec's [[estimators]] (plus any given on the command line), loaded, fed and
collected by the plugin machinery of a simulated run (testbed.plugins: the same Measurement order,
the same checks of every Estimate) and scored by the same function (testbed.plugins.score) against
the dataset's truth when it has one. The output directory follows testbed.outdir (temporary
sibling, marker, atomic rename) and holds
- spec.toml: the spec as read (enough, with the dataset, to replay again);
- metrics.json (strict JSON): window, measurement counts, per-link residual statistics against
  truth (measured minus true range or range rate: samples, mean, std, RMSE), and per estimator
  its scores (RMSE, ANEES, per target), health counts and the estimates it made that truth cannot
  score (outside the truth's time span, a velocity without truth velocity);
- estimates.npz: every estimate, `KEY/TARGET/QUANTITY/{time,value,cov}` (time in window clock s;
  testbed.plugins.collect.track_arrays),
  and an estimator's per-epoch diagnostics (e.g. graph.poses: iterations, final cost, converged),
  `KEY/diagnostics/NAME` (summarized in metrics.json under `diagnostics`);
- timing.json: wall-clock per estimator; plots/: error plots as a simulated run's.
With a calibration file (`--calibration`, testbed.replay.calibration), metrics.json's
`calibration` names it, its window (never scored) and the noise defaults it gave each estimator.
An estimator that fails is its own result (testbed.plugins.failures): the others are scored, the
directory is written with metrics.json marked incomplete, then EstimatorsFailed (exit 1).
An estimator that gives no estimate says why in one line (silence_reason): in its health block
(`no_estimates`) and on stderr.
"""
from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import numpy as np

from testbed.errors import ConfigError, PluginError
from testbed.log import save_npz
from testbed.scoring.metrics import network_summary
from testbed.outdir import Output, write_json
from testbed.plugins.collect import Series, Track, track_arrays
from testbed.plugins.failures import failed_entry, mark_incomplete, raise_failed
from testbed.plugins.feed import run_plugin
from testbed.plugins.loading import resolve
from testbed.plugins.params import params_class
from testbed.plugins.score import plot_errors, score
from testbed.config.estimators import EstimatorSpec
from testbed.replay.linkstats import link_statistics
from testbed.replay.recording import RecordedTruth, Recording, load_recording


def _scorable(track: Track, truth: RecordedTruth, exclude: tuple[float, float] | None = None) -> tuple[Track, dict[str, int]]:
    """The estimates truth can score, and the count of the others per "target quantity"; an
    estimate relative to a body (its frame) needs that body's truth too, at its time. exclude:
    (t0, t1) window clock s, the calibration window, whose estimates are never scored (counted
    apart, "target quantity in the calibration window")."""
    keep: Track = {}
    dropped: dict[str, int] = {}
    for (target, q), s in track.items():
        bodies = [truth.body_of(target)] + ([s.frame] if s.frame != "world" else [])
        if not truth.known(target, q) or not all(truth.known(b, q) for b in bodies[1:]):
            dropped[f"{target} {q}"] = int(s.time.size)
            continue
        inside = np.logical_and.reduce([(s.time >= truth.span[b][0]) & (s.time <= truth.span[b][1]) for b in bodies])
        if not inside.all():
            dropped[f"{target} {q}"] = int((~inside).sum())
        if exclude is not None:
            fitted = inside & (s.time >= exclude[0]) & (s.time <= exclude[1])
            if fitted.any():
                dropped[f"{target} {q} in the calibration window"] = int(fitted.sum())
            inside &= ~fitted
        if inside.any():
            keep[(target, q)] = Series(s.time[inside], s.value[inside], s.cov[inside], s.has_cov[inside], s.frame)
    return keep, dropped


def _summary(diagnostics: dict[str, np.ndarray]) -> dict:
    """Per-epoch diagnostics summarized: the count, and per column its mean, min and max."""
    n = int(next(iter(diagnostics.values())).size)
    out: dict = {"epochs": n}
    for k, v in diagnostics.items():
        if n and k != "time":
            out[k] = {"mean": float(v.mean()), "min": float(v.min()), "max": float(v.max())}
    return out


def silence_reason(key: str, health: dict[str, int], fed: dict[str, int]) -> str:
    """One line saying why estimator `key` gave no estimate: what it was fed (rows per stream)
    and what its health counted (its nonzero counts), or that it counted nothing, so it used
    none of those rows (no stream, site or body it knows)."""
    rows = ", ".join(f"{k} {n}" for k, n in fed.items() if n) or "nothing"
    counted = ", ".join(f"{k} {n}" for k, n in health.items() if n)
    why = f"its health counts {counted}" if counted else \
        "its health counts nothing: none of them is of a stream, site or body it uses"
    return f"{key}: no estimates from the rows fed ({rows}); {why}"


def replay_recording(rec: Recording, specs: tuple[EstimatorSpec, ...], out_dir: Path | None) -> tuple[dict, dict, dict]:
    """Run and score every estimator on a loaded recording; returns (metrics, estimates arrays,
    timing). out_dir: where plots/ goes (None: no plots)."""
    plugins = resolve(specs)
    truth = RecordedTruth(rec) if "truth" in rec.tables else None
    w = rec.spec.window
    metrics: dict = {
        "description": rec.spec.description,
        "window_s": [w.start, w.end],
        "duration_s": rec.duration,
        "bodies": list(rec.spec.bodies),
        "measurements": rec.counts(),
        "truth": truth is not None,
        "links": link_statistics(rec, truth) if truth is not None else {},
        "estimators": {},
    }
    cal = rec.calibration
    exclude = None if cal is None else (cal.window[0] - w.start, cal.window[1] - w.start)
    if cal is not None:
        metrics["calibration"] = {
            "file": str(cal.path), "window_s": list(cal.window),
            "scoring": "estimates inside the calibration window (its fitted segment) are not scored: "
                       "each estimator's unscored_estimates counts them",
            "noise": cal.noise, "defaults": {}}
    arrays, timing, shown = {}, {}, {}
    for p in plugins:
        diagnostics: dict = {}
        ctx = rec.context(p.key, p.params)
        try:
            track, health, wall_ms = run_plugin(p, ctx, rec.feed, diagnostics)
        except PluginError as e:  # its own result; the others are still scored (testbed.plugins.failures)
            metrics["estimators"][p.key] = failed_entry(p.entry, e)
            continue
        entry: dict = {"entry": p.entry}
        if truth is not None:
            scored, unscored = _scorable(track, truth, exclude)
            scores, errs = score(scored, truth)
            entry.update(scores)
            entry["unscored_estimates"] = unscored
            shown[p.key] = (scored, errs)
        else:
            entry["estimates"] = int(sum(s.time.size for s in track.values()))
            entry["unscored_reason"] = "the dataset has no truth table"
        if not any(s.time.size for s in track.values()):
            reason = silence_reason(p.key, health, rec.counts())
            health = {**health, "no_estimates": reason}
            print(f"testbed: note: {reason}", file=sys.stderr)
        if health:
            entry["health"] = health
        network = ctx.channel.stats() if ctx.channel is not None else None
        if network is not None:
            entry["network"] = network_summary(network)
        if diagnostics:
            entry["diagnostics"] = _summary(diagnostics)
            arrays.update({f"{p.key}/diagnostics/{k}": v for k, v in diagnostics.items()})
        metrics["estimators"][p.key] = entry
        arrays.update(track_arrays(p.key, track))
        timing[p.key] = {"wall_ms": wall_ms}
    if out_dir is not None and shown:
        plot_errors(shown, Path(out_dir) / "plots")
    mark_incomplete(metrics)
    return metrics, arrays, timing


def noise_defaults(specs: tuple[EstimatorSpec, ...], noise: dict[str, float]) -> tuple[tuple[EstimatorSpec, ...], dict]:
    """The specs with a calibration file's noise figures (testbed.replay.calibration.NOISE_KEYS) as
    their params where the estimator's Params has a key of that name and the user set none; and
    {key: {param: value}} of what was set."""
    out, given = [], {}
    for spec, plugin in zip(specs, resolve(specs)):
        Params = params_class(plugin.cls)
        names = {f.name for f in dataclasses.fields(Params)} if Params is not None else set()
        add = {k: v for k, v in noise.items() if k in names and k not in spec.params}
        out.append(dataclasses.replace(spec, params={**spec.params, **add}) if add else spec)
        if add:
            given[spec.key] = add
    return tuple(out), given


def replay(spec_path: Path, out: Path, *, estimators: tuple[EstimatorSpec, ...] = (), force: bool = False,
           plots: bool = True, calibration: Path | None = None) -> dict:
    """Read and check the dataset of spec_path, run its estimators (and `estimators`), write the
    replay directory at `out` (see the module docstring); returns the metrics. calibration: a
    calibration file (`testbed calibrate`): its bias and scale removed from the ranges, its noise
    figures the estimators' defaults (noise_defaults), its window never scored."""
    rec = load_recording(Path(spec_path), calibration=calibration)
    specs = rec.spec.estimators + tuple(estimators)
    if not specs:
        raise ConfigError(f"{spec_path}: no estimator to run: add [[estimators]] tables or --estimator ENTRY")
    resolve(specs)  # a bad entry stops here, before anything is written
    defaults: dict = {}
    if rec.calibration is not None:
        specs, defaults = noise_defaults(specs, rec.calibration.noise)
    with Output(Path(out), kind="replay", force=force) as o:
        (o.path / "plots").mkdir()
        metrics, arrays, timing = replay_recording(rec, specs, o.path if plots else None)
        if defaults:
            metrics["calibration"]["defaults"] = defaults
        metrics = {"spec": str(spec_path), **metrics}
        shutil.copyfile(spec_path, o.path / "spec.toml")
        write_json(o.path / "metrics.json", metrics)
        write_json(o.path / "timing.json", {"spec": str(spec_path), "estimators": timing})
        save_npz(o.path / "estimates.npz", arrays)
        o.commit()
    raise_failed(metrics, Path(out) / "metrics.json")
    return metrics
