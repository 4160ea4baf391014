"""Plugin estimators in a reproduction (`testbed reproduce PAPER --estimator ENTRY`).

Every run of the reproduction also runs and scores the plugins (testbed.plugins, the same metrics
as `testbed run`); here their scores over the runs become one more row each in the report:
`table.md` gets a "Plugin estimators" section and `table_plugins.csv` every number, per group of
runs (a formation, a noise case, ...) and estimator: mean and standard deviation (ddof 1) over
the runs of each summary score the estimator has (RMSE of position, velocity, attitude, ANEES of
position, and the scenario's PCRB of position where it has one).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from testbed.report import fmt_pm, markdown_table, write_csv

COLUMNS = (("rmse_position_m", "RMSE pos [m]"), ("pcrb_rmse_position_m", "PCRB pos [m]"),
           ("rmse_velocity_m_s", "RMSE vel [m/s]"), ("rmse_attitude_deg", "RMSE att [deg]"),
           ("anees_position", "ANEES pos (3)"))


def _stats(runs: list[dict], key: str) -> tuple[float, float] | None:
    x = np.array([r[key] for r in runs if key in r], float)
    if x.size == 0:
        return None
    return float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else 0.0


def table(groups: dict[str, list[dict]], keys: list[str]) -> tuple[list[str], list[dict]]:
    """The columns present and one row per (group, estimator). groups: {label: [the metrics.json
    `estimators` object of each run]}; keys: the plugin estimators' names."""
    rows = []
    for label, runs in groups.items():
        for k in keys:
            scores = [r[k] for r in runs if "failed" not in r[k]]  # a failed run has no scores (testbed.plugins.failures)
            rows.append({"group": label, "estimator": k, "runs": len(scores),
                         **{c: _stats(scores, c) for c, _ in COLUMNS}})
    cols = [c for c, _ in COLUMNS if any(r[c] is not None for r in rows)]
    return cols, rows


def markdown(groups: dict[str, list[dict]], keys: list[str], what: str) -> list[str]:
    """The "Plugin estimators" section of table.md; what: the group column's header."""
    if not keys:
        return []
    cols, rows = table(groups, keys)
    head = dict(COLUMNS)
    return ["## Plugin estimators (--estimator)", "",
            "Scored in every run like `testbed run` scores them (metrics.json `estimators.NAME`), over all their "
            "estimates; mean ± std over runs.", ""] \
        + markdown_table([what, "estimator", "runs"] + [head[c] for c in cols],
                         [[r["group"], r["estimator"], r["runs"]] + [fmt_pm(*r[c]) if r[c] else "" for c in cols]
                          for r in rows]) + [""]


def write(path: Path, groups: dict[str, list[dict]], keys: list[str]) -> None:
    """table_plugins.csv: group, estimator, runs and every score's mean and std (nothing without plugins)."""
    if not keys:
        return
    cols, rows = table(groups, keys)
    write_csv(path, ["group", "estimator", "runs"] + [f"{c}_{s}" for c in cols for s in ("mean", "std")],
              [[r["group"], r["estimator"], r["runs"]] + [v for c in cols for v in (r[c] or (None, None))] for r in rows])
