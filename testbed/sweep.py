"""Monte Carlo runner: N seeds of one scenario in parallel worker processes.

Run i uses seed `scenario.seed + i` and writes `OUT/run-XXX/` (a full run directory). Each run is
deterministic in its seed, so the results are bit-identical to running the seeds one by one.
The `metrics.json` files are aggregated into `OUT/summary.csv` and `OUT/summary.json`: mean,
std (ddof=1), min, max, count and the 95 % confidence interval of the mean (`ci95`: Student t
interval over the runs, mean +- t(0.975, n - 1) std / sqrt(n), testbed.scoring.metrics.mean_ci; the runs
are independent, one seed each; null with fewer than 2 runs) of every numeric score, keyed by its
dotted path (`estimators.ekf.rmse_position_m`, `tracking_rmse_m.6`), always from the metrics.json files on disk;
an ANEES also gets the interval of a consistent estimator's mean over the runs (`interval`, at the
runs' own level) and its effective samples (`n_eff`: testbed.scoring.metrics.anees_over_runs,
docs/consistency.md), empty in summary.csv for the other scores; in summary.json a null interval
has `null_reason` beside it, and one from the spread of the runs' values `interval_method`.
`OUT/sweep.toml` is the swept scenario (run i: its seed + i). A plugin estimator that fails in a
run is that run's result (testbed.plugins.failures): the sweep goes on, summary.json lists
`failed_estimators` {KEY: [run indices]}, and sweep raises EstimatorsFailed (exit 1) once written. Ctrl-C, SIGTERM or SIGHUP stop every
worker at once (and so does a Ray task lost for good, testbed.cluster.TaskLost); the finished runs are kept with summary.json marked incomplete (`"incomplete": true,
"runs_done": k`, no summary.csv) and `testbed sweep ... --resume` finishes the sweep.
Backends (testbed.workers): a local process pool (default) or Ray tasks (`--backend ray`, on this
machine or a cluster; testbed.cluster). The runs and the summary are the same bytes either way.
"""
from __future__ import annotations

import csv
import io
import json
import os
import re
import signal
from pathlib import Path

import numpy as np

from testbed.config import scenario as scenario_mod
from testbed.cluster import TaskLost
from testbed.config import from_dict, to_dict
from testbed.errors import EstimatorsFailed, RunError
from testbed.interrupt import Interrupted
from testbed.scoring.metrics import anees_over_runs, mean_ci
from testbed.outdir import Output, marker, remove_unheld_locks, write_json, write_text
from testbed.progress import bar as progress_bar
from testbed.runner import run
from testbed.config.scenario import Scenario
from testbed.workers import backend as use_backend, current_backend, run_parallel


def _one(args: tuple[dict, int, str, bool]) -> None:
    table, seed, out, plots = args
    scenario = from_dict(Scenario, {**table, "seed": seed}, "sweep")
    try:
        run(scenario, Path(out), progress=False, plots=plots)
    except EstimatorsFailed:  # the run is written, marked incomplete; the sweep reports it at the end
        pass


def flatten(obj: object, prefix: str = "") -> dict[str, float]:
    """Numeric leaves of nested dicts/lists as {dotted.path: value}."""
    out: dict[str, float] = {}
    if isinstance(obj, dict):
        for k, v in obj.items():
            out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out.update(flatten(v, f"{prefix}.{i}"))
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        out[prefix] = float(obj)
    return out


def summarize(metrics: list[dict]) -> dict[str, dict[str, float]]:
    """Per-score statistics over runs: {key: {mean, std, min, max, n, ci95}} (ci95: [lo, hi] Student t
    95 % interval of the mean over the runs, None with one run); an ANEES (a key with its
    KEY_dof beside it) also {interval, n_eff} of its mean over the runs (anees_over_runs), with
    null_reason where the interval is null and interval_method where the runs' spread decides."""
    flat = [flatten(m) for m in metrics]
    keys = sorted({k for f in flat for k in f if k != "seed"})
    summary = {}
    for k in keys:
        v = np.array([f[k] for f in flat if k in f])
        summary[k] = {
            "mean": float(v.mean()),
            "std": float(v.std(ddof=1)) if v.size > 1 else 0.0,
            "min": float(v.min()),
            "max": float(v.max()),
            "n": int(v.size),
            "ci95": list(mean_ci(v, 0.95)[1:]) if v.size > 1 else None,
        }
    for k in keys:
        if f"{k}_dof" in summary:
            summary[k].update(_over_runs(metrics, k))
    return summary


def _over_runs(metrics: list[dict], key: str) -> dict:
    """{interval, n_eff[, null_reason][, interval_method]} of the mean over the runs of the ANEES `key`
    (a dotted path into each run's metrics), at the level of the runs' own interval (KEY_interval_PCT
    beside it): the object holding the key in each run, as anees_keys wrote it, goes to anees_over_runs."""
    parent, _, name = key.rpartition(".")
    runs = [d for d in (_at(m, parent) if parent else m for m in metrics) if isinstance(d, dict) and d.get(name) is not None]
    pct = next(int(g[1]) for r in runs for k in r if (g := re.fullmatch(re.escape(name) + r"_interval_(\d+)", k)))
    got = anees_over_runs(runs, name, pct / 100)
    # a null interval has its reason, a run-spread interval its method (docs/consistency.md, "Several runs")
    return {"interval": got[f"{name}_interval_{pct}"], "n_eff": got[name.replace("anees", "n_eff")],
            **{w: got[f"{name}_{w}"] for w in ("null_reason", "interval_method") if f"{name}_{w}" in got}}


def _at(obj: object, path: str) -> object:
    """The value at a dotted path of flatten's (a key may hold dots itself: an estimator's entry
    point), None where there is none."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            if path == k:
                return v
            if path.startswith(f"{k}.") and (got := _at(v, path[len(k) + 1:])) is not None:
                return got
    elif isinstance(obj, list):
        head, _, rest = path.partition(".")
        if head.isdigit() and int(head) < len(obj):
            return _at(obj[int(head)], rest) if rest else obj[int(head)]
    return None


def run_complete(run_dir: Path) -> bool:
    """A run directory the testbed finished (it appears only by a rename when complete)."""
    return marker(run_dir) is not None and (run_dir / "metrics.json").is_file()


def _write_summary(d: Path, scenario: Scenario, runs: int, done: list[int]) -> dict:
    """summary.json (+ summary.csv when all runs are done) from the runs' metrics.json on disk."""
    metrics = [json.loads((d / f"run-{i:03d}" / "metrics.json").read_text()) for i in done]
    summary = summarize(metrics)
    doc = {"scenario": scenario.name, "runs": runs, "seeds": [scenario.seed + i for i in done], "scores": summary}
    failed: dict[str, list[int]] = {}
    for i, m in zip(done, metrics):
        for key in m.get("failed_estimators", []):
            failed.setdefault(key, []).append(i)
    if failed:  # their runs' metrics.json say when and why (testbed.plugins.failures)
        doc["failed_estimators"] = failed
    if len(done) < runs:  # marked incomplete; `--resume` finishes it
        write_json(d / "summary.json", {**doc, "incomplete": True, "runs_done": len(done)})
        (d / "summary.csv").unlink(missing_ok=True)
        return summary
    write_json(d / "summary.json", doc)
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(["score", "mean", "std", "min", "max", "n", "ci95_lo", "ci95_hi", "interval_lo", "interval_hi", "n_eff"])
    for k, s in summary.items():
        ci = [repr(s["ci95"][0]), repr(s["ci95"][1])] if s["ci95"] is not None else ["", ""]
        extra = ([*([repr(v) for v in s["interval"]] if s["interval"] else ["", ""]),
                  repr(s["n_eff"]) if s["n_eff"] is not None else ""] if "interval" in s else ["", "", ""])
        w.writerow([k, repr(s["mean"]), repr(s["std"]), repr(s["min"]), repr(s["max"]), s["n"], *ci, *extra])
    write_text(d / "summary.csv", buf.getvalue())
    return summary


def sweep(scenario: Scenario, runs: int, out: Path, *, workers: int | None = None, force: bool = False,
          resume: bool = False, progress: bool = True, backend: str | None = None, address: str | None = None,
          plots: bool = True) -> dict:
    """Run `runs` seeds of `scenario` into `out/run-XXX`, aggregate, return the summary.

    `out` follows testbed.outdir. Interrupted (Ctrl-C, SIGTERM, SIGHUP): the workers stop, the
    finished runs are kept at `out` with summary.json marked incomplete (unless `out` held an
    earlier output, which is then left as it was), and the Interrupted exception says so.
    resume: continue the incomplete sweep at `out` (same scenario), skipping finished runs; the
    final summary is byte-identical to an uninterrupted sweep's. progress: a bar over the runs on
    stderr (testbed.progress). plots: each run writes its figures (run-XXX/plots/, testbed.runner.run);
    False skips them, the bulk of a short run's CPU time.
    backend, address: "local" or "ray" and the Ray address (testbed.workers.backend); None keeps the
    caller's choice (a reproduction's). With Ray, `out` must be on a path every node shares, and
    workers caps the tasks in flight (None: all).
    """
    if runs < 1:
        raise RunError(f"--runs must be at least 1, got {runs}")
    if backend is not None:
        with use_backend(backend, address):
            return sweep(scenario, runs, out, workers=workers, force=force, resume=resume, progress=progress, plots=plots)
    out = Path(out)
    spec = scenario_mod.dumps(scenario)
    with Output(out, kind="sweep", force=force, resume=resume) as o:
        d = o.path
        if o.resume and (d / "sweep.toml").read_text() != spec:
            raise RunError(f"{out}: was swept with a different scenario ({out / 'sweep.toml'}); cannot resume it with this one")
        if not o.resume:
            write_text(d / "sweep.toml", spec)
        table = to_dict(scenario)
        done = [i for i in range(runs) if run_complete(d / f"run-{i:03d}")]
        todo = [i for i in range(runs) if i not in done]
        jobs = [(table, scenario.seed + i, str(d / f"run-{i:03d}"), plots) for i in todo]
        bar = progress_bar(runs, f"sweep {scenario.name}", initial=len(done), on=progress)
        if current_backend() == "local" or workers:
            workers = max(1, min(workers or os.cpu_count() or 1, runs))
        try:
            for k, _ in run_parallel(_one, jobs, workers):
                if not run_complete(d / f"run-{todo[k]:03d}"):  # written on another node, not shared
                    raise RunError(f"{out}: run-{todo[k]:03d} finished but is not visible here; with --backend ray, "
                                   "--out must be on a file system shared by every node")
                done.append(todo[k])
                bar.update()
        except (KeyboardInterrupt, TaskLost) as e:
            bar.close()
            # runs that completed while the others were being stopped count as well
            done = [i for i in range(runs) if run_complete(d / f"run-{i:03d}")]
            # of runs whose task was killed before it could release them, with their temporary directories
            remove_unheld_locks(d, wait_s=10.0)
            if done and (o.resume or not o.existed):
                _write_summary(d, scenario, runs, sorted(done))
                o.commit()
                kept = f"{len(done)} of {runs} runs kept in {out} (summary.json marked incomplete; continue with --resume)"
            else:
                kept = f"no run kept; {out} left as it was" if o.existed else "no run finished; nothing kept"
            if isinstance(e, TaskLost):
                raise RunError(f"{e}; {kept}") from None
            raise Interrupted(getattr(e, "signum", signal.SIGINT), kept) from None
        bar.close()
        summary = _write_summary(d, scenario, runs, sorted(done))
        o.commit()
    failed = json.loads((out / "summary.json").read_text()).get("failed_estimators", {})
    if failed:
        raise EstimatorsFailed(f"estimators failed in some runs, the others were scored ({out / 'summary.json'}; each run's "
                               f"metrics.json says when and why): "
                               + ", ".join(f"{k} in runs {', '.join(map(str, v))}" for k, v in failed.items()))
    return summary


__all__ = ["sweep", "summarize", "flatten"]
