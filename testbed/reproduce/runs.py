"""Run numbering of every reproduction: Monte Carlo run i uses seed `base + i` (base: the scenario's
seed) and, when it is a full run directory, lives in `ROOT/run-XXX` (testbed.sweep's convention,
ROOT = OUT/runs or OUT/runs/<scenario> when a reproduction sweeps several scenarios). A sweep
resumes what it finds at ROOT (a resumed reproduction's finished runs), so an interrupted
reproduction continues where it stopped (testbed.reproduce). A reproduction whose runs are not run
directories keeps each run's result in ROOT/run-XXX.pkl instead (save_result, load_result). Within
`run_plots(False)` (`testbed reproduce --no-run-plots`) the run directories get no figures."""
from __future__ import annotations

import json
import os
import pickle
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Iterator

from testbed.errors import EstimatorsFailed
from testbed.config.scenario import Scenario
from testbed.outdir import TMP_TAG
from testbed.progress import enabled
from testbed.sweep import run_complete, sweep


_RUN_PLOTS: ContextVar[bool] = ContextVar("testbed_run_plots", default=True)


@contextmanager
def run_plots(on: bool) -> Iterator[None]:
    """Within the block, sweep_runs' run directories get their figures (on) or none (not on)."""
    token = _RUN_PLOTS.set(bool(on))
    try:
        yield
    finally:
        _RUN_PLOTS.reset(token)


def run_name(i: int) -> str:
    """Directory name of run i: run-000, run-001, ..."""
    return f"run-{i:03d}"


def seeds(base: int, runs: int) -> list[int]:
    """Seed of every run: base, base + 1, ..."""
    return [base + i for i in range(runs)]


def sweep_runs(scenario: Scenario, runs: int, root: Path, *, workers: int | None) -> list[Path]:
    """Simulate and score runs 0..runs-1 of `scenario` into root/run-XXX (testbed.sweep), skipping
    the runs already finished there, with a bar over them where the command shows progress
    (testbed.progress) and their figures unless run_plots(False) says otherwise; returns the run
    directories in run order."""
    try:
        sweep(scenario, runs, root, workers=workers, force=True, resume=True, progress=enabled(), plots=_RUN_PLOTS.get())
    except EstimatorsFailed:  # every run is written; the reproduction reports them at its end (failed_runs)
        pass
    return [Path(root) / run_name(i) for i in range(runs)]


def load_metrics(run_dirs: list[Path]) -> list[dict]:
    """metrics.json of every run directory, in the given order."""
    return [json.loads((d / "metrics.json").read_text()) for d in run_dirs]


def save_result(root: Path, i: int, result: object) -> None:
    """Keep run i's result as root/run-XXX.pkl (written atomically)."""
    path = Path(root) / f"{run_name(i)}.pkl"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}{TMP_TAG}{os.getpid()}")
    try:
        tmp.write_bytes(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def load_result(root: Path, i: int) -> object | None:
    """Run i's result kept by save_result, else None. Only files the testbed wrote are read (the
    reproduction directory carries its marker)."""
    path = Path(root) / f"{run_name(i)}.pkl"
    return pickle.loads(path.read_bytes()) if path.is_file() else None


def runs_done(out: Path) -> int:
    """How many finished Monte Carlo runs a reproduction directory holds (run directories and kept
    results anywhere below it)."""
    return sum(run_complete(p) if p.is_dir() else p.suffix == ".pkl" for p in Path(out).rglob("run-*"))


def failed_runs(out: Path) -> dict[str, list[str]]:
    """{run: the estimators that failed in it} of a reproduction (testbed.plugins.failures): its run
    directories' metrics.json `failed_estimators`, and runs.json's {key: [seeds]} of a reproduction
    that scores its runs in process (visnav)."""
    found: dict[str, list[str]] = {}
    for path in sorted(Path(out).rglob("run-*/metrics.json")):
        keys = json.loads(path.read_text()).get("failed_estimators", [])
        if keys:
            found[str(path.parent.relative_to(out))] = keys
    runs_json = Path(out) / "runs.json"
    if runs_json.is_file():
        for key, seeds in json.loads(runs_json.read_text()).get("failed_estimators", {}).items():
            for seed in seeds:
                found.setdefault(f"seed {seed}", []).append(key)
    return found
