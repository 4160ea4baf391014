"""Paper reproductions (`testbed reproduce PAPER --out DIR`): tables, figures and claims.

Each paper's module `testbed.reproduce.<paper>` exposes
`reproduce(out: Path, *, runs: int, motion: str, duration: float | None, workers: int | None) -> dict`
and writes `DIR/table.md`, `DIR/table.csv`, `DIR/claims.json` (a list of the paper's claims, each
with the numbers it was judged on and `holds: true/false`) and `DIR/plots/`.
"""
from __future__ import annotations

import importlib
from pathlib import Path

from testbed.errors import UsageError
from testbed.outdir import Output

DEFAULT_RUNS = {"phase": 20, "visnav": 50, "bandwidth": 500, "coop": 20}


def reproduce(paper: str, out: Path, *, runs: int | None = None, motion: str = "prescribed",
              duration: float | None = None, workers: int | None = None, force: bool = False) -> dict:
    """Dispatch to the paper's reproduction; returns its summary (claims included)."""
    runs = DEFAULT_RUNS[paper] if runs is None else runs
    if runs < 1:
        raise UsageError(f"--runs must be at least 1, got {runs}")
    module = importlib.import_module(f"testbed.reproduce.{paper}")
    with Output(Path(out), kind=f"reproduce-{paper}", force=force) as o:
        result = module.reproduce(o.path, runs=runs, motion=motion, duration=duration, workers=workers)
        o.commit()
    return result
