"""`testbed reproduce phase`: seed 003 (Pan, Yin, Xu 2023), eight formations, claims decided.

Every scenario `phase-*` runs N Monte Carlo seeds (seed, seed + 1, ...) through testbed.sweep. The
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
"""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np

from testbed.metrics import mean_ci, paired_test

SCENARIOS = ("phase-line-h000", "phase-cross-h000", "phase-vobtuse-h000", "phase-vacute-h000",
             "phase-line-h100", "phase-line-h600", "phase-vobtuse-h100", "phase-vobtuse-h600")
FRACTION = 0.95
CMP_KEY = "rmse_position_last_100s_m"


def _runs(sweep_dir: Path) -> list[dict]:
    return [json.loads(p.read_text())["estimators"]["ekf"] for p in sorted(sweep_dir.glob("run-*/metrics.json"))]


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


def claims(R: dict[str, list[dict]]) -> list[dict]:
    """The paper's claims (SPEC seed 003) decided with the module's criteria."""
    out = []
    line = R["phase-line-h000"]
    fin = np.array([r["position_error_final_m"] for r in line])
    mid = np.array([r["position_error_mid_m"] for r in line])
    rms_fin, rms_mid = np.sqrt((fin ** 2).mean(0)), np.sqrt((mid ** 2).mean(0))
    div = {ax: bool(rms_fin[i] > rms_mid[i] and rms_fin[i] > 0.03) for ax, i in (("x (paper X)", 0), ("z (paper Y)", 2))}
    acc = _within(line, 0.03, axes=(1,))
    out.append({"id": "line-h000-xy-diverge-z-accurate", "claim": "line H000: X and Y errors diverge, Z stays accurate",
                "numbers": {"rms_final_error_m": rms_fin.tolist(), "rms_mid_error_m": rms_mid.tolist(), "diverges": div,
                            "z_accurate": acc, "pcrb_sigma_final_m": _pcrb_axes(line)},
                "holds": bool(all(div.values()) and acc["holds"])})
    v = _within(line, 0.005, key="max_abs_velocity_error_last_100s_mps")
    out.append({"id": "line-h000-velocity", "claim": "line H000: velocity error within +/-0.005 m/s after it settles",
                "numbers": v, "holds": v["holds"]})
    c = _within(R["phase-cross-h000"], 0.01)
    out.append({"id": "cross-h000-0.01", "claim": "cross H000: all three position errors within +/-0.01 m",
                "numbers": {**c, "pcrb_sigma_final_m": _pcrb_axes(R["phase-cross-h000"])}, "holds": c["holds"]})
    ob, ac = _within(R["phase-vobtuse-h000"], 0.03), _within(R["phase-vacute-h000"], 0.03)
    out.append({"id": "v-h000-0.03", "claim": "obtuse and acute V H000: within +/-0.03 m",
                "numbers": {"vobtuse": ob, "vacute": ac}, "holds": ob["holds"] and ac["holds"]})
    eq = _equal(R["phase-vobtuse-h000"], R["phase-vacute-h000"])
    out.append({"id": "v-h000-equal", "claim": "obtuse and acute V H000: about equal", "numbers": eq, "holds": eq["holds"]})
    l1, l6 = _within(R["phase-line-h100"], 0.03), _within(R["phase-line-h600"], 0.03)
    out.append({"id": "line-h100-h600-converge", "claim": "line H100 and H600 converge",
                "numbers": {"h100": l1, "h600": l6}, "holds": l1["holds"] and l6["holds"]})
    b = _better(R["phase-line-h600"], R["phase-line-h100"])
    out.append({"id": "line-h600-better", "claim": "line: H600 better than H100", "numbers": b, "holds": b["holds"]})
    b = _better(R["phase-vobtuse-h600"], R["phase-vobtuse-h100"])
    b["holds"] = bool(b["holds"] and 0.5 <= b["ratio_of_means"] < 1.0)
    out.append({"id": "vobtuse-h600-slightly-better", "claim": "obtuse V: H600 slightly better than H100", "numbers": b, "holds": b["holds"]})
    eq = _equal(R["phase-vobtuse-h100"], R["phase-vobtuse-h000"])
    out.append({"id": "vobtuse-h100-equal-h000", "claim": "obtuse V: H100 about equal to H000", "numbers": eq, "holds": eq["holds"]})
    return out


COLS = [("rmse_position_m", "RMSE pos [m]"), ("pcrb_rmse_position_m", "PCRB pos [m]"),
        ("rmse_position_last_100s_m", "RMSE pos last 100 s [m]"), ("pcrb_rmse_position_last_100s_m", "PCRB last 100 s [m]"),
        ("rmse_velocity_mps", "RMSE vel [m/s]"), ("rmse_attitude_deg", "RMSE att [deg]"), ("anees", "ANEES body (6)"),
        ("anees_state18", "ANEES (18)"), ("anees_body6_actual_cov", "ANEES body vs P_act (6)")]


def table(R: dict[str, list[dict]], out: Path) -> None:
    rows = []
    for name, runs in R.items():
        row = {"scenario": name, "runs": len(runs)}
        for key, _ in COLS:
            x = np.array([r[key] for r in runs])
            row[key] = (float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else 0.0)
        mx = np.array([r["max_abs_position_error_last_100s_m"] for r in runs])
        row["max_abs_last_100s"] = (mx.mean(0), mx.max(0))
        rows.append(row)
    with open(out / "table.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scenario", "runs"] + [f"{k}_{s}" for k, _ in COLS for s in ("mean", "std")]
                   + [f"max_abs_pos_last_100s_{a}_{s}" for s in ("mean", "worst") for a in "xyz"])
        for r in rows:
            w.writerow([r["scenario"], r["runs"]] + [repr(v) for k, _ in COLS for v in r[k]]
                       + [repr(float(v)) for v in np.concatenate(r["max_abs_last_100s"])])
    lines = ["| scenario | runs | " + " | ".join(h for _, h in COLS) + " | max abs pos last 100 s x / y / z [m] (mean; worst) |",
             "|---" * (len(COLS) + 3) + "|"]
    for r in rows:
        cells = [f"{r[k][0]:.4g} ± {r[k][1]:.2g}" for k, _ in COLS]
        m, wst = r["max_abs_last_100s"]
        cells.append(" / ".join(f"{v:.4f}" for v in m) + "; " + " / ".join(f"{v:.4f}" for v in wst))
        lines.append(f"| {r['scenario']} | {r['runs']} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("mean ± std over runs; RMSE over t >= 10 s; axes of N: x forward, y left, z up (paper X = x, Y = z, Z = -y).")
    (out / "table.md").write_text("\n".join(lines) + "\n")


def reproduce(out: Path, *, runs: int, motion: str = "prescribed", duration: float | None = None,
              workers: int | None = None) -> dict:
    from testbed import scenario as scenario_mod
    from testbed.plots import compare_bars
    from testbed.sweep import sweep

    out = Path(out)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    R: dict[str, list[dict]] = {}
    for name in SCENARIOS:
        sc = scenario_mod.load(name, motion=motion, duration=duration)
        d = out / "runs" / name
        sweep(sc, runs, d, workers=workers, force=True, progress=True)
        R[name] = _runs(d)
        for fig in ("position_error.png", "velocity_error.png"):
            src = d / "run-000" / "plots" / fig
            if src.exists():
                shutil.copy(src, out / "plots" / f"{name}-{fig}")
    table(R, out)
    stats = [mean_ci(np.array([r[CMP_KEY] for r in R[n]])) for n in SCENARIOS]
    compare_bars([n.removeprefix("phase-") for n in SCENARIOS], np.array([s[0] for s in stats]),
                 np.array([s[1] for s in stats]), np.array([s[2] for s in stats]), out / "plots" / "rmse_last_100s.png",
                 title=f"seed 003: position RMSE over the last 100 s ({runs} runs, 95% CI)", ylabel="m")
    cl = claims(R)
    (out / "claims.json").write_text(json.dumps(cl, indent=2) + "\n")
    return {"runs": runs, "motion": motion, "claims": cl}
