"""`testbed reproduce coop`: seed 001 (Chen et al. 2020), factor-graph cooperative navigation.

Runs scenario `coop-fg` (18 UAVs, 3 RTK, GNSS + UWB, 1 Hz epochs, 300 s) over `runs` seeds with
testbed.sweep (run i: seed 1 + i, the scenario's seed + i, in OUT/runs/run-XXX; testbed.reproduce.runs),
then writes:
- Table 3: mean number of UWB neighbours and RTK neighbours per UAV (over the epochs of run 0; the
  geometry is the same in every run, only the noise changes);
- Table 4: per-UAV RMSE of every estimator of the runs -- GNSS only, one optimization, message
  iteration, the centralized solution and each `--estimator` plugin, in that order (pooled over
  runs: sqrt of the mean of the per-run squared RMSEs) -- and the improvement factor
  RMSE_gnss / RMSE_estimator of every estimator after GNSS only;
- the consistency table (every estimator: ANEES over all vehicles and over the SPP ones, mean over
  the runs with its interval over the runs, testbed.scoring.metrics.anees_over_runs, or "not
  decidable from one run"; solver counts where the estimator reports them), the improvement table (every estimator: mean factor, the factors of
  the four figure UAVs, Spearman correlation with the neighbour counts) and the pairwise table
  (every pair of estimators, each per-UAV Wilcoxon test both ways, paired over the same seeds);
- figure 6 (plots/fig6_error_vs_time.png): position error against time in run 0 for four SPP
  UAVs chosen like the paper's UAVs 1, 7, 12, 13 (testbed.plugins.coop_scores.choose_four: different
  neighbour counts), every estimator; plots/rmse_mean.png: every estimator's mean per-UAV RMSE
  over the runs (95 % Student t interval);
- table.md, table.csv, claims.json (each claim with its numbers and `holds`; testbed.outputs.report).
Every estimator is read the same way, built-in or not: its per-run scores from each run's
metrics.json (the seed 001 hook's keys, testbed.plugins.coop_scores, given to any estimator whose
outputs fit), run 0's estimates from its estimates.npz (testbed.plugins.collect.load_tracks).
Also: the GTSAM check of the centralized solver on the epoch graphs of run 0 of every estimator
that exposes them (testbed.plugins.graph_check), the effect of the round cap (the first
`CAP_EPOCHS` epochs of run 0 re-solved by the coop.iterated plugin with max_rounds = CAP_LARGE;
a round cap is a setting of the distributed built-ins, a plugin has none) and, if obstacles are
enabled (default), a one-run NLOS experiment: pillars in the box, the built-ins with least squares
vs Huber (their `robust` setting) and every plugin with its own settings on the same log. The
re-solves run the estimators as plugins on a log (testbed.plugins.run.run_estimators) with params.

Statistics: per UAV, the per-run RMSEs of two estimators are compared with a one-sided Wilcoxon
signed-rank test (testbed.scoring.stats.wilcoxon_paired: per-run RMSEs are positive and skewed, the
signed-rank test does not assume normal differences) at alpha = 0.01 / 18 (Bonferroni over the
UAVs; the exact test can reach it from 11 runs on: min p = 2^-n); with a single run the test is
not available and the claim is decided on the point values only (said so in the claim). Rank
correlations: scipy.stats.spearmanr, one-sided, alpha = 0.05, over the 15 SPP UAVs. Centralized
joint ANEES (54 dof): every epoch of a run shares the run's per-device antenna delays and clock
offsets, so the K epochs are not independent samples; its 99 % interval comes from the spread of
the per-run joint ANEES over the independent runs (testbed.scoring.metrics.anees_run_interval, Student t
with runs - 1 dof; docs/papers.md, seed 001). The 3-dof interval of the iterated ANEES counts the
effective samples of each run (testbed.scoring.metrics.sample_size) combined over the independent
runs, or the spread of the per-run values when a run cannot decide its own (anees_over_runs, the
one method of docs/consistency.md); with one such run the claim is not decidable.

Round cap: the paper's scheme needs hundreds of rounds per epoch (seeded run: median ~230, 36 %
of the epochs reach 300); the scenario caps them at pipeline.max_rounds = 300 with tol = 1 mm. The
reproduction measures what the cap costs (claims.json `cap_effect`).

Shape (as every reproduction): `compute` (runs -> `CoopResults`), `decide` (numbers -> claims),
`write` (files through testbed.outputs.report); `reproduce` chains them.
"""
from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from testbed.config import from_dict, to_dict
from testbed.log import load_log
from testbed.scoring.metrics import anees_over_runs, anees_run_interval, mean_ci
from testbed.plugins import coop_scores
from testbed.plugins.collect import load_tracks
from testbed.plugins.graph_check import exposes_graphs, gtsam_check
from testbed.plugins.loading import resolve
from testbed.plugins.run import run_estimators
from testbed.config.estimators import EstimatorSpec
from testbed.outputs.plots import compare_bars
from testbed.outputs.report import Claim, Undefined, claims_section, fmt, fmt_anees, fmt_list, markdown_table, \
    write_claims, write_csv, write_markdown
from testbed.reproduce.runs import load_metrics, run_name, seeds, sweep_runs
from testbed.config.scenario import Scenario, load
from testbed.sim.simulate import simulate
from testbed.scoring.stats import wilcoxon_paired
from testbed.sim.world import build

VARIANTS = ("gnss_only", "one_shot", "iterated", "centralized")
LABELS = {"gnss_only": "GNSS only", "one_shot": "one optimization", "iterated": "message iteration",
          "centralized": "centralized"}
PAPER_UAVS = (1, 7, 12, 13)
PAPER_FACTORS = (3.37, 4.53, 7.38, 6.35)
ORDER_SLACK = 1.5  # "of the order of 3-7x": every factor within [3.37 / 1.5, 7.38 * 1.5]
ALPHA_RANK = 0.05
CAP_EPOCHS = 60
CAP_LARGE = 5000
NLOS_DURATION = 60.0
CAP_NOT_PLUGINS = "not applicable: the round cap is a setting (max_rounds) of the distributed built-ins; a plugin has none"
# Three pillars (radius 8 m, 0-120 m tall) between the UAVs, >= 20 m from every base point
# horizontally (>= 3.5 m clear of every UAV's oscillation); they block ~15 of the 70 links.
NLOS_OBSTACLES = (
    {"type": "cylinder", "pos": [70.0, 162.0, 60.0], "size": [8.0, 60.0, 0.0]},
    {"type": "cylinder", "pos": [115.0, 158.0, 60.0], "size": [8.0, 60.0, 0.0]},
    {"type": "cylinder", "pos": [100.0, 80.0, 60.0], "size": [8.0, 60.0, 0.0]},
)


def _pooled(x: np.ndarray) -> np.ndarray:
    """Pooled RMSE over runs from per-run RMSEs x (runs, N): sqrt(mean_runs x^2) (NaN for a UAV
    where some run has none: an estimator that failed or gave no estimate there)."""
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=0))


def _better(a: np.ndarray, b: np.ndarray, alpha: float) -> dict:
    """Is estimator a better (smaller RMSE) than b for every UAV? a, b: (runs, N) per-run RMSEs of
    the same seeds (paired)."""
    runs, n = a.shape
    pa, pb = _pooled(a), _pooled(b)
    per = []
    tests = []
    for i in range(n):
        t = wilcoxon_paired(a[:, i], b[:, i], alternative="less", level=1 - alpha) if runs > 1 else None
        ok = bool(pa[i] < pb[i]) if t is None else bool(np.isfinite(t.p_value) and t.p_value < alpha)
        tests.append(t)
        per.append({"uav": i + 1, "rmse_a_m": float(pa[i]), "rmse_b_m": float(pb[i]), "factor": float(pb[i] / pa[i]),
                    "p_one_sided": Undefined("1 run: no paired test") if t is None else t.p_value,
                    "better": ok})
    if runs > 1:
        worst = max(tests, key=lambda t: t.p_value if np.isfinite(t.p_value) else np.inf)
        fields = {**worst.claim_fields(), "test": f"{n} x {worst.test}, alpha 0.01/{n}; the largest p shown"}
    else:
        fields = {"test": "point comparison of 1 run (no test possible)", "n": 1}
    return {"per_uav": per, "uavs_better": int(sum(p["better"] for p in per)), "uavs": n, "fields": fields}


def _per_uav_rmse(m: dict, key: str, n: int) -> list[float]:
    """(N,) m: one run's RMSE of each UAV's uwb site for estimator `key` (metrics.json): the seed 001
    hook's rmse_position_per_vehicle_m where its outputs fit the hook, else each target's own RMSE;
    NaN where it gave none or failed (testbed.plugins.failures)."""
    e = m["estimators"].get(key, {})
    if "rmse_position_per_vehicle_m" in e:
        return [float(x) for x in e["rmse_position_per_vehicle_m"]]
    return [e.get("targets", {}).get(f"uav{i}/uwb", {}).get("position", {}).get("rmse_m", np.nan) for i in range(1, n + 1)]


def _run0_positions(run_dir: Path, hook: coop_scores.CoopHook, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """{name: (K, N, 3) m} run 0's estimates at the epochs of every estimator whose outputs fit the
    seed 001 hook, read from the run's estimates.npz (the others are left out)."""
    tracks = load_tracks(run_dir / "estimates.npz")
    out = {}
    for w in names:
        got = hook.positions(tracks[w]) if w in tracks else None
        if got is not None:
            out[w] = got[0]
    return out


def _gtsam(scenario: Scenario, run_dir: Path, specs: tuple[EstimatorSpec, ...]) -> dict[str, dict]:
    """{key: the GTSAM check (testbed.plugins.graph_check)} of every estimator of the run that
    exposes its epoch graphs, run again as a plugin on run 0's log."""
    plugins = [p for p in resolve(specs) if exposes_graphs(p.cls)]
    kept: dict[str, object] = {}
    run_estimators(scenario, build(scenario), load_log(run_dir), plugins, None, keep=kept)
    return gtsam_check(kept)


def _cap_log(scenario: Scenario, run_dir: Path) -> tuple[Scenario, dict]:
    """(scenario, log) of run 0's first CAP_EPOCHS epochs: run 0's own log when it is that short,
    else the same seed simulated for CAP_EPOCHS - 1 s (its streams are the prefix of run 0's:
    checked, a RuntimeError if not)."""
    log = load_log(run_dir)
    epochs = np.unique(log["gnss/state_index"]).size
    if epochs <= CAP_EPOCHS:
        return scenario, log
    sc = replace(scenario, duration=float(log["time"][np.unique(log["gnss/state_index"])[CAP_EPOCHS - 1]]))
    short, _ = simulate(sc)
    for k in ("gnss/value", "uwb/value"):
        if not np.array_equal(short[k], log[k][:short[k].shape[0]]):
            raise RuntimeError(f"coop cap effect: {k} of the {sc.duration:g}-s simulation is not the prefix of run 0's")
    return sc, short


def _cap_effect(scenario: Scenario, run_dir: Path) -> dict:
    """coop.iterated on the first CAP_EPOCHS epochs of run 0 with the scenario's round cap vs
    CAP_LARGE rounds (params max_rounds), and coop.centralized: rounds, converged fraction, SPP
    RMSE pooled over the SPP UAVs' epochs, largest change of a position between the capped and the
    uncapped iteration (the estimators as plugins on the log; their estimates at the epochs through
    the seed 001 hook)."""
    sc, log = _cap_log(scenario, run_dir)
    physics = build(sc)
    cfg = scenario.pipeline
    hook = coop_scores.coop_hook(sc, log)
    capped, ct = run_estimators(sc, physics, log, resolve([EstimatorSpec(entry="coop.iterated", name="iterated")]), None)
    big, bt = run_estimators(sc, physics, log, resolve([EstimatorSpec(entry=f"coop.{w}", name=w, params={"max_rounds": CAP_LARGE})
                                                        for w in ("iterated", "centralized")]), None)
    c, b = capped["iterated"], big["iterated"]
    ep = hook.epochs
    pos = {"capped": hook.positions(ct["iterated"])[0], "large": hook.positions(bt["iterated"])[0],
           "centralized": hook.positions(bt["centralized"])[0]}
    # RMSE over the SPP UAVs' epochs pooled (m)
    r = {k: float(np.sqrt(np.mean(np.sum((x - ep.truth) ** 2, axis=-1)[:, ~ep.is_rtk]))) for k, x in pos.items()}
    return {
        "epochs": int(c["epochs"]), "cap": cfg.max_rounds, "large_cap": CAP_LARGE, "tol_m": cfg.tol,
        "rounds_capped_mean": c["iterations_mean"], "capped_fraction": 1.0 - c["converged_fraction"],
        "rounds_large_mean": b["iterations_mean"], "rounds_large_max": b["iterations_max"],
        "converged_large_fraction": b["converged_fraction"],
        "rmse_spp_capped_m": r["capped"], "rmse_spp_large_m": r["large"], "rmse_spp_centralized_m": r["centralized"],
        "max_position_change_m": float(np.linalg.norm(pos["capped"] - pos["large"], axis=-1).max()),
        "plugins": CAP_NOT_PLUGINS,
    }


def _nlos_experiment(scenario: Scenario, seed: int, specs: tuple[EstimatorSpec, ...]) -> dict:
    """One run with pillars in the box (NLOS ranges from mj_ray): the built-ins with least squares
    vs Huber (params robust), every plugin of `specs` with its own settings, all on the same log."""
    table = to_dict(replace(scenario, estimators=()))
    table["world"]["obstacles"] = [dict(o) for o in NLOS_OBSTACLES]
    table["duration"] = min(NLOS_DURATION, scenario.duration)
    table["seed"] = seed
    sc = from_dict(Scenario, table, "coop-fg (NLOS experiment)")
    log, physics = simulate(sc)
    nl = log["uwb/nlos"]
    ep = coop_scores.epochs_from_log(log, sc.vehicles)
    out = {"duration_s": sc.duration, "obstacles": list(NLOS_OBSTACLES),
           "nlos_fraction": float(np.concatenate(ep.nlos).mean()),
           "nlos_error_mean_m": float(np.mean((log["uwb/value"][:, 0] - log["uwb/clean"][:, 0])[nl])) if nl.any() else 0.0,
           "mujoco_warnings": physics.warnings()}

    def scores(specs_: list[EstimatorSpec]) -> dict:
        got = run_estimators(sc, physics, log, resolve(specs_), None)[0]
        # the ANEES with its interval and effective samples (anees_keys), for fmt_anees
        return {k: {"rmse_position_spp_mean_m": v.get("rmse_position_spp_mean_m"),
                    **{a: x for a, x in v.items()
                       if a in ("anees", "n_eff", "anees_null_reason") or a.startswith("anees_interval_")}}
                for k, v in got.items()}

    for robust in ("none", "huber"):
        out[robust] = scores([EstimatorSpec(entry=f"coop.{w}", name=w, params={"robust": robust})
                              for w in ("gnss_only", "iterated", "centralized")])
    out["plugins"] = scores(list(specs)) if specs else {}
    return out


def _rank_claim(claim_id: str, what: str, rho, counts: np.ndarray, factors: np.ndarray) -> Claim:
    """Claim "the improvement grows with the number of <what>": one-sided Spearman rank
    correlation rho (scipy result) of the iterated improvement factors with the counts, over the
    SPP UAVs, at ALPHA_RANK."""
    return Claim(id=claim_id, text=f"the improvement grows with the number of {what}",
                 numbers={"spearman_rho": float(rho.statistic), "p_one_sided": float(rho.pvalue),
                          "uavs": int(counts.size), what.lower().replace(" ", "_"): [float(x) for x in counts],
                          "factor_iterated": [float(x) for x in factors]},
                 criterion=f"Spearman rank correlation over the SPP UAVs, one-sided, alpha = {ALPHA_RANK}",
                 holds=bool(rho.statistic > 0 and rho.pvalue < ALPHA_RANK),
                 summary=f"rho = {fmt(rho.statistic)}", paper_value="grows (Table 4)",
                 test="Spearman rank correlation (greater)", statistic=float(rho.statistic),
                 p_value=float(rho.pvalue), n=int(counts.size), level=1 - ALPHA_RANK)


@dataclass(frozen=True, kw_only=True, slots=True)
class CoopResults:
    """What the runs gave (compute's output, decide's and write's input).

    names: every estimator of the runs (VARIANTS, then the plugins); rmse: {name: (runs, N) m}
    per-run per-UAV RMSE; metrics: metrics.json of every run; epochs: run 0's epochs; pos0:
    {name: (K, N, 3) m} run 0's estimates of the estimators that fit the seed 001 hook;
    neighbours, rtk_neighbours: (N,) mean counts over run 0; four: the figure 6 UAVs (1-based);
    gtsam: {key: check} on run 0 (testbed.plugins.graph_check); cap: the round-cap effect (run 0);
    nlos: the NLOS experiment or None.
    """

    scenario: Scenario
    motion: str
    runs: int
    names: tuple[str, ...]
    metrics: list[dict]
    rmse: dict[str, np.ndarray]
    epochs: coop_scores.Epochs
    pos0: dict[str, np.ndarray]
    neighbours: np.ndarray
    rtk_neighbours: np.ndarray
    four: list[int]
    gtsam: dict
    cap: dict
    nlos: dict | None

    @property
    def plugins(self) -> tuple[str, ...]:
        """The `--estimator` plugins' keys (the estimators after the built-ins)."""
        return self.names[len(VARIANTS):]

    @property
    def pooled(self) -> dict[str, np.ndarray]:
        """{estimator: (N,) m} RMSE pooled over runs."""
        return {w: _pooled(self.rmse[w]) for w in self.names}

    @property
    def factor(self) -> dict[str, np.ndarray]:
        """{estimator: (N,)} improvement factor RMSE_gnss / RMSE_estimator (pooled), every estimator after GNSS only."""
        p = self.pooled
        return {w: p["gnss_only"] / p[w] for w in self.names[1:]}

    @property
    def spp(self) -> np.ndarray:
        return ~self.epochs.is_rtk


def compute(out: Path, *, runs: int, motion: str, duration: float | None, workers: int | None,
            nlos: bool, estimators: tuple = ()) -> CoopResults:
    """The Monte Carlo (OUT/runs/run-XXX) and the run-0 analyses (GTSAM check, cap effect, NLOS).
    estimators: plugin EstimatorSpecs run and scored in every run beside the built-ins, and given
    everything they are (module docstring)."""
    scenario = replace(load("coop-fg", motion=motion, duration=duration), estimators=tuple(estimators))
    cfg = scenario.pipeline
    names = VARIANTS + tuple(s.key for s in estimators)
    run_dirs = sweep_runs(scenario, runs, out / "runs", workers=workers)
    metrics = load_metrics(run_dirs)
    n = scenario.vehicles
    # run 0's geometry (Table 3) and estimates (figure 6), from its log and estimates.npz
    ep = coop_scores.epochs_from_log(load_log(run_dirs[0]), n)
    hook = coop_scores.CoopHook(ep, tuple(cfg.plot_uavs) or tuple(coop_scores.choose_four(ep)))
    nb, nr = coop_scores.neighbour_counts(ep)
    specs = tuple(EstimatorSpec(entry=f"coop.{w}", name=w) for w in VARIANTS) + tuple(estimators)
    return CoopResults(
        scenario=scenario, motion=motion, runs=runs, names=names, metrics=metrics,
        rmse={w: np.array([_per_uav_rmse(m, w, n) for m in metrics], float) for w in names},
        epochs=ep, pos0=_run0_positions(run_dirs[0], hook, names), neighbours=nb, rtk_neighbours=nr, four=list(hook.uavs),
        gtsam=_gtsam(scenario, run_dirs[0], specs), cap=_cap_effect(replace(scenario, estimators=()), run_dirs[0]),
        nlos=_nlos_experiment(scenario, scenario.seed, tuple(estimators)) if nlos else None)


def _better_claim(claim_id: str, text: str, c: dict, numbers: dict, test_note: str, summary: str, spp: np.ndarray,
                  note: str = "") -> Claim:
    """A per-UAV ordering claim; its summary names the UAVs not shown better (RTK or SPP, factor, p), up to 3."""
    missed = [f"UAV {p['uav']} ({'SPP' if spp[p['uav'] - 1] else 'RTK'}, x{fmt(p['factor'])}, p {fmt(p['p_one_sided'])})"
              for p in c["per_uav"] if not p["better"]]
    if missed:
        summary += "; not shown: " + (", ".join(missed) if len(missed) <= 3 else f"{len(missed)} UAVs")
    return Claim(id=claim_id, text=text, numbers={"uavs_better": c["uavs_better"], "uavs": c["uavs"], **numbers,
                                                  "per_uav": c["per_uav"]},
                 criterion=test_note, holds=c["uavs_better"] == c["uavs"], summary=summary, note=note,
                 paper_value="better for every UAV", **c["fields"])


def _test_note(runs: int, n: int) -> str:
    """How a per-UAV ordering is decided with `runs` runs and n UAVs (alpha 0.01 / n, Bonferroni)."""
    alpha = 0.01 / n
    # the exact signed-rank test's smallest p-value is 2^-runs: below that many runs it cannot reach alpha
    min_runs = math.ceil(math.log2(1 / alpha))
    note = (f"one-sided Wilcoxon signed-rank test per UAV over {runs} paired runs, alpha = 0.01/{n}" if runs > 1
            else "1 run: decided on the point values, no test")
    if 1 < runs < min_runs:
        note += f" (not reachable with {runs} runs: the smallest p is 2^-{runs}; {min_runs} runs needed)"
    return note


def _gtsam_claim(gtsam: dict) -> Claim:
    """(testbed) our centralized Gauss-Newton equals GTSAM's on the epoch graphs of every estimator that exposes them."""
    text = "(testbed) our centralized Gauss-Newton equals GTSAM's on the same graph"
    if not gtsam:
        return Claim(id="centralized_equals_gtsam", text=text, numbers={}, criterion="no estimator exposes its epoch graphs",
                     holds=False, not_decidable="no estimator of the runs exposes its epoch graphs", summary="n/a",
                     paper_value="(testbed check)", test="none")
    dpos = max(g["max_position_diff_m"] for g in gtsam.values())
    dcov = max(g["max_cov_rel_diff"] for g in gtsam.values())
    epochs = max(g["epochs"] for g in gtsam.values())
    return Claim(id="centralized_equals_gtsam", text=text,
                 numbers={"estimators": gtsam, "max_position_diff_m": dpos, "max_cov_rel_diff": dcov, "epochs": epochs},
                 criterion=next(iter(gtsam.values()))["criterion"] + "; on the graphs of every estimator that exposes them",
                 holds=all(g["holds"] for g in gtsam.values()),
                 summary=f"max |dx| {fmt(dpos)} m, max cov rel diff {fmt(dcov)} ({epochs} epochs; graphs of "
                         f"{', '.join(gtsam)})", paper_value="(testbed check)",
                 test="deterministic comparison on every epoch of run 0 (nothing sampled)", statistic=dpos, n=epochs)


def decide(res: CoopResults) -> list[Claim]:
    """The paper's claims (and the testbed's own) from the numbers, with the module's criteria."""
    R, pooled, spp, runs = res.rmse, res.pooled, res.spp, res.runs
    n = R["gnss_only"].shape[1]
    alpha = 0.01 / n
    mean_row = [float(np.mean(pooled[w])) for w in VARIANTS]
    c_every = _better(R["iterated"], R["gnss_only"], alpha)
    c_every_spp = int(sum(p["better"] for p, s in zip(c_every["per_uav"], spp) if s))
    c_one = _better(R["one_shot"], R["gnss_only"], alpha)
    c_iter = _better(R["iterated"], R["one_shot"], alpha)
    fac = res.factor["iterated"]
    nb, nr = res.neighbours, res.rtk_neighbours
    rho_n = spearmanr(nb[spp], fac[spp], alternative="greater")
    rho_r = spearmanr(nr[spp], fac[spp], alternative="greater")
    four = res.four
    f4 = [float(fac[u - 1]) for u in four]
    lo_o, hi_o = min(PAPER_FACTORS) / ORDER_SLACK, max(PAPER_FACTORS) * ORDER_SLACK
    test_note = _test_note(runs, n)
    return [
        _better_claim("cooperation_improves_every_uav", "cooperation improves the positioning of every UAV", c_every,
                      {"spp_uavs_better": c_every_spp, "spp_uavs": int(spp.sum())}, test_note,
                      f"{c_every['uavs_better']}/{n} UAVs better than GNSS only ({c_every_spp}/{int(spp.sum())} SPP)", spp,
                      note="iterated vs GNSS only; RTK UAVs (2-3 cm fixes) gain little from 10 cm ranges to SPP "
                           "neighbours"),
        _better_claim("one_optimization_helps", "one optimization without message iteration already improves the "
                      "accuracy", c_one, {"mean_rmse_gnss_m": mean_row[0], "mean_rmse_one_shot_m": mean_row[1]},
                      test_note, f"{c_one['uavs_better']}/{n} UAVs; mean {fmt(mean_row[0])} -> {fmt(mean_row[1])} m",
                      spp),
        _better_claim("iteration_helps_more", "message iteration improves further over one optimization", c_iter,
                      {"mean_rmse_one_shot_m": mean_row[1], "mean_rmse_iterated_m": mean_row[2]}, test_note,
                      f"{c_iter['uavs_better']}/{n} UAVs; mean {fmt(mean_row[1])} -> {fmt(mean_row[2])} m", spp),
        _rank_claim("improvement_grows_with_neighbours", "neighbours", rho_n, nb[spp], fac[spp]),
        _rank_claim("improvement_grows_with_rtk_neighbours", "RTK neighbours", rho_r, nr[spp], fac[spp]),
        Claim(id="improvement_factors_3_to_7",
              text="after iteration the RMSE of UAVs 1, 7, 12, 13 fell 3.37x, 4.53x, 7.38x, 6.35x",
              numbers={"uavs": four, "neighbours": [float(nb[u - 1]) for u in four],
                       "rtk_neighbours": [float(nr[u - 1]) for u in four], "factors": f4,
                       "paper_uavs": list(PAPER_UAVS), "paper_factors": list(PAPER_FACTORS),
                       "accepted_range": [lo_o, hi_o]},
              criterion=f"every factor within [min/{ORDER_SLACK}, max*{ORDER_SLACK}] of the paper's 3.37-7.38",
              holds=bool(all(lo_o <= f <= hi_o for f in f4)),
              summary=f"UAVs {four}: {fmt_list(f4)}x", paper_value=f"{fmt_list(PAPER_FACTORS)}x",
              test="point comparison with the paper's single values (pooled RMSE; the paper gives no spread)",
              interval=(lo_o, hi_o), n=runs),
        _gtsam_claim(res.gtsam),
        _covariance_claim([m["estimators"] for m in res.metrics], n),
    ]


def _covariance_claim(est: list[dict], n: int) -> Claim:
    """The claim "re-using neighbours' estimates makes the distributed covariance over-confident" from
    est, each run's metrics.json `estimators` (the iterated and centralized keys of
    testbed.plugins.coop_scores), n UAVs: every interval by the one method of docs/consistency.md."""
    runs = len(est)
    anees_it = float(np.mean([e["iterated"]["anees_spp"] for e in est]))
    anees_c = float(np.mean([e["centralized"]["anees_spp"] for e in est]))
    joint_runs = np.array([e["centralized"]["anees_joint"] for e in est])
    jn = float(np.mean(joint_runs))
    # every interval by the one method over the independent runs (anees_over_runs, docs/consistency.md):
    # the runs' effective samples combined, or the spread of their values when a run cannot decide
    # its own; with one undecidable run, no interval (its reason)
    over = {w: anees_over_runs([e[w] for e in est], "anees_spp") for w in ("iterated", "centralized")}
    joint = anees_over_runs([e["centralized"] for e in est], "anees_joint")
    # the epochs of a run share its radios' antenna delays and clock offsets (constant): the runs,
    # not the K runs epochs, are the independent samples, so from 2 runs on the joint interval is the
    # spread of the per-run values (testbed.scoring.metrics.anees_run_interval)
    jint = list(anees_run_interval(joint_runs, 3 * n)) if runs > 1 else joint["anees_joint_interval_99"]
    it3, c3 = (over[w]["anees_spp_interval_99"] for w in ("iterated", "centralized"))
    why = "; ".join(f"{what}: {d[f'{k}_null_reason']}" for what, d, k, got in
                    (("iterated SPP ANEES", over["iterated"], "anees_spp", it3),
                     ("centralized joint ANEES", joint, "anees_joint", jint)) if got is None)
    return Claim(id="distributed_covariance_overconfident",
                 text="(the paper's open question, docs/papers.md) re-using neighbours' estimates makes the "
                      "distributed covariance over-confident",
                 numbers={"anees_spp_iterated": anees_it, "anees_spp_centralized": anees_c,
                          "anees_joint_centralized": jn, "joint_dof": 3 * n,
                          "interval_99_upper_3dof": it3[1] if it3 else None, "interval_99_3dof_iterated": it3,
                          "interval_99_3dof_centralized": c3, "joint_interval_99": jint,
                          "anees_spp_over_runs": over, "anees_joint_over_runs": joint,
                          "anees_joint_centralized_per_run": [float(x) for x in joint_runs],
                          "anees_iterated_run0": est[0]["iterated"]["anees"],
                          "anees_centralized_run0": est[0]["centralized"]["anees"]},
                 criterion="iterated ANEES (3 dof, SPP UAVs) above the upper end of the 99 % interval of a consistent "
                           "estimator over the runs (docs/consistency.md: the runs' combined effective samples of the "
                           "correlated epochs and vehicles, or the spread of the per-run values when a run cannot decide "
                           "its own) while the centralized joint ANEES (54 dof) is inside its 99 % interval, from the "
                           "spread of the per-run joint ANEES (runs independent, epochs of a run not: Student t, runs - 1 "
                           "dof; with 1 run the run's own interval over its effective epochs); not decidable where an "
                           "interval is not",
                 holds=bool(not why and anees_it > it3[1] and jint[0] <= jn <= jint[1]), not_decidable=why,
                 summary=f"ANEES iterated {fmt_anees(over['iterated'], 'anees_spp')} vs centralized "
                         f"{fmt_anees(over['centralized'], 'anees_spp')} (3 dof, 99 %); joint {fmt(jn)} in "
                         + (f"({fmt(jint[0])}, {fmt(jint[1])})" if jint else "(not decidable from one run)"),
                 paper_value="(open question)",
                 test=f"iterated ANEES {fmt(anees_it)} against the upper end {fmt(it3[1] if it3 else None)} of its 99 % "
                      f"interval (3 dof); statistic and interval: the centralized joint ANEES ({3 * n} dof) and its 99 % "
                      "interval over the runs",
                 statistic=jn, interval=tuple(jint) if jint else None, n=runs, level=0.99)


def _column(w: str) -> str:
    """Table 4's RMSE column of estimator w (table.csv)."""
    return "rmse_gnss_m" if w == "gnss_only" else f"rmse_{w}_m"


def _columns(res: CoopResults) -> list[str]:
    """table.csv's columns: the UAV, Table 3's counts, every estimator's RMSE, then every improvement factor."""
    return (["uav", "rtk", "neighbours", "rtk_neighbours"] + [_column(w) for w in res.names]
            + [f"factor_{w}" for w in res.names[1:]])


def _rows(res: CoopResults) -> list[list]:
    """Table 3 and 4 per UAV, in _columns order."""
    p, f = res.pooled, res.factor
    return [[i + 1, bool(res.epochs.is_rtk[i]), res.neighbours[i], res.rtk_neighbours[i]]
            + [p[w][i] for w in res.names] + [f[w][i] for w in res.names[1:]] for i in range(res.neighbours.size)]


def _mean(x) -> float | None:
    """Mean of the finite values of x; None when there is none (an estimator without that score)."""
    x = np.asarray([v for v in x if v is not None], float)
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else None


def _consistency(res: CoopResults) -> list[dict]:
    """Per estimator, over the runs where it has the keys: ANEES of all vehicles (anees_over_runs:
    mean, 99 % interval of a consistent estimator, combined effective samples), the same of the SPP
    vehicles' ANEES (anees_spp keys, 3 dof), iterations and messages per epoch (solver counts,
    where the estimator reports them)."""
    rows = []
    for w in res.names:
        runs = [m["estimators"].get(w, {}) for m in res.metrics]
        rows.append({"estimator": w, "runs_scored": sum("failed" not in r and bool(r) for r in runs),
                     **anees_over_runs(runs, "anees", 0.99), **anees_over_runs(runs, "anees_spp", 0.99),
                     "iterations_mean": _mean(r.get("iterations_mean") for r in runs),
                     "messages_per_epoch": _mean(r.get("messages_per_epoch") for r in runs)})
    return rows


def _improvement(res: CoopResults) -> list[dict]:
    """Per estimator after GNSS only: its improvement factors (pooled RMSE_gnss / RMSE), their mean
    over all and over the SPP UAVs, the factors of the figure UAVs, and the one-sided Spearman rank
    correlation of the SPP factors with the neighbour counts (as the paper's claim for iteration)."""
    spp, nb = res.spp, res.neighbours
    rows = []
    for w, f in res.factor.items():
        ok = spp & np.isfinite(f)
        rho = spearmanr(nb[ok], f[ok], alternative="greater") if ok.sum() > 2 else None
        rows.append({"estimator": w, "factor_mean": _mean(f), "factor_spp_mean": _mean(f[spp]),
                     "factors_four": [float(f[u - 1]) for u in res.four],
                     "spearman_rho_neighbours": float(rho.statistic) if rho is not None else None,
                     "p_one_sided": float(rho.pvalue) if rho is not None else None})
    return rows


def _pairwise(res: CoopResults) -> list[dict]:
    """Every pair (a, b) of estimators (a listed first): the per-UAV one-sided Wilcoxon signed-rank
    tests of both directions over the same seeds (paired runs) at alpha 0.01 / N, as the claims
    use (_better); the UAVs each is shown better on, the largest p of each direction, the mean
    pooled RMSEs."""
    n = res.neighbours.size
    alpha = 0.01 / n
    rows = []
    for i, a in enumerate(res.names):
        for b in res.names[i + 1:]:
            ab, ba = _better(res.rmse[a], res.rmse[b], alpha), _better(res.rmse[b], res.rmse[a], alpha)
            rows.append({"a": a, "b": b, "mean_rmse_a_m": _mean(res.pooled[a]), "mean_rmse_b_m": _mean(res.pooled[b]),
                         "uavs_a_better": ab["uavs_better"], "uavs_b_better": ba["uavs_better"], "uavs": n,
                         "p_max_a_better": ab["fields"].get("p_value"), "p_max_b_better": ba["fields"].get("p_value"),
                         "test": ab["fields"]["test"], "runs": res.runs, "alpha": alpha})
    return rows


def _label(w: str) -> str:
    return LABELS.get(w, w)


def _markdown(res: CoopResults, claims: list[Claim], cons: list[dict], impr: list[dict], pairs: list[dict]) -> list[str]:
    sc, runs, rows, names = res.scenario, res.runs, _rows(res), res.names
    md = [f"# Seed 001 reproduction: coop-fg, {res.motion}, {runs} run(s) of {fmt(sc.duration)} s "
          f"({res.epochs.time.size} epochs each), seeds {sc.seed}..{sc.seed + runs - 1}", ""]
    if res.plugins:
        md += [f"Estimators: the paper's four and {', '.join(res.plugins)} (--estimator), scored alike in every run.", ""]
    md += ["## Table 3: neighbours per UAV (mean over the epochs of run 0; UWB/data link within 100 m)", ""]
    md += markdown_table(["UAV", "RTK", "neighbours", "RTK neighbours"],
                         [[r[0], "yes" if r[1] else "", r[2], r[3]] for r in rows])
    md += ["", "## Table 4: position RMSE per UAV (m, pooled over runs) and improvement factor over GNSS only", ""]
    md += markdown_table(["UAV", *map(_label, names), *(f"x {_label(w)}" for w in names[1:])],
                         [[f"{r[0]}{' (RTK)' if r[1] else ''}", *r[4:]] for r in rows]
                         + [["mean", *(_mean(res.pooled[w]) for w in names), *(_mean(res.factor[w]) for w in names[1:])]])
    md += ["", f"## Consistency and solver effort (every estimator, over the {runs} run(s))", "",
           "ANEES: mean over the runs [99 % interval of a consistent estimator over the runs' combined effective "
           "samples, or from the spread of the per-run values when a run cannot decide its own; or not decidable "
           "from one run] (n_eff; docs/consistency.md); iterations and messages per epoch where the estimator "
           "reports them (health()).", ""]
    md += markdown_table(["estimator", "runs", "ANEES (3 dof)", "ANEES SPP (3 dof)", "iterations/epoch", "messages/epoch"],
                         [[_label(c["estimator"]), c["runs_scored"], fmt_anees(c) or "n/a",
                           fmt_anees(c, "anees_spp") or "n/a",
                           fmt(c["iterations_mean"]), fmt(c["messages_per_epoch"])] for c in cons])
    md += ["", "## Improvement over GNSS only (every estimator)", "",
           f"Factor RMSE_gnss / RMSE per UAV (pooled); UAVs {res.four} are figure 6's; Spearman: one-sided rank "
           f"correlation of the SPP UAVs' factors with their neighbour counts.", ""]
    md += markdown_table(["estimator", "mean factor", "mean factor SPP", f"factors UAVs {res.four}", "Spearman rho", "p"],
                         [[_label(r["estimator"]), fmt(r["factor_mean"]), fmt(r["factor_spp_mean"]),
                           fmt_list(r["factors_four"]), fmt(r["spearman_rho_neighbours"]), fmt(r["p_one_sided"])]
                          for r in impr])
    md += ["", "## Pairwise comparisons (every pair of estimators, paired over the same seeds)", "",
           f"Per UAV, both directions: {_test_note(runs, res.neighbours.size)}; the largest p of each direction.", ""]
    md += markdown_table(["A", "B", "mean RMSE A [m]", "mean RMSE B [m]", "UAVs A better", "UAVs B better", "max p (A better)",
                          "max p (B better)"],
                         [[_label(p["a"]), _label(p["b"]), fmt(p["mean_rmse_a_m"]), fmt(p["mean_rmse_b_m"]),
                           f"{p['uavs_a_better']}/{p['uavs']}", f"{p['uavs_b_better']}/{p['uavs']}", fmt(p["p_max_a_better"]),
                           fmt(p["p_max_b_better"])] for p in pairs])
    md += [""]
    md += claims_section(claims)
    cap = res.cap
    md += ["", f"Round cap: {cap['cap']} rounds, tol {fmt(cap['tol_m'] * 1e3)} mm: {fmt(100 * cap['capped_fraction'])} % "
           f"of the first {cap['epochs']} epochs hit the cap; with {cap['large_cap']} rounds they need "
           f"{fmt(cap['rounds_large_mean'])} on average (max {cap['rounds_large_max']}); SPP RMSE "
           f"{fmt(cap['rmse_spp_capped_m'])} m (capped) vs {fmt(cap['rmse_spp_large_m'])} m (uncapped) vs centralized "
           f"{fmt(cap['rmse_spp_centralized_m'])} m; largest position change {fmt(cap['max_position_change_m'])} m."
           + (f" Plugins ({', '.join(res.plugins)}): {CAP_NOT_PLUGINS}." if res.plugins else "")]
    if res.nlos is not None:
        nx = res.nlos
        spp_rmse = {(r, w): fmt(nx[r][w]["rmse_position_spp_mean_m"]) for r in ("none", "huber") for w in nx[r]}
        md += ["", f"NLOS experiment ({fmt(nx['duration_s'])} s, 3 pillars): {fmt(100 * nx['nlos_fraction'])} % NLOS "
               f"ranges, mean NLOS range error {fmt(nx['nlos_error_mean_m'])} m. SPP mean RMSE least squares / Huber: "
               f"iterated {spp_rmse['none', 'iterated']} / {spp_rmse['huber', 'iterated']} m, centralized "
               f"{spp_rmse['none', 'centralized']} / {spp_rmse['huber', 'centralized']} m (GNSS only "
               f"{spp_rmse['none', 'gnss_only']} m)."
               + "".join(f" {k} (its own settings; the robust loss is a built-in setting): SPP mean RMSE "
                         f"{fmt(v['rmse_position_spp_mean_m'])} m, ANEES {fmt_anees(v) or fmt(None)}."
                         for k, v in nx["plugins"].items())]
    return md


def write(out: Path, res: CoopResults, claims: list[Claim]) -> dict:
    """plots/ (figure 6, mean RMSE bars, run 0's error curves with 3-sigma envelopes), table.md,
    table.csv, pairwise.csv, claims.json; returns claims.json's content. Every estimator alike."""
    sc, runs = res.scenario, res.runs
    (out / "plots").mkdir(parents=True, exist_ok=True)
    for f in sorted((out / "runs" / run_name(0) / "plots").glob("*_envelope.png")):
        shutil.copy(f, out / "plots" / f"run0_{f.name}")
    coop_scores.plot_error_vs_time(res.epochs, res.pos0, res.four, out / "plots" / "fig6_error_vs_time.png",
                                   f"Figure 6 (run 0, seed {sc.seed}): position error, UAVs {res.four}")
    # per run, the mean over UAVs of each estimator's RMSE; its mean and 95 % Student t interval over the runs
    stats = [mean_ci(x[np.isfinite(x)]) if np.isfinite(x).any() else (np.nan,) * 3
             for x in (res.rmse[w].mean(axis=1) for w in res.names)]
    compare_bars(list(res.names), np.array([s[0] for s in stats]), np.array([s[1] for s in stats]),
                 np.array([s[2] for s in stats]), out / "plots" / "rmse_mean.png",
                 title=f"Mean per-UAV RMSE over {runs} runs (95 % CI)", ylabel="RMSE [m]")
    cons, impr, pairs = _consistency(res), _improvement(res), _pairwise(res)
    write_csv(out / "table.csv", _columns(res), _rows(res))
    write_csv(out / "pairwise.csv", list(pairs[0]), [list(p.values()) for p in pairs])
    write_markdown(out / "table.md", _markdown(res, claims, cons, impr, pairs))
    spp = res.spp
    extra = {"estimators": list(res.names), "cap_effect": res.cap}
    if res.nlos is not None:
        extra["nlos_experiment"] = res.nlos
    extra["iterated_over_centralized_rmse_spp_mean_ratio"] = float(
        np.mean(res.pooled["iterated"][spp] / res.pooled["centralized"][spp]))
    return write_claims(out / "claims.json", claims, paper="001", scenario=sc.name, motion=res.motion, runs=runs,
                        seeds=seeds(sc.seed, runs), epochs_per_run=int(res.epochs.time.size),
                        round_cap=sc.pipeline.max_rounds, consistency=cons, improvement=impr, pairwise=pairs, **extra)


def reproduce(out: Path, *, runs: int, motion: str = "prescribed", duration: float | None = None,
              workers: int | None = None, nlos: bool = True, estimators: tuple = ()) -> dict:
    """Seed 001 reproduction into `out` (see the module docstring); returns claims.json's content.
    estimators: plugin EstimatorSpecs, given every table, plot and test the built-ins get."""
    out = Path(out)
    res = compute(out, runs=runs, motion=motion, duration=duration, workers=workers, nlos=nlos, estimators=estimators)
    return write(out, res, decide(res))
