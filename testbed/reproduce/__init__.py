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
command and seeds, the versions, the verdicts with their tests, the figures and the tables. The runs
go to a local process pool or, with `backend="ray"`, to Ray tasks (testbed.workers, testbed.cluster).
"""
from __future__ import annotations

import importlib
from pathlib import Path

from testbed.errors import UsageError
from testbed.outdir import Output
from testbed.reproduce.document import write_report
from testbed.workers import backend as use_backend

DEFAULT_RUNS = {"phase": 20, "visnav": 50, "bandwidth": 500, "coop": 20, "denied": 5}
DEFAULT_MOTION = {"denied": "flown"}  # --motion when not given: "prescribed" unless listed


def reproduce(paper: str, out: Path, *, runs: int | None = None, motion: str | None = None,
              duration: float | None = None, workers: int | None = None, force: bool = False,
              estimators: tuple = (), backend: str = "local", address: str | None = None) -> dict:
    """Dispatch to the paper's reproduction; returns its summary (claims included).

    estimators: plugin EstimatorSpecs run beside the paper's in every run (coop: one more column of
    Table 4; phase, visnav, bandwidth: one more row each in table.md, testbed.reproduce.plugins);
    backend, address: where the runs execute, "local" or "ray" (testbed.workers.backend)."""
    runs = DEFAULT_RUNS[paper] if runs is None else runs
    motion = motion or DEFAULT_MOTION.get(paper, "prescribed")
    if runs < 1:
        raise UsageError(f"--runs must be at least 1, got {runs}")
    module = importlib.import_module(f"testbed.reproduce.{paper}")
    extra = {"estimators": tuple(estimators)} if estimators else {}
    with use_backend(backend, address), Output(Path(out), kind=f"reproduce-{paper}", force=force) as o:
        result = module.reproduce(o.path, runs=runs, motion=motion, duration=duration, workers=workers, **extra)
        write_report(o.path, paper=paper, command=command(paper, out, runs=runs, motion=motion, duration=duration,
                                                          workers=workers, estimators=tuple(estimators)))
        o.commit()
    return result


def command(paper: str, out: Path, *, runs: int, motion: str, duration: float | None, workers: int | None,
            estimators: tuple = ()) -> str:
    """The command line that reproduces this output (every option explicit)."""
    cmd = f"testbed reproduce {paper} --out {out} --runs {runs} --motion {motion}"
    if duration is not None:
        cmd += f" --duration {duration:g}"
    cmd += "".join(f" --estimator {e.entry}" for e in estimators)
    return cmd + (f" --workers {workers}" if workers is not None else "")
