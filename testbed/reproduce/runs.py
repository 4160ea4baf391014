"""Run numbering of every reproduction: Monte Carlo run i uses seed `base + i` (base: the scenario's
seed) and, when it is a full run directory, lives in `ROOT/run-XXX` (testbed.sweep's convention,
ROOT = OUT/runs or OUT/runs/<scenario> when a reproduction sweeps several scenarios)."""
from __future__ import annotations

import json
from pathlib import Path

from testbed.scenario import Scenario
from testbed.sweep import sweep


def run_name(i: int) -> str:
    """Directory name of run i: run-000, run-001, ..."""
    return f"run-{i:03d}"


def seeds(base: int, runs: int) -> list[int]:
    """Seed of every run: base, base + 1, ..."""
    return [base + i for i in range(runs)]


def sweep_runs(scenario: Scenario, runs: int, root: Path, *, workers: int | None, progress: bool = False) -> list[Path]:
    """Simulate and score runs 0..runs-1 of `scenario` into root/run-XXX (testbed.sweep, replacing
    root); returns the run directories in run order."""
    sweep(scenario, runs, root, workers=workers, force=True, progress=progress)
    return [Path(root) / run_name(i) for i in range(runs)]


def load_metrics(run_dirs: list[Path]) -> list[dict]:
    """metrics.json of every run directory, in the given order."""
    return [json.loads((d / "metrics.json").read_text()) for d in run_dirs]
