"""The Python API of the testbed, re-exported by `import testbed` (docs/api.md).

    sc = testbed.load_scenario("coop-fg", overrides={"sensors.uwb.noise": 0.2}, duration=10)
    r = testbed.run(sc)                     # or testbed.run(sc, out="runs/x")
    r.metrics["estimators"]["centralized"]["rmse_position_mean_m"]
    uwb = r.stream("uwb")                   # Stream: time, value, clean, src, dst, sigma, nlos
    t3 = r.truth("uav3/uwb")                # Truth: pos, quat, vel, omega at r.time
    r2 = testbed.load_run("runs/x")         # the same from a run directory on disk
    r2.provenance["testbed"]["git"]         # how it was made (provenance.json), None if absent
    testbed.view("runs/x")                  # runs/x/recording.rrd: Rerun recording (the viz extra)

A run is always written as a run directory (testbed.runner: scenario.toml, scene.xml, log.npz,
metrics.json, provenance.json, plots/), so what the API returns is exactly what `testbed run`
writes. With `out=None` the directory is a fresh temporary one, removed by `Run.close()` (or
leaving a `with` block, or when the Run is garbage-collected); its log, scene, metrics and
provenance are read into memory first, so they stay usable after it is gone.
"""
from __future__ import annotations

import json
import tempfile
import warnings
from functools import cached_property
from pathlib import Path
from typing import Any, Iterable

import mujoco
import numpy as np

from testbed import provenance, runner
from testbed.config import scenario as scenario_mod
from testbed import reference
from testbed.sim import world
from testbed.errors import RunError
from testbed.log import load_log
from testbed.plugins.api import Estimate
from testbed.plugins.collect import Collector
from testbed.plugins.context import make_context
from testbed.sim.world import lever_arms
from testbed.plugins.loading import Plugin
from testbed.plugins.score import score as score_track
from testbed.plugins.truth import Truth as PluginTruth
from testbed.config.scenario import Scenario
from testbed.stream import Stream, make_stream, stream_names
from testbed.truth import Truth, object_truth
from testbed.viewer import view

RUN_FILES = ("scenario.toml", "scene.xml", "log.npz", "metrics.json")


def builtin_scenarios() -> list[str]:
    """Names of the built-in scenarios (`testbed list`)."""
    return scenario_mod.builtin_names()


def load_scenario(name_or_path: str | Path, overrides: dict[str, Any] | None = None, *, seed: int | None = None,
                  motion: str | None = None, duration: float | None = None) -> Scenario:
    """A validated Scenario: a built-in by name or a TOML file by path, with overrides applied.

    overrides: {dotted key: value}, the `--set` of the command line: keys as in docs/scenario.md,
    list elements by 0-based index (`"world.obstacles[0].size"`, `"trajectory.offsets[2]"`); a
    str value is read as TOML (as `--set` does; a string that is not TOML stays a string), any
    other value (number, bool, list, a config dataclass such as scenario.Obstacle) is used as it
    is. seed, motion ("prescribed" | "flown"), duration (s): None keeps the scenario's.
    Raises testbed.errors.ConfigError naming the file, the key and the value, also for a reference
    path that comes within the airframe radius of the floor, an obstacle or another vehicle
    (world.clearance, as `testbed run` does; "warn": a UserWarning instead).
    """
    sc = scenario_mod.load(str(name_or_path), overrides, seed=seed, motion=motion, duration=duration)
    _check_clearance(sc, scenario_mod.resolve(str(name_or_path))[1])
    return sc


def _check_clearance(sc: Scenario, label: str) -> None:
    """world.clearance (testbed.reference.check_clearance): ConfigError, or a UserWarning."""
    warning = reference.check_clearance(sc, label)
    if warning is not None:
        warnings.warn(warning, UserWarning, stacklevel=3)


class Run:
    """A run directory: its scenario, metrics, log, streams and truth.

    path: the run directory. scenario: the resolved Scenario (from its scenario.toml).
    metrics: metrics.json as a dict (`estimators` -> name -> scores). provenance: provenance.json
    as a dict (testbed version and git commit, command, Python and package versions, BLAS kernel,
    CPU, wall and CPU time: testbed.provenance), None for a run written before it existed.
    time: (K,) s, the log instants. log: every array of log.npz by key (data contract,
    docs/usage.md "Run directory").
    Loaded lazily from disk, except for a temporary run (`run(..., out=None)`), which is read in
    at once. Use as a context manager to remove a temporary run's directory on exit.
    """

    def __init__(self, path: Path, tmp: tempfile.TemporaryDirectory | None = None):
        self.path = Path(path)
        self._tmp = tmp
        self.scenario: Scenario = scenario_mod.load(str(self.path / "scenario.toml"))
        self.metrics: dict = json.loads((self.path / "metrics.json").read_text())
        record = self.path / provenance.PROVENANCE
        self.provenance: dict | None = json.loads(record.read_text()) if record.is_file() else None
        self._scene_xml = (self.path / "scene.xml").read_text()
        if tmp is not None:
            _ = self.log  # read in before the temporary directory can go

    @cached_property
    def log(self) -> dict[str, np.ndarray]:
        return load_log(self.path / "log.npz")

    @property
    def time(self) -> np.ndarray:
        """(K,) s: the log instants (truth is given at these)."""
        return self.log["time"]

    @property
    def files(self) -> dict[str, Path]:
        """The files of the run directory by name (scenario.toml, scene.xml, log.npz,
        metrics.json, and provenance.json, timing.json, plots, video.mp4 where written)."""
        names = (*RUN_FILES, provenance.PROVENANCE, "timing.json", "plots", "video.mp4")
        return {n: self.path / n for n in names if (self.path / n).exists()}

    @property
    def streams(self) -> list[str]:
        """Names of the sensor streams in the log."""
        return stream_names(self.log)

    def stream(self, name: str) -> Stream:
        """Stream `name` (imu, uwb, phase, gnss, camera) with its declared sigma; KeyError if absent."""
        return make_stream(name, self.log, self.scenario)

    @cached_property
    def model(self) -> mujoco.MjModel:
        """The MuJoCo model simulated (scene.xml)."""
        return mujoco.MjModel.from_xml_string(self._scene_xml)

    def truth(self, name: str) -> Truth:
        """Exact pose and velocity of a body (`uav3`, `uav3/base`) or site (`uav3/uwb`,
        `uav3/ant1`, `uav3/imu`, `anchor2`) at the log instants `time`, from the logged qpos/qvel
        and scene.xml. KeyError if the scene has no such site or body."""
        return object_truth(self.model, name, self.time, self.log["qpos"], self.log["qvel"])

    def close(self) -> None:
        """Remove the directory of a temporary run (no effect on a run written to `out`)."""
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> "Run":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r}, scenario={self.scenario.name!r}, seed={self.scenario.seed}, motion={self.scenario.motion!r})"


def run(scenario: Scenario, out: str | Path | None = None, *, force: bool = False, plots: bool = True,
        progress: bool = False, video: bool = False) -> Run:
    """Simulate `scenario`, score its estimators and write the run directory; returns the Run.

    out: the run directory, as `testbed run --out` (refused if it exists and is not an earlier
    output of the testbed; replaced only with force). None: a fresh temporary directory, removed
    by Run.close() (see the module docstring). plots: write plots/*.png; video: video.mp4.
    The reference paths' clearance is checked first, as in load_scenario (the message names the
    scenario by its name). A plugin estimator that fails: the run directory is still written
    (metrics.json marked incomplete, testbed.plugins.failures), then EstimatorsFailed is raised.
    """
    _check_clearance(scenario, scenario.name)
    tmp = None
    if out is None:
        tmp = tempfile.TemporaryDirectory(prefix="testbed-run-")
        out = Path(tmp.name) / "run"
    runner.run(scenario, Path(out), force=force, progress=progress, plots=plots, video=video)
    return Run(Path(out), tmp)


def load_run(path: str | Path) -> Run:
    """The Run of an existing run directory (written by `testbed run` or `testbed.run`).

    Raises testbed.errors.RunError if `path` lacks one of scenario.toml, scene.xml, log.npz,
    metrics.json.
    """
    path = Path(path)
    missing = [f for f in RUN_FILES if not (path / f).is_file()]
    if missing:
        raise RunError(f"{path}: not a run directory (missing {', '.join(missing)})")
    return Run(path)


__all__ = ["Run", "Stream", "Truth", "builtin_scenarios", "load_run", "load_scenario", "run", "score", "view"]


def score(estimates: Iterable[Estimate], run: Run, *, name: str = "estimates") -> dict:
    """Score estimates made outside the testbed (testbed.plugins.Estimate objects: a body or site
    of `run`, position m / velocity m/s / attitude wxyz, world frame, optional covariance) against
    the run's truth with the metrics every estimator gets (testbed.plugins.score: RMSE total, per
    axis and per target, coverage, ANEES with its 95 % interval over effective samples where a
    covariance is given; docs/consistency.md).

    Returns the dict metrics.json would hold for an estimator called `name`. A bad estimate (unknown
    target, wrong shape, NaN, time outside the run, a covariance that is not SPD) raises PluginError.
    """
    physics = world.build(run.scenario)
    context = make_context(run.scenario, lever_arms(physics), name, {})
    collector = Collector(Plugin(key=name, entry="testbed.score", cls=object), set(context.vehicles) | set(context.sites),
                          run.scenario.duration)
    collector.add(list(estimates), "in testbed.score")
    scores, _ = score_track(collector.track(), PluginTruth(run.log, context))
    return scores
