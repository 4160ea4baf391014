"""`testbed reproduce bandwidth --out DIR [--runs N]`: seed 000 in both measurement modes.

DIR/paper/: the paper mode (testbed.reproduce.bandwidth_paper: synthetic y = C x + v with the
paper's A, W, V, x(0), M(0); readings (a) W per step, dt = 1 s and (b) W as a rate, dt = 0.1 s;
horizon 50 s; `runs` Monte Carlo runs, default 500).

DIR/uwb/: the uwb mode. `min(runs, UWB_MAX_RUNS)` seeds (default 100) of the `bandwidth` scenario
are simulated through testbed.sweep (DIR/uwb/runs/run-XXX, full run directories, run i: seed
scenario.seed + i; testbed.reproduce.runs) over `duration` (default 50 s, the paper mode's horizon), in `motion` mode.
Every run's log then goes through the pipeline's measurement step once (UWB ranges -> eqs. 21-23
pseudo-measurements with V from the range noise) and through the estimator for each case:
T1, T2, T3 and the bound-optimal selection (exhaustive search over the 2430 admissible sets,
P1, V of run 0's first epoch) with P1, and T1 with P2, P3. All cases see the same logs (common
random numbers), so cases are compared on paired per-run differences. The prescribed truth has
no process noise: W (the paper's, read as a rate) is the estimator's model, not the truth's.

DIR/table.md, table.csv, claims.json, plots/ gather both modes (claims carry "mode").

Shape (as every reproduction): `compute` (runs -> numbers), `decide` (numbers -> claims), `write`
(files through testbed.outputs.report), for each mode (`compute_uwb`, `decide_uwb`, `write_uwb`; the paper
mode in testbed.reproduce.bandwidth_paper); `reproduce` chains them and gathers both modes.
"""
from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
from scipy.stats import norm

from estimators import bandwidth as bw
from testbed.config import scenario as scenario_mod
from testbed.log import load_log
from testbed.plugins.collect import ESTIMATES_FILE, load_tracks
from testbed.plugins.context import make_context
from testbed.plugins.truth import Truth, errors
from testbed.reproduce import bandwidth_batch as pb
from testbed.outputs.plots import compare_bars
from testbed.outputs.report import Claim, claims_section, fmt, fmt_list, markdown_table, write_claims, write_csv, write_json, \
    write_markdown
from testbed.reproduce import bandwidth_paper as paper_mode
from testbed.reproduce import bandwidth_plots as bplots
from testbed.reproduce.bandwidth_paper import _fmt_T
from testbed.synthetic.bandwidth import P_SETS, T_SETS
from testbed.reproduce import plugins as plugin_rows
from testbed.reproduce.runs import load_metrics, run_name, seeds, sweep_runs
from testbed.scoring.stats import paired_t
from testbed.sim.world import build, lever_arms

UWB_MAX_RUNS = 100
HORIZON_S = 50.0
# "significantly different / lower": paired t test of the per-run J (eq. 12; a sum of many squared errors,
# so its paired differences are near normal: the t test is the right one) beyond 3 standard errors
# (two-sided p ~ 0.3 %), fixed before the runs
Z_PAIR = 3.0
PAPER_SEED = 0


def reproduce(out: Path, *, runs: int, motion: str = "prescribed", duration: float | None = None,
              workers: int | None = None, estimators: tuple = ()) -> dict:
    """Both modes into out/paper and out/uwb, gathered in out/ (see the module docstring); returns
    {"paper": paper/claims.json, "uwb": uwb/claims.json, "claims": claims.json's claims}.
    estimators: plugin EstimatorSpecs scored in every uwb-mode run, one more row each in table.md
    (testbed.reproduce.plugins; paper mode has no physics run to give them)."""
    out = Path(out)
    readings = paper_mode.compute(runs, PAPER_SEED)
    paper_claims = paper_mode.decide(readings)
    paper = paper_mode.write(out / "paper", readings, paper_claims, runs=runs, seed=PAPER_SEED)
    uwb_res = compute_uwb(out / "uwb", runs=min(runs, UWB_MAX_RUNS), motion=motion,
                          duration=HORIZON_S if duration is None else duration, workers=workers, estimators=estimators)
    uwb_claims = decide_uwb(uwb_res)
    uwb = write_uwb(out / "uwb", uwb_res, uwb_claims)
    claims = paper_claims + uwb_claims
    doc = write_claims(out / "claims.json", claims, paper="000", runs_paper_mode=runs, seed_paper_mode=PAPER_SEED,
                       runs_uwb_mode=uwb_res["context"]["runs"], seeds_uwb_mode=uwb_res["context"]["seeds"],
                       motion=motion)
    (out / "plots").mkdir(exist_ok=True)
    for mode in ("paper", "uwb"):
        for f in sorted((out / mode / "plots").glob("*.png")):
            shutil.copy(f, out / "plots" / f"{mode}_{f.name}")
    for f in sorted((out / "uwb" / "runs" / run_name(0) / "plots").glob("*.png")):  # error with +-3 sqrt(diag M)
        shutil.copy(f, out / "plots" / f"uwb_run0_{f.name}")
    md = ["# Seed 000 reproduction: both measurement modes", "",
          "Paper mode (synthetic measurements, the paper's setup): `paper/`. UWB mode (the `bandwidth` "
          "scenario's physics-based UWB ranges): `uwb/`.", ""]
    md += _demote(paper_mode.markdown(readings, paper_claims, runs=runs, seed=PAPER_SEED)) + [""]
    md += _demote(_uwb_markdown(uwb_res, uwb_claims))
    keys = [e.key for e in estimators]
    groups = {"uwb mode": [m["estimators"] for m in load_metrics(
        [out / "uwb" / "runs" / run_name(i) for i in range(uwb_res["context"]["runs"])])]} if keys else {}
    md += _demote(plugin_rows.markdown(groups, keys, "mode"))
    plugin_rows.write(out / "table_plugins.csv", groups, keys)
    write_markdown(out / "table.md", md)
    rows = ([dict(mode="paper", **r) for r in paper_mode.rows(readings)]
            + [dict(mode="uwb", **r) for r in _uwb_rows(uwb_res)])
    keys = list(dict.fromkeys(k for r in rows for k in r))
    write_csv(out / "table.csv", keys, [[r.get(k) for k in keys] for r in rows])
    return {"paper": paper, "uwb": uwb, "claims": doc["claims"]}


def _demote(lines: list[str]) -> list[str]:
    """Markdown headings one level down (a mode's report inside the gathered one)."""
    return ["#" + ln if ln.startswith("#") else ln for ln in lines]


# ------------------------------------------------------------------------------------ uwb mode


def _load_runs(scenario, run_dirs: list[Path]) -> dict:
    metas = []
    for seed, d in zip(seeds(scenario.seed, len(run_dirs)), run_dirs):
        sc = dataclasses.replace(scenario, seed=seed)  # the seed the sweep gave this run
        metas.append(pb.measurements(sc, load_log(d / "log.npz")))
    return pb.stack_runs(metas)


def _case(scenario, meas: dict, S: np.ndarray, P: np.ndarray) -> dict:
    """Filter every run for one (T, P); per-run and per-step numbers."""
    est = pb.estimate(scenario, meas=meas, select=S, weights=P)
    e = meas["truth"][:, :, None, :] - est["xhat"]  # eq. 10, (R, K+1, N, 3)
    d = (e ** 2).sum(-1)  # (R, K+1, N)
    trM = np.trace(est["M"], axis1=-2, axis2=-1)  # (R, K+1, N)
    R = d.shape[0]
    per_run_J = d.sum(axis=(1, 2))  # eq. 12 realised per run
    per_run_Jb = trM.sum(axis=(1, 2))  # eq. 16 per run (V differs per run)
    # bound per node and step: E|e_i(k)|^2 <= E tr M_i(k), paired over runs, Bonferroni 1 %
    diff = d - trM
    se = diff.std(0, ddof=1) / np.sqrt(R)
    z = float(norm.ppf(1 - 0.01 / diff[0].size))
    excess = diff.mean(0) / np.maximum(se, 1e-300)
    return dict(
        per_run_J=per_run_J, J_emp=float(per_run_J.mean()), J_emp_se=float(per_run_J.std(ddof=1) / np.sqrt(R)),
        J_bound=float(per_run_Jb.mean()), J_bound_min=float(per_run_Jb.min()), J_bound_max=float(per_run_Jb.max()),
        cum_emp=np.cumsum(d.mean(0).sum(-1)), cum_bound=np.cumsum(trM.mean(0).sum(-1)),
        tr_emp=d.mean(0), tr_M=trM.mean(0),
        rms_node_m=np.sqrt(d[:, 1:].mean(axis=(0, 1))).tolist(),
        bias_final_m=e[:, -1].mean(0), bias_final_se_m=e[:, -1].std(0, ddof=1) / np.sqrt(R),
        bound_violations=int((excess > z).sum()), bound_tests=int(excess.size), z_bonf=z,
        worst_excess_sigma=float(excess.max()), bound_holds_node_step=(excess <= z),
        bytes_per_step_received=(est["comm"].bytes.mean(0).sum(0)).tolist(),
        within_budget=est["comm"].within_budget(),
        truth0=meas["truth"][0], xhat0=est["xhat"][0], t=meas["t"],
    )


def compute_uwb(out: Path, *, runs: int, motion: str, duration: float, workers: int | None, estimators: tuple = ()) -> dict:
    """Sweep the `bandwidth` scenario (out/runs/run-XXX) and filter every run for each case.
    Returns {"res": {case: _case(...)}, "context": JSON-able description of the runs, "plugins":
    {name: _plugin_case(...)} of the plugin estimators whose outputs fit}.
    estimators: plugin EstimatorSpecs scored in every run too (in its metrics.json)."""
    scenario = scenario_mod.load("bandwidth", motion=motion, duration=duration)
    cfg = scenario.pipeline
    run_dirs = sweep_runs(dataclasses.replace(scenario, estimators=tuple(estimators)), runs, Path(out) / "runs", workers=workers or 2)
    meas = _load_runs(scenario, run_dirs)
    K = meas["K"]
    # bound-optimal selection for P1 over the horizon (design-time V: run 0, first full epoch)
    av0 = meas["available"][0].all(-1)
    k0 = int(np.argmax(av0))
    W = np.diag(cfg.process_noise) * (cfg.dt if cfg.w_reading == "rate" else 1.0)
    model0 = bw.NetworkModel.create(A=np.eye(3), B=np.asarray(cfg.velocity) * cfg.dt, C=np.eye(3), W=W,
                                    V=list(meas["V"][0, k0]), N=4)
    search = bw.search_selection(model0, P_SETS["P1"], np.diag(cfg.M0), K, [cfg.budget] * 4, objective="bound")
    cases = {"T1+P1": (T_SETS["T1"], P_SETS["P1"]), "T2+P1": (T_SETS["T2"], P_SETS["P1"]),
             "T3+P1": (T_SETS["T3"], P_SETS["P1"]), "Tbest_bound+P1": (search.best, P_SETS["P1"]),
             "T1+P2": (T_SETS["T1"], P_SETS["P2"]), "T1+P3": (T_SETS["T1"], P_SETS["P3"])}
    res = {k: _case(scenario, meas, S, P) for k, (S, P) in cases.items()}
    # each plugin whose outputs fit beside the cases, from its runs' estimates (the others: reproduce's plugin section)
    plugins = {e.key: p for e in estimators if (p := _plugin_case(scenario, run_dirs, e.key, meas["t"]))}
    avail = meas["available"]
    trV = np.trace(meas["V"], axis1=-2, axis2=-1)
    raw_rms_node = np.sqrt(np.nanmean(np.where(avail, trV, np.nan)[:, :-1], axis=(0, 1)))  # (N,) m
    ctx = dict(runs=runs, seeds=seeds(scenario.seed, runs), motion=motion, duration_s=duration,
               dt_s=cfg.dt, steps=K, measurement_epochs_missing=int((~avail).sum()),
               raw_pseudo_measurement_rms_m=raw_rms_node.tolist(), search_count=search.count,
               best_T_by_bound=_fmt_T(search.best), best_T_by_bound_Jbound_design=search.best_J)
    return {"res": res, "context": ctx, "plugins": plugins}


def _plugin_case(scenario, run_dirs: list[Path], key: str, t: np.ndarray) -> dict:
    """A plugin's numbers beside the cases', when every run has its estimates of every node's tag
    position with a covariance at each epoch t (K+1,) s (else {}; its other scores are in the
    "Plugin estimators" section): per_run_J (runs,) the realised eq. 12, the sum over nodes and
    epochs of |e_i(k)|^2 (the tags' true positions, testbed.plugins.truth: the fusion bound hook's
    J_empirical), J_emp and J_emp_se its mean and standard error over the runs, J_bound the mean
    over runs of the sum of tr M_i(k) of its own covariances (eq. 16's sum), rms_node_m (N,) the
    RMS over runs and epochs k >= 1 of each node's error, and for figs. 3-4 cum_emp, cum_bound
    (K+1,) the cumulative mean over runs of both sums per epoch (as _case's)."""
    physics = build(scenario)
    targets = [f"uav{i + 1}/uwb" for i in range(scenario.vehicles)]
    se, tr = [], []
    for d in run_dirs:
        track = load_tracks(d / ESTIMATES_FILE).get(key, {}) if (d / ESTIMATES_FILE).is_file() else {}
        series = [track.get((tg, "position")) for tg in targets]
        if any(x is None or x.frame != "world" or x.time.shape != t.shape or not np.allclose(x.time, t, rtol=0, atol=1e-9)
               or not x.has_cov.all() for x in series):
            return {}
        truth = Truth(load_log(d / "log.npz"), make_context(scenario, lever_arms(physics), "truth", {}))
        e = np.stack([errors(truth, tg, "position", x.time, x.value) for tg, x in zip(targets, series)], 1)  # (K+1, N, 3)
        se.append((e ** 2).sum(-1))
        tr.append(np.stack([np.trace(x.cov, axis1=-2, axis2=-1) for x in series], 1))
    d, trM = np.array(se), np.array(tr)  # (R, K+1, N)
    J = d.sum(axis=(1, 2))
    return dict(per_run_J=J, J_emp=float(J.mean()), J_emp_se=float(J.std(ddof=1) / np.sqrt(J.size)) if J.size > 1 else np.nan,
                J_bound=float(trM.sum(axis=(1, 2)).mean()), rms_node_m=np.sqrt(d[:, 1:].mean(axis=(0, 1))).tolist(),
                cum_emp=np.cumsum(d.mean(0).sum(-1)), cum_bound=np.cumsum(trM.mean(0).sum(-1)))


def _plugin_tests(uwb: dict) -> list[dict]:
    """Each plugin against each case: the paired t test of the per-run J (eq. 12) over the runs
    where the plugin has it (the claims' test, testbed.scoring.stats.paired_t, two-sided), the
    means and the improvement factor J_case / J_plugin (> 1: the plugin is better)."""
    rows = []
    for k, p in uwb.get("plugins", {}).items():
        for c, r in uwb["res"].items():
            a, b = p["per_run_J"], r["per_run_J"]
            t = paired_t(a, b, alternative="two-sided") if a.size > 1 else None
            rows.append({"estimator": k, "against": c, "runs": int(a.size), "J_estimator": float(a.mean()),
                         "J_against": float(b.mean()), "factor": float(b.mean() / a.mean()),
                         "t": t.statistic if t else None, "p_two_sided": t.p_value if t else None})
    return rows


def decide_uwb(uwb: dict) -> list[Claim]:
    """The paper's claims on the uwb-mode Monte Carlo."""
    res, ctx = uwb["res"], uwb["context"]
    cx = {"mode": "uwb"}
    out = []
    c = res["T1+P1"]
    raw = np.array(ctx["raw_pseudo_measurement_rms_m"])
    bz = np.abs(c["bias_final_m"]) / c["bias_final_se_m"]
    z_bias = float(norm.ppf(1 - 0.01 / (2 * bz.size)))
    out.append(Claim(id="track", context=cx, text="the fused estimates track the truth (T1, P1)",
                     holds=bool(np.all(np.array(c["rms_node_m"]) < raw) and bz.max() < z_bias),
                     criterion="every node's RMS error over runs and steps k >= 1 < the RMS of its raw pseudo-"
                               "measurement sqrt(mean tr V_i) (no process noise in the truth: the naive predictor "
                               f"y_i + B has exactly that error), and final-step mean error within z = {z_bias:.2f} "
                               "standard errors of 0 (Bonferroni 1 % over nodes and axes)",
                     numbers=dict(rms_err_per_node_m=c["rms_node_m"], raw_pseudo_measurement_rms_m=raw.tolist(),
                                  max_bias_z=float(bz.max()), final_mean_error_m=c["bias_final_m"].tolist(),
                                  runs=ctx["runs"]),
                     summary=f"node RMS {fmt_list(c['rms_node_m'])} m vs raw {fmt_list(raw)} m",
                     paper_value="tracks (fig. 2)", test="z test of the final mean error per node and axis, "
                     "Bonferroni 1 %, and RMS comparison", statistic=float(bz.max()), n=ctx["runs"], level=0.99))
    tp = {f"J({a})-J({b})": paired_t(res[f"{a}+P1"]["per_run_J"], res[f"{b}+P1"]["per_run_J"], alternative="two-sided")
          for a, b in (("T1", "T2"), ("T1", "T3"), ("T2", "T3"))}
    pairs = {k: v.to_json() for k, v in tp.items()}
    for v in pairs.values():
        v["t"] = v["statistic"]
    top = max(tp.values(), key=lambda v: abs(v.statistic) if np.isfinite(v.statistic) else -1.0)
    out.append(Claim(id="T-changes-J", context=cx, text="the selection set T changes J (T1, T2, T3 with P1)",
                     holds=bool(any(abs(v["t"]) > Z_PAIR for v in pairs.values())),
                     criterion=f"some paired Monte Carlo difference of J (eq. 12) exceeds {Z_PAIR} standard errors",
                     numbers=dict(J_emp={t: res[f"{t}+P1"]["J_emp"] for t in T_SETS},
                                  J_bound_mean={t: res[f"{t}+P1"]["J_bound"] for t in T_SETS}, paired=pairs),
                     summary="t " + ", ".join(f"{k} {fmt(v['t'])}" for k, v in pairs.items()),
                     paper_value="T changes J", **{**top.claim_fields(), "test": f"3 x {top.test}; the largest |t| shown"}))
    t12 = paired_t(res["T1+P1"]["per_run_J"], res["T1+P2"]["per_run_J"], alternative="less")
    t23 = paired_t(res["T1+P2"]["per_run_J"], res["T1+P3"]["per_run_J"], alternative="less")
    p12, p23 = {**t12.to_json(), "t": t12.statistic}, {**t23.to_json(), "t": t23.statistic}
    weak = max((t12, t23), key=lambda v: v.statistic if np.isfinite(v.statistic) else np.inf)
    out.append(Claim(id="P-order-J", context=cx, text="P1 gives lower J than P2, P2 lower than P3 (T1), J of eq. 12",
                     holds=bool(p12["t"] < -Z_PAIR and p23["t"] < -Z_PAIR),
                     criterion=f"paired t of J(P1)-J(P2) and J(P2)-J(P3) both below -{Z_PAIR}",
                     numbers=dict(J_emp={p: res[f"T1+{p}"]["J_emp"] for p in P_SETS},
                                  paired={"J(P1)-J(P2)": p12, "J(P2)-J(P3)": p23}),
                     summary=f"t {fmt(p12['t'])}, {fmt(p23['t'])}", paper_value="P1 < P2 < P3",
                     **{**weak.claim_fields(), "test": f"2 x {weak.test}; the weaker shown"}))
    Jb = {p: res[f"T1+{p}"]["J_bound"] for p in P_SETS}
    out.append(Claim(id="P-order-bound", context=cx,
                     text="P1 gives lower J than P2, P2 lower than P3 (T1), bound J of eq. 16",
                     holds=bool(Jb["P1"] < Jb["P2"] < Jb["P3"]), criterion="J_bar (mean over runs) ordering",
                     numbers=dict(J_bound_mean=Jb), summary=f"J_bar {fmt_list(Jb.values())}", paper_value="P1 < P2 < P3",
                     test="comparison of the bound's means over the runs (the bound is computed, not estimated)",
                     n=ctx["runs"]))
    viol = sum(v["bound_violations"] for v in res.values())
    tests = sum(v["bound_tests"] for v in res.values())
    out.append(Claim(id="M-bounds-Sigma", context=cx, text="M_i(k) bounds the true error covariance (per node and step)",
                     holds=bool(viol == 0),
                     criterion="mean over runs of |e_i(k)|^2 - tr M_i(k) <= z * its standard error, z Bonferroni "
                               "1 % over nodes and steps, per case (M_i(k) varies with the run's measured V)",
                     numbers=dict(violations=viol, tests=tests,
                                  worst_excess_sigma={k: v["worst_excess_sigma"] for k, v in res.items()},
                                  bound_over_emp={k: v["J_bound"] / v["J_emp"] for k, v in res.items()}),
                     summary=f"{viol}/{tests} violations", paper_value="M bounds Sigma",
                     test="one-sided paired z tests per node and step, Bonferroni 1 %; the largest excess shown",
                     statistic=max(v["worst_excess_sigma"] for v in res.values()), n=ctx["runs"], level=0.99))
    tbest = paired_t(res["Tbest_bound+P1"]["per_run_J"],
                     res[min(T_SETS, key=lambda t: res[f"{t}+P1"]["J_emp"]) + "+P1"]["per_run_J"], alternative="less")
    pbest = {**tbest.to_json(), "t": tbest.statistic}
    out.append(Claim(id="search-beats-T1-T3", context=cx,
                     text="searching T for the lowest bound gives a more accurate estimator than T1-T3",
                     holds=bool(pbest["t"] < -Z_PAIR),
                     criterion=f"paired t of J(best by bound) - J(best of T1-T3) below -{Z_PAIR}",
                     numbers=dict(J_emp={k: v["J_emp"] for k, v in res.items() if k.endswith("P1")},
                                  paired_vs_best_paper_set=pbest, admissible_sets=ctx["search_count"],
                                  best_T_by_bound=ctx["best_T_by_bound"]),
                     summary=f"t {fmt(pbest['t'])}", paper_value="search beats T1-T3", **tbest.claim_fields()))
    return out


def _uwb_rows(uwb: dict) -> list[dict]:
    """One row per case, then one per plugin (its bound columns empty: a per-step bound test needs
    the case's per-step errors)."""
    return [dict(case=k, J_emp=r["J_emp"], J_emp_ci95=1.96 * r["J_emp_se"], J_bound_mean=r["J_bound"],
                 bound_over_emp=r["J_bound"] / r["J_emp"], max_node_rms_m=max(r["rms_node_m"]),
                 bound_violations=r.get("bound_violations"), bound_tests=r.get("bound_tests"),
                 bytes_recv_per_node_step=r["bytes_per_step_received"][0] if "bytes_per_step_received" in r else None)
            for k, r in {**uwb["res"], **uwb.get("plugins", {})}.items()]


def _uwb_markdown(uwb: dict, claims: list[Claim]) -> list[str]:
    ctx = uwb["context"]
    lines = [f"# Seed 000 uwb-mode reproduction ({ctx['runs']} seeds of `bandwidth`, {ctx['motion']}, "
             f"{fmt(ctx['duration_s'])} s, dt {fmt(ctx['dt_s'])} s, {ctx['steps']} steps)", "",
             "J_emp: Monte Carlo mean of the realised eq. 12 per run (CI95 half-width); J_bound: eq. 16, mean over "
             "runs (M depends on each run's measured V); bound violations: node-steps where the mean |e|^2 exceeds "
             "the mean tr M by more than the Bonferroni margin.", ""]
    lines += markdown_table(["case", "J_emp", "±CI95", "J_bound", "bound/emp", "max node RMS m", "bound viol. / tests",
                             "bytes recv/node/step"],
                            [[r["case"], r["J_emp"], fmt(r["J_emp_ci95"], 2), r["J_bound_mean"], r["bound_over_emp"],
                              r["max_node_rms_m"],
                              f"{r['bound_violations']} / {r['bound_tests']}" if r["bound_tests"] is not None else "",
                              r["bytes_recv_per_node_step"] if r["bytes_recv_per_node_step"] is not None else ""]
                             for r in _uwb_rows(uwb)])
    if tests := _plugin_tests(uwb):
        lines += ["", "Plugin estimators (--estimator) with every tag's position and covariance at the K + 1 epochs of "
                      "every run, against every case, paired over the same seeds: J (eq. 12) of the plugin's estimates, "
                      "factor = J of the case / J of the plugin (> 1: the plugin is better), two-sided paired t test of "
                      "the per-run J.", ""]
        lines += markdown_table(["estimator", "against", "runs", "J estimator", "J case", "factor", "t", "p (two-sided)"],
                                [[r["estimator"], r["against"], r["runs"], r["J_estimator"], r["J_against"],
                                  fmt(r["factor"]), fmt(r["t"]), fmt(r["p_two_sided"])] for r in tests])
    lines += ["", f"- raw pseudo-measurement RMS per node (sqrt mean tr V): "
                  f"{fmt_list(ctx['raw_pseudo_measurement_rms_m'])} m; missing node-epochs: "
                  f"{ctx['measurement_epochs_missing']}",
              f"- best by bound (design V of run 0, {ctx['search_count']} sets enumerated): {ctx['best_T_by_bound']}",
              ""]
    return lines + claims_section(claims)


def _metrics(out: Path, c: dict, ctx: dict) -> None:
    """metrics_mc.json: the estimators.bandwidth scores of T1+P1 over the Monte Carlo."""
    node_ok = c["bound_holds_node_step"]  # (K+1, N)
    m = {"scenario": "bandwidth", "seeds": ctx["seeds"], "motion": ctx["motion"], "estimators": {"bandwidth": {
        "J_empirical": c["J_emp"], "J_empirical_ci95": 1.96 * c["J_emp_se"], "J_bound": c["J_bound"],
        "rmse_position_per_vehicle_m": c["rms_node_m"],
        "bound_holds": bool(node_ok.all()),
        "bound_holds_per_node": [bool(v) for v in node_ok.all(0)],
        "bound_holds_fraction_of_steps_per_node": [float(v) for v in node_ok.mean(0)],
        "bytes_per_step_received": c["bytes_per_step_received"], "within_budget": c["within_budget"]}}}
    write_json(out / "metrics_mc.json", m)


def _plots(pdir: Path, res: dict, ctx: dict, plugins: dict | None = None) -> None:
    """plots/: fig2 (T1 P1, run 0), figs. 3-4 (cumulative J and bound of the cases and of every
    plugin with every tag at every epoch), J_by_case (every case and plugin: J with its 95 %
    interval), bound_vs_cov (T1 P1)."""
    plugins = plugins or {}
    c = res["T1+P1"]
    t = c["t"]
    bplots.tracking(pdir / "fig2_tracking.png", t, c["truth0"], c["xhat0"],
                    "Fig. 2 analogue, uwb mode, T1 P1 (run 0 of the sweep)")
    for name, keys in (("fig3_J_vs_T", ["T1+P1", "T2+P1", "T3+P1", "Tbest_bound+P1"]),
                       ("fig4_J_vs_P", ["T1+P1", "T1+P2", "T1+P3"])):
        bplots.cumulative_J(pdir / f"{name}.png", t, {**res, **plugins}, keys + list(plugins),
                            emp_title=f"J(k), eq. 12, Monte Carlo over {ctx['runs']} seeds",
                            bound_title="bound J_bar(k), eq. 16 (mean over seeds)")
    every = {**res, **plugins}  # the cases, then each plugin (--estimator)
    names = list(every)
    m = np.array([every[k]["J_emp"] for k in names])
    h = 1.96 * np.array([every[k]["J_emp_se"] for k in names])
    compare_bars(names, m, m - h, m + h, pdir / "J_by_case.png", title="J (eq. 12), uwb mode, 95 % CI",
                 ylabel="J [m^2]")
    bplots.bound_vs_cov(pdir / "bound_vs_cov.png", t, [("mean tr M_i", "-", c["tr_M"]), ("mean |e_i|^2", ":", c["tr_emp"])],
                        "bound vs empirical error, uwb mode, T1 P1")


def write_uwb(out: Path, uwb: dict, claims: list[Claim]) -> dict:
    """uwb/: table.md, table.csv, claims.json, metrics_mc.json, plots/; returns claims.json's content."""
    out = Path(out)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    rows = _uwb_rows(uwb)
    write_csv(out / "table.csv", list(rows[0]), [list(r.values()) for r in rows])
    write_markdown(out / "table.md", _uwb_markdown(uwb, claims))
    _metrics(out, uwb["res"]["T1+P1"], uwb["context"])
    _plots(out / "plots", uwb["res"], uwb["context"], uwb.get("plugins"))
    if tests := _plugin_tests(uwb):
        write_csv(out / "table_plugins_paired_J.csv", list(tests[0]), [list(r.values()) for r in tests])
    return write_claims(out / "claims.json", claims, paper="000", mode="uwb", **uwb["context"])
