"""Seed 003 process noise q chosen by a stated rule on calibration seeds (docs/papers.md).

The phase EKF's q (white acceleration per antenna axis, m^2/s^3; estimators.phase_ekf) is a
modelling choice: the eq. 31 body moves at exactly constant velocity and its antennas accelerate
only by the slow attitude oscillation (<= 1.7e-4 m/s^2), so no physical q exists to copy, and the
accuracy, the filter's covariance and the PCRB all depend on it. It is therefore chosen per
scenario by this rule, fixed before any evaluation run was looked at:

    RULE: q = the value of Q_GRID whose body ANEES (position and velocity, 6 dof, the filter's own
    covariance; metrics.json `anees`: the NEES averaged over the scored epochs t >= score_start of
    a CALIBRATION_HORIZON_S run), averaged over the calibration seeds CALIBRATION_SEEDS, is closest
    to its dof 6 on a log scale (|ln(ANEES / 6)| smallest; the larger q on a tie).

The calibration seeds (1000..1009) are disjoint from the evaluation seeds of every test and of
`testbed reproduce phase` (the scenario seed 1 + run index, < 1000), so q is never chosen on the
runs it is judged on. The rule asks for a consistent filter (ANEES = dof), the property the
consistency tests of the built-in scenarios check on other seeds (tests/test_phase_scenario.py).
The horizon is the one the claims are judged on: the scenarios' whole 200 s run (the accuracy
claims of `testbed reproduce phase` and the long consistency test), and the quantity is the
run's ANEES, not the NEES at one instant. (Until this horizon was adopted the rule calibrated the
final NEES of 20 s runs; a filter tuned so was conservative over 200 s, docs/papers.md.)
Grid Q_GRID: from 1e-12 (the smallest magnitude a scenario file accepts; the velocity random walk
sqrt(q 200 s) = 1.4e-5 m/s, i.e. q -> 0, the constant-velocity body of eq. 31) to 1e-6 (the flown
mode's q).

Stage 2, rotational process noise q_rotation (rad^2/s^3, ProcessNoise.rotation: a white angular
acceleration of the follower's rigid body per body axis). Fixed, like stage 1, before any
evaluation run was looked at:

    RULE (stage 2): with q fixed by stage 1, q_rotation = the value of QR_GRID whose attitude
    ANEES (yaw, pitch, roll and their rates, 6 dof, the filter's own covariance linearized through
    eq. 30; metrics.json `anees_attitude6`: over the scored epochs, one a second, whose attitude the
    filter observes), averaged over the same CALIBRATION_SEEDS on CALIBRATION_HORIZON_S runs, is
    closest to its dof 6 on a log scale (the larger q_rotation on a tie). Stage 1 runs with
    q_rotation = 0, so the rule does not depend on the value a scenario file already carries.
    This stage 2 runs where stage 1's runs at its q observe the attitude at every scored epoch
    (`attitude_unobserved_fraction` 0 on every calibration seed).

    RULE (stage 2, attitude unobserved): elsewhere an attitude the filter does not observe has no
    ANEES to calibrate (line H000: a line of masters cannot see a turn about the line), and stage
    1's q, found without rotational noise, stands in for the antennas' rotation: there q = Q_GRID[0]
    (the eq. 31 body has no random acceleration), and q_rotation = the value of QR_GRID whose body
    ANEES (stage 1's quantity, over the directions the masters observe: `anees` with `anees_dof`)
    at that q, averaged over the same seeds and runs, is closest to its dof on a log scale (the
    larger q_rotation on a tie). Written after the calibration runs of line H000 showed that no q
    of the grid at q_rotation = 0 is consistent over 200 s on the observed directions (5 dof: 1562
    at 1e-12, 480 at 1e-11, 3.0 at 1e-9, 2.2 at 1e-8), before any evaluation run of this rule.
    Re-applied, unchanged, when the rotational noise began to average over the lever arms'
    uncertainty (estimators.phase_ekf, "Uncertain lever arms"): line H000's q_rotation 1e-5 -> 1e-6
    (docs/papers.md, seed 003).

Why the attitude: at stage 1's small q the filter is over-confident in its attitude and, through
it, in the 18-state (tests/test_phase_scenario.py), because the independent per-antenna q no longer
covers the antennas' deterministic accelerations from the eq. 31 attitude oscillation. A random
angular acceleration alpha moves antenna j by alpha x rho_j: it reaches exactly the 6 attitude
directions (the body origin is the mid wing tips, rho_2 + rho_3 = 0, so the body position and
velocity calibrated by stage 1 get nothing to first order; a rotation does not change the
triangle's side lengths). The stage-2 quantity is therefore the block the stage-2 parameter drives,
and nothing else; the 18-state NEES would also count the 6 side-length directions, which no
rigid-body noise reaches, and is left as the evaluation's check (on other seeds). Grid QR_GRID: 0
(the paper's Q) and the decades 1e-10 .. 1e-5 (1e-5: the model-matched test's rotational
disturbance; the eq. 31 attitude-rate amplitude squared over one 200 s period is 1.5e-7).

`choose(rows)` applies the rule to a sweep (`choose(rows, "q_rotation")` stage 2), `rule(rows1, rows2)`
both stages to their sweeps; `calibrate(name)`
runs both stages on one scenario; `sweep(name, seeds, qs, q_rotations=...)` simulates each seed once and runs the EKF on that log with
every (q, q_rotation) (`score_ekf`: the phase.ekf estimator and its scores);
`python -m testbed.reproduce.phase_q` prints the rule's q and q_rotation for every built-in phase
scenario (the command that produced the scenarios' `pipeline.q` and `pipeline.q_rotation`), and `testbed reproduce phase` writes the sweep
and the figure plots/q_sweep.png into its report.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from testbed.config import scenario as scenario_mod
from testbed.errors import TestbedError
from testbed.scoring.metrics import anees_run_interval

CALIBRATION_SEEDS = tuple(range(1000, 1010))
CALIBRATION_HORIZON_S = 200.0  # s: the built-in phase scenarios' duration, the horizon of their claims
Q_GRID = (1e-12, 1e-11, 1e-9, 1e-8, 1e-7, 1e-6)  # m^2/s^3 (1e-12: the smallest number a scenario file accepts)
QR_GRID = (0.0, 1e-10, 1e-9, 1e-8, 1e-7, 1e-6, 1e-5)  # rad^2/s^3, stage 2
DOF = 6  # body position and velocity: the `anees` of testbed.plugins.phase_scores.PhaseScored; also the attitude's
#: per stage: the swept parameter -> (the ANEES over the run the rule calibrates, its dof unless the
#: rows carry KEY_dof: the body's is 5 where a line of masters leaves one direction unobserved,
#: testbed.plugins.phase_scores.PhaseScored)
RULE_NEES = {"q": ("anees", DOF), "q_rotation": ("anees_attitude6", 6)}
#: the scores of one (seed, q, q_rotation) kept by the sweep: row key -> key of score_ekf (the RMSEs
#: and the PCRB over t >= score_start, testbed.plugins.phase_scores.PhaseScored; the gate's
#: rejected rows, the filter's health())
KEPT = {"nees_body6_final": "nees_body6_final", "nees_attitude6_final": "nees_attitude6_final",
        "nees_final": "nees_final", "anees": "anees", "anees_dof": "anees_dof", "anees_attitude6": "anees_attitude6",
        "attitude_unobserved_fraction": "attitude_unobserved_fraction",
        "rmse_position_m": "rmse_position_after_start_m",
        "pcrb_rmse_position_m": "pcrb_rmse_position_after_start_m", "rmse_attitude_deg": "rmse_attitude_after_start_deg",
        "gate_rejected_rows": "rejected_measurements"}


def score_ekf(sc, log: dict, physics=None) -> dict:
    """The scores of the scenario's phase.ekf (its default estimator "ekf") on a run log, its
    health() counts merged in (metrics.json `estimators.ekf` with `health` flattened). physics:
    the scenario's world (testbed.sim.world.build; built here when None), given by a sweep that
    scores one log under several pipelines (the pipeline does not enter the world)."""
    # lazy: the filter and the scoring only when a sweep runs
    from testbed.errors import PluginError
    from testbed.plugins.defaults import default_specs
    from testbed.plugins.loading import resolve
    from testbed.plugins.run import run_estimators
    from testbed.sim.world import build

    m = run_estimators(sc, build(sc) if physics is None else physics, log, resolve(default_specs(sc)), None)[0]["ekf"]
    if "failed" in m:
        raise PluginError(m["failed"]["reason"], m["failed"]["time_s"])
    return {**m, **m.get("health", {})}


def simulate_seeds(name: str, seeds=CALIBRATION_SEEDS, *, duration: float | None = CALIBRATION_HORIZON_S,
                   motion: str = "prescribed"):
    """(scenario, run log) of scenario `name` for every seed (duration s, None = the scenario's),
    simulated lazily one at a time (a generator)."""
    # lazy: mujoco only when a sweep runs
    from testbed.sim.simulate import simulate

    for seed in seeds:
        sc = scenario_mod.load(name, seed=int(seed), duration=duration, motion=motion)
        yield sc, simulate(sc)[0]


def sweep(name: str, seeds=CALIBRATION_SEEDS, qs=Q_GRID, *, q_rotations=None,
          duration: float | None = CALIBRATION_HORIZON_S, motion: str = "prescribed", progress=None,
          runs=None) -> list[dict]:
    """Rows {scenario, seed, q, q_rotation, KEPT scores and, when the run covers the window, the
    window scores} of scenario `name`: every seed simulated once (duration s, None = the
    scenario's), the EKF run on its log with each q (pipeline.q, or q_flown in flown mode) and each
    q_rotation (pipeline.q_rotation; None: the scenario's own). runs: the (scenario, log) pairs to use instead of simulating
    `seeds` (simulate_seeds); progress: optional callable(str) told after each seed."""
    # lazy: the phase model and the physics only when a sweep runs
    from testbed.plugins.phase_scores import window_keys
    from testbed.sim.world import build

    field = "q_flown" if motion == "flown" else "q"
    rows = []
    for sc, log in (runs if runs is not None else simulate_seeds(name, seeds, duration=duration, motion=motion)):
        physics = build(sc)  # one world for every (q, q_rotation) of this seed
        for q in qs:
            for qr in (q_rotations if q_rotations is not None else (sc.pipeline.q_rotation,)):
                m = score_ekf(replace(sc, pipeline=replace(sc.pipeline, **{field: float(q), "q_rotation": float(qr)})),
                              log, physics)
                k = window_keys(m["last_window_s"])
                extra = {key: m[k[key]] for key in ("rmse", "pcrb_rmse", "max_abs_position") if k[key] in m}
                rows.append({"scenario": name, "seed": sc.seed, "q": float(q), "q_rotation": float(qr),
                             **{key: m.get(src, np.nan) for key, src in KEPT.items()}, **extra})
        if progress is not None:
            progress(f"{name}: seed {sc.seed} done")
    return rows


def anees_by_q(rows: list[dict], param: str = "q", key: str | None = None) -> dict[float, float]:
    """{value of `param`: mean over the rows' seeds of the ANEES the rule calibrates for it
    (RULE_NEES, or the rows' `key`; a seed without one, e.g. an attitude never observed, is left
    out)} of one scenario's sweep."""
    return {v: float(np.mean(kept)) if kept.size else math.nan  # no seed observed it
            for v, kept in _per_value(rows, param, key).items()}


def anees_interval_by_q(rows: list[dict], param: str = "q", key: str | None = None,
                        level: float = 0.99) -> dict[float, list[float] | None]:
    """{value of `param`: the interval a consistent filter's mean (anees_by_q) falls in, from the
    spread of the seeds' per-run ANEES (testbed.scoring.metrics.anees_run_interval, Student t: the
    seeds are independent runs, docs/consistency.md), None with fewer than 2 seeds}."""
    dof = rule_dof(rows, param, key)
    return {v: list(anees_run_interval(kept, dof, level)) if kept.size >= 2 else None
            for v, kept in _per_value(rows, param, key).items()}


def _per_value(rows: list[dict], param: str, key: str | None = None) -> dict[float, np.ndarray]:
    """{value of `param`: the seeds' ANEES the rule calibrates (RULE_NEES, or the rows' `key`) at it,
    NaN left out}."""
    key = key or RULE_NEES[param][0]
    return {v: np.array([x for x in (r.get(key, np.nan) for r in rows if r[param] == v) if not math.isnan(x)])
            for v in sorted({r[param] for r in rows})}


def choose(rows: list[dict], param: str = "q", key: str | None = None) -> float:
    """The RULE (module docstring) on one scenario's sweep over `param` ("q": stage 1,
    "q_rotation": stage 2; key "anees": stage 2 with the attitude unobserved): the value whose
    ANEES is closest to its dof on a log scale, the larger value on a tie."""
    a, dof = anees_by_q(rows, param, key), rule_dof(rows, param, key)
    return min(a, key=lambda v: (abs(math.log(a[v] / dof)), -v))


def rule_dof(rows: list[dict], param: str = "q", key: str | None = None) -> int:
    """The dof of the ANEES the rule calibrates for `param` (or of the rows' `key`) on one
    scenario's rows (RULE_NEES; the rows' KEY_dof where they carry it)."""
    name, dof = RULE_NEES[param]
    key = key or name
    return int(rows[0].get(f"{key}_dof", dof if key == name else DOF))


def attitude_observed(rows1: list[dict]) -> bool:
    """Whether every stage-1 run at stage 1's q observes the attitude at every scored epoch (the
    RULE's stage 2 by the attitude; else stage 2 with the attitude unobserved)."""
    q = choose(rows1)
    return not any(r["attitude_unobserved_fraction"] > 0 for r in rows1 if r["q"] == q)


def stage1_q(rows1: list[dict]) -> float:
    """q of the RULE's stage 1 from one scenario's stage-1 rows (Q_GRID at q_rotation 0): choose's,
    or Q_GRID[0] where the attitude is unobserved (the stage 2 that calibrates without it)."""
    return choose(rows1) if attitude_observed(rows1) else Q_GRID[0]


def rule(rows1: list[dict], rows2: list[dict]) -> tuple[float, float]:
    """(q, q_rotation) of the RULE from one scenario's stage-1 rows (Q_GRID at q_rotation 0) and
    stage-2 rows (QR_GRID at stage1_q, the q `calibrate` sweeps them at)."""
    return stage1_q(rows1), choose(rows2, "q_rotation", None if attitude_observed(rows1) else "anees")


def calibrate(name: str, seeds=CALIBRATION_SEEDS, *, duration: float | None = CALIBRATION_HORIZON_S,
              motion: str = "prescribed", progress=None) -> tuple[float, float, list[dict], list[dict]]:
    """Both stages of the rule on scenario `name`, each seed simulated once: (q, q_rotation,
    stage-1 rows over Q_GRID at q_rotation 0, stage-2 rows over QR_GRID at the chosen q). In flown
    mode the swept q is q_flown (the scenarios' q_flown is not calibrated by this rule)."""
    runs = list(simulate_seeds(name, seeds, duration=duration, motion=motion))
    rows1 = sweep(name, qs=Q_GRID, q_rotations=(0.0,), motion=motion, runs=runs, progress=progress)
    rows2 = sweep(name, qs=(stage1_q(rows1),), q_rotations=QR_GRID, motion=motion, runs=runs)
    return (*rule(rows1, rows2), rows1, rows2)


def _mean_by_q(rows: list[dict], key: str, rms: bool = False) -> tuple[list[float], list[float]]:
    """(qs, mean over the seeds of rows[key] at each q; root mean square if rms)."""
    qs = sorted({r["q"] for r in rows})
    vals = [np.array([r[key] for r in rows if r["q"] == q], float) for q in qs]
    return qs, [float(np.sqrt(np.mean(v ** 2)) if rms else np.mean(v)) for v in vals]


def plot(sweeps: dict[str, list[dict]], chosen: dict[str, float], path: Path, *, horizon: float,
         long: list[dict] | None = None) -> Path:
    """plots/q_sweep.png. Left: per scenario the calibration ANEES against q (dof and the chosen q
    marked). Right, with `long` (a sweep of one scenario over its full duration on the calibration
    seeds): its position RMSE and PCRB over the last window and its ANEES over the run against q;
    without (or if its runs are shorter than the window): RMSE and PCRB of the calibration sweeps."""
    from testbed.outputs.plots import figure, save

    fig = figure(figsize=(10.0, 3.6))
    ax1, ax2 = fig.subplots(1, 2)
    if long is not None and "rmse" not in long[0]:  # runs shorter than the window: no window scores
        long = None
    for i, (name, rows) in enumerate(sweeps.items()):
        a = anees_by_q(rows)
        label = name.removeprefix("phase-")
        ax1.plot(list(a), list(a.values()), "o-", color=f"C{i}", ms=3, label=label)
        ax1.plot([chosen[name]], [a[chosen[name]]], "*", color=f"C{i}", ms=11)
        if long is None:
            ax2.plot(*_mean_by_q(rows, "rmse_position_m", rms=True), "o-", color=f"C{i}", ms=3)
            ax2.plot(*_mean_by_q(rows, "pcrb_rmse_position_m"), "--", color=f"C{i}", lw=1)
    ax1.axhline(DOF, color="k", lw=0.8)
    n = len({r["seed"] for rows in sweeps.values() for r in rows})
    ax1.set(xscale="log", yscale="log", xlabel="q [m^2/s^3]", ylabel="ANEES body (6 dof)",
            title=f"ANEES over {horizon:g} s runs, {n} calibration seeds (* = rule's q)")
    ax1.legend(fontsize=7, ncol=2)
    title = "body position RMSE (solid) and PCRB (dashed)"
    if long is not None:
        name = long[0]["scenario"]
        ax2.plot(*_mean_by_q(long, "rmse", rms=True), "o-", color="C0", ms=3, label="RMSE, last window")
        ax2.plot(*_mean_by_q(long, "pcrb_rmse"), "s--", color="C1", ms=3, label="PCRB, last window")
        mx = [max(r["max_abs_position"]) for r in long]
        qs = sorted({r["q"] for r in long})
        ax2.plot(qs, [np.median([m for m, r in zip(mx, long) if r["q"] == q]) for q in qs], "^:", color="C2", ms=3,
                 label="median of max |error|, last window")
        ax2.axvline(chosen.get(name, np.nan), color="k", lw=0.8, ls=":")
        twin = ax2.twinx()
        twin.plot(*_mean_by_q(long, "anees"), "d-", color="C3", ms=3, lw=0.8)
        twin.set_ylabel("ANEES over the run (6 dof)", color="C3")
        ax2.legend(fontsize=7)
        title = f"{name.removeprefix('phase-')}, full runs, {len({r['seed'] for r in long})} calibration seeds"
    ax2.set(xscale="log", yscale="log", xlabel="q [m^2/s^3]", ylabel="m", title=title)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3, which="both")
    return save(fig, path)


def main(argv: list[str] | None = None) -> int:
    """Print the rule's q and q_rotation for the built-in phase scenarios (the command of the
    scenarios' q and q_rotation);
    --plot PATH also writes the sweep's figure (plots/q_sweep.png of the reproduction)."""
    p = argparse.ArgumentParser(prog="python -m testbed.reproduce.phase_q", description=main.__doc__)
    p.add_argument("scenarios", nargs="*", default=[n for n in scenario_mod.builtin_names() if n.startswith("phase-")])
    p.add_argument("--plot", type=Path, help="write the figure of the sweep to this PNG")
    p.add_argument("--long", help="with --plot: also sweep this scenario over its full duration (right panel)")
    args = p.parse_args(argv)
    try:
        for name in args.scenarios + ([args.long] if args.long else []):
            scenario_mod.load(name)  # a bad name: one line and exit 2 before anything runs
    except TestbedError as e:
        print(f"phase_q: error: {e}", file=sys.stderr)
        return e.exit_code
    sweeps, chosen = {}, {}
    for name in args.scenarios:
        q, qr, sweeps[name], rows2 = calibrate(name)
        chosen[name] = q
        # one ANEES per calibration seed; seeds share no noise: the runs are independent samples
        lo, hi = anees_run_interval(np.array([r["anees"] for r in rows2 if r["q_rotation"] == qr]), rule_dof(rows2))
        print(f"{name}: q = {q:g}, q_rotation = {qr:g}  (body ANEES at both, 99 % run interval "
              f"[{lo:.2f}, {hi:.2f}]; body ANEES by q: "
              + ", ".join(f"{v:g}: {a:.2f}" for v, a in anees_by_q(sweeps[name]).items())
              + f"; attitude / body ANEES by q_rotation at q = {q:g}: "
              + ", ".join(f"{v:g}: {a:.2f} / {b:.2f}" for (v, a), b in zip(anees_by_q(rows2, "q_rotation").items(),
                                                                           anees_by_q(rows2, "q_rotation", "anees").values()))
              + ")", flush=True)
    if args.plot is not None:
        plot(sweeps, chosen, args.plot, horizon=CALIBRATION_HORIZON_S,
             long=sweep(args.long, duration=None) if args.long else None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
