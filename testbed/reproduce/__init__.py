"""Paper reproductions (`testbed reproduce PAPER --out DIR`): tables, figures and claims.

Each paper's module `testbed.reproduce.<paper>` has the same shape: `compute` (runs -> numbers),
`decide` (numbers -> `testbed.report.Claim`s), `write` (files through testbed.report), and
`reproduce(out: Path, *, runs: int, motion: str, duration: float | None, workers: int | None) -> dict`
chaining them. It writes `DIR/table.md` (tables and the verdicts), `DIR/table.csv` (every number at
full precision), `DIR/claims.json` (strict JSON: the reproduction's context and `claims`, each with
`id`, the paper's `claim`, the `criterion`, `holds: true/false` and the `numbers` it was judged on)
and `DIR/plots/`. Monte Carlo run i uses the scenario's seed + i (testbed.reproduce.runs).
Every claim carries the test that decided it (testbed.stats; `test` in claims.json). Then
testbed.reproduce.document writes `DIR/report.md` and the self-contained `DIR/report.html`: the
command and seeds, the versions, the verdicts with their tests, the figures and the tables.
"""
from __future__ import annotations

import importlib
from pathlib import Path

from testbed.errors import UsageError
from testbed.outdir import Output
from testbed.reproduce.document import write_report

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
        write_report(o.path, paper=paper, command=command(paper, out, runs=runs, motion=motion, duration=duration,
                                                          workers=workers))
        o.commit()
    return result


def command(paper: str, out: Path, *, runs: int, motion: str, duration: float | None, workers: int | None) -> str:
    """The command line that reproduces this output (every option explicit)."""
    cmd = f"testbed reproduce {paper} --out {out} --runs {runs} --motion {motion}"
    if duration is not None:
        cmd += f" --duration {duration:g}"
    return cmd + (f" --workers {workers}" if workers is not None else "")
