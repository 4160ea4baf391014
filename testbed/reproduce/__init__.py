"""Paper reproductions (`testbed reproduce PAPER --out DIR`): tables, figures and claims.

Each paper's module writes `DIR/table.md`, `DIR/table.csv`, `DIR/claims.json` (a list of the
paper's claims, each with the numbers it was judged on and `holds: true/false`) and `DIR/plots/`.
"""
from __future__ import annotations

from pathlib import Path

from testbed.cli import UsageError

DEFAULT_RUNS = {"phase": 20, "visnav": 50, "bandwidth": 500, "coop": 20}


def reproduce(paper: str, out: Path, *, runs: int | None = None, motion: str = "prescribed",
              duration: float | None = None, workers: int | None = None) -> dict:
    """Dispatch to the paper's reproduction; returns its summary (claims included)."""
    runs = DEFAULT_RUNS[paper] if runs is None else runs
    if runs < 1:
        raise UsageError(f"--runs must be at least 1, got {runs}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if paper == "bandwidth":
        from testbed.reproduce.bandwidth_paper import reproduce_paper

        return reproduce_paper(out, runs=runs, seed=0)
    raise UsageError(f"reproduce {paper}: not available yet (see the open issue for seed {paper})")
