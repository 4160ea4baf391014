"""Plugin estimators in a reproduction (`testbed reproduce PAPER --estimator ENTRY`).

Every run of the reproduction also runs and scores the plugins (testbed.plugins, the same metrics
as `testbed run`); here their scores over the runs become one more row each in the report:
`table.md` gets a "Plugin estimators" section and `table_plugins.csv` every number, per group of
runs (a formation, a noise case, ...) and estimator: mean and standard deviation (ddof 1) over
the runs of each summary score the estimator has (RMSE of position, velocity, attitude, the
coverage of position, and the scenario's PCRB of position where it has one); the ANEES of position
as the mean over the runs with its 95 % interval and effective samples (the runs' own combined:
testbed.metrics.anees_over_runs, docs/consistency.md).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from testbed.metrics import anees_over_runs
from testbed.report import fmt_anees, fmt_pm, markdown_table, write_csv

COLUMNS = (("rmse_position_m", "RMSE pos [m]"), ("pcrb_rmse_position_m", "PCRB pos [m]"),
           ("rmse_velocity_m_s", "RMSE vel [m/s]"), ("rmse_attitude_deg", "RMSE att [deg]"),
           ("coverage_position", "coverage pos"))
ANEES = "anees_position"  # 3 dof, 95 % (testbed.plugins.score)


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
                         **{c: _stats(scores, c) for c, _ in COLUMNS}, ANEES: anees_over_runs(scores, ANEES, 0.95)})
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
            "estimates; mean ± std over runs; ANEES: mean over runs [95 % interval of a consistent estimator] "
            "(effective samples, docs/consistency.md).", ""] \
        + markdown_table([what, "estimator", "runs"] + [head[c] for c in cols] + ["ANEES pos (3)"],
                         [[r["group"], r["estimator"], r["runs"]] + [fmt_pm(*r[c]) if r[c] else "" for c in cols]
                          + [fmt_anees(r[ANEES], ANEES)] for r in rows]) + [""]


def write(path: Path, groups: dict[str, list[dict]], keys: list[str]) -> None:
    """table_plugins.csv: group, estimator, runs, every score's mean and std, and the ANEES of position's
    mean, interval and effective samples (nothing without plugins)."""
    if not keys:
        return
    cols, rows = table(groups, keys)
    interval, n_eff = f"{ANEES}_interval_95", ANEES.replace("anees", "n_eff")
    write_csv(path, ["group", "estimator", "runs"] + [f"{c}_{s}" for c in cols for s in ("mean", "std")]
              + [f"{ANEES}_mean", f"{interval}_lo", f"{interval}_hi", n_eff],
              [[r["group"], r["estimator"], r["runs"]] + [v for c in cols for v in (r[c] or (None, None))]
               + ([r[ANEES][ANEES], *r[ANEES][interval], r[ANEES][n_eff]] if r[ANEES] else [None] * 4) for r in rows])
