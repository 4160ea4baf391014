"""Paper reproductions (`testbed reproduce PAPER --out DIR`): tables, figures and claims.

Each paper's module `testbed.reproduce.<paper>` has the same shape: `compute` (runs -> numbers),
`decide` (numbers -> `testbed.outputs.report.Claim`s), `write` (files through testbed.outputs.report), and
`reproduce(out: Path, *, runs: int, motion: str, duration: float | None, workers: int | None) -> dict`
chaining them. It writes `DIR/table.md` (tables and the verdicts), `DIR/table.csv` (every number at
full precision), `DIR/claims.json` (strict JSON: the reproduction's context and `claims`, each with
`id`, the paper's `claim`, the `criterion`, `holds: true/false` (null with `not_decidable`: the runs
never met the claim's condition, testbed.outputs.report.Claim) and the `numbers` it was judged on)
and `DIR/plots/`. Monte Carlo run i uses the scenario's seed + i (testbed.reproduce.runs).
Every claim carries the test that decided it (testbed.scoring.stats; `test` in claims.json). Then
testbed.reproduce.document writes `DIR/report.md` and the self-contained `DIR/report.html`: the
command and seeds, the versions, the verdicts with their tests, the figures and the tables. The runs
go to a local process pool or, with `backend="ray"`, to Ray tasks (testbed.workers, testbed.cluster).

Interrupted (Ctrl-C, SIGTERM, SIGHUP) after at least one Monte Carlo run finished, a reproduction
keeps its finished runs at DIR with `DIR/summary.json` marked incomplete (`"incomplete": true,
"runs_done": k` and the reproduction's options); `resume=True` (`--resume`) continues it with the
same options, skipping the finished runs (testbed.reproduce.runs), and removes summary.json when
done: the outputs are then byte-identical to an uninterrupted reproduction's (all but visnav's
wall-clock columns, its time per filter step and wall time, which differ between any two runs).
A plugin estimator (`--estimator`) that fails in a run is that run's result: its run directory is
written with metrics.json marked incomplete (testbed.plugins.failures), the tables are computed
from the runs where it did not fail, and once everything is written EstimatorsFailed (exit 1)
names the runs and estimators.
"""
from __future__ import annotations

import importlib
import json
import shlex
import signal
from pathlib import Path

import tomli_w

from testbed.errors import EstimatorsFailed, RunError, UsageError
from testbed.interrupt import Interrupted
from testbed.outdir import Output, write_json
from testbed.reproduce.document import write_report
from testbed.reproduce.runs import failed_runs, run_plots as runs_plotted, runs_done
from testbed.workers import backend as use_backend

DEFAULT_RUNS = {"phase": 20, "visnav": 50, "bandwidth": 500, "coop": 20, "denied": 5}
DEFAULT_MOTION = {"denied": "flown"}  # --motion when not given: "prescribed" unless listed
#: written only while a reproduction is incomplete
SUMMARY = "summary.json"


def reproduce(paper: str, out: Path, *, runs: int | None = None, motion: str | None = None,
              duration: float | None = None, workers: int | None = None, force: bool = False,
              estimators: tuple = (), backend: str = "local", address: str | None = None, resume: bool = False,
              run_plots: bool = True) -> dict:
    """Dispatch to the paper's reproduction; returns its summary (claims included).

    estimators: plugin EstimatorSpecs run beside the paper's in every run, each in every table and
    figure that shows the built-ins' per-estimator results and tested against each built-in over
    the same seeds (the paper's module; testbed.reproduce.plugins; denied: offline on the flown
    logs, it does not fly);
    backend, address: where the runs execute, "local" or "ray" (testbed.workers.backend);
    resume: continue the interrupted reproduction at `out` (see the module docstring);
    run_plots: False writes no figures into the Monte Carlo run directories (`--no-run-plots`;
    the reproduction's own figures, DIR/plots/, are drawn all the same, but not the copies of run
    0's figures that coop, phase and bandwidth put there)."""
    runs = DEFAULT_RUNS[paper] if runs is None else runs
    motion = motion or DEFAULT_MOTION.get(paper, "prescribed")
    if runs < 1:
        raise UsageError(f"--runs must be at least 1, got {runs}")
    module = importlib.import_module(f"testbed.reproduce.{paper}")
    extra = {"estimators": tuple(estimators)} if estimators else {}
    options = {"paper": paper, "runs": runs, "motion": motion, "duration": duration,
               "estimators": [e.entry for e in estimators], "run_plots": run_plots}
    with use_backend(backend, address), runs_plotted(run_plots), \
            Output(Path(out), kind=f"reproduce-{paper}", force=force, resume=resume) as o:
        if o.resume:
            _check_resumable(Path(out), options)
        try:
            result = module.reproduce(o.path, runs=runs, motion=motion, duration=duration, workers=workers, **extra)
            write_report(o.path, paper=paper, command=command(paper, out, runs=runs, motion=motion, duration=duration,
                                                              workers=workers, estimators=tuple(estimators),
                                                              run_plots=run_plots))
        except KeyboardInterrupt as e:
            raise _keep_finished(o, options, getattr(e, "signum", signal.SIGINT)) from None
        (o.path / SUMMARY).unlink(missing_ok=True)
        o.commit()
    if failed := failed_runs(Path(out)):  # scored without them; exit 1 once everything is written
        raise EstimatorsFailed(f"estimators failed in {len(failed)} runs of {out}, the tables hold the others (each run's "
                               "metrics.json, or runs.json, says when and why): "
                               + ", ".join(f"{run}: {', '.join(keys)}" for run, keys in failed.items()))
    return result


def _check_resumable(out: Path, options: dict) -> None:
    """Refuse to resume `out` unless it is an interrupted reproduction with the same options."""
    try:
        summary = json.loads((out / SUMMARY).read_text())
    except (OSError, ValueError):
        summary = {}
    if summary.get("incomplete") is not True:
        raise RunError(f"{out}: is not an interrupted reproduction (no incomplete {SUMMARY}); nothing to resume")
    if summary.get("options") != options:
        raise RunError(f"{out}: was reproduced with other options ({out / SUMMARY}: {json.dumps(summary.get('options'))}); "
                       "cannot resume it with these")


def _keep_finished(o: Output, options: dict, signum: int) -> Interrupted:
    """After an interrupt: keep the finished runs at o.out with summary.json marked incomplete
    (unless none finished, or o.out held another output); the Interrupted saying what was kept."""
    done = runs_done(o.path)
    if done and (o.resume or not o.existed):
        write_json(o.path / SUMMARY, {"paper": options["paper"], "options": options, "incomplete": True, "runs_done": done})
        o.commit()
        return Interrupted(signum, f"{done} runs kept in {o.out} ({SUMMARY} marked incomplete; continue with --resume)")
    return Interrupted(signum, f"no run kept; {o.out} left as it was" if o.existed else "no run finished; nothing kept")


def command(paper: str, out: Path, *, runs: int, motion: str, duration: float | None, workers: int | None,
            estimators: tuple = (), run_plots: bool = True) -> str:
    """The command line that reproduces this output (every option explicit, each estimator's params
    as --param KEY=VALUE)."""
    cmd = f"testbed reproduce {paper} --out {out} --runs {runs} --motion {motion}"
    if duration is not None:
        cmd += f" --duration {duration:g}"
    cmd += "".join(f" --estimator {shlex.quote(e.entry)}"
                   + "".join(f" --param {shlex.quote(f'{k}={_toml(v)}')}" for k, v in e.params.items()) for e in estimators)
    if not run_plots:
        cmd += " --no-run-plots"
    return cmd + (f" --workers {workers}" if workers is not None else "")


def _toml(value) -> str:
    """value as `--param` reads it back: a TOML value, a table inline."""
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return tomli_w.dumps({"v": value}).partition("=")[2].strip()
