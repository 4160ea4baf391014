"""Paper reproductions (`testbed reproduce PAPER --out DIR`): tables, figures and claims.

Each paper's module `testbed.reproduce.<paper>` has the same shape: `compute` (runs -> numbers),
`decide` (numbers -> `testbed.report.Claim`s), `write` (files through testbed.report), and
`reproduce(out: Path, *, runs: int, motion: str, duration: float | None, workers: int | None) -> dict`
chaining them. It writes `DIR/table.md` (tables and the verdicts), `DIR/table.csv` (every number at
full precision), `DIR/claims.json` (strict JSON: the reproduction's context and `claims`, each with
`id`, the paper's `claim`, the `criterion`, `holds: true/false` and the `numbers` it was judged on)
and `DIR/plots/`. Monte Carlo run i uses the scenario's seed + i (testbed.reproduce.runs). The runs
go to a local process pool or, with `backend="ray"`, to Ray tasks (testbed.workers, testbed.cluster).
"""
from __future__ import annotations

import importlib
from pathlib import Path

from testbed.errors import UsageError
from testbed.outdir import Output
from testbed.workers import backend as use_backend

DEFAULT_RUNS = {"phase": 20, "visnav": 50, "bandwidth": 500, "coop": 20}


def reproduce(paper: str, out: Path, *, runs: int | None = None, motion: str = "prescribed",
              duration: float | None = None, workers: int | None = None, force: bool = False,
              backend: str = "local", address: str | None = None) -> dict:
    """Dispatch to the paper's reproduction; returns its summary (claims included).
    backend, address: where the runs execute, "local" or "ray" (testbed.workers.backend)."""
    runs = DEFAULT_RUNS[paper] if runs is None else runs
    if runs < 1:
        raise UsageError(f"--runs must be at least 1, got {runs}")
    module = importlib.import_module(f"testbed.reproduce.{paper}")
    with use_backend(backend, address), Output(Path(out), kind=f"reproduce-{paper}", force=force) as o:
        result = module.reproduce(o.path, runs=runs, motion=motion, duration=duration, workers=workers)
        o.commit()
    return result
