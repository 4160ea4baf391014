"""`testbed reproduce phase`: seed 003 (Pan, Yin, Xu 2023), eight formations, claims decided.

Every scenario `phase-*` runs N Monte Carlo seeds through testbed.sweep (run i: the scenario's seed
+ i, in OUT/runs/<scenario>/run-XXX; testbed.reproduce.runs). The
same seed index gives the same noise draws and initial error in every formation (each stream's
generator depends only on the seed and its name), so formations are compared run by run (paired).

Axes: the table is in the navigation frame N (x forward, y left, z up). The paper's axes
(x forward, Y up, Z right) are X = x, Y = z, Z = -y.

Claim criteria (fixed before any result was looked at):
- "within +/-L m" (cross L = 0.01, V formations L = 0.03): max |error| over the last 100 s, every
  axis, below L in at least 95 % of the runs;
- "converges" (line H100/H600): the same with L = 0.03 m (the paper's V-formation level);
- "accurate" (line H000, paper Z = our y): the same with L = 0.03 m on that axis;
- "diverges" (line H000, paper X and Y = our x and z): on that axis the RMS over runs of the error
  at the end of the run exceeds the RMS at mid-run AND exceeds 0.03 m;
- line H000 velocity "within +/-0.005 m/s": max |velocity error| over the last 100 s, every axis,
  below 0.005 m/s in at least 95 % of the runs;
- "A better than B": paired one-sided t-test (testbed.metrics.paired_test) of the per-run RMSE of
  the position over the last 100 s, p < 0.05; "slightly better": better, with
  mean(A) / mean(B) in [0.5, 1);
- "about equal": mean(A) / mean(B) of the same score in [0.8, 1.25].

Shape (as every reproduction): `compute` (runs -> per-run EKF scores per scenario), `decide`
(numbers -> claims), `write` (files through testbed.report); `reproduce` chains them.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from testbed import scenario as scenario_mod
from testbed.metrics import mean_ci, paired_test
from testbed.plots import compare_bars
from testbed.report import Claim, claims_section, fmt, fmt_list, fmt_pm, markdown_table, write_claims, write_csv, \
    write_markdown
from testbed.reproduce.runs import load_metrics, seeds, sweep_runs

SCENARIOS = ("phase-line-h000", "phase-cross-h000", "phase-vobtuse-h000", "phase-vacute-h000",
             "phase-line-h100", "phase-line-h600", "phase-vobtuse-h100", "phase-vobtuse-h600")
FRACTION = 0.95
CMP_KEY = "rmse_position_last_100s_m"


def _within(runs: list[dict], level: float, axes=(0, 1, 2), key="max_abs_position_error_last_100s_m") -> dict:
    worst = np.array([[r[key][a] for a in axes] for r in runs])
    ok = np.all(worst < level, axis=1)
    return {"level": level, "axes": list(axes), "fraction_of_runs": float(ok.mean()),
            "max_abs_mean": worst.mean(axis=0).tolist(), "max_abs_worst": worst.max(axis=0).tolist(),
            "holds": bool(ok.mean() >= FRACTION)}


def _ratio(a: list[dict], b: list[dict]) -> float:
    return float(np.mean([r[CMP_KEY] for r in a]) / np.mean([r[CMP_KEY] for r in b]))


def _better(a: list[dict], b: list[dict]) -> dict:
    t = paired_test(np.array([r[CMP_KEY] for r in a]), np.array([r[CMP_KEY] for r in b]))
    return {**t, "ratio_of_means": _ratio(a, b), "holds": bool(np.isfinite(t["p_one_sided"]) and t["p_one_sided"] < 0.05)}


def _equal(a: list[dict], b: list[dict]) -> dict:
    r = _ratio(a, b)
    return {"ratio_of_means": r, "range": [0.8, 1.25], "holds": bool(0.8 <= r <= 1.25)}


def _pcrb_axes(runs: list[dict]) -> list[float]:
    return np.mean([r["pcrb_sigma_position_final_m"] for r in runs], axis=0).tolist()



def _within_text(what: str, level: float, unit: str = "m") -> str:
    return (f"max |{what}| over the last 100 s below {level:g} {unit} on every axis named, in at least "
            f"{FRACTION:.0%} of the runs")


def _within_summary(*named: tuple[str, dict], unit: str = "m") -> str:
    return "; ".join(f"{name}{fmt(100 * w['fraction_of_runs'])} % of runs within, worst {fmt_list(w['max_abs_worst'])} "
                     f"{unit}" for name, w in named)


def _equal_claim(claim_id: str, text: str, a: list[dict], b: list[dict]) -> Claim:
    eq = _equal(a, b)
    return Claim(id=claim_id, text=text, numbers=eq, criterion=f"mean({CMP_KEY}) ratio in [0.8, 1.25]",
                 holds=eq["holds"], summary=f"ratio {fmt(eq['ratio_of_means'])}")


def decide(R: dict[str, list[dict]]) -> list[Claim]:
    """The paper's claims (seed 003, docs/papers.md) decided with the module's criteria. R: {scenario: the EKF
    scores of every run}."""
    out = []
    line = R["phase-line-h000"]
    fin = np.array([r["position_error_final_m"] for r in line])
    mid = np.array([r["position_error_mid_m"] for r in line])
    rms_fin, rms_mid = np.sqrt((fin ** 2).mean(0)), np.sqrt((mid ** 2).mean(0))
    div = {ax: bool(rms_fin[i] > rms_mid[i] and rms_fin[i] > 0.03) for ax, i in (("x (paper X)", 0), ("z (paper Y)", 2))}
    acc = _within(line, 0.03, axes=(1,))
    out.append(Claim(id="line-h000-xy-diverge-z-accurate", text="line H000: X and Y errors diverge, Z stays accurate",
                     numbers={"rms_final_error_m": rms_fin.tolist(), "rms_mid_error_m": rms_mid.tolist(),
                              "diverges": div, "z_accurate": acc, "pcrb_sigma_final_m": _pcrb_axes(line)},
                     criterion="x and z (paper X, Y): RMS over runs of the final error above the RMS at mid-run and "
                               "above 0.03 m; y (paper Z): " + _within_text("position error", 0.03),
                     holds=bool(all(div.values()) and acc["holds"]),
                     summary=f"RMS final {fmt_list(rms_fin)} m vs mid {fmt_list(rms_mid)} m; "
                             + _within_summary(("y: ", acc))))
    v = _within(line, 0.005, key="max_abs_velocity_error_last_100s_mps")
    out.append(Claim(id="line-h000-velocity", text="line H000: velocity error within +/-0.005 m/s after it settles",
                     numbers=v, criterion=_within_text("velocity error", 0.005, "m/s"), holds=v["holds"],
                     summary=_within_summary(("", v), unit="m/s")))
    c = _within(R["phase-cross-h000"], 0.01)
    out.append(Claim(id="cross-h000-0.01", text="cross H000: all three position errors within +/-0.01 m",
                     numbers={**c, "pcrb_sigma_final_m": _pcrb_axes(R["phase-cross-h000"])},
                     criterion=_within_text("position error", 0.01), holds=c["holds"],
                     summary=_within_summary(("", c))))
    ob, ac = _within(R["phase-vobtuse-h000"], 0.03), _within(R["phase-vacute-h000"], 0.03)
    out.append(Claim(id="v-h000-0.03", text="obtuse and acute V H000: within +/-0.03 m",
                     numbers={"vobtuse": ob, "vacute": ac}, criterion=_within_text("position error", 0.03) + ", both",
                     holds=ob["holds"] and ac["holds"], summary=_within_summary(("obtuse: ", ob), ("acute: ", ac))))
    out.append(_equal_claim("v-h000-equal", "obtuse and acute V H000: about equal", R["phase-vobtuse-h000"],
                            R["phase-vacute-h000"]))
    l1, l6 = _within(R["phase-line-h100"], 0.03), _within(R["phase-line-h600"], 0.03)
    out.append(Claim(id="line-h100-h600-converge", text="line H100 and H600 converge", numbers={"h100": l1, "h600": l6},
                     criterion=_within_text("position error", 0.03) + ", both", holds=l1["holds"] and l6["holds"],
                     summary=_within_summary(("H100: ", l1), ("H600: ", l6))))
    better_text = f"paired one-sided t test of the per-run {CMP_KEY}, p < 0.05"
    b = _better(R["phase-line-h600"], R["phase-line-h100"])
    out.append(Claim(id="line-h600-better", text="line: H600 better than H100", numbers=b, criterion=better_text,
                     holds=b["holds"], summary=f"p = {fmt(b['p_one_sided'])}, ratio {fmt(b['ratio_of_means'])}"))
    b = _better(R["phase-vobtuse-h600"], R["phase-vobtuse-h100"])
    b["holds"] = bool(b["holds"] and 0.5 <= b["ratio_of_means"] < 1.0)
    out.append(Claim(id="vobtuse-h600-slightly-better", text="obtuse V: H600 slightly better than H100", numbers=b,
                     criterion=better_text + ", and the ratio of the means in [0.5, 1)", holds=b["holds"],
                     summary=f"p = {fmt(b['p_one_sided'])}, ratio {fmt(b['ratio_of_means'])}"))
    out.append(_equal_claim("vobtuse-h100-equal-h000", "obtuse V: H100 about equal to H000", R["phase-vobtuse-h100"],
                            R["phase-vobtuse-h000"]))
    return out


COLS = [("rmse_position_m", "RMSE pos [m]"), ("pcrb_rmse_position_m", "PCRB pos [m]"),
        ("rmse_position_last_100s_m", "RMSE pos last 100 s [m]"), ("pcrb_rmse_position_last_100s_m", "PCRB last 100 s [m]"),
        ("rmse_velocity_mps", "RMSE vel [m/s]"), ("rmse_attitude_deg", "RMSE att [deg]"), ("anees", "ANEES body (6)"),
        ("anees_state18", "ANEES (18)"), ("anees_body6_actual_cov", "ANEES body vs P_act (6)")]


def _table_rows(R: dict[str, list[dict]]) -> list[dict]:
    """Per scenario: mean and std (ddof 1) over runs of every COLS score; max abs position error over
    the last 100 s per axis, (mean, worst) over runs."""
    rows = []
    for name, runs in R.items():
        row = {"scenario": name, "runs": len(runs)}
        for key, _ in COLS:
            x = np.array([r[key] for r in runs])
            row[key] = (float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else 0.0)
        mx = np.array([r["max_abs_position_error_last_100s_m"] for r in runs])
        row["max_abs_last_100s"] = (mx.mean(0), mx.max(0))
        rows.append(row)
    return rows


def write(out: Path, R: dict[str, list[dict]], claims: list[Claim], *, runs: int, motion: str, base_seed: int) -> dict:
    """table.md, table.csv, plots/rmse_last_100s.png, claims.json; returns claims.json's content."""
    rows = _table_rows(R)
    write_csv(out / "table.csv",
              ["scenario", "runs"] + [f"{k}_{s}" for k, _ in COLS for s in ("mean", "std")]
              + [f"max_abs_pos_last_100s_{a}_{s}" for s in ("mean", "worst") for a in "xyz"],
              [[r["scenario"], r["runs"]] + [v for k, _ in COLS for v in r[k]]
               + np.concatenate(r["max_abs_last_100s"]).tolist() for r in rows])
    md = [f"# Seed 003 reproduction: eight formations, {motion}, {runs} run(s) each, seeds "
          f"{base_seed}..{base_seed + runs - 1}", ""]
    md += markdown_table(["scenario", "runs"] + [h for _, h in COLS]
                         + ["max abs pos last 100 s x / y / z [m] (mean; worst)"],
                         [[r["scenario"], r["runs"]] + [fmt_pm(*r[k]) for k, _ in COLS]
                          + [fmt_list(r["max_abs_last_100s"][0], " / ") + "; "
                             + fmt_list(r["max_abs_last_100s"][1], " / ")] for r in rows])
    md += ["", "mean ± std over runs; RMSE over t >= 10 s; axes of N: x forward, y left, z up "
               "(paper X = x, Y = z, Z = -y).", ""]
    write_markdown(out / "table.md", md + claims_section(claims))
    stats = [mean_ci(np.array([r[CMP_KEY] for r in R[n]])) for n in R]
    compare_bars([n.removeprefix("phase-") for n in R], np.array([s[0] for s in stats]),
                 np.array([s[1] for s in stats]), np.array([s[2] for s in stats]), out / "plots" / "rmse_last_100s.png",
                 title=f"seed 003: position RMSE over the last 100 s ({runs} runs, 95% CI)", ylabel="m")
    return write_claims(out / "claims.json", claims, paper="003", scenarios=list(R), motion=motion, runs=runs,
                        seeds=seeds(base_seed, runs))


def compute(out: Path, *, runs: int, motion: str, duration: float | None,
            workers: int | None) -> tuple[dict[str, list[dict]], int]:
    """Sweep every formation (OUT/runs/<scenario>/run-XXX) and copy run 0's error figures to
    OUT/plots/; returns ({scenario: the EKF scores of every run}, the base seed)."""
    R: dict[str, list[dict]] = {}
    base = set()
    for name in SCENARIOS:
        sc = scenario_mod.load(name, motion=motion, duration=duration)
        base.add(sc.seed)
        dirs = sweep_runs(sc, runs, out / "runs" / name, workers=workers, progress=True)
        R[name] = [m["estimators"]["ekf"] for m in load_metrics(dirs)]
        for fig in ("position_error.png", "velocity_error.png"):
            src = dirs[0] / "plots" / fig
            if src.exists():
                shutil.copy(src, out / "plots" / f"{name}-{fig}")
    if len(base) != 1:  # the paired comparisons need the same seed index to mean the same draws
        raise ValueError(f"phase scenarios must share one seed, got {sorted(base)}")
    return R, base.pop()


def reproduce(out: Path, *, runs: int, motion: str = "prescribed", duration: float | None = None,
              workers: int | None = None) -> dict:
    """Seed 003 reproduction into `out` (see the module docstring); returns claims.json's content."""
    out = Path(out)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    R, base_seed = compute(out, runs=runs, motion=motion, duration=duration, workers=workers)
    return write(out, R, decide(R), runs=runs, motion=motion, base_seed=base_seed)
