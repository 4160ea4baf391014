"""testbed.scoring.stats against scipy and closed forms on known cases."""
import math

import numpy as np
import pytest
from scipy import stats as ss

from testbed.scoring import stats


@pytest.mark.parametrize("alternative", ["less", "greater", "two-sided"])
def test_paired_t_equals_scipy_ttest_rel(alternative):
    rng = np.random.default_rng(1)
    a, b = rng.normal(1.0, 0.3, 15), rng.normal(1.1, 0.3, 15)
    r = stats.paired_t(a, b, alternative=alternative, level=0.9)
    ref = ss.ttest_rel(a, b, alternative=alternative)
    ci = ref.confidence_interval(0.9)
    assert r.statistic == pytest.approx(ref.statistic, rel=1e-12)
    assert r.p_value == pytest.approx(ref.pvalue, rel=1e-10)
    assert r.interval == pytest.approx((ci.low, ci.high), rel=1e-10)
    assert r.n == 15 and r.level == 0.9


def test_paired_t_of_one_run_cannot_exist():
    r = stats.paired_t([1.0], [2.0])
    assert math.isnan(r.statistic) and math.isnan(r.p_value) and r.n == 1


def test_wilcoxon_exact_known_case():
    """Five runs, a smaller in every one: W+ = 0, exact one-sided p = 1 / 2^5."""
    a = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    r = stats.wilcoxon_paired(a, a + np.array([0.1, 0.5, 0.2, 0.4, 0.3]), alternative="less")
    assert r.statistic == 0.0 and r.p_value == pytest.approx(1 / 32, rel=1e-12) and r.n == 5
    # one difference of the other sign, the smallest rank: W+ = 1, p = 2 / 32
    r = stats.wilcoxon_paired(a, a + np.array([-0.1, 0.5, 0.2, 0.4, 0.3]), alternative="less")
    assert r.statistic == 1.0 and r.p_value == pytest.approx(2 / 32, rel=1e-12)


def test_tost_equals_two_one_sided_scipy_tests():
    rng = np.random.default_rng(2)
    b = rng.uniform(0.01, 0.03, 20)
    a = b * np.exp(rng.normal(0.05, 0.08, 20))
    r = stats.tost_log_ratio(a, b, margin=1.25, alpha=0.05)
    x, d = np.log(a / b), math.log(1.25)
    p_lo = ss.ttest_1samp(x, -d, alternative="greater").pvalue
    p_hi = ss.ttest_1samp(x, d, alternative="less").pvalue
    assert r.p_value == pytest.approx(max(p_lo, p_hi), rel=1e-10) and r.p_value < 0.05
    ci = ss.ttest_1samp(x, 0.0).confidence_interval(0.90)
    assert r.interval == pytest.approx((math.exp(ci.low), math.exp(ci.high)), rel=1e-10)
    assert r.level == pytest.approx(0.90)
    # a 1.5x difference is not equivalent within x1.25
    far = stats.tost_log_ratio(1.5 * b * np.exp(rng.normal(0, 0.02, 20)), b, margin=1.25)
    assert far.p_value > 0.5


def test_clopper_pearson_known_values():
    r = stats.clopper_pearson(0, 20, level=0.95)  # one-sided: 1 - 0.05^(1/20)
    assert r.interval[0] == 0.0 and r.interval[1] == pytest.approx(1 - 0.05 ** (1 / 20), rel=1e-10)
    two = stats.clopper_pearson(3, 20, level=0.95, sided="two-sided")
    ci = ss.binomtest(3, 20).proportion_ci(0.95, method="exact")
    assert two.interval == pytest.approx((ci.low, ci.high), rel=1e-10) and two.statistic == 0.15
    assert stats.clopper_pearson(20, 20).interval[1] == 1.0
