"""The ANEES interval of correlated NEES samples (testbed.scoring.metrics.sample_size, docs/consistency.md).

Errors of a filter are autocorrelated; the chi-square interval that counts every output as an
independent sample is far too narrow for them. Here the error is an AR(1) Gaussian sequence
e_k = a e_{k-1} + w_k (3-D) with its exact stationary covariance P = I, so its NEES e^T P^-1 e is
that of a consistent filter: its ANEES must fall in the interval built on the effective number of
samples at the stated rate, which the exact binomial (Clopper-Pearson) interval of the count over
SEQUENCES independent sequences checks; the interval that counts every sample rejects it far more
often. White noise (a = 0) gets nearly the independent interval. An error correlated over the
whole run (a line fitted to every position so far, tests.interval_coverage.line_fit_nees) is, as
a rule, not decidable from one run, and the decided runs keep the false-alarm rate at 1 - level.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from testbed.scoring.metrics import (COVERAGE_TOLERANCE_S, MIN_SPAN, anees_interval, anees_keys, anees_over_runs, coverage,
                                     integrated_time, runs_effective_samples, sample_size)
from testbed.scoring.stats import clopper_pearson
from tests.interval_coverage import judged, line_fit_nees


def effective_samples(ne: np.ndarray, **layout) -> float:
    """sample_size's n_eff."""
    return sample_size(ne, **layout).n_eff

SEQUENCES, STEPS, DOF, LEVEL = 400, 2000, 3, 0.99


def _ar1(a: float, rng: np.random.Generator, shape=(SEQUENCES, STEPS, DOF)) -> np.ndarray:
    """AR(1) errors (..., STEPS, DOF) along the steps axis, stationary with covariance I from k = 0."""
    w = rng.standard_normal(shape) * np.sqrt(1 - a * a)
    w[:, 0] = rng.standard_normal((shape[0],) + shape[2:])  # e_0 ~ N(0, I): stationary from the start
    return lfilter([1.0], [1.0, -a], w, axis=1)


def _inside(nees: np.ndarray, n: np.ndarray | float, nu: np.ndarray | float = np.inf) -> int:
    """How many sequences' ANEES (mean over axis 1) lie in anees_interval(DOF, n, LEVEL, nu)."""
    m = nees.mean(axis=1)
    n, nu = np.broadcast_to(n, m.shape), np.broadcast_to(nu, m.shape)
    return int(sum(lo <= x <= hi for x, lo, hi in ((x, *anees_interval(DOF, float(k), LEVEL, float(v)))
                                                   for x, k, v in zip(m, n, nu))))


def test_ar1_errors_fall_in_the_correlated_interval_at_the_stated_rate_and_the_independent_one_rejects_them():
    a = 0.9  # NEES autocorrelation a^(2k): tau = (1 + a^2) / (1 - a^2) = 9.5
    nees = (_ar1(a, np.random.default_rng(32)) ** 2).sum(axis=-1)  # P = I
    sizes = [sample_size(x) for x in nees]
    n_eff, nu = np.array([s.n_eff for s in sizes]), np.array([s.nu for s in sizes])
    tau = (1 + a * a) / (1 - a * a)
    assert abs(np.median(STEPS / n_eff) / tau - 1) < 0.1  # the estimated tau is the true one
    assert all(s.decidable for s in sizes)  # 2000 steps span about 210 correlation times
    new = clopper_pearson(_inside(nees, n_eff, nu), SEQUENCES, level=0.999, sided="two-sided")
    old = clopper_pearson(_inside(nees, STEPS), SEQUENCES, level=0.999, sided="two-sided")
    assert new.interval[0] <= LEVEL <= new.interval[1], new
    assert old.interval[1] < 0.8, old  # measured 0.59: the independent interval rejects a consistent filter


def test_white_nees_gets_nearly_the_independent_interval():
    nees = (np.random.default_rng(5).standard_normal((SEQUENCES, STEPS, DOF)) ** 2).sum(axis=-1)
    sizes = [sample_size(x) for x in nees]
    n_eff, nu = np.array([s.n_eff for s in sizes]), np.array([s.nu for s in sizes])
    assert np.all(n_eff <= STEPS)
    # tau - 1 is a sum of a few sample autocorrelations of white noise, each of std 1/sqrt(STEPS)
    assert np.median(STEPS / n_eff) < 1 + 6 / np.sqrt(STEPS)
    lo, hi = anees_interval(DOF, float(np.median(n_eff)), LEVEL, float(np.median(nu)))
    lo0, hi0 = anees_interval(DOF, STEPS, LEVEL)
    assert abs(hi - hi0) < 0.1 * (hi0 - DOF) and abs(lo - lo0) < 0.1 * (DOF - lo0)
    inside = clopper_pearson(_inside(nees, n_eff, nu), SEQUENCES, level=0.999, sided="two-sided")
    assert inside.interval[0] <= LEVEL <= inside.interval[1], inside


def test_targets_sharing_their_errors_count_once_independent_ones_count_each():
    """Per-instant samples of m targets: m independent targets give m times the samples of one;
    m targets with one common error (a cooperative filter's) give those of one."""
    rng = np.random.default_rng(7)
    m, a = 6, 0.8
    e = _ar1(a, rng, (m, STEPS, DOF))  # (m, T, 3): m independent targets
    indep = (e**2).sum(-1).T  # (T, m)
    shared = np.repeat(indep[:, :1], m, axis=1)
    one = effective_samples(indep[:, 0])
    assert abs(effective_samples(indep) / (m * one) - 1) < 0.25
    assert effective_samples(shared) == pytest.approx(one)
    # a target without a sample at an instant (NaN) is left out of that instant's mean
    holes = indep.copy()
    holes[::2, 0] = np.nan
    assert 0.7 * effective_samples(indep) < effective_samples(holes) <= np.isfinite(holes).sum()
    # targets whose instants never coincide (one sample per row): still about m times one, not T m
    staggered = np.full((STEPS * m, m), np.nan)
    for i in range(m):
        staggered[i::m, i] = indep[:, i]
    assert abs(effective_samples(staggered) / (m * one) - 1) < 0.25
    # the sparse layout (sample, its instant, its target) is the same as the (T, m) array
    rows, cols = np.nonzero(np.isfinite(holes))
    assert effective_samples(holes[rows, cols], instant=rows * 7, target=cols) == pytest.approx(effective_samples(holes))


def test_scale_free_and_edge_cases():
    nees = (_ar1(0.7, np.random.default_rng(3), (1, 500, DOF))[0] ** 2).sum(-1)
    assert effective_samples(10 * nees) == pytest.approx(effective_samples(nees))
    assert integrated_time(np.full(10, 3.0)) == 1.0
    assert effective_samples(np.array([2.0])) == 1.0
    keys = anees_keys(nees, DOF, "anees_position", 0.95)
    s = sample_size(nees)
    assert keys["anees_position"] == pytest.approx(nees.mean()) and keys["n_eff_position"] == s.n_eff
    assert keys["n_eff_nu_position"] == s.nu and s.decidable
    assert keys["anees_position_interval_95"] == list(anees_interval(DOF, s.n_eff, 0.95, s.nu))
    # an estimated n_eff (finite nu) widens the interval around DOF, a count does not
    lo, hi = anees_interval(DOF, 50.0, 0.99, 10.0)
    lo0, hi0 = anees_interval(DOF, 50.0, 0.99)
    assert lo < lo0 < DOF < hi0 < hi
    assert runs_effective_samples(np.array([100.0, 100.0, 100.0])) == pytest.approx(300.0)
    assert runs_effective_samples(np.array([10.0, 1000.0])) == pytest.approx(4 / (0.1 + 0.001))


def test_coverage_counts_the_truth_instants_near_an_estimate():
    """Truth at 100 Hz over 10 s, estimates at 2 Hz from 4 s on, with a gap from 6 to 8 s: covered
    are the instants within 0.5 s of an estimate, from 3.5 s on minus the gap's inside."""
    truth = np.arange(1001) / 100.0
    est = np.concatenate([np.arange(4.0, 6.01, 0.5), np.arange(8.0, 10.01, 0.5)])
    c = coverage(truth, est)
    expected = np.mean([any(abs(t - e) <= 0.5 + 1e-12 for e in est) for t in truth])
    assert c["coverage"] == pytest.approx(expected, abs=2e-3)  # the 1e-12 at the ends: one instant each
    assert c["rate_hz"] == pytest.approx((est.size - 1) / 6.0) and c["first_estimate_s"] == 4.0
    assert c["coverage_tolerance_s"] == COVERAGE_TOLERANCE_S == 0.5
    full = coverage(truth, np.arange(0.0, 10.01, 1.0))
    assert full["coverage"] == 1.0 and full["rate_hz"] == pytest.approx(1.0)
    none = coverage(truth, np.zeros(0))
    assert none["coverage"] == 0.0 and none["rate_hz"] is None and none["first_estimate_s"] is None
    assert set(none["null_reasons"]) == {"rate_hz", "first_estimate_s"}


def test_runs_are_independent_samples():
    """The independent-sample arithmetic across runs (runs_effective_samples, anees_run_interval,
    one final NEES per seed) rests on runs sharing no noise: run i draws every stream from
    rng.stream_rng(seed + i, name). Over RUNS consecutive seeds, per stream: the lag-1 correlation
    of consecutive runs' draws and the lag-1 autocorrelation of a per-run value (the mean of a
    chi-square-3 NEES series, a stand-in for a per-run ANEES) are consistent with 0 (4 sigma)."""
    from testbed.rng import stream_rng

    runs, n = 60, 3000
    for name in ("uwb", "gnss", "imu", "camera", "phase", "init", "links", "disturbance"):
        draws = np.array([stream_rng(1 + i, name).standard_normal(n) for i in range(runs)])  # (runs, n)
        pair = np.mean([np.corrcoef(draws[i], draws[i + 1])[0, 1] for i in range(runs - 1)])
        assert abs(pair) < 4 / np.sqrt(n * (runs - 1)), (name, pair)
        per_run = (draws.reshape(runs, -1, 3) ** 2).sum(-1).mean(1)  # (runs,) ANEES of white 3-dof NEES
        d = per_run - per_run.mean()
        rho1 = float(d[:-1] @ d[1:] / (d @ d))
        assert abs(rho1) < 4 / np.sqrt(runs), (name, rho1)


def test_an_error_correlated_over_the_whole_run_is_not_decidable_from_one_run():
    """The filter of a line fitted to every position so far (no process noise, the exact model of its
    truth): its error is correlated over the whole run, which the within-run autocorrelation cannot
    measure (the sample mean absorbs it). The rule (span >= MIN_SPAN) declares most runs not
    decidable (measured: 9 % decided, tests.interval_coverage), the runs it decides fall outside at
    most at 1 - level (exact binomial), and the former interval (Geyer's tau, every run judged) rejects many (measured 8 %).
    Across the runs, the spread of the per-run values decides (anees_over_runs)."""
    runs = 300
    nees = line_fit_nees(runs, 500, np.random.default_rng(11))
    span, inside = judged(nees)
    decided = span >= MIN_SPAN
    assert decided.mean() < 0.25, decided.mean()
    alarm = clopper_pearson(int(np.sum(decided & ~inside)), runs, level=0.999, sided="two-sided")
    assert alarm.interval[0] <= 1 - LEVEL, alarm
    old = _inside(nees, np.array([nees.shape[1] / integrated_time(x) for x in nees]))  # Geyer's tau, every run judged
    assert clopper_pearson(runs - old, runs, level=0.999, sided="two-sided").interval[0] > 1 - LEVEL, runs - old
    keys = [anees_keys(x, DOF) for x in nees[:20]]
    undecided = [k for k in keys if k["anees_interval_99"] is None]
    assert undecided and all(k["anees_null_reason"].startswith("not decidable from one run") for k in undecided)
    pooled = anees_over_runs(keys, "anees")
    lo, hi = pooled["anees_interval_99"]
    assert lo < DOF < hi and pooled["n_eff_nu"] == 19 and "spread" in pooled["anees_interval_method"]
    assert anees_over_runs(undecided[:1], "anees")["anees_interval_99"] is None


def test_only_the_scoring_module_builds_an_anees_interval_from_its_parts():
    """One method (docs/consistency.md): outside testbed.scoring.metrics no module of testbed/ takes
    the chi-square interval or the runs' pooled effective samples directly, which would skip the rule
    (MIN_SPAN) and the nu widening (eq. C3); each goes through anees_keys, anees_over_runs or
    anees_interval. The check can fail: a planted import is found."""
    import ast
    from pathlib import Path

    parts = {"chi2_interval", "runs_effective_samples"}

    def takes(source: str) -> set[str]:
        if not any(w in source for w in parts):  # parse only the files that name one
            return set()
        return parts & set().union(*({a.name for a in node.names} if isinstance(node, ast.ImportFrom) else
                                     {node.attr} if isinstance(node, ast.Attribute) else set()
                                     for node in ast.walk(ast.parse(source))))

    assert takes("from estimators.core import chi2_interval\n") == {"chi2_interval"}
    root = Path(__file__).resolve().parents[1] / "testbed"
    offenders = {str(p.relative_to(root)): got for p in sorted(root.rglob("*.py"))
                 if p.relative_to(root).as_posix() != "scoring/metrics.py" and (got := takes(p.read_text()))}
    assert offenders == {}
