"""Statistical tests that decide the paper claims of the reproductions (`testbed reproduce`).

Every test returns a `TestResult`: the test's name, its statistic, the p-value and/or a
confidence interval, the sample size n and the level, so that a verdict line can show all of them.

- Orderings ("A better than B"): `wilcoxon_paired` (Wilcoxon signed-rank on the paired per-run
  differences, scipy.stats.wilcoxon, exact for small n without ties). Chosen over the paired t test
  because per-run RMSEs are positive and right-skewed (a few bad runs), so their differences are
  far from normal at the 10-50 runs of a reproduction; the signed-rank test needs only symmetric
  differences and keeps its level. `paired_t` is kept for scores that are sums of many terms.
- "About equal": `tost_log_ratio`, two one-sided paired t tests (TOST, Schuirmann 1987) on the
  per-run log ratios log(a_i / b_i) against +-log(margin): equal within the margin when both
  one-sided nulls are rejected at alpha, i.e. the (1 - 2 alpha) interval of the mean log ratio lies
  inside the band. The log makes "25 % either way" symmetric and the ratios of RMSEs near normal.
- Bounds ("within +-L"): `clopper_pearson` interval of the probability that a run violates the
  bound, from the count of violations among n runs (exact binomial).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import beta as beta_dist
from scipy.stats import t as student_t
from scipy.stats import wilcoxon


@dataclass(frozen=True, kw_only=True, slots=True)
class TestResult:
    """One statistical test. test: its name; statistic: the test statistic (NaN if it cannot
    exist, e.g. n < 2); p_value: NaN for an interval-only result; interval: (lo, hi) confidence
    interval of the tested quantity at `level` or None; n: sample size (runs); level: confidence
    level of the interval (1 - alpha of the decision)."""

    __test__ = False  # not a pytest test class

    test: str
    statistic: float
    p_value: float
    n: int
    level: float
    interval: tuple[float, float] | None = None

    def claim_fields(self) -> dict:
        """The verdict fields of a testbed.outputs.report.Claim (test, statistic, p_value, interval, n, level);
        an interval-only test has p_value None."""
        return {"test": self.test, "statistic": self.statistic,
                "p_value": None if math.isnan(self.p_value) else self.p_value, "interval": self.interval,
                "n": self.n, "level": self.level}

    def to_json(self) -> dict:
        return {"test": self.test, "statistic": self.statistic, "p_value": self.p_value, "n": self.n,
                "level": self.level, "interval": list(self.interval) if self.interval is not None else None}


def paired_t(a: np.ndarray, b: np.ndarray, *, alternative: str = "less", level: float = 0.95) -> TestResult:
    """Paired t test of mean(a - b) (alternative "less": a < b; "greater"; "two-sided"), with the
    matching (one- or two-sided) Student-t confidence interval of the mean difference at `level`."""
    d = np.asarray(a, float) - np.asarray(b, float)
    n = int(d.size)
    if n < 2 or not np.all(np.isfinite(d)):
        return TestResult(test="paired t", statistic=math.nan, p_value=math.nan, n=n, level=level)
    m, se = float(d.mean()), float(d.std(ddof=1) / math.sqrt(n))
    if se == 0.0:
        tstat = math.copysign(math.inf, m) if m != 0 else math.nan
    else:
        tstat = m / se
    df = n - 1
    if alternative == "less":
        p = float(student_t.cdf(tstat, df))
        ci = (-math.inf, m + float(student_t.ppf(level, df)) * se)
    elif alternative == "greater":
        p = float(student_t.sf(tstat, df))
        ci = (m - float(student_t.ppf(level, df)) * se, math.inf)
    else:
        p = float(2 * student_t.sf(abs(tstat), df))
        h = float(student_t.ppf(0.5 + level / 2, df)) * se
        ci = (m - h, m + h)
    return TestResult(test=f"paired t ({alternative})", statistic=tstat, p_value=p, n=n, level=level, interval=ci)


def wilcoxon_paired(a: np.ndarray, b: np.ndarray, *, alternative: str = "less", level: float = 0.95) -> TestResult:
    """Wilcoxon signed-rank test of the paired differences a - b (scipy.stats.wilcoxon; "less":
    a tends to be smaller than b). statistic: the sum of the ranks of the positive differences
    (W+). No interval. With fewer than 2 non-zero differences the test cannot be made (NaN)."""
    d = np.asarray(a, float) - np.asarray(b, float)
    n = int(d.size)
    if np.count_nonzero(d) < 2 or not np.all(np.isfinite(d)):
        return TestResult(test=f"Wilcoxon signed-rank ({alternative})", statistic=math.nan, p_value=math.nan,
                          n=n, level=level)
    r = wilcoxon(d, alternative=alternative)
    return TestResult(test=f"Wilcoxon signed-rank ({alternative})", statistic=float(r.statistic),
                      p_value=float(r.pvalue), n=n, level=level)


def tost_log_ratio(a: np.ndarray, b: np.ndarray, *, margin: float, alpha: float = 0.05) -> TestResult:
    """Equivalence of paired positive scores a, b (runs,) within the ratio band [1/margin, margin]:
    TOST of the mean of log(a/b) against +-log(margin) with paired t tests at alpha each.
    p_value: max of the two one-sided p-values (equivalent when < alpha); statistic: the smaller of
    the two t statistics; interval: the (1 - 2 alpha) interval of the ratio exp(mean log(a/b))."""
    name = f"TOST paired t on log ratio, margin x{margin:g}"
    x = np.log(np.asarray(a, float)) - np.log(np.asarray(b, float))
    n = int(x.size)
    if n < 2 or not np.all(np.isfinite(x)):
        return TestResult(test=name, statistic=math.nan, p_value=math.nan, n=n, level=1 - 2 * alpha)
    delta = math.log(margin)
    lower = paired_t(x, np.full(n, -delta), alternative="greater")  # H0: mean <= -delta
    upper = paired_t(x, np.full(n, delta), alternative="less")      # H0: mean >= +delta
    m, se = float(x.mean()), float(x.std(ddof=1) / math.sqrt(n))
    h = float(student_t.ppf(1 - alpha, n - 1)) * se
    return TestResult(test=name, statistic=min(lower.statistic, -upper.statistic),
                      p_value=max(lower.p_value, upper.p_value), n=n, level=1 - 2 * alpha,
                      interval=(math.exp(m - h), math.exp(m + h)))


def clopper_pearson(k: int, n: int, *, level: float = 0.95, sided: str = "upper") -> TestResult:
    """Exact binomial (Clopper-Pearson) interval of a probability from k successes in n trials.
    sided "upper": one-sided (0, hi) at `level`; "two-sided": (lo, hi) at `level`. statistic: k / n."""
    if n < 1:
        return TestResult(test="Clopper-Pearson", statistic=math.nan, p_value=math.nan, n=0, level=level)
    a = 1 - level if sided == "upper" else (1 - level) / 2
    lo = 0.0 if sided == "upper" or k == 0 else float(beta_dist.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta_dist.ppf(1 - a, k + 1, n - k))
    return TestResult(test=f"Clopper-Pearson ({sided})", statistic=k / n, p_value=math.nan, n=n, level=level,
                      interval=(lo, hi))
