"""Writing a run directory (the data contract) atomically.

`run(scenario, out)` simulates (with the estimator of [control] feedback in the loop, if any,
testbed.plugins.online), runs the scenario's estimators (the defaults of its [pipeline] kind and its
`[[estimators]]`, testbed.plugins.defaults), scores a flown run's safety (testbed.scoring.safety), and writes
`scenario.toml`, `scene.xml`, `log.npz`, `metrics.json` (bit-identical for the same seed),
`estimates.npz` (every estimate of the plugin estimators, when there are any),
`timing.json` (wall-clock costs, when a pipeline reports them), `plots/` and the testbed's marker
`.testbed` into a temporary sibling directory that is renamed to `out` only when everything
succeeded (testbed.outdir): an interrupted or failed run leaves nothing half-written. A plugin
estimator that fails is its own result (testbed.plugins.failures): the run is written, marked
incomplete, and then raises EstimatorsFailed (exit 1).
"""
from __future__ import annotations

import gc
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from testbed.config import scenario as scenario_mod
from testbed.errors import ConfigError, RunError
from testbed.interrupt import poll
from testbed.log import LogWriter, NpzLog, save_npz
from testbed.scoring.metrics import ranging_rate
from testbed.outdir import Output, write_json
from testbed.plugins.collect import ESTIMATES_FILE, track_arrays
from testbed.plugins.defaults import estimator_specs
from testbed.plugins.failures import mark_incomplete, raise_failed
from testbed.plugins.loading import resolve
from testbed.plugins.online import in_the_loop
from testbed.outputs.render_overlay import FEEDBACK_FILE, feedback_arrays
from testbed.plugins.run import run_estimators
from testbed.scoring.safety import flight
from testbed.config.scenario import Scenario
from testbed.sim.simulate import record
from testbed.sim.world import build

SPILL_DIR = ".log-chunks"  # inside the run's temporary directory, deleted once log.npz is written


def tracking_rmse(log: Mapping[str, np.ndarray]) -> list[float]:
    """RMS distance (m) between each vehicle's true and reference position, UAV order. From a
    saved log (NpzLog) the positions are read a block of rows at a time: only the distances
    (K, N) are held, not the positions."""
    if isinstance(log, NpzLog):
        err = np.concatenate([np.linalg.norm(t - r, axis=-1) for t, r in zip(log.row_blocks("truth/pos"), log.row_blocks("reference/pos"))])
    else:
        err = np.linalg.norm(log["truth/pos"] - log["reference/pos"], axis=-1)
    return [float(x) for x in np.sqrt((err**2).mean(axis=0))]


def split_timing(estimators: dict) -> tuple[dict, dict]:
    """Separate wall-clock timings (keys ending in `_ms`) from the scores.

    metrics.json must be bit-identical for the same seed, and timings never are: they go to
    timing.json, with the same layout ({estimator: {key: value}}).
    """
    scores = {name: {k: v for k, v in est.items() if not k.endswith("_ms")} for name, est in estimators.items()}
    timing = {name: {k: v for k, v in est.items() if k.endswith("_ms")} for name, est in estimators.items()}
    return scores, {name: t for name, t in timing.items() if t}


@contextmanager
def _long_lived_frozen() -> Iterator[None]:
    """The objects alive before a run (the modules and classes of numpy, scipy, MuJoCo, ...:
    100k-160k after a command's imports) outlive it: Python's cycle collector is kept from
    scanning them at each of its full passes during the run (gc.freeze), then given them back
    (gc.unfreeze; a caller that froze objects itself keeps them frozen). Measured: a 10-s
    coop-denied flight in a process with the bench's imports, 0.1-0.17 s of CPU less (5-8 %)."""
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def run(scenario: Scenario, out: Path, *, force: bool = False, progress: bool = False, plots: bool = True,
        video: bool = False) -> dict:
    """Simulate `scenario` and write its run directory at `out`; returns the metrics.

    `out` follows testbed.outdir (refused if not ours; replaced only with force); video: also
    render `video.mp4` before the directory is put in place. The log streams to chunk files
    (testbed.log.LogWriter) and then into log.npz, from which the scoring reads the arrays it
    needs: a long run of a large swarm never holds its whole log in memory.
    """
    plugins = resolve(estimator_specs(scenario))  # a bad plugin entry stops here, before anything is written
    with _long_lived_frozen(), Output(Path(out), kind="run", force=force) as o:
        tmp = o.path
        writer = LogWriter(tmp / SPILL_DIR)
        try:
            physics = build(scenario)
            online = in_the_loop(scenario, physics, plugins)
            physics = record(scenario, writer, physics, progress=progress, feedback=online)
            done = {online.plugin.key: online.finish()} if online is not None else {}
            writer.save(tmp / "log.npz")
        finally:
            writer.close()
        (tmp / "plots").mkdir()
        with NpzLog(tmp / "log.npz") as log:
            metrics = {
                "scenario": scenario.name,
                "seed": scenario.seed,
                "motion": scenario.motion,
                "duration_s": scenario.duration,
                "vehicles": scenario.vehicles,
                "tracking_rmse_m": tracking_rmse(log),
                "mujoco_warnings": physics.warnings(),
                "estimators": {},
            }
            if (rate := ranging_rate(log, scenario.duration)) is not None:  # [sensors.uwb.schedule] only
                metrics["uwb_pairs_served_per_s"] = rate
            poll()  # a worker asked to stop does so between stages (testbed.interrupt)
            estimators, tracks = run_estimators(scenario, physics, log, plugins, tmp / "plots" if plots else None,
                                                done=done)
            if scenario.motion == "flown":  # contacts, separation, crashes, GNSS outages (testbed.scoring.safety)
                metrics["flight"] = flight(log, physics)
        metrics["estimators"], timing = split_timing(estimators)
        mark_incomplete(metrics)
        poll()
        (tmp / "scenario.toml").write_text(scenario_mod.dumps(scenario))
        (tmp / "scene.xml").write_text(physics.to_xml())
        if online is not None:  # what the controller flew on (the video draws that estimator: testbed.outputs.render_overlay)
            save_npz(tmp / FEEDBACK_FILE, feedback_arrays(done[online.plugin.key][0], scenario.vehicles, online.plugin.key))
        if tracks:  # every estimate of the plugin estimators, for `testbed view` (testbed.viewer)
            save_npz(tmp / ESTIMATES_FILE, {k: v for key, track in tracks.items() for k, v in track_arrays(key, track).items()})
        write_json(tmp / "metrics.json", metrics)
        if timing:
            write_json(tmp / "timing.json", {"scenario": scenario.name, "seed": scenario.seed, "estimators": timing})
        if video:
            from testbed.outputs.render import render_run  # lazy: the renderer loads OpenGL, only for --video

            render_run(tmp, progress=progress)
        o.commit()
    raise_failed(metrics, Path(out) / "metrics.json")
    return metrics


__all__ = ["run", "RunError", "ConfigError", "tracking_rmse", "write_json"]
