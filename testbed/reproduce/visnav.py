"""`testbed reproduce visnav`: seed 004 (Jin et al. 2017) Monte Carlo of EKF, CKF, HCKF, MCKF, RHCF.

Design. Run i simulates the built-in `visnav` scenario with seed 1 + i (the scenario's seed + i,
testbed.reproduce.runs; in memory, no run directories) twice, from the same seed:
with the paper's glint noise (camera preset paper004: with probability 0.1 a LOS sample has
5 x the nominal 3500 micro-rad std) and Gaussian (`sensors.camera.glint_prob = 0`). The camera
draws the same standard normals and the same glint coin flips in both, so the two cases differ
only by the glint scaling: a paired comparison. All five filters run on the same log (same truth,
same IMU and camera noise, same initial error, stream "init"). Default horizon 60 s (the scenario
has 120 s; 60 s keeps `--runs 50` within ~15-25 min on two cores), 10 Hz camera, 20 Hz predict.

Claim (paper figs. 5-7): under glint noise RHCF is most accurate in relative position, velocity
and attitude, then MCKF, then HCKF, then EKF. Judged on the per-run RMSEs by one-sided Wilcoxon
signed-rank tests (testbed.scoring.stats.wilcoxon_paired; per-run RMSEs are skewed by the glint runs, the
signed-rank test does not assume normal differences) of rhcf < mckf, mckf < hckf, hckf < ekf for
each of the three quantities: 9 comparisons, each must have p < 0.05 / 9 (Bonferroni, family level
0.05). The claim holds only if all 9 do; it is "not decidable" (testbed.outputs.report.Claim) when no
run of the glint case drew a glint outlier (camera/glint). Also reported: the Gaussian case, where the robust filters
"should cost little": a non-inferiority test per comparison (RHCF vs HCKF and MCKF vs EKF, three
quantities): one-sided paired t test (testbed.scoring.stats.paired_t) of the mean per-run relative RMSE
change against the margin GAUSSIAN_COST_LIMIT = +5 % (stated here, before the runs), p < 0.025
each (the same decision as the upper end of a two-sided 95 % interval below +5 %).

Also run (short): the other motion mode (2 runs, both noise cases) and the pixel camera path
(1 run, 10 s): finite, scored, shown in the table.

The filters are the scenario's default estimators (visnav.ekf ... visnav.rhcf, testbed.plugins
.defaults) run as plugins and scored like any estimator (testbed.plugins.score, with the
relative-frame hook testbed.plugins.relnav_scores): per run the RMSE of each quantity, the ANEES
of the 9-dim navigation error (p, v, theta with the filter's (9, 9) covariance, `anees`, 9 dof)
and, as extra rows, each quantity's 3-dof ANEES (with the estimate's own (3, 3) block).

Outputs: table.md, table.csv (per case, filter and score: mean, lo, hi: an RMSE's 95 % confidence
interval, each ANEES's 99 % interval of a consistent filter over its effective samples n_eff, a
row of its own), claims.json, runs.json (every run's metrics), plots/.
While the reproduction is incomplete (interrupted), each finished run's result is kept in runs/run-XXX.pkl
(runs-extra/ for the extra runs) for `--resume`; they are removed when it completes.

Shape (as every reproduction): `compute` (runs -> `VisnavResults`), `decide` (numbers -> claims),
`write` (files through testbed.outputs.report); `reproduce` chains them.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from testbed.config import scenario as scenario_mod
from testbed.scoring.metrics import anees_over_runs, mean_ci
from testbed.outputs.plots import compare_bars, error_envelope, save
from testbed.outputs.report import Claim, claims_section, fmt, fmt_anees, fmt_ci, interval_cells, markdown_table, \
    write_claims, write_csv, write_json, write_markdown
from testbed.plugins.context import make_context
from testbed.sim.world import lever_arms
from testbed.plugins.defaults import default_specs, estimator_specs
from testbed.plugins.loading import resolve
from testbed.plugins.relnav_scores import relnav_hook
from testbed.plugins.run import run_estimators
from testbed.plugins.truth import Truth, errors
from testbed.progress import bar
from testbed.reproduce import plugins as plugin_rows
from testbed.reproduce.runs import load_result, save_result, seeds
from testbed.sim.simulate import simulate
from testbed.scoring.stats import paired_t, wilcoxon_paired
from testbed.workers import run_parallel

FILTERS = ("ekf", "ckf", "hckf", "mckf", "rhcf")
QUANTITIES = (("rmse_position_m", "position", "m"), ("rmse_velocity_m_s", "velocity", "m/s"),
              ("rmse_attitude_deg", "attitude", "deg"))
CASES = ("glint", "gaussian")
#: the ANEES reported: the 9-dof navigation one (relnav hook), then each quantity's 3-dof one
ANEES = ("anees",) + tuple(f"anees_{q}" for _, q, _ in QUANTITIES)
ANEES_LABEL = {"anees": "ANEES (9)", **{f"anees_{q}": f"ANEES {q}" for _, q, _ in QUANTITIES}}
#: where the runs' results are kept while the reproduction is incomplete (testbed.reproduce.runs)
RUNS_DIR, EXTRA_DIR = "runs", "runs-extra"
CLAIM_PAIRS = (("rhcf", "mckf"), ("mckf", "hckf"), ("hckf", "ekf"))
ALPHA = 0.05  # family level of the 9 ordering tests (Bonferroni: 0.05 / 9 each)
# "costs little": the non-inferiority margin, +5 % RMSE, fixed before any run: below the run-to-run spread
# of one filter's RMSE and far below the 20-50 % gains the paper reports under glint.
GAUSSIAN_COST_LIMIT = 0.05
DEFAULT_DURATION = 60.0


def _scenario(seed: int, motion: str, duration: float, case: str, mode: str = "geometric"):
    over = {"sensors.camera.mode": f'"{mode}"'}
    if case == "gaussian":
        over["sensors.camera.glint_prob"] = "0.0"
    return scenario_mod.load("visnav", overrides=over, seed=seed, motion=motion, duration=duration)


def one_run(args: tuple) -> dict:
    """Worker: one seed, the given cases; metrics and error-norm series of every filter.

    args = (seed, motion, duration, cases, mode, keep_full[, estimators]). Returns {case: {"metrics":
    {filter: scores (testbed.plugins.score, plus time_per_step_ms)}, "t": (E,), "norms": {filter:
    (E, 3) [|dp| m, |dv| m/s, attitude deg]} of every filter and plugin whose outputs fit the
    relative-frame hook, "full": {name: (errors (E, 9), sigmas (E, 9))} of the same if keep_full,
    "plugins": {name: scores} of the plugin EstimatorSpecs `estimators` (testbed.plugins)}}.
    """
    seed, motion, duration, cases, mode, keep_full, *rest = args
    extra = tuple(rest[0]) if rest else ()
    out = {}
    for case in cases:
        s = _scenario(seed, motion, duration, case, mode)
        plugins = resolve(estimator_specs(dataclasses.replace(s, estimators=extra)))
        log, physics = simulate(s)
        scores, tracks = run_estimators(s, physics, log, plugins, None)
        hook, truth = relnav_hook(s), Truth(log, make_context(s, lever_arms(physics), "truth", {}))
        fits = {}
        for key in [spec.key for spec in default_specs(s)] + [e.key for e in extra]:
            track = tracks.get(key, {})
            errs = {(tg, q): errors(truth, tg, q, se.time, se.value, se.frame) for (tg, q), se in track.items()}
            if (fit := hook.fit(track, errs)) is not None:  # a plugin whose outputs do not fit has no curves
                fits[key] = fit
        metrics = {n: {**{k: v for k, v in scores[n].items() if k != "wall_ms"},
                       "time_per_step_ms": scores[n]["wall_ms"] / max(scores[n]["epochs"], 1)} for n in FILTERS}
        res = {
            "metrics": metrics,
            "t": fits[FILTERS[0]][0],
            "times": {n: t for n, (t, _, _) in fits.items()},
            "norms": {n: np.column_stack([np.linalg.norm(e[0], axis=1), np.linalg.norm(e[1], axis=1),
                                          np.degrees(np.linalg.norm(e[2], axis=1))]) for n, (_, e, _) in fits.items()},
            "glint_fraction": float(np.mean(log["camera/glint"])) if log["camera/glint"].size else 0.0,
            "leds_per_epoch": float(log["camera/time"].size / max(np.unique(log["camera/time"]).size, 1)),
        }
        if keep_full:
            res["full"] = {n: (np.hstack(e), np.hstack(sig)) for n, (_, e, sig) in fits.items()}
        if extra:
            res["plugins"] = {k: v for k, v in scores.items() if k not in FILTERS}
        out[case] = res
    return out


def _run_many(jobs: list[tuple], workers: int, root: Path) -> list[dict]:
    """one_run of every job (workers stop with us, testbed.workers), each result kept in
    root/run-XXX.pkl as it arrives and reused from there (an interrupted reproduction resumed)."""
    results = [load_result(root, i) for i in range(len(jobs))]
    todo = [i for i, r in enumerate(results) if r is None]
    with bar(len(jobs), "reproduce visnav", initial=len(jobs) - len(todo)) as shown:
        for k, r in run_parallel(one_run, [jobs[i] for i in todo], workers):
            results[todo[k]] = r
            save_result(root, todo[k], r)
            shown.update()
    return results  # type: ignore[return-value]


@dataclass(frozen=True, kw_only=True, slots=True)
class VisnavResults:
    """What the runs gave. results: one_run's output per Monte Carlo run (run i: seed meta["seeds"][i]);
    extra: {label: {case: {filter: metrics}}} of the short extra runs; meta: runs, duration, motion,
    workers, wall_s, seeds."""

    results: list[dict]
    extra: dict
    meta: dict


def compute(*, runs: int, motion: str, duration: float, workers: int, estimators: tuple = (),
            keep: Path | None = None) -> VisnavResults:
    """The Monte Carlo (both noise cases per seed) and the extra runs (other motion, pixel camera).
    estimators: plugin EstimatorSpecs scored in every Monte Carlo run (results[i][case]["plugins"]);
    keep: where each run's result is kept until the reproduction is complete (keep/runs,
    keep/runs-extra; testbed.reproduce.runs.save_result), None: a temporary directory."""
    if keep is None:
        with tempfile.TemporaryDirectory(prefix="testbed-visnav-") as tmp:
            return compute(runs=runs, motion=motion, duration=duration, workers=workers, estimators=estimators,
                           keep=Path(tmp))
    t0 = time.perf_counter()
    base = scenario_mod.load("visnav").seed
    run_seeds = seeds(base, runs)
    jobs = [(seed, motion, duration, CASES, "geometric", i == 0, tuple(estimators)) for i, seed in enumerate(run_seeds)]
    print(f"visnav: {runs} runs x {len(CASES)} noise cases x {len(FILTERS)} filters, {duration:g} s, {motion}", file=sys.stderr)
    results = _run_many(jobs, workers, keep / RUNS_DIR)
    other = "flown" if motion == "prescribed" else "prescribed"
    print(f"visnav: {other} motion (2 runs) and the pixel camera path (1 run, 10 s)", file=sys.stderr)
    extra_jobs = [(seed, other, duration, CASES, "geometric", False, tuple(estimators)) for seed in seeds(base, 2)]
    extra_jobs.append((base, motion, min(10.0, duration), ("glint",), "pixels", False, tuple(estimators)))
    extra_res = _run_many(extra_jobs, workers, keep / EXTRA_DIR)
    extra = {f"{other} motion, run {i} (seed {base + i})": {c: _estimators(r[c]) for c in CASES}
             for i, r in enumerate(extra_res[:2])}
    extra[f"pixel camera path, {motion}, 10 s (seed {base}; no added noise: rendering + detection error)"] = {
        "pixels": _estimators(extra_res[2]["glint"])}
    meta = {"runs": runs, "duration": duration, "motion": motion, "workers": workers,
            "wall_s": time.perf_counter() - t0, "seeds": run_seeds}
    return VisnavResults(results=results, extra=extra, meta=meta)


def _col(results: list[dict], case: str, name: str, key: str) -> np.ndarray:
    return np.array([r[case]["metrics"][name][key] for r in results])


def _estimators(r: dict) -> dict:
    """One run-case's `estimators` object: the built-in filters' metrics and the plugins' scores."""
    return {**r["metrics"], **r.get("plugins", {})}


def summarize(results: list[dict], case: str, keys: tuple[str, ...] = ()) -> dict:
    """Per filter, then per plugin (keys), over the runs where it did not fail: mean and 95 %
    interval of each RMSE it has, mean of each ANEES (ANEES) over the runs with its 99 % interval
    and effective samples (testbed.scoring.metrics.anees_over_runs), time per step, runs finite."""
    table = {}
    for name in plugin_rows.estimator_names(FILTERS, keys):
        scored = [e[name] for e in (_estimators(r[case]) for r in results)
                  if isinstance(e.get(name), dict) and "failed" not in e[name]]
        row = {}
        for key, _, _ in QUANTITIES:
            m, lo, hi = mean_ci(plugin_rows.column([{name: e} for e in scored], name, key)) if scored else (np.nan,) * 3
            row[key] = {"mean": m, "lo": lo, "hi": hi}
        row["anees"] = {key: anees_over_runs(scored, key) for key in ANEES}
        steps = [e.get("time_per_step_ms", e.get("wall_ms", np.nan) / max(e.get("epochs", 0), 1)) for e in scored]
        row["time_per_step_ms"] = float(np.mean(steps)) if scored else float("nan")
        row["finite_runs"] = int(sum(bool(e.get("finite", False)) for e in scored))
        table[name] = row
    return table


def decide(res: VisnavResults) -> list[Claim]:
    """The paper's ordering under glint (paired tests) and the Gaussian cost of robustness."""
    results = res.results
    level = ALPHA / (len(CLAIM_PAIRS) * len(QUANTITIES))
    comparisons, tests, ok = [], [], True
    for key, label, unit in QUANTITIES:
        for a, b in CLAIM_PAIRS:
            test = wilcoxon_paired(_col(results, "glint", a, key), _col(results, "glint", b, key),
                                   alternative="less", level=1 - level)
            holds = bool(np.isfinite(test.p_value) and test.p_value < level)
            ok &= holds
            tests.append(test)
            comparisons.append({"quantity": label, "unit": unit, "better": a, "worse": b,
                                "mean_a": float(_col(results, "glint", a, key).mean()),
                                "mean_b": float(_col(results, "glint", b, key).mean()),
                                **test.to_json(), "alpha": level, "holds": holds})
    worst = max(tests, key=lambda t: t.p_value if np.isfinite(t.p_value) else np.inf)
    glints = sum(r["glint"]["glint_fraction"] > 0 for r in results)  # runs with a glint outlier
    claims = [Claim(
        id="glint-ordering",
        text="under glint noise RHCF is most accurate in relative position, velocity and attitude, then MCKF, then "
             "HCKF, then EKF (paper figs. 5-7)",
        criterion=f"one-sided Wilcoxon signed-rank test of the per-run RMSE for each adjacent pair and quantity; "
                  f"each p < {ALPHA}/{len(comparisons)} (Bonferroni)",
        holds=bool(ok), numbers={"runs": len(results), "comparisons": comparisons},
        paper_value="RHCF < MCKF < HCKF < EKF",
        summary=f"{sum(c['holds'] for c in comparisons)}/{len(comparisons)} comparisons significant",
        not_decidable="" if glints else "no glint outlier in these runs (the glint case drew none)",
        **{**worst.claim_fields(), "test": f"{len(tests)} x {worst.test}, Bonferroni; the largest p shown"})]
    cost, ok2, cost_tests = [], True, []
    for key, label, unit in QUANTITIES:
        for a, b in (("rhcf", "hckf"), ("mckf", "ekf")):
            xa, xb = _col(results, "gaussian", a, key), _col(results, "gaussian", b, key)
            rel = xa / xb - 1.0
            t = paired_t(rel, np.full(rel.size, GAUSSIAN_COST_LIMIT), alternative="less", level=0.975)
            holds = bool(np.isfinite(t.p_value) and t.p_value < 0.025)
            ok2 &= holds
            cost_tests.append(t)
            upper = GAUSSIAN_COST_LIMIT + t.interval[1] if t.interval is not None else float("nan")
            cost.append({"quantity": label, "robust": a, "baseline": b, "mean_rel_change": float(rel.mean()),
                         "upper_975": upper, "mean_robust": float(xa.mean()), "mean_baseline": float(xb.mean()),
                         **t.to_json(), "holds": holds})
    worst = max(cost_tests, key=lambda t: t.p_value if np.isfinite(t.p_value) else np.inf)
    claims.append(Claim(
        id="gaussian-cost",
        text="with Gaussian noise the robust filters cost little: RHCF vs HCKF and MCKF vs EKF",
        criterion=f"non-inferiority: one-sided paired t test of the mean per-run relative RMSE change against "
                  f"+{GAUSSIAN_COST_LIMIT:.0%}, p < 0.025 for each of the {len(cost)} comparisons",
        holds=bool(ok2), numbers={"runs": len(results), "comparisons": cost}, paper_value="cost little",
        summary=f"largest upper bound of the relative change {fmt(100 * max(c['upper_975'] for c in cost))} %",
        **{**worst.claim_fields(), "test": f"{len(cost_tests)} x {worst.test} (non-inferiority); the largest p shown",
           "interval": None}))
    return claims


def _markdown(summaries: dict, meta: dict, extra: dict, claims: list[Claim]) -> list[str]:
    lines = [f"# Seed 004 reproduction: {meta['runs']} runs x {fmt(meta['duration'])} s, motion {meta['motion']}, "
             f"geometric camera, seeds {meta['seeds'][0]}..{meta['seeds'][-1]}",
             "", "RMSE over the run (mean over runs [95 % interval]); ANEES (9) of the 9 navigation states "
             "(expected 9), then the ANEES of the relative position, velocity and attitude, each with its own "
             "(3, 3) covariance block (expected 3) [99 % interval of a consistent filter] (effective samples: the "
             "epochs of a run are correlated, docs/consistency.md); wall time "
             "per camera epoch (the estimator's whole processing: IMU pairing, two 20 Hz predicts, one update).", ""]
    for case, summ in summaries.items():
        lines += [f"## {case}", ""]
        lines += markdown_table(["filter", "position (m)", "velocity (m/s)", "attitude (deg)"]
                                + [ANEES_LABEL[key] for key in ANEES] + ["ms/epoch", "finite runs"],
                                [[name] + [fmt_ci(**r[key]) for key, _, _ in QUANTITIES]
                                 + [fmt_anees(r["anees"][key], key) for key in ANEES]
                                 + [r["time_per_step_ms"], r["finite_runs"]]
                                 for name, r in summ.items()])
        lines.append("")
    for label, ex in extra.items():
        lines += [f"## {label}", ""]
        lines += markdown_table(["case", "filter", "position (m)", "velocity (m/s)", "attitude (deg)"]
                                + [ANEES_LABEL[key] for key in ANEES],
                                [[case, name] + [m.get(key, "") for key, _, _ in QUANTITIES]
                                 + [fmt_anees(anees_over_runs([m], key), key) for key in ANEES]
                                 for case, per in ex.items() for name, m in per.items()])
        lines.append("")
    lines += [f"Wall time: {fmt(meta['wall_s'])} s with {meta['workers']} worker(s).", ""]
    return lines + claims_section(claims)


def _csv_rows(summaries: dict, extra: dict) -> list[list]:
    rows = []
    for case, summ in summaries.items():
        for name, r in summ.items():
            rows += [[case, name, key, r[key]["mean"], r[key]["lo"], r[key]["hi"]] for key, _, _ in QUANTITIES]
            for key in ANEES:
                if a := r["anees"][key]:  # {}: an estimator without that ANEES (a plugin's outputs that do not fit)
                    rows += [[case, name, key, a[key], *interval_cells(a[f"{key}_interval_99"])],
                             [case, name, key.replace("anees", "n_eff"), a[key.replace("anees", "n_eff")], None, None]]
            rows += [[case, name, "time_per_step_ms", r["time_per_step_ms"], None, None]]
    for label, ex in extra.items():
        for case, per in ex.items():
            for name, m in per.items():
                rows += [[f"{label}/{case}", name, key, m.get(key), None, None] for key, _, _ in QUANTITIES]
                for key in ANEES:
                    if not (a := anees_over_runs([m], key)):  # one run: its 99 % interval; {}: none
                        continue
                    rows += [[f"{label}/{case}", name, key, a[key], *interval_cells(a[f"{key}_interval_99"])],
                             [f"{label}/{case}", name, key.replace("anees", "n_eff"), a[key.replace("anees", "n_eff")],
                              None, None]]
    return rows


def _rms_curves(results: list[dict], case: str, path: Path, names: list[str]) -> Path:
    """RMS over runs of the error norms against time, every filter and every plugin whose outputs
    fit the relative-frame hook in every run, on its own instants (like the paper's figs. 5-7)."""
    fig = Figure(figsize=(7.5, 7.0))
    axes = fig.subplots(3, 1, sharex=True)
    names = [n for n in names if all(n in r[case]["norms"] for r in results)]
    for i, (_, label, unit) in enumerate(QUANTITIES):
        for j, name in enumerate(names):
            t = results[0][case].get("times", {}).get(name, results[0][case]["t"])
            series = [r[case]["norms"][name][:, i] for r in results]
            if any(x.shape != (t.size,) for x in series):  # instants that differ between runs: no RMS over runs
                continue
            axes[i].semilogy(t, np.sqrt(np.mean(np.array(series) ** 2, axis=0)), lw=1.0, color=f"C{j}",
                             label=name.upper() if name in FILTERS else name)
        axes[i].set_ylabel(f"{label} [{unit}]")
        axes[i].grid(alpha=0.3, which="both")
    axes[0].set_title(f"RMS error over {len(results)} runs ({case})")
    axes[0].legend(ncol=5, fontsize=8)
    axes[-1].set_xlabel("time [s]")
    return save(fig, path)


def write_plots(out: Path, results: list[dict], summaries: dict, keys: tuple[str, ...] = ()) -> None:
    """plots/: RHCF's run-0 errors with their 3-sigma envelopes, and per noise case the RMS error
    curves and the RMSE bars of every filter and plugin (keys)."""
    names = plugin_rows.estimator_names(FILTERS, keys)
    labels = [n.upper() if n in FILTERS else n for n in names]
    plots = out / "plots"
    t = results[0]["glint"]["t"]
    err, sig = results[0]["glint"]["full"]["rhcf"]
    for sl, label, unit, conv in ((slice(0, 3), "position", "m", 1.0), (slice(3, 6), "velocity", "m/s", 1.0),
                                  (slice(6, 9), "attitude", "deg", 180.0 / np.pi)):
        error_envelope(t, conv * err[:, sl], conv * sig[:, sl], plots / f"rhcf_{label}_glint_run0.png",
                       title=f"RHCF relative {label} error, glint noise (run 0), ±3σ", ylabel=unit)
    for case in CASES:
        _rms_curves(results, case, plots / f"rms_error_vs_time_{case}.png", names)
        for key, label, unit in QUANTITIES:
            s = summaries[case]
            compare_bars(labels, np.array([s[n][key]["mean"] for n in names]),
                         np.array([s[n][key]["lo"] for n in names]), np.array([s[n][key]["hi"] for n in names]),
                         plots / f"compare_{label}_{case}.png",
                         title=f"RMSE of relative {label}, {case} noise, {len(results)} runs (95 % CI)", ylabel=unit)


def write(out: Path, res: VisnavResults, claims: list[Claim], keys: tuple[str, ...] = ()) -> dict:
    """table.md, table.csv, plots/, claims.json and runs.json (every run's metrics); returns the
    summary (per-case tables, claims.json's content, meta). keys: the plugin estimators' names: a row
    each in every noise case's table (after the five filters), a bar in every RMSE figure, a curve
    in the RMS figures where its outputs fit the relative-frame hook, and the "Plugin estimators"
    section with its paired tests against each filter (testbed.reproduce.plugins, table_plugins.csv,
    table_plugins_paired.csv)."""
    meta, results = res.meta, res.results
    summaries = {case: summarize(results, case, keys) for case in CASES}
    groups = {case: [_estimators(r[case]) for r in results] for case in CASES}  # built-ins too: the paired tests
    md = _markdown(summaries, meta, res.extra, claims)
    at = next((i for i, line in enumerate(md) if line.startswith("Wall time")), len(md))
    write_markdown(out / "table.md", md[:at] + plugin_rows.markdown(groups, list(keys), "case") + md[at:])
    plugin_rows.write(out / "table_plugins.csv", groups, list(keys))
    # lo, hi: the 95 % confidence interval of an RMSE's mean; the 99 % interval of a consistent filter's ANEES
    write_csv(out / "table.csv", ["case", "filter", "score", "mean", "lo", "hi"],
              _csv_rows(summaries, res.extra))
    write_plots(out, results, summaries, keys)
    doc = write_claims(out / "claims.json", claims, paper="004", scenario="visnav", motion=meta["motion"],
                       runs=meta["runs"], duration_s=meta["duration"], seeds=meta["seeds"])
    runs_out = [{"seed": seed, **{c: {"metrics": r[c]["metrics"], "glint_fraction": r[c]["glint_fraction"],
                                      "leds_per_epoch": r[c]["leds_per_epoch"],
                                      **({"plugins": r[c]["plugins"]} if "plugins" in r[c] else {})} for c in CASES}}
                for seed, r in zip(meta["seeds"], results)]
    failed: dict[str, list[int]] = {}  # plugin estimators that failed (testbed.plugins.failures): {key: [seeds]}
    for seed, r in zip(meta["seeds"], results):
        for key in dict.fromkeys(k for c in CASES for k, v in r[c].get("plugins", {}).items() if "failed" in v):
            failed.setdefault(key, []).append(seed)
    write_json(out / "runs.json", {"meta": meta, "runs": runs_out, "extra": res.extra,
                                   **({"failed_estimators": failed} if failed else {})})
    return {"summary": summaries, "claims": doc["claims"], "meta": meta}


def reproduce(out: Path, *, runs: int, motion: str = "prescribed", duration: float | None = None,
              workers: int | None = None, estimators: tuple = ()) -> dict:
    """Run the Monte Carlo and write table.md/csv, claims.json, runs.json and plots/ into out.
    estimators: plugin EstimatorSpecs, one more row each per noise case."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    duration = DEFAULT_DURATION if duration is None else float(duration)
    workers = max(1, min(workers or min(2, os.cpu_count() or 1), runs))
    res = compute(runs=runs, motion=motion, duration=duration, workers=workers, estimators=estimators, keep=out)
    summary = write(out, res, decide(res), keys=tuple(e.key for e in estimators))
    for d in (RUNS_DIR, EXTRA_DIR):  # kept only while incomplete
        shutil.rmtree(out / d, ignore_errors=True)
    return summary
