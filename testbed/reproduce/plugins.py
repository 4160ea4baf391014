"""Plugin estimators in a reproduction (`testbed reproduce PAPER --estimator ENTRY`).

Every run of the reproduction also runs and scores the plugins (testbed.plugins, the same metrics
as `testbed run`); here their scores over the runs become one more row each in the report:
`table.md` gets a "Plugin estimators" section and `table_plugins.csv` every number, per group of
runs (a formation, a noise case, ...) and estimator: mean and standard deviation (ddof 1) over
the runs of each summary score the estimator has (RMSE of position, velocity, attitude, the
coverage of position, and the scenario's PCRB of position where it has one); the ANEES of position
as the mean over the runs with its 95 % interval and effective samples (the runs' own combined:
testbed.scoring.metrics.anees_over_runs, docs/consistency.md).
Each plugin is also compared with every other estimator of the same runs that has the same
score (`paired`): the position RMSE (`rmse_position_m`, a number) of both in each run, paired over
the same seeds, with a two-sided Wilcoxon signed-rank test (testbed.scoring.stats.wilcoxon_paired) and
the improvement factor mean_other / mean_plugin; `table_plugins_paired.csv` has every number.
A reproduction whose group objects hold only the plugins (not the built-ins) gets no comparison.

The figures of a reproduction draw every estimator the same way, built-in or plugin: `estimator_names`
(the built-ins, then the plugins), `column` (one score of one estimator over the runs, from the
same `estimators` objects) and `bars` (that score's mean and 95 % Student t interval over the runs,
per group and estimator, testbed.outputs.plots.grouped_bars).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from testbed.scoring.metrics import anees_over_runs, mean_ci
from testbed.outputs.plots import grouped_bars
from testbed.outputs.report import fmt, fmt_anees, fmt_pm, interval_cells, markdown_table, write_csv
from testbed.scoring.stats import wilcoxon_paired

COLUMNS = (("rmse_position_m", "RMSE pos [m]"), ("pcrb_rmse_position_m", "PCRB pos [m]"),
           ("rmse_velocity_m_s", "RMSE vel [m/s]"), ("rmse_attitude_deg", "RMSE att [deg]"),
           ("coverage_position", "coverage pos"))
ANEES = "anees_position"  # 3 dof, 95 % (testbed.plugins.score)
PAIRED = "rmse_position_m"  # the score each plugin is compared on with every other estimator
PAIRED_COLUMNS = ("group", "estimator", "against", "runs", "mean_estimator_m", "mean_against_m", "factor", "statistic",
                  "p_two_sided")


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


def _score(run: dict, key: str, score: str = PAIRED) -> float | None:
    """Estimator key's `score` in one run's `estimators` object (None: absent, failed or not a number)."""
    v = run.get(key, {}).get(score) if isinstance(run.get(key), dict) else None
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def estimator_names(builtins, keys) -> list[str]:
    """The estimators a reproduction's tables and figures show, in their order: the built-ins, then
    the plugins (--estimator), each once."""
    return list(dict.fromkeys([*builtins, *keys]))


def column(runs: list[dict], name: str, score: str) -> np.ndarray:
    """(len(runs),) estimator `name`'s number `score` in each run's `estimators` object, NaN where
    it has none (absent, failed: testbed.plugins.failures, or not a number)."""
    return np.array([np.nan if (v := _score(r, name, score)) is None else v for r in runs], float)


def interval(x: np.ndarray) -> tuple[float, float, float]:
    """Mean and 95 % Student t interval (testbed.scoring.metrics.mean_ci) of the finite values of x
    (independent runs); NaN when there is none."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return mean_ci(x) if x.size else (np.nan,) * 3


def bars(groups: dict[str, list[dict]], names: list[str], score: str, path: Path, *, title: str, ylabel: str) -> Path:
    """The figure of one score of every estimator `names` per group: mean and 95 % Student t interval
    over the runs (`interval` of `column`); groups: {label: [the `estimators` object of each run]}."""
    stats = np.array([[interval(column(runs, n, score)) for n in names] for runs in groups.values()])  # (G, E, 3)
    return grouped_bars(list(groups), list(names), stats[..., 0], stats[..., 1], stats[..., 2], path, title=title,
                        ylabel=ylabel)


def paired(groups: dict[str, list[dict]], keys: list[str]) -> list[dict]:
    """Per group, each plugin against every other estimator of the runs (built-in or plugin) with a
    PAIRED score in the same runs: runs paired, means, factor mean_against / mean_estimator (> 1:
    the plugin is better), and the two-sided Wilcoxon signed-rank test of the paired differences
    (statistic and p NaN when it cannot be made: fewer than 2 non-zero differences)."""
    rows = []
    for label, runs in groups.items():
        others = sorted({b for r in runs for b in r if isinstance(r[b], dict)}, key=str)
        for k in keys:
            for b in others:
                if b == k:
                    continue
                both = [(a, c) for r in runs if (a := _score(r, k)) is not None and (c := _score(r, b)) is not None]
                if not both:
                    continue
                a, c = np.array(both).T
                t = wilcoxon_paired(a, c, alternative="two-sided")
                rows.append(dict(zip(PAIRED_COLUMNS, (label, k, b, len(both), float(a.mean()), float(c.mean()),
                                                      float(c.mean() / a.mean()), t.statistic, t.p_value))))
    return rows


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
                          + [fmt_anees(r[ANEES], ANEES)] for r in rows]) + [""] + _paired_markdown(groups, keys, what)


def _paired_markdown(groups: dict[str, list[dict]], keys: list[str], what: str) -> list[str]:
    """The "against the other estimators" part of the section (nothing when no comparison exists)."""
    rows = paired(groups, keys)
    if not rows:
        return []
    return ["Against every other estimator of the same runs (paired over the same seeds): position RMSE means, "
            "factor = mean of the other / mean of the plugin (> 1: the plugin is better), two-sided Wilcoxon "
            "signed-rank test of the per-run differences.", ""] \
        + markdown_table([what, "estimator", "against", "runs", "mean RMSE [m]", "other's [m]", "factor", "p (two-sided)"],
                         [[r["group"], r["estimator"], r["against"], r["runs"], fmt(r["mean_estimator_m"]),
                           fmt(r["mean_against_m"]), fmt(r["factor"]), fmt(r["p_two_sided"])] for r in rows]) + [""]


def write(path: Path, groups: dict[str, list[dict]], keys: list[str]) -> None:
    """table_plugins.csv: group, estimator, runs, every score's mean and std, and the ANEES of position's
    mean, interval and effective samples; table_plugins_paired.csv: `paired`'s rows (nothing without
    plugins)."""
    if not keys:
        return
    pairs = paired(groups, keys)
    if pairs:
        write_csv(Path(path).with_name("table_plugins_paired.csv"), list(PAIRED_COLUMNS), [list(r.values()) for r in pairs])
    cols, rows = table(groups, keys)
    interval, n_eff = f"{ANEES}_interval_95", ANEES.replace("anees", "n_eff")
    write_csv(path, ["group", "estimator", "runs"] + [f"{c}_{s}" for c in cols for s in ("mean", "std")]
              + [f"{ANEES}_mean", f"{interval}_lo", f"{interval}_hi", n_eff],
              [[r["group"], r["estimator"], r["runs"]] + [v for c in cols for v in interval_cells(r[c])]
               + ([r[ANEES][ANEES], *interval_cells(r[ANEES][interval]), r[ANEES][n_eff]] if r[ANEES] else [None] * 4)
               for r in rows])
