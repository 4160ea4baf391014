"""Monte Carlo runner: N seeds of one scenario in parallel worker processes.

Run i uses seed `scenario.seed + i` and writes `OUT/run-XXX/` (a full run directory). Each run is
deterministic in its seed, so the results are bit-identical to running the seeds one by one.
The `metrics.json` files are aggregated into `OUT/summary.csv` and `OUT/summary.json`: mean,
std (ddof=1), min, max and count of every numeric score, keyed by its dotted path
(`estimators.ekf.rmse_position_m`, `tracking_rmse_m.6`).
"""
from __future__ import annotations

import csv
import multiprocessing as mp
import os
import shutil
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
from tqdm import tqdm

from testbed.config import from_dict, to_dict
from testbed.environment import apply_defaults
from testbed.runner import RunError, prepare_out, run, write_json
from testbed.scenario import Scenario


def _one(args: tuple[dict, int, str]) -> dict:
    table, seed, out = args
    scenario = from_dict(Scenario, {**table, "seed": seed}, "sweep")
    return run(scenario, Path(out), force=True, progress=False)


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
    """Per-score statistics over runs: {key: {mean, std, min, max, n}}."""
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
        }
    return summary


def sweep(scenario: Scenario, runs: int, out: Path, *, workers: int | None = None, force: bool = False, progress: bool = True) -> dict:
    """Run `runs` seeds of `scenario` into `out/run-XXX`, aggregate, return the summary."""
    if runs < 1:
        raise RunError(f"--runs must be at least 1, got {runs}")
    out = Path(out)
    prepare_out(out, force)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    workers = max(1, min(workers or os.cpu_count() or 1, runs))
    table = to_dict(scenario)
    jobs = [(table, scenario.seed + i, str(out / f"run-{i:03d}")) for i in range(runs)]
    results: list[dict | None] = [None] * runs
    bar = tqdm(total=runs, desc=f"sweep {scenario.name}", unit="run", disable=not progress)
    if workers == 1:
        for i, job in enumerate(jobs):
            results[i] = _one(job)
            bar.update()
    else:
        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"), initializer=apply_defaults) as pool:
            futures = {pool.submit(_one, job): i for i, job in enumerate(jobs)}
            for fut in as_completed(futures):
                results[futures[fut]] = fut.result()
                bar.update()
    bar.close()
    summary = summarize(results)  # type: ignore[arg-type]
    write_json(out / "summary.json", {"scenario": scenario.name, "runs": runs, "seeds": [j[1] for j in jobs], "scores": summary})
    with open(out / "summary.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["score", "mean", "std", "min", "max", "n"])
        for k, s in summary.items():
            w.writerow([k, repr(s["mean"]), repr(s["std"]), repr(s["min"]), repr(s["max"]), s["n"]])
    return summary


__all__ = ["sweep", "summarize", "flatten"]
