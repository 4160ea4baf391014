"""`testbed reproduce bandwidth --out DIR [--runs N]`: seed 000 in both measurement modes.

DIR/paper/: the paper mode (testbed/reproduce/bandwidth_paper.py: synthetic y = C x + v with the
paper's A, W, V, x(0), M(0); readings (a) W per step, dt = 1 s and (b) W as a rate, dt = 0.1 s;
horizon 50 s; `runs` Monte Carlo runs, default 500).

DIR/uwb/: the uwb mode. `min(runs, UWB_MAX_RUNS)` seeds (default 100) of the `bandwidth` scenario
are simulated through testbed.sweep (DIR/uwb/sweep/run-XXX, full run directories, seeds
scenario.seed + i) over `duration` (default 50 s, the paper mode's horizon), in `motion` mode.
Every run's log then goes through the pipeline's measurement step once (UWB ranges -> eqs. 21-23
pseudo-measurements with V from the range noise) and through the estimator for each case:
T1, T2, T3 and the bound-optimal selection (exhaustive search over the 2430 admissible sets,
P1, V of run 0's first epoch) with P1, and T1 with P2, P3. All cases see the same logs (common
random numbers), so cases are compared on paired per-run differences. The prescribed truth has
no process noise: W (the paper's, read as a rate) is the estimator's model, not the truth's.

DIR/table.md, table.csv, claims.json, plots/ gather both modes (claims carry "mode").
"""
from __future__ import annotations

import csv
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
from scipy.stats import norm

from testbed.reproduce.bandwidth_paper import P_SETS, T_SETS, _fmt_T, reproduce_paper

UWB_MAX_RUNS = 100
HORIZON_S = 50.0
Z_PAIR = 3.0  # z for "significantly different" on paired per-run differences


def reproduce(out: Path, *, runs: int, motion: str = "prescribed", duration: float | None = None,
              workers: int | None = None) -> dict:
    out = Path(out)
    paper = reproduce_paper(out / "paper", runs=runs, seed=0)
    uwb = reproduce_uwb(out / "uwb", runs=min(runs, UWB_MAX_RUNS), motion=motion,
                        duration=HORIZON_S if duration is None else duration, workers=workers)
    claims = [dict(mode="paper", **c) for c in paper["claims"]] + [dict(mode="uwb", **c) for c in uwb["claims"]]
    (out / "claims.json").write_text(json.dumps(claims, indent=2))
    (out / "plots").mkdir(exist_ok=True)
    for mode in ("paper", "uwb"):
        for f in sorted((out / mode / "plots").glob("*.png")):
            shutil.copy(f, out / "plots" / f"{mode}_{f.name}")
    md = ["# Seed 000 reproduction: both measurement modes", "",
          "Paper mode (synthetic measurements, the paper's setup): `paper/`. UWB mode (the `bandwidth` "
          "scenario's physics-based UWB ranges): `uwb/`.", "",
          (out / "paper" / "table.md").read_text().replace("\n# ", "\n## ").replace("# ", "## ", 1), "",
          (out / "uwb" / "table.md").read_text().replace("\n# ", "\n## ").replace("# ", "## ", 1)]
    (out / "table.md").write_text("\n".join(md))
    rows = []
    for mode in ("paper", "uwb"):
        with open(out / mode / "table.csv") as f:
            rows += [dict(mode=mode, **r) for r in csv.DictReader(f)]
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(out / "table.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    return {"paper": paper, "uwb": uwb, "claims": claims}


# ------------------------------------------------------------------------------------ uwb mode


def _load_runs(scenario, sweep_dir: Path, runs: int) -> dict:
    from testbed.log import load_log
    from testbed.pipelines import bandwidth as pb

    metas = []
    for i in range(runs):
        sc = dataclasses.replace(scenario, seed=scenario.seed + i)  # the seed the sweep gave run i
        metas.append(pb.measurements(sc, load_log(sweep_dir / f"run-{i:03d}" / "log.npz")))
    return pb.stack_runs(metas)


def _case(scenario, meas: dict, S: np.ndarray, P: np.ndarray) -> dict:
    """Filter every run for one (T, P); per-run and per-step numbers."""
    from testbed.pipelines import bandwidth as pb

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


def reproduce_uwb(out: Path, *, runs: int, motion: str, duration: float, workers: int | None) -> dict:
    from estimators import bandwidth as bw
    from testbed import scenario as scenario_mod
    from testbed.metrics import paired_test
    from testbed.sweep import sweep

    out = Path(out)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    scenario = scenario_mod.load("bandwidth", motion=motion, duration=duration)
    cfg = scenario.pipeline
    sweep(scenario, runs, out / "sweep", workers=workers or 2, force=True, progress=False)
    meas = _load_runs(scenario, out / "sweep", runs)
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
    avail = meas["available"]
    trV = np.trace(meas["V"], axis1=-2, axis2=-1)
    raw_rms_node = np.sqrt(np.nanmean(np.where(avail, trV, np.nan)[:, :-1], axis=(0, 1)))  # (N,) m
    ctx = dict(runs=runs, seeds=[scenario.seed + i for i in range(runs)], motion=motion, duration_s=duration,
               dt_s=cfg.dt, steps=K, measurement_epochs_missing=int((~avail).sum()),
               raw_pseudo_measurement_rms_m=raw_rms_node.tolist(), search_count=search.count,
               best_T_by_bound=_fmt_T(search.best), best_T_by_bound_Jbound_design=search.best_J)
    claims = _claims(res, ctx, paired_test)
    rows = [dict(case=k, J_emp=r["J_emp"], J_emp_ci95=1.96 * r["J_emp_se"], J_bound_mean=r["J_bound"],
                 bound_over_emp=r["J_bound"] / r["J_emp"], max_node_rms_m=max(r["rms_node_m"]),
                 bound_violations=r["bound_violations"], bound_tests=r["bound_tests"],
                 bytes_recv_per_node_step=r["bytes_per_step_received"][0]) for k, r in res.items()]
    _write(out, rows, ctx, claims)
    _metrics(out, res["T1+P1"], ctx)
    _plots(out / "plots", res, ctx)
    return {"context": ctx, "claims": claims}


def _claims(res: dict, ctx: dict, paired_test) -> list[dict]:
    out = []
    c = res["T1+P1"]
    raw = np.array(ctx["raw_pseudo_measurement_rms_m"])
    bz = np.abs(c["bias_final_m"]) / c["bias_final_se_m"]
    z_bias = float(norm.ppf(1 - 0.01 / (2 * bz.size)))
    holds = bool(np.all(np.array(c["rms_node_m"]) < raw) and bz.max() < z_bias)
    out.append(dict(claim="the fused estimates track the truth (T1, P1)", holds=holds,
                    criterion="every node's RMS error over runs and steps k >= 1 < the RMS of its raw pseudo-"
                              "measurement sqrt(mean tr V_i) (no process noise in the truth: the naive predictor "
                              f"y_i + B has exactly that error), and final-step mean error within z = {z_bias:.2f} "
                              "standard errors of 0 (Bonferroni 1 % over nodes and axes)",
                    numbers=dict(rms_err_per_node_m=c["rms_node_m"], raw_pseudo_measurement_rms_m=raw.tolist(),
                                 max_bias_z=float(bz.max()), final_mean_error_m=c["bias_final_m"].tolist(),
                                 runs=ctx["runs"])))
    pairs = {f"J({a})-J({b})": paired_test(res[f"{a}+P1"]["per_run_J"], res[f"{b}+P1"]["per_run_J"])
             for a, b in (("T1", "T2"), ("T1", "T3"), ("T2", "T3"))}
    holds = any(abs(v["t"]) > Z_PAIR for v in pairs.values())
    out.append(dict(claim="the selection set T changes J (T1, T2, T3 with P1)", holds=bool(holds),
                    criterion=f"some paired Monte Carlo difference of J (eq. 12) exceeds {Z_PAIR} standard errors",
                    numbers=dict(J_emp={t: res[f"{t}+P1"]["J_emp"] for t in T_SETS},
                                 J_bound_mean={t: res[f"{t}+P1"]["J_bound"] for t in T_SETS}, paired=pairs)))
    p12 = paired_test(res["T1+P1"]["per_run_J"], res["T1+P2"]["per_run_J"])
    p23 = paired_test(res["T1+P2"]["per_run_J"], res["T1+P3"]["per_run_J"])
    holds = bool(p12["t"] < -Z_PAIR and p23["t"] < -Z_PAIR)
    out.append(dict(claim="P1 gives lower J than P2, P2 lower than P3 (T1), J of eq. 12", holds=holds,
                    criterion=f"paired t of J(P1)-J(P2) and J(P2)-J(P3) both below -{Z_PAIR}",
                    numbers=dict(J_emp={p: res[f"T1+{p}"]["J_emp"] for p in P_SETS},
                                 paired={"J(P1)-J(P2)": p12, "J(P2)-J(P3)": p23})))
    Jb = {p: res[f"T1+{p}"]["J_bound"] for p in P_SETS}
    out.append(dict(claim="P1 gives lower J than P2, P2 lower than P3 (T1), bound J of eq. 16",
                    holds=bool(Jb["P1"] < Jb["P2"] < Jb["P3"]), criterion="J_bar (mean over runs) ordering",
                    numbers=dict(J_bound_mean=Jb)))
    viol = sum(v["bound_violations"] for v in res.values())
    tests = sum(v["bound_tests"] for v in res.values())
    out.append(dict(claim="M_i(k) bounds the true error covariance (per node and step)", holds=bool(viol == 0),
                    criterion="mean over runs of |e_i(k)|^2 - tr M_i(k) <= z * its standard error, z Bonferroni "
                              "1 % over nodes and steps, per case (M_i(k) varies with the run's measured V)",
                    numbers=dict(violations=viol, tests=tests,
                                 worst_excess_sigma={k: v["worst_excess_sigma"] for k, v in res.items()},
                                 bound_over_emp={k: v["J_bound"] / v["J_emp"] for k, v in res.items()})))
    pb = paired_test(res["Tbest_bound+P1"]["per_run_J"],
                     res[min(T_SETS, key=lambda t: res[f"{t}+P1"]["J_emp"]) + "+P1"]["per_run_J"])
    out.append(dict(claim="searching T for the lowest bound gives a more accurate estimator than T1-T3",
                    holds=bool(pb["t"] < -Z_PAIR),
                    criterion=f"paired t of J(best by bound) - J(best of T1-T3) below -{Z_PAIR}",
                    numbers=dict(J_emp={k: v["J_emp"] for k, v in res.items() if k.endswith("P1")},
                                 paired_vs_best_paper_set=pb, admissible_sets=ctx["search_count"],
                                 best_T_by_bound=ctx["best_T_by_bound"])))
    return out


def _write(out: Path, rows: list[dict], ctx: dict, claims: list[dict]) -> None:
    with open(out / "table.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    lines = [f"# Seed 000 uwb-mode reproduction ({ctx['runs']} seeds of `bandwidth`, {ctx['motion']}, "
             f"{ctx['duration_s']:g} s, dt {ctx['dt_s']:g} s, {ctx['steps']} steps)", "",
             "J_emp: Monte Carlo mean of the realised eq. 12 per run (CI95 half-width); J_bound: eq. 16, mean over "
             "runs (M depends on each run's measured V); bound violations: node-steps where the mean |e|^2 exceeds "
             "the mean tr M by more than the Bonferroni margin.", "",
             "| case | J_emp | ±CI95 | J_bound | bound/emp | max node RMS m | bound viol. / tests | bytes recv/node/step |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['J_emp']:.4g} | {r['J_emp_ci95']:.2g} | {r['J_bound_mean']:.4g} | "
                     f"{r['bound_over_emp']:.3g} | {r['max_node_rms_m']:.3f} | {r['bound_violations']} / "
                     f"{r['bound_tests']} | {r['bytes_recv_per_node_step']:g} |")
    lines += ["", f"- raw pseudo-measurement RMS per node (sqrt mean tr V): "
                  f"{', '.join(f'{v:.3f}' for v in ctx['raw_pseudo_measurement_rms_m'])} m; missing node-epochs: "
                  f"{ctx['measurement_epochs_missing']}",
              f"- best by bound (design V of run 0, {ctx['search_count']} sets enumerated): {ctx['best_T_by_bound']}",
              "", "## Claims", ""]
    for c in claims:
        lines.append(f"- {c['claim']}: **{'holds' if c['holds'] else 'does not hold'}**")
    (out / "table.md").write_text("\n".join(lines) + "\n")
    (out / "claims.json").write_text(json.dumps(claims, indent=2))


def _metrics(out: Path, c: dict, ctx: dict) -> None:
    """metrics_mc.json: the estimators.bandwidth scores of T1+P1 over the Monte Carlo."""
    node_ok = c["bound_holds_node_step"]  # (K+1, N)
    m = {"scenario": "bandwidth", "seeds": ctx["seeds"], "motion": ctx["motion"], "estimators": {"bandwidth": {
        "J_empirical": c["J_emp"], "J_empirical_ci95": 1.96 * c["J_emp_se"], "J_bound": c["J_bound"],
        "rmse_position_m": c["rms_node_m"],
        "bound_holds": bool(node_ok.all()),
        "bound_holds_per_node": [bool(v) for v in node_ok.all(0)],
        "bound_holds_fraction_of_steps_per_node": [float(v) for v in node_ok.mean(0)],
        "bytes_per_step_received": c["bytes_per_step_received"], "within_budget": c["within_budget"]}}}
    (out / "metrics_mc.json").write_text(json.dumps(m, indent=2))


def _plots(pdir: Path, res: dict, ctx: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from testbed.plots import compare_bars

    c = res["T1+P1"]
    t = c["t"]
    fig, axs = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    for a, ax in enumerate(axs):
        ax.plot(t, c["truth0"][:, a], "k-", lw=2, label="truth")
        for i in range(4):
            ax.plot(t, c["xhat0"][:, i, a], lw=0.8, label=f"UAV {i + 1}")
        ax.set_ylabel(f"{'xyz'[a]} [m]")
    axs[0].legend(ncol=5, fontsize=7)
    axs[-1].set_xlabel("t [s]")
    fig.suptitle("Fig. 2 analogue, uwb mode, T1 P1 (seed 0 of the sweep)")
    fig.tight_layout()
    fig.savefig(pdir / "fig2_tracking.png", dpi=110)
    plt.close(fig)
    for name, keys in (("fig3_J_vs_T", ["T1+P1", "T2+P1", "T3+P1", "Tbest_bound+P1"]),
                       ("fig4_J_vs_P", ["T1+P1", "T1+P2", "T1+P3"])):
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
        for k in keys:
            a1.plot(t, res[k]["cum_emp"], label=k)
            a2.semilogy(t, res[k]["cum_bound"], label=k)
        a1.set_title(f"J(k), eq. 12, Monte Carlo over {ctx['runs']} seeds")
        a2.set_title("bound J_bar(k), eq. 16 (mean over seeds)")
        for ax in (a1, a2):
            ax.set_xlabel("t [s]")
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(pdir / f"{name}.png", dpi=110)
        plt.close(fig)
    names = list(res)
    m = np.array([res[k]["J_emp"] for k in names])
    h = 1.96 * np.array([res[k]["J_emp_se"] for k in names])
    compare_bars(names, m, m - h, m + h, pdir / "J_by_case.png", title="J (eq. 12), uwb mode, 95 % CI",
                 ylabel="J [m^2]")
    fig, axs = plt.subplots(1, 4, figsize=(14, 3.5), sharey=True)
    for i, ax in enumerate(axs):
        ax.semilogy(t, c["tr_M"][:, i], label="mean tr M_i")
        ax.semilogy(t, c["tr_emp"][:, i], ":", label="mean |e_i|^2")
        ax.set_title(f"UAV {i + 1}")
        ax.set_xlabel("t [s]")
    axs[0].legend(fontsize=7)
    fig.suptitle("bound vs empirical error, uwb mode, T1 P1")
    fig.tight_layout()
    fig.savefig(pdir / "bound_vs_cov.png", dpi=110)
    plt.close(fig)
