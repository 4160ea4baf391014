"""Seed 003 end to end: the phase.ekf estimator and its scores on logs simulated by the real testbed.

Monte Carlo sizes and horizons are chosen for CI (see each test); tolerances come from the sample
size (chi-square intervals of estimators.core.chi2_interval), never tuned.
"""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

from estimators.core import Epoch, Gate, chi2_interval, drive, is_spd, nees
from estimators import phase_frames as PF
from estimators.phase_ekf import AnalyzedGaussian, PhaseEkfCovarianceAnalysis
from estimators.phase_model import body_from_antennas, line_rotation, masters_line
from testbed.config import scenario as scenario_mod
from testbed.errors import ConfigError
from testbed.plugins import builtin_phase as PB
from testbed.plugins import phase_scores as PS
from testbed.reproduce.phase_q import score_ekf
from testbed.rng import stream_rng
from testbed.scoring.metrics import anees_over_runs
from testbed.sim.simulate import simulate

NAME = "phase-cross-h000"


def _filter(sc, log):
    """phase.ekf's pieces: inputs, prior, filter (the seed 003 EKF over all epochs through the
    library's driver, estimators.core.drive, as phase.ekf steps it), truth in N."""
    cfg, ph = sc.pipeline, sc.sensors.phase
    inp = PB.phase_inputs(log, 1.0 / ph.phase_rate_hz, cfg.nav_master)
    prior, P0, err0 = PB.initial_prior(cfg, sc, inp, stream_rng(sc.seed, "init"))
    meas = PB.measurement_epochs(cfg, inp)
    filt = PhaseEkfCovarianceAnalysis(PB.process_noise_model(cfg, sc.motion), Gate(alpha=cfg.gate_alpha, enabled=cfg.gate),
                                      cfg.iterations, cfg.rigid)
    track = drive(filt, AnalyzedGaussian(prior.mean, prior.cov, prior.cov), [Epoch(float(t), m) for t, m in zip(inp.times, meas)])
    means, covs = track.mean, track.cov
    infos = [b.info for b in track.beliefs]
    acts = np.stack([b.actual for b in track.beliefs])
    body, RN, states = PS.truth_in_nav(log, inp.state_index, cfg.nav_master, inp.follower,
                                      sc.world.antenna_a, sc.world.antenna_b)
    return dict(inp=inp, prior=prior, P0=P0, err0=err0, meas=meas, means=means, covs=covs,
                infos=infos, acts=acts, body=body, states=states, track=track)


def test_reported_rate_is_the_window_mean_of_the_resolved_ranges():
    """Documented in the pipeline: eq. 7's rate = (r_hat(t) - r_hat(t - W)) / W, W = 0.7 s."""
    sc = scenario_mod.load(NAME, duration=3.0)
    log, _ = simulate(sc)
    v = log["phase/value"].reshape(-1, 45, 3)
    W = log["phase/rate_periods"].reshape(-1, 45) / sc.sensors.phase.phase_rate_hz
    k = np.arange(7, v.shape[0])
    assert np.all(W[k] == pytest.approx(0.7))
    assert np.abs((v[k, :, 1] - v[k - 7, :, 1]) / W[k] - v[k, :, 2]).max() < 1e-9


# The follower's random body motion of the model-matched Monte Carlo (a priori, not tuned): a
# translational random walk of 1e-3 m^2/s^3 (velocity std 0.14 m/s, position std 1.6 m after
# 20 s) and a rotational one of 1e-5 rad^2/s^3 (rate std 0.014 rad/s, attitude std 9 deg after
# 20 s); both far above the eq. 31 accelerations (<= 1.7e-4 m/s^2), so the truth is the filter's
# model. Range rows only: the eq. 7 rates are exact differences of range rows the filter already
# used (test_reported_rate_is_the_window_mean_of_the_resolved_ranges), i.e. no new information.
MATCHED = {
    "disturbance.accel_density": "1e-3", "disturbance.angular_accel_density": "1e-5",
    "disturbance.vehicles": "[6]",
    "pipeline.q_translation": "1e-3", "pipeline.q_rotation": "1e-5", "pipeline.rate_rows": '"off"',
}


def _sides(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The antenna triangle's side lengths and their rates (6,) at the 18-state x, and their
    Jacobian (6, 18): the directions a rigid body never moves in."""
    X, V = x[:9].reshape(3, 3), x[9:].reshape(3, 3)
    val, J = np.zeros(6), np.zeros((6, 18))
    for k, (i, j) in enumerate([(0, 1), (0, 2), (1, 2)]):
        d, dv = X[i] - X[j], V[i] - V[j]
        length = np.linalg.norm(d)
        u = d / length
        val[k], val[3 + k] = length, u @ dv
        du = (dv - u * (u @ dv)) / length
        for col, sign in ((i, 1.0), (j, -1.0)):
            J[k, 3 * col:3 * col + 3] = sign * u
            J[3 + k, 3 * col:3 * col + 3] = sign * du
            J[3 + k, 9 + 3 * col:9 + 3 * col + 3] = sign * u
    return val, J


def _monte_carlo(runs: int, horizon: float, overrides: dict | None = None, alt: dict | None = None) -> dict:
    """`runs` seeds of phase-cross-h000 (with overrides) through the testbed and the filter.

    Final-epoch values over the runs: n18, n6 (the filter's NEES, 18-state and body position +
    velocity), n12 (NEES of the 12 body quantities of eq. 29-30: position, velocity, yaw / pitch /
    roll and their rates, linearized), n_sides (NEES of the triangle's side lengths and rates, 6 dof, linearized),
    n6_act (body NEES against the Gelb covariance P_act), P_minus_P_act_min (smallest eigenvalue
    of P - P_act), RMSE of the antenna positions / body position next to the PCRB (each run's
    bound along its own true trajectory, averaged over the runs); n6_alt: body NEES of the
    filter with the pipeline overrides `alt` on the same logs; n6_runs: the body NEES of each run
    (runs,), seed 1 first.
    """
    e18, n18, n6, n12, n6a, ns, n6alt, gap, bounds = [], [], [], [], [], [], [], [], []
    B = PF.BODY_PV
    for i in range(runs):
        sc = scenario_mod.load(NAME, seed=1 + i, duration=horizon, overrides=overrides)
        log, _ = simulate(sc)
        r = _filter(sc, log)
        e = r["means"][-1] - r["states"][-1]
        e18.append(e)
        n18.append(nees(e, r["covs"][-1]))
        n6.append(nees(B @ e, B @ r["covs"][-1] @ B.T))
        n6a.append(nees(B @ e, B @ r["acts"][-1] @ B.T))
        (s_true, _), (s_est, J) = _sides(r["states"][-1]), _sides(r["means"][-1])
        ns.append(nees(s_est - s_true, J @ r["covs"][-1] @ J.T))
        (y_true, _), (y_est, J) = body_from_antennas(r["states"][-1]), body_from_antennas(r["means"][-1])
        ey = y_est - y_true
        ey[6:9] = (ey[6:9] + np.pi) % (2 * np.pi) - np.pi
        n12.append(nees(ey, J @ r["covs"][-1] @ J.T))
        if alt:
            ra = _filter(scenario_mod.load(NAME, seed=1 + i, duration=horizon, overrides={**(overrides or {}), **alt}), log)
            ea = ra["means"][-1] - ra["states"][-1]
            n6alt.append(nees(B @ ea, B @ ra["covs"][-1] @ B.T))
        gap.append(np.linalg.eigvalsh(r["covs"][-1] - r["acts"][-1]).min())
        q = PB.process_noise_model(sc.pipeline, sc.motion)
        bounds.append(PS.phase_pcrb(sc.pipeline, q, r["states"], r["inp"], r["meas"], r["P0"])[-1])
    E, bound = np.array(e18), np.mean(bounds, axis=0)
    return dict(
        n18=np.mean(n18), n6=np.mean(n6), n12=np.mean(n12), n6_act=np.mean(n6a), n_sides=np.mean(ns), P_minus_P_act_min=min(gap),
        n6_alt=np.mean(n6alt) if n6alt else np.nan, n6_runs=np.array(n6),
        rmse_ant=np.sqrt(np.mean(np.sum(E[:, :9] ** 2, axis=1))),
        rmse_body=np.sqrt(np.mean(np.sum((E @ PF.BODY_POS.T) ** 2, axis=1))),
        pcrb_ant=np.sqrt(np.trace(bound[:9, :9])),
        pcrb_body=np.sqrt(np.trace(PF.BODY_POS @ bound @ PF.BODY_POS.T)),
    )


def _report(label: str, mc: dict, runs: int) -> None:
    lo6, hi6 = chi2_interval(6, runs)
    lo18, hi18 = chi2_interval(18, runs)
    print(f"{label}: ANEES body6 {mc['n6']:.2f} (vs P_act {mc['n6_act']:.2f}; other rows {mc['n6_alt']:.2f}) "
          f"[{lo6:.2f}, {hi6:.2f}]; body12 {mc['n12']:.2f} {tuple(round(v, 2) for v in chi2_interval(12, runs))}; 18-state {mc['n18']:.2f} [{lo18:.2f}, {hi18:.2f}]; side lengths and "
          f"rates {mc['n_sides']:.2f} (6 dof); RMSE antennas {mc['rmse_ant']:.4f} / PCRB {mc['pcrb_ant']:.4f}, "
          f"body {mc['rmse_body']:.4f} / PCRB {mc['pcrb_body']:.4f}")


@pytest.mark.slow
def test_monte_carlo_cross_h000_matched_truth_is_consistent_and_near_pcrb():
    """The issue's consistency test: 30 seeds of phase-cross-h000 through the real testbed, 20 s
    (CI budget), with the follower disturbed by the random body accelerations the filter's
    process noise describes ([disturbance] = pipeline q_translation, q_rotation: MATCHED).

    At the final epoch over the 30 independent runs:
    - ANEES of the body position and velocity (the `anees` metric, 6 dof) with the filter's own
      covariance inside its 99 % chi-square interval (consistent, neither over- nor under-confident);
    - the same for all 12 rigid-body quantities of eq. 29-30 (position, velocity, attitude and
      attitude rates, covariance J P J^T);
    - RMSE of the body position and of the antenna positions <= 1.5 x the PCRB.
    Printed, not asserted: the 18-state ANEES, over-confident in the 6 remaining directions (the
    antenna triangle's side lengths and their rates, also printed) in which a rigid body has no
    random motion (phase_ekf docstring); and the body ANEES of the paper's row set (eq. 7 rates as
    independent rows) on the same logs, over-confident because they repeat the ranges (with
    PHASE_LONG=1).
    """
    runs = 30
    # the paper's row set on the same logs is printed only (with PHASE_LONG=1 and -s): it asserts
    # nothing, and its 30 filter runs are a quarter of this test's CPU
    alt = {"pipeline.rate_rows": '"window"'} if os.environ.get("PHASE_LONG") else None
    mc = _monte_carlo(runs, 20.0, MATCHED, alt=alt)
    _report("matched truth", mc, runs)
    lo6, hi6 = chi2_interval(6, runs)
    assert lo6 < mc["n6"] < hi6
    lo12, hi12 = chi2_interval(12, runs)
    assert lo12 < mc["n12"] < hi12
    assert mc["rmse_ant"] < 1.5 * mc["pcrb_ant"] and mc["rmse_body"] < 1.5 * mc["pcrb_body"]


@pytest.fixture(scope="module")
def deterministic_mc() -> dict:
    """30 seeds of phase-cross-h000 as the paper flies it (eq. 31, no random motion), 20 s, the
    scenario's own filter (shared by the two tests below, and its seeds 1..8 by the default
    consistency test of phase-cross-h000: the same runs)."""
    mc = _monte_carlo(30, 20.0)
    _report("eq. 31 truth", mc, 30)
    return mc


@pytest.mark.slow
def test_monte_carlo_cross_h000_deterministic_truth(deterministic_mc):
    """30 seeds of phase-cross-h000 as the paper flies it (eq. 31, no random motion), 20 s.

    At the final epoch over the 30 independent runs:
    - the NEES of the body position and velocity against the error covariance this filter really
      has on a truth without random acceleration (P_act, Gelb's covariance analysis: the eq. 31
      body moves at exactly constant velocity) is inside its 99 % chi-square interval;
    - the filter's own P is not overconfident for the body: P >= P_act, body ANEES below the 99 %
      upper limit;
    - RMSE of the antenna positions and of the body position <= 1.5 x the PCRB.
    """
    runs = 30
    mc = deterministic_mc
    lo6, hi6 = chi2_interval(6, runs)
    assert lo6 < mc["n6_act"] < hi6
    assert mc["P_minus_P_act_min"] > -1e-12
    assert mc["n6"] < hi6
    assert mc["rmse_ant"] < 1.5 * mc["pcrb_ant"] and mc["rmse_body"] < 1.5 * mc["pcrb_body"]


@pytest.mark.slow
def test_monte_carlo_cross_h000_deterministic_truth_18_state_not_overconfident(deterministic_mc):
    """The same 30 runs: the 18-state ANEES (antenna positions and velocities) below its 99 %
    upper limit, i.e. the filter's P not over-confident in any direction (Q > 0 and the truth has
    no random acceleration, but the antennas accelerate deterministically with the attitude).
    Held by the rotational process noise of the q rule's stage 2 (testbed.reproduce.phase_q,
    q_rotation = 1e-7 on this scenario, chosen on seeds 1000..1009 by the attitude NEES) and, at
    the rule's q = 1e-12 with the rigid prediction, by the centripetal term's input noise
    (estimators.phase_ekf, "Rigid rotation"); without it the 18-state ANEES was 35.2, without
    stage 2 (q_rotation = 0 at the earlier q = 1e-9) 43.1, against 20.95."""
    mc = deterministic_mc
    assert mc["n18"] < chi2_interval(18, 30)[1]


def test_attitude_nees_sees_the_attitude_and_not_a_common_shift_of_the_antennas():
    """PS.attitude_nees (the stage-2 quantity of the q rule): a translation of all antennas (and a
    common velocity error) is no attitude error; a yaw error d gives a NEES growing as d^2 and
    equal to d^2 / var(yaw) when the attitude covariance is diagonal in yaw."""
    from estimators.phase_model import antenna_state_from_body
    from estimators.so3 import rot_zyx

    p, v, Rd = np.array([10.0, -5.0, 3.0]), np.array([4.0, -4.0, 3.0]), np.zeros((3, 3))
    x_true = antenna_state_from_body(p, v, rot_zyx(0.2, -0.1, 0.05), Rd)
    cov = 1e-4 * np.eye(18)
    shifted = x_true + np.concatenate([np.tile([0.3, -0.2, 0.1], 3), np.tile([0.1, 0.0, -0.05], 3)])
    assert PS.attitude_nees(shifted, cov, x_true) < 1e-12
    n1 = PS.attitude_nees(antenna_state_from_body(p, v, rot_zyx(0.2 + 1e-3, -0.1, 0.05), Rd), cov, x_true)
    n2 = PS.attitude_nees(antenna_state_from_body(p, v, rot_zyx(0.2 + 2e-3, -0.1, 0.05), Rd), cov, x_true)
    assert n1 > 0 and n2 / n1 == pytest.approx(4.0, rel=0.01)
    # the angle error is wrapped: yaw pi - 1e-3 estimated as -pi + 1e-3 is a 2e-3 error, not 2 pi
    x_pi = antenna_state_from_body(p, v, rot_zyx(np.pi - 1e-3, -0.1, 0.05), Rd)
    n_pi = PS.attitude_nees(antenna_state_from_body(p, v, rot_zyx(-np.pi + 1e-3, -0.1, 0.05), Rd), cov, x_pi)
    assert n_pi == pytest.approx(n2, rel=0.05)


PHASE_SCENARIOS = [n for n in scenario_mod.builtin_names() if n.startswith("phase-")]
# Monte Carlo of the default-consistency test: runs per scenario and horizon, for the CI budget (8
# scenarios x 8 runs of 20 s); the horizon is the one the q rule was calibrated at, on other seeds.
CONSISTENCY_RUNS = 8
SHORT_HORIZON_S = 20.0  # s: the 20 s consistency test's horizon (deterministic_mc's)


def test_every_builtin_phase_scenario_is_listed_by_the_reproduction():
    from testbed.reproduce.phase import SCENARIOS

    assert sorted(SCENARIOS) == PHASE_SCENARIOS and len(PHASE_SCENARIOS) == 8


@pytest.mark.slow
@pytest.mark.parametrize("name", PHASE_SCENARIOS)
def test_default_ekf_is_consistent_on_every_builtin_phase_scenario(name, request):
    """Issue 15, defect 1: the DEFAULT filter of every built-in phase scenario (its own rate_rows
    and q, as shipped) is consistent on the scenario as flown (prescribed eq. 31 motion). Evaluation
    seeds 1..8 (the q rule used 1000..1009, testbed.reproduce.phase_q), horizon
    SHORT_HORIZON_S: the final-epoch NEES of the body position and velocity (6 dof; 5 where the
    masters lie along a line, the turn about it left out and reported apart: metrics.json `anees`)
    averaged over the independent runs lies inside the two-sided 95 % chi-square interval of
    chi2(dof runs) / runs. One test per scenario, each at 95 % (no family-wise correction: a stricter
    check of every scenario). phase-cross-h000's runs are the first 8 of deterministic_mc (the
    same scenario, seeds, horizon and filter), not computed twice."""
    if name == NAME:
        n6, dof = list(request.getfixturevalue("deterministic_mc")["n6_runs"][:CONSISTENCY_RUNS]), 6
    else:
        n6, dof, _ = _short_runs(name)
    sc = scenario_mod.load(name, seed=CONSISTENCY_RUNS, duration=SHORT_HORIZON_S)
    lo, hi = chi2_interval(dof, CONSISTENCY_RUNS, level=0.95)
    print(f"{name}: q = {sc.pipeline.q:g}, rate_rows {sc.pipeline.rate_rows}: ANEES body ({dof} dof) {np.mean(n6):.2f} "
          f"in [{lo:.2f}, {hi:.2f}] ({CONSISTENCY_RUNS} runs, {SHORT_HORIZON_S:g} s)")
    assert lo < np.mean(n6) < hi


def _body_nees_observed(r: dict) -> tuple[float, int, float | None]:
    """(final-epoch NEES, dof, turn) of the body position and velocity of a _filter result: 6 dof,
    or 5 where the masters lie along a line (estimators.phase_model.masters_line), the turn about it
    left out (PS.nees_along), as metrics.json `anees` does; turn: that turn's own NEES (1 dof; None
    without a line)."""
    B = PF.BODY_PV
    e, C = B @ (r["means"][-1] - r["states"][-1]), B @ r["covs"][-1] @ B.T
    line = masters_line(r["inp"].master_pos[-1], r["inp"].master_vel[-1])
    if line is None:
        return nees(e, C), 6, None
    n = line_rotation(*np.split(B @ r["means"][-1], 2), line)
    turn = PS.nees_along(e[None], C[None], n[None])[0]
    return nees(e, C) - turn, 5, turn


_SHORT_RUNS: dict[str, tuple] = {}  # scenario -> _short_runs', each scenario's runs simulated once


def _short_runs(name: str) -> tuple[list[float], int, list[float | None]]:
    """(body NEES per run, dof, the turn's NEES per run) of the default filter on scenario name,
    evaluation seeds 1..CONSISTENCY_RUNS, SHORT_HORIZON_S (_body_nees_observed)."""
    if name not in _SHORT_RUNS:
        runs = []
        for seed in range(1, CONSISTENCY_RUNS + 1):
            sc = scenario_mod.load(name, seed=seed, duration=SHORT_HORIZON_S)
            runs.append(_body_nees_observed(_filter(sc, simulate(sc)[0])))
        _SHORT_RUNS[name] = ([r[0] for r in runs], runs[0][1], [r[2] for r in runs])
    return _SHORT_RUNS[name]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: the turn about the masters' line of phase-line-h000 has final-epoch "
                   "NEES 6.98 on 1 dof over seeds 1-8 at 20 s (per run 2.40, 2.10, 27.7, 0.50, 0.02, 8.13, 0.27, 14.8) "
                   "against [0.27, 2.19]: the direction is reported apart (anees_unobserved) but its covariance is "
                   "over-confident after a bad start (docs/papers.md, seed 003, 'Line H000 over 200 s')")
def test_the_turn_about_the_masters_line_is_consistent():
    """Where the masters lie on a line (phase-line-h000), the turn about it that the body ANEES
    leaves out (test above) is judged on its own: the mean of its final-epoch NEES (1 dof) over the
    same independent runs lies inside the two-sided 95 % chi-square interval of chi2(runs) / runs."""
    _, _, turn = _short_runs("phase-line-h000")
    assert all(t is not None for t in turn)
    lo, hi = chi2_interval(1, CONSISTENCY_RUNS, level=0.95)
    print(f"phase-line-h000: the turn about the line (1 dof) {np.mean(turn):.2f} in [{lo:.2f}, {hi:.2f}]")
    assert lo < np.mean(turn) < hi


LONG_RUNS = 6  # evaluation seeds 1..6


@pytest.mark.skipif(not os.environ.get("PHASE_LONG"), reason="200 s runs: PHASE_LONG=1 pytest -s -k whole_run")
@pytest.mark.parametrize("name", PHASE_SCENARIOS)
def test_default_ekf_is_consistent_over_the_whole_run_of_every_builtin_phase_scenario(name):
    """The default filter of every built-in phase scenario over its whole 200 s run, evaluation
    seeds 1..LONG_RUNS (the q rule used 1000..1009 over the same horizon): the body ANEES of each
    run (metrics.json `anees`, t >= score_start; its `anees_dof`) averaged over the runs lies inside
    the 99 % interval over the runs (anees_over_runs, docs/consistency.md: the runs' effective samples
    pooled when every run is decidable from itself, else the Student t interval of the spread of the
    independent runs); where the masters lie on a line, the turn about it that they do not observe
    (`anees_unobserved`, 1 dof, reported apart) too. About 10 s of CPU a run, 8 minutes in all."""
    runs = []
    for seed in range(1, LONG_RUNS + 1):
        sc = scenario_mod.load(name, seed=seed)
        runs.append(score_ekf(sc, simulate(sc)[0]))
    a = anees_over_runs(runs, "anees")
    turn = anees_over_runs(runs, "anees_unobserved")
    per = [m["anees"] for m in runs]
    print(f"{name}, {sc.duration:g} s: body ANEES ({a['anees_dof']} dof) {a['anees']:.2f} in "
          f"{np.round(a['anees_interval_99'], 2).tolist()} (n_eff {a['n_eff']:.1f}, "
          f"{a.get('anees_interval_method', 'effective samples pooled')}); per run {np.round(per, 2).tolist()}, "
          f"n_eff {np.round([m['n_eff'] for m in runs], 1).tolist()}; attitude ANEES "
          f"{np.nanmean([m.get('anees_attitude6', np.nan) for m in runs]):.2f}"
          + (f"; the line's turn (1 dof) {turn['anees_unobserved']:.2f} in "
             f"{np.round(turn['anees_unobserved_interval_99'], 2).tolist()}" if turn else ""))
    assert sc.duration == 200.0
    intervals = [a["anees_interval_99"]] + ([turn["anees_unobserved_interval_99"]] if turn else [])
    if any(lo <= 0 for lo, _ in intervals):  # the runs' spread: an interval that reaches 0 cannot reject
        pytest.xfail(f"not decidable from {LONG_RUNS} runs: the interval over the runs' spread reaches 0 "
                     f"({[np.round(i, 2).tolist() for i in intervals]})")
    lo, hi = a["anees_interval_99"]
    assert lo < a["anees"] < hi
    if turn:
        lo, hi = turn["anees_unobserved_interval_99"]
        assert lo < turn["anees_unobserved"] < hi


def test_unrepaired_cycle_slip_is_rejected_by_the_gate_not_absorbed():
    """Corrupt the logged stream with a slip the sensor did not repair: +1 cycle (lambda = 2 m) on
    one link from t = 15 s on. The gate must reject that row at every later epoch, and the
    estimate must stay where the clean run's is (far inside the 2 m the slip would pull)."""
    sc = scenario_mod.load(NAME, duration=25.0)
    log, _ = simulate(sc)
    clean = _filter(sc, log)
    bad = dict(log)
    val = log["phase/value"].copy()
    t = log["phase/time"]
    m, i, j = 2, 1, 0  # master 2, slot 2 (lambda = 2 m), follower antenna 1
    rows = (np.arange(t.size) % 45 == 9 * (m - 1) + 3 * i + j) & (t >= 15.0)
    lam = log["phase/wavelength"][rows][0]
    assert lam == 2.0
    val[rows, 1] += lam
    bad["phase/value"] = val
    slipped = _filter(sc, bad)
    row = 18 * (m - 1) + 3 * i + j  # eq. 12/25 row of that range
    after = clean["inp"].times >= 15.0
    for info_c, info_s, late in zip(clean["infos"], slipped["infos"], after):
        if late:
            assert row in info_s.rejected
        assert row not in info_c.rejected
    # not absorbed: the final estimate differs from the clean run's (which has one row more per
    # epoch) by well under its own sigma, component by component; absorbing 2 m would be ~100 sigma
    d = np.abs(slipped["means"][-1] - clean["means"][-1]) / np.sqrt(np.diag(clean["covs"][-1]))
    print(f"max |slipped - clean| / sigma = {d.max():.3f}")
    assert d.max() < 0.5
    # and the run-level metric reports it
    metrics = score_ekf(sc, bad)
    assert metrics["rejected_measurements"] >= after.sum()


def test_run_directory_metrics_plots_and_reproducibility(tmp_path):
    from testbed.runner import run

    sc = scenario_mod.load(NAME, duration=12.0, seed=4)
    m1 = run(sc, tmp_path / "a")
    m2 = run(sc, tmp_path / "b", plots=False)  # the same metrics without its figures
    assert (tmp_path / "a" / "metrics.json").read_text() == (tmp_path / "b" / "metrics.json").read_text()
    ekf = json.loads((tmp_path / "a" / "metrics.json").read_text())["estimators"]["ekf"]
    for key in ("rmse_position_after_start_m", "rmse_velocity_after_start_m_s", "rmse_attitude_after_start_deg", "anees",
                "anees_state18", "anees_body6_actual_cov", "pcrb_rmse_position_after_start_m"):
        assert np.isfinite(ekf[key]), key
    # a 12 s run does not cover the 100 s window: no window score under a name it would not deserve
    assert not any("last_100s" in k for k in ekf) and ekf["last_window_s"] == 100.0
    assert "shorter than last_window" in ekf["last_window_omitted_reason"]
    assert {"covariance_repairs", "rejected_measurements", "nonconverged_steps", "gate_epochs_with_rejection"} <= set(ekf["health"])
    assert (tmp_path / "a" / "plots" / "ekf_position_error.png").stat().st_size > 10_000
    assert (tmp_path / "a" / "plots" / "ekf_velocity_error.png").stat().st_size > 10_000
    assert m1 == m2
    # after 12 s on the cross the body position is at the cm level, and the covariances are SPD
    assert ekf["rmse_position_m"] < 0.1


def test_paper_initial_error_option_applies_the_mapped_fixed_error():
    sc = scenario_mod.load(NAME, duration=1.0, overrides={"pipeline.init": '"paper"'})
    log, _ = simulate(sc)
    r = _filter(sc, log)
    err = r["err0"]
    # same body error on every antenna: paper (x, y, z) -> ours (x, -z, y)
    for j in range(3):
        assert np.allclose(err[3 * j:3 * j + 3], [-1.335, 1.68219, -1.621], atol=1e-9)
        assert np.allclose(err[9 + 3 * j:12 + 3 * j], [0.8186, -0.7415, 0.6861], atol=1e-9)
    assert is_spd(r["P0"])
    # drawn (default) differs per seed and is reproducible per seed
    a = PB.initial_prior(scenario_mod.load(NAME, seed=3).pipeline, sc, r["inp"], stream_rng(3, "init"))[2]
    b = PB.initial_prior(scenario_mod.load(NAME, seed=3).pipeline, sc, r["inp"], stream_rng(3, "init"))[2]
    c = PB.initial_prior(scenario_mod.load(NAME, seed=3).pipeline, sc, r["inp"], stream_rng(4, "init"))[2]
    assert np.array_equal(a, b) and not np.allclose(a, c)


def test_flown_mode_nav_frame_from_master_antennas():
    """Flown: master 3's pose comes from its own antennas; the filter tracks the flown follower."""
    sc = scenario_mod.load(NAME, duration=12.0, motion="flown")
    log, _ = simulate(sc)
    assert PB.process_noise_model(sc.pipeline, sc.motion).antenna == sc.pipeline.q_flown
    metrics = score_ekf(sc, log)
    assert metrics["rmse_position_after_start_m"] < 0.1 and metrics["rmse_attitude_after_start_deg"] < 5.0


def test_flown_line_h000_keeps_the_tangential_velocity():
    """The line of masters at one height cannot see rotation about the line (ranges and rates are
    blind to it); only the curvature of the ranges gives the follower's velocity across the
    line. A flown follower started at eq. 31's attitude (pitched 10 deg, which a quadrotor cannot
    hold at constant velocity) levelled itself in the first second and the filter, on that
    transient, locked onto a wrong velocity (error 4.8 m/s, then defended by its gate). The flown
    start is now the flat attitude: the body velocity NEES at 20 s is below the chi-square(3)
    0.999 quantile (16.3), with no row rejected."""
    sc = scenario_mod.load("phase-line-h000", duration=20.0, motion="flown")
    log, _ = simulate(sc)
    r = _filter(sc, log)
    B = PF.BODY_PV[3:]
    e = B @ (r["means"][-1] - r["states"][-1])
    n3 = nees(e, B @ r["covs"][-1] @ B.T)
    rejected = sum(i.rejected.size for i in r["infos"])
    assert rejected == r["track"].rejected_measurements.sum()  # the driver's health count
    print(f"velocity error {e.round(4)} m/s, NEES {n3:.2f}, rejected rows {rejected}")
    assert n3 < 16.27 and rejected == 0


@pytest.mark.parametrize("key,value", [("pipeline.rate_rows", '"sometimes"'), ("pipeline.q", "-1.0"),
                                       ("pipeline.iterations", "0"), ("pipeline.init", '"zero"')])
def test_bad_pipeline_values_are_one_line_config_errors(key, value):
    with pytest.raises(ConfigError) as e:
        scenario_mod.load(NAME, overrides={key: value})
    assert key.split(".")[1] in str(e.value) and "\n" not in str(e.value)


def test_window_scores_are_named_by_the_window_they_cover():
    """pipeline.last_window = 5 s on an 8 s run: the window scores are `*_last_5s_*`, computed over
    exactly the epochs t >= t_last - 5 s; no `last_100s` name appears."""
    sc = scenario_mod.load(NAME, duration=8.0, overrides={"pipeline.last_window": "5.0"})
    log, _ = simulate(sc)
    metrics = score_ekf(sc, log)
    keys = PS.window_keys(5.0)
    assert keys["rmse"] == "rmse_position_last_5s_m" and not any("last_100s" in k for k in metrics)
    r = _filter(sc, log)
    t, e = r["inp"].times, r["means"] @ PF.BODY_PV.T - r["body"][:, :6]
    last = t >= t[-1] - 5.0 + 1e-9
    assert 0 < last.sum() < t.size
    # phase.ekf's estimates are in the world, scored back in N with the true nav pose: round-off
    # (measured <= 1.2e-11 relative against the filter's own N frame) below the 1e-9 of the golden values
    np.testing.assert_allclose(metrics[keys["max_abs_position"]], np.abs(e[last, :3]).max(axis=0), rtol=1e-9)
    assert metrics[keys["rmse"]] == pytest.approx(float(np.sqrt(np.mean(np.sum(e[last, :3] ** 2, axis=1)))), rel=1e-9)
    assert "last_window_omitted_reason" not in metrics
