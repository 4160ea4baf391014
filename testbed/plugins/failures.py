"""An estimator that fails is its own result: `testbed run`, `testbed replay` and the sweeps of
the reproductions score the others, write their output, and exit 1.

A plugin that raises, or returns an estimate the checks refuse (NaN, wrong shape: a diverged
filter), becomes in metrics.json `estimators.KEY = {"entry": ..., "failed": {"time_s": t,
"reason": "..."}}` (time_s: the time of the measurement it was given, null when it failed outside
the feed, in its constructor or finish(), which the reason says). The metrics then carry
`"incomplete": true` and `"failed_estimators": [KEY, ...]`; after the output is in place,
EstimatorsFailed (exit 1) says on stderr which ones failed, when and why, in one line.

The estimator a closed loop flies on (`[control] feedback`) is not one of these: its failure stops
the flight, and the run writes nothing (testbed.plugins.online).
"""
from __future__ import annotations

from pathlib import Path

from testbed.errors import EstimatorsFailed, PluginError


def failed_entry(entry: str, e: PluginError) -> dict:
    """The metrics.json entry of an estimator that failed with e."""
    return {"entry": entry, "failed": {"time_s": e.time, "reason": str(e)}}


def mark_incomplete(metrics: dict) -> list[str]:
    """Mark metrics (with an `estimators` object) incomplete if any estimator failed; returns their keys."""
    failed = [k for k, v in metrics["estimators"].items() if "failed" in v]
    if failed:
        metrics["incomplete"] = True
        metrics["failed_estimators"] = failed
    return failed


def raise_failed(metrics: dict, path: Path) -> None:
    """EstimatorsFailed naming every failed estimator of metrics (written to path), if there is one."""
    failed = metrics.get("failed_estimators", [])
    if failed:
        reasons = "; ".join(metrics["estimators"][k]["failed"]["reason"] for k in failed)
        raise EstimatorsFailed(f"{len(failed)} of {len(metrics['estimators'])} estimators failed, the others were scored "
                               f"({path} is marked incomplete): {reasons}")
