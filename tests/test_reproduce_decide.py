"""The decide step of the reproductions on hand-made numbers (no runs): each claim follows its
stated criterion, and claims.json is strict JSON even when a statistic cannot exist."""
import json

import numpy as np
import pytest

from testbed.reproduce import phase, visnav
from testbed.outputs.report import NULL_SUFFIX, write_claims


def _ekf_scores(max_abs_pos: float, rmse: float, rng: np.random.Generator) -> dict:
    """One run's EKF scores with the keys phase.decide reads."""
    return {
        "last_window_s": 100.0,
        "max_abs_position_error_last_100s_m": [max_abs_pos] * 3,
        "max_abs_velocity_error_last_100s_mps": [0.001] * 3,
        "rmse_position_last_100s_m": rmse * (1 + 0.01 * rng.standard_normal()),
        "position_error_final_m": [0.1 * (1 + 0.1 * rng.random()), 0.001, 0.1 * (1 + 0.1 * rng.random())],
        "position_error_mid_m": [0.01, 0.001, 0.01],
        "pcrb_sigma_position_final_m": [0.01, 0.01, 0.01],
    }


def _phase_runs(runs: int, cross_max: float) -> dict[str, list[dict]]:
    rng = np.random.default_rng(0)
    rmse = {"phase-line-h600": 0.01, "phase-line-h100": 0.02, "phase-vobtuse-h600": 0.015,
            "phase-vobtuse-h100": 0.02, "phase-vobtuse-h000": 0.02, "phase-vacute-h000": 0.02}
    return {name: [_ekf_scores(cross_max if name == "phase-cross-h000" else 0.02, rmse.get(name, 0.02), rng)
                   for _ in range(runs)] for name in phase.SCENARIOS}


def test_phase_claims_follow_their_criteria():
    claims = {c.id: c for c in phase.decide(_phase_runs(20, cross_max=0.005))}
    assert list(claims)[:3] == [
        "line-h000-xy-diverge-z-accurate", "line-h000-velocity", "cross-h000-0.01"]
    assert claims["cross-h000-0.01"].holds and claims["line-h000-velocity"].holds
    assert claims["line-h000-xy-diverge-z-accurate"].holds
    assert claims["v-h000-equal"].holds and claims["vobtuse-h100-equal-h000"].holds  # TOST, ratio 1 +- 1 %
    assert claims["line-h600-better"].holds  # 0.01 vs 0.02 m over 20 paired runs
    assert claims["vobtuse-h600-slightly-better"].holds  # ratio 0.75
    assert claims["v-h000-0.03"].holds  # 0.02 < 0.03 m in every run
    for c in claims.values():  # every verdict names its test, its sample size and a p-value or interval
        assert c.criterion and c.summary and c.test and c.n == 20, c.id
        assert c.p_value is not None or c.interval is not None, c.id
    cp = claims["cross-h000-0.01"]
    assert cp.test.startswith("Clopper-Pearson") and cp.interval[1] == pytest.approx(1 - 0.05 ** (1 / 20))
    assert claims["line-h600-better"].test.startswith("Wilcoxon") and claims["line-h600-better"].p_value < 1e-5
    assert claims["v-h000-equal"].test.startswith("TOST")
    worse = {c.id: c for c in phase.decide(_phase_runs(20, cross_max=0.02))}
    assert not worse["cross-h000-0.01"].holds
    assert worse["cross-h000-0.01"].numbers["violations"] == 20
    # too few runs to show a bound: no violation in 10 runs gives an upper bound 0.26 > 0.15
    few = {c.id: c for c in phase.decide(_phase_runs(10, cross_max=0.005))}
    assert not few["cross-h000-0.01"].holds and few["cross-h000-0.01"].numbers["violations"] == 0
    assert "not reachable with 10 runs" in few["cross-h000-0.01"].summary  # and the verdict says so
    assert "not reachable" not in claims["cross-h000-0.01"].summary  # 20 runs can show it
    # "about equal" fails when the ratio is 1.5 (outside the x1.25 margin)
    R = _phase_runs(20, cross_max=0.005)
    R["phase-vacute-h000"] = [dict(r, rmse_position_last_100s_m=1.5 * r["rmse_position_last_100s_m"])
                              for r in R["phase-vacute-h000"]]
    assert not {c.id: c for c in phase.decide(R)}["v-h000-equal"].holds


def test_phase_claims_of_one_run_are_strict_json(tmp_path):
    """With one run the paired t test has no statistic: the verdict is False and claims.json says why."""
    claims = phase.decide(_phase_runs(1, cross_max=0.005))
    better = next(c for c in claims if c.id == "line-h600-better")
    assert better.holds is False
    write_claims(tmp_path / "claims.json", claims, paper="003", runs=1)
    text = (tmp_path / "claims.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    doc = json.loads(text)
    numbers = next(c for c in doc["claims"] if c["id"] == "line-h600-better")["numbers"]
    assert numbers["p_value"] is None and numbers["p_value" + NULL_SUFFIX]
    test = next(c for c in doc["claims"] if c["id"] == "line-h600-better")["test"]
    assert test["n"] == 1 and test["p_value"] is None


def _visnav_results(runs: int, glint_scale: list[float], rng: np.random.Generator, glints: float = 0.1) -> list[dict]:
    def case(scale):
        return {"metrics": {n: {k: s * (1 + 0.05 * rng.random()) for k, _, _ in visnav.QUANTITIES}
                            for n, s in zip(visnav.FILTERS, scale)}, "glint_fraction": glints}
    return [{"glint": case(glint_scale), "gaussian": case([1.0] * 5)} for _ in range(runs)]


def test_visnav_claims_are_decided_by_their_named_tests():
    rng = np.random.default_rng(3)
    ok = visnav.decide(visnav.VisnavResults(results=_visnav_results(12, [5, 5, 4, 3, 2], rng), extra={}, meta={}))
    assert [c.holds for c in ok] == [True, True]
    assert ok[0].test.startswith("9 x Wilcoxon") and ok[0].n == 12 and ok[0].p_value < 0.05 / 9
    assert "non-inferiority" in ok[1].test and ok[1].p_value < 0.025
    # MCKF no better than HCKF: the ordering fails; the robust filters 20 % worse: the cost claim fails
    bad = _visnav_results(12, [5, 5, 4, 4, 2], rng)
    for r in bad:
        for k, _, _ in visnav.QUANTITIES:
            r["gaussian"]["metrics"]["rhcf"][k] *= 1.2
    no = visnav.decide(visnav.VisnavResults(results=bad, extra={}, meta={}))
    assert [c.holds for c in no] == [False, False]
    assert [c.not_decidable for c in ok + no] == [""] * 4


def test_visnav_glint_ordering_is_not_decidable_without_a_glint():
    rng = np.random.default_rng(3)
    res = visnav.VisnavResults(results=_visnav_results(12, [5, 5, 4, 3, 2], rng, glints=0.0), extra={}, meta={})
    glint, cost = visnav.decide(res)
    assert glint.not_decidable.startswith("no glint outlier") and glint.to_json()["holds"] is None
    assert not cost.not_decidable and cost.holds  # the Gaussian case needs no event


def _sweep_rows(anees: dict[float, list[float]]) -> list[dict]:
    """Sweep rows of phase_q with the given body ANEES per q (one per seed)."""
    return [{"scenario": "s", "seed": 1000 + i, "q": q, "nees_body6_final": 6.0, "anees": a, "rmse_position_m": 0.01,
             "pcrb_rmse_position_m": 0.01, "rmse": 0.008, "pcrb_rmse": 0.009, "max_abs_position": [0.01, 0.02, 0.01]}
            for q, values in anees.items() for i, a in enumerate(values)]


def test_phase_q_rule_picks_the_anees_closest_to_dof_on_a_log_scale(tmp_path):
    from testbed.reproduce import phase_q

    # means 14 / 7 / 4.5 / 2.5: |ln(7/6)| = 0.15 < |ln(4.5/6)| = 0.29 -> 1e-9
    rows = _sweep_rows({1e-13: [13.0, 15.0], 1e-11: [6.0, 8.0], 1e-9: [4.0, 5.0], 1e-7: [2.0, 3.0]})
    assert phase_q.anees_by_q(rows) == {1e-13: 14.0, 1e-11: 7.0, 1e-9: 4.5, 1e-7: 2.5}
    assert phase_q.choose(rows) == 1e-11
    # a log-scale tie (3 and 12 are both a factor 2 from 6): the larger q
    assert phase_q.choose(_sweep_rows({1e-13: [12.0], 1e-9: [3.0]})) == 1e-9
    # the figure is written, with and without the full-duration sweep
    path = phase_q.plot({"s": rows}, {"s": 1e-11}, tmp_path / "q_sweep.png", horizon=20.0)
    assert path.stat().st_size > 10_000
    path = phase_q.plot({"s": rows}, {"s": 1e-11}, tmp_path / "q_sweep_long.png", horizon=20.0, long=rows)
    assert path.stat().st_size > 10_000
    short = [{k: v for k, v in r.items() if k not in ("rmse", "pcrb_rmse", "max_abs_position")} for r in rows]
    path = phase_q.plot({"s": rows}, {"s": 1e-11}, tmp_path / "q_sweep_short.png", horizon=4.0, long=short)
    assert path.stat().st_size > 10_000


def test_phase_q_stage_2_picks_the_attitude_anees_closest_to_dof_and_ignores_the_body_nees():
    """Stage 2 of the rule: q_rotation by the attitude ANEES over the run (6 dof), 0 allowed in the
    grid; the body ANEES (stage 1's quantity) does not enter; a seed whose attitude was never
    observed (no attitude ANEES) is left out of the mean."""
    from testbed.reproduce import phase_q

    # attitude means 20 / 9 / 5 / 2.5: |ln(5/6)| = 0.18 < |ln(9/6)| = 0.41 -> 1e-7; body NEES all 6
    att = {0.0: [18.0, 22.0], 1e-8: [8.0, 10.0], 1e-7: [4.0, 6.0], 1e-6: [2.0, 3.0]}
    rows = [{"q": 1e-9, "q_rotation": qr, "anees": 6.0 if qr != 1e-7 else 60.0, "anees_attitude6": a}
            for qr, values in att.items() for a in values]
    rows.append({"q": 1e-9, "q_rotation": 1e-7, "anees": 6.0, "anees_attitude6": float("nan")})
    assert phase_q.anees_by_q(rows, "q_rotation") == {0.0: 20.0, 1e-8: 9.0, 1e-7: 5.0, 1e-6: 2.5}
    assert phase_q.choose(rows, "q_rotation") == 1e-7
    # 0 can be the rule's value (a filter already consistent without rotational noise)
    assert phase_q.choose([{"q_rotation": 0.0, "anees_attitude6": 6.2},
                           {"q_rotation": 1e-8, "anees_attitude6": 4.0}], "q_rotation") == 0.0
    assert 0.0 in phase_q.QR_GRID and phase_q.RULE_NEES["q_rotation"] == ("anees_attitude6", 6)


def test_phase_q_stage_2_uses_the_body_at_the_smallest_q_where_the_attitude_is_unobserved(monkeypatch):
    """Stage 2 by the attitude runs at stage 1's q where stage 1's runs at that q observe the
    attitude at every scored epoch; elsewhere q = Q_GRID[0] and q_rotation is the value whose body
    ANEES (over its `anees_dof`, 5 here) is closest to that dof."""
    from testbed.reproduce import phase_q

    calls = []

    def fake_sweep(name, seeds=(), qs=(), *, q_rotations=None, runs=None, **kw):
        calls.append((tuple(qs), tuple(q_rotations)))
        return [{"q": q, "q_rotation": qr, "anees": (6.0 if q == 1e-9 else 3.0) if qr == 0.0 else (5.0 if qr == 1e-5 else 12.0),
                 "anees_dof": dof, "anees_attitude6": 6.0 if qr == 1e-7 else 20.0,
                 "attitude_unobserved_fraction": unobserved} for q in qs for qr in q_rotations]

    monkeypatch.setattr(phase_q, "simulate_seeds", lambda *a, **k: iter(()))
    monkeypatch.setattr(phase_q, "sweep", fake_sweep)
    unobserved, dof = 0.3, 5
    q, qr, rows1, rows2 = phase_q.calibrate("s")
    assert (q, qr) == (phase_q.Q_GRID[0], 1e-5) and calls[1] == ((phase_q.Q_GRID[0],), phase_q.QR_GRID)
    assert phase_q.rule(rows1, rows2) == (q, qr)
    unobserved, dof, calls[:] = 0.0, 6, []
    assert phase_q.calibrate("s")[:2] == (1e-9, 1e-7) and calls[1] == ((1e-9,), phase_q.QR_GRID)


def test_phase_q_command_refuses_an_unknown_scenario_in_one_line(capsys):
    from testbed.reproduce import phase_q

    assert phase_q.main(["phase-nope"]) == 2
    err = capsys.readouterr().err
    assert "phase-nope" in err and err.count("\n") == 1
