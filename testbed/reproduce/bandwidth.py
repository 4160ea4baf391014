"""`testbed reproduce bandwidth`: seed 000 reproduction (paper mode; uwb mode being added)."""
from __future__ import annotations

from pathlib import Path

from testbed.reproduce.bandwidth_paper import reproduce_paper


def reproduce(out: Path, *, runs: int, motion: str = "prescribed", duration: float | None = None, workers: int | None = None) -> dict:
    return reproduce_paper(out, runs=runs, seed=0)
