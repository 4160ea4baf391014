"""Scores shared by every pipeline: RMSE, attitude error on SO(3), NEES/ANEES, run statistics.

Conventions: errors are estimate minus truth; RMSE is the root of the mean over samples of the
squared error norm (the 3-D error for positions); attitude errors are the angle of the relative
rotation R_true^T R_est (never a difference of Euler angles or quaternions).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import norm
from scipy.stats import t as student_t

from estimators.core import chi2_interval


def rmse(err: np.ndarray, axis: int = 0) -> np.ndarray | float:
    """sqrt(mean over `axis` of |e|^2), the norm taken over the last axis. err: (K, d) or (K, ..., d)."""
    val = np.sqrt(np.mean(np.sum(np.asarray(err) ** 2, axis=-1), axis=axis))
    return float(val) if np.ndim(val) == 0 else val


def attitude_error_deg(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """Angle (deg) of R_true^T R_est for wxyz quaternions (..., 4); shape (...)."""
    r_est = Rotation.from_quat(np.reshape(q_est, (-1, 4)), scalar_first=True)
    r_true = Rotation.from_quat(np.reshape(q_true, (-1, 4)), scalar_first=True)
    return np.degrees((r_true.inv() * r_est).magnitude()).reshape(np.shape(q_est)[:-1])


def attitude_error_vector(R_est: np.ndarray, R_true: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of R_true^T R_est for rotation matrices (..., 3, 3): (..., 3)."""
    rel = Rotation.from_matrix(np.reshape(np.swapaxes(R_true, -1, -2) @ R_est, (-1, 3, 3)))
    return rel.as_rotvec().reshape(*np.shape(R_est)[:-2], 3)


#: The fewest correlation times the NEES series behind a per-run ANEES must span for its interval to be
#: decided from that run (docs/consistency.md, "Decidable from one run"; derived on AR(1) series by
#: `python -m tests.interval_coverage`): below it the run's interval is null, "not decidable from one run"
MIN_SPAN = 20.0


def anees_interval(dof: int, samples: float, level: float = 0.99, nu: float = np.inf) -> tuple[float, float]:
    """Interval a consistent filter's ANEES falls in with probability `level`: the chi-square
    interval of `samples` independent NEES samples of `dof` degrees each (estimators.core.chi2_interval),
    its distances to dof widened by t_nu / z (Student and normal quantiles at `level`) when `samples` is
    an estimate with nu degrees of freedom (docs/consistency.md, eq. C3). For the NEES of a filter,
    whose errors are correlated in time, `samples` is their effective number (sample_size), not their
    count; nu = inf: a known number (independent samples)."""
    lo, hi = chi2_interval(dof, samples, level)
    if not np.isfinite(nu):
        return lo, hi
    q = 0.5 + level / 2
    # eq. C3 (docs/consistency.md)
    f = float(student_t.ppf(q, nu) / norm.ppf(q))
    return dof - f * (dof - lo), dof + f * (hi - dof)


def autocovariance_sums(x: np.ndarray) -> np.ndarray:
    """(T,) the sums S_k = sum_i d_i d_{i+k}, k = 0 .. T - 1, of d = x - mean(x), x (T,) (FFT,
    zero-padded: the linear, not circular, autocovariance). Series of one process add up."""
    x = np.asarray(x, float)
    n = x.size
    d = x - x.mean()
    f = np.fft.rfft(d, 2 * n)
    return np.fft.irfft(f * np.conj(f), 2 * n)[:n]


def _geyer(acov: np.ndarray) -> tuple[float, int]:
    """(tau, W) of geyer_time: tau >= 1 and W, the number of lags -W/2 .. W/2 its sum covers (1 when
    nothing is summed)."""
    n = acov.size
    if n < 4 or not acov[0] > 0:
        return 1.0, 1
    rho = acov / acov[0]
    pairs = rho[0 : n - 1 : 2] + rho[1:n:2]  # G_m, m = 0 .. n//2 - 1
    stop = np.flatnonzero(pairs <= 0)
    pairs = np.minimum.accumulate(pairs[: stop[0] if stop.size else pairs.size])
    return max(1.0, float(2 * pairs.sum() - 1)), max(1, 4 * pairs.size - 1)


def geyer_time(acov: np.ndarray) -> float:
    """Integrated autocorrelation time tau = 1 + 2 sum_{k>=1} rho_k (in lags) of autocovariance sums
    acov (K,) (autocovariance_sums, or their sum over series of one process), rho_k = acov_k / acov_0,
    the sum truncated by Geyer's initial monotone sequence (pairs G_m = rho_2m + rho_2m+1 summed while
    positive, each capped by the one before). Returns tau >= 1 (1 when K < 4 or acov_0 = 0)."""
    return _geyer(acov)[0]


def integrated_time(x: np.ndarray) -> float:
    """Integrated autocorrelation time tau = 1 + 2 sum_{k>=1} rho_k of a stationary series x (T,)
    in its index (docs/consistency.md): rho_k its sample autocorrelation at lag k (FFT), the sum
    truncated by Geyer's initial monotone sequence (geyer_time). Returns tau >= 1 (1 for a constant
    series or T < 4)."""
    x = np.asarray(x, float)
    if x.size < 4 or not np.any(x - x.mean()):
        return 1.0
    return geyer_time(autocovariance_sums(x))


def _series_time(x: np.ndarray) -> tuple[float, float]:
    """(tau_c, nu) of one NEES series x (T,) in time order: Geyer's tau corrected for the bias the
    sample mean gives it, and the degrees of freedom of that estimate (docs/consistency.md, eqs. C1-C2):

        tau_c = tau / (1 - (W - tau) / T)   (at most T),      nu = T / W

    W the lags Geyer's sum covers. A constant series or T < 4: (1, T)."""
    x = np.asarray(x, float)
    n = x.size
    if n < 4 or not np.any(x - x.mean()):
        return 1.0, float(n)
    tau, w = _geyer(autocovariance_sums(x))
    # eq. C1 (tau_c) and eq. C2 (nu), docs/consistency.md
    den = 1.0 - (w - tau) / n
    return (min(tau / den, float(n)) if den > 0 else float(n)), n / w


@dataclass(frozen=True, slots=True)
class SampleSize:
    """How many independent samples a run's NEES are worth (sample_size). n_eff: effective samples
    (Var(ANEES) = 2 dof / n_eff); nu: degrees of freedom of that estimate (inf: a count, exact);
    span: correlation times covered by the shortest series that sets n_eff (inf: independent samples);
    decidable: span >= MIN_SPAN, one run can decide the interval."""

    n_eff: float
    nu: float
    span: float

    @property
    def decidable(self) -> bool:
        return self.span >= MIN_SPAN


def sample_size(ne: np.ndarray, instant: np.ndarray | None = None, target: np.ndarray | None = None) -> SampleSize:
    """Effective number of independent samples behind the ANEES (mean of the finite entries) of
    NEES samples ne (T,) of one target in time order, or (T, m) of m targets at T common instants
    (NaN: no sample of that target at that instant), or (N,) samples with instant (N,) int, the
    index of each sample's instant in time order, and target (N,) int, its target's (the same
    layout without the T x m array): n_eff with Var(ANEES) = 2 dof / n_eff for a consistent
    estimator, so that anees_interval(dof, n_eff, level, nu) holds (docs/consistency.md):

        n_eff = min(N, T / (tau_y r), sum_i T_i / tau_i),   r = Var(y) / mean_i Var(ne_i)

    y (T,) the per-instant mean over the targets, tau_y its bias-corrected time (_series_time), r
    the share of a single target's variance the per-instant mean keeps (1/m for independent
    targets, 1 for targets that share their errors: a cooperative filter's), N the number of
    samples; T_i / tau_i the effective samples of target i alone, whose sum (the targets taken as
    independent) bounds n_eff when the targets' instants do not coincide (then y interleaves them
    and hides their own correlation). nu and span are those of the term that sets n_eff: T / W_y
    and T / tau_y; for the sum, the Satterthwaite combination (sum s_i)^2 / sum (s_i^2 / nu_i) and
    the shortest min_i T_i / tau_i; for N, inf. Scale free: an over-confident filter's NEES,
    scaled up, gets the same n_eff. (0, inf, 0) for no sample, (1, inf, inf) for one.
    """
    x = np.asarray(ne, float)
    if instant is None:
        x = x.reshape(len(x), -1)
        instant, target = np.nonzero(np.isfinite(x))
        x = x[instant, target]
    keep = np.isfinite(x)
    x, instant, target = x[keep], np.asarray(instant)[keep], np.asarray(target)[keep]
    if x.size < 2:
        return SampleSize(float(x.size), np.inf, np.inf if x.size else 0.0)
    _, at = np.unique(instant, return_inverse=True)
    y = np.bincount(at, x) / np.bincount(at)  # (T,) the per-instant mean
    order = np.lexsort((instant, target))  # by target, each in time order
    series = np.split(x[order], np.flatnonzero(np.diff(target[order])) + 1)
    var = np.array([s.var() for s in series])
    r = float(np.var(y) / var.mean()) if var.mean() > 0 else 1.0
    tau_y, nu_y = _series_time(y)
    times = [_series_time(x_i) for x_i in series]
    own = np.array([(x_i.size / t, nu) for x_i, (t, nu) in zip(series, times)])  # (m, 2): T_i / tau_i, nu_i
    alone = float(own[:, 0].sum())
    terms = [SampleSize(float(x.size), np.inf, np.inf),
             SampleSize(y.size / (tau_y * max(r, 1.0 / len(series))), nu_y, y.size / tau_y),
             SampleSize(alone, satterthwaite(own[:, 0], own[:, 1]), float(own[:, 0].min()))]
    return min(terms, key=lambda s: s.n_eff)


def satterthwaite(s: np.ndarray, nu: np.ndarray) -> float:
    """Degrees of freedom of a sum of independent estimates s (m,), each with nu (m,) degrees of
    freedom (Satterthwaite): (sum s)^2 / sum(s^2 / nu); inf when every nu is inf (exact counts)."""
    spread = float(np.sum(np.asarray(s, float) ** 2 / np.asarray(nu, float)))
    return float(np.sum(s)) ** 2 / spread if spread > 0 else np.inf


def runs_effective_samples(n_eff: np.ndarray) -> float:
    """Effective samples of the mean over R independent runs (their own seeds) of per-run ANEES
    with effective samples n_eff (R,): R^2 / sum(1 / n_eff), from Var = (2 dof / R^2) sum 1/n_eff.
    Independent-sample arithmetic is right here: runs share no noise (docs/consistency.md)."""
    n = np.asarray(n_eff, float)
    return float(n.size**2 / np.sum(1.0 / n))


def anees_keys(ne: np.ndarray, dof: int, key: str = "anees", level: float = 0.99, **layout) -> dict:
    """metrics.json keys of the ANEES of NEES samples ne (at least one; layout of sample_size,
    `layout` its instant and target): {key: the mean of the samples, KEY_dof: dof, KEY_interval_PCT:
    its interval at `level` (PCT = 100 level, e.g. anees_interval_99), the key with "anees" ->
    "n_eff": sample_size's n_eff, "anees" -> "n_eff_nu": its nu}. A run whose series spans fewer
    than MIN_SPAN correlation times has the interval null and KEY_null_reason saying why."""
    s = sample_size(ne, **layout)
    out = {key: float(np.nanmean(ne)), f"{key}_dof": dof,
           f"{key}_interval_{round(100 * level)}": list(anees_interval(dof, s.n_eff, level, s.nu)) if s.decidable else None,
           key.replace("anees", "n_eff"): s.n_eff, key.replace("anees", "n_eff_nu"): _json_float(s.nu)}
    if not s.decidable:
        out[f"{key}_null_reason"] = (f"not decidable from one run: its NEES span {s.span:.3g} correlation times, "
                                     f"fewer than {MIN_SPAN:g}")
    return out


def anees_interval_at(keys: dict, key: str, level: float) -> list[float] | None:
    """KEY's interval at another `level` from the keys anees_keys wrote (KEY_dof, the n_eff and
    n_eff_nu keys); None where the run is not decidable (KEY_null_reason)."""
    if f"{key}_null_reason" in keys:
        return None
    nu = keys.get(key.replace("anees", "n_eff_nu"))
    return list(anees_interval(keys[f"{key}_dof"], keys[key.replace("anees", "n_eff")], level, np.inf if nu is None else nu))


def _json_float(v: float) -> float | None:
    """v, or None for inf (strict JSON; an n_eff_nu of None: a count of independent samples, exact)."""
    return float(v) if np.isfinite(v) else None


def anees_run_interval(per_run: np.ndarray, dof: int, level: float = 0.99) -> tuple[float, float]:
    """Interval the mean of R per-run ANEES values falls in with probability `level` for a
    consistent estimator whose NEES samples are dependent within a run (a constant per-run error such
    as a radio's antenna delay makes every epoch of the run share it, so the chi-square interval of
    anees_interval, which counts K R independent samples, is too narrow).

    per_run: (R,) ANEES of each run (runs independent: their own seeds); dof: NEES degrees of
    freedom (the expected value of every per-run ANEES). Returns dof -+ t s / sqrt(R), s the sample
    standard deviation of per_run, t the Student quantile with R - 1 degrees of freedom (a per-run
    ANEES is a mean over many epochs, close to normal). R >= 2, else ValueError.
    """
    x = np.asarray(per_run, float)
    if x.size < 2:
        raise ValueError(f"anees_run_interval: needs at least 2 runs, got {x.size}")
    h = float(student_t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return dof - h, dof + h


def mean_ci(x: np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and Student-t confidence interval (lo, hi) of independent samples x (n,)."""
    x = np.asarray(x, float)
    m = float(x.mean())
    if x.size < 2:
        return m, m, m
    h = float(student_t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return m, m - h, m + h


def network_summary(stats: dict[str, float], **extra: float) -> dict:
    """The `network` object of metrics.json from testbed.sim.network.Network.stats() (and extra counts
    such as `late`): counts and bytes as integers, latencies in s; strict JSON: a latency or a
    fraction that cannot exist (nothing was sent or queued) is null with the reason beside it."""
    out: dict = {}
    why = {}
    for k, v in {**stats, **extra}.items():
        if k.startswith("latency_") or k == "drop_fraction":
            out[k] = None if np.isnan(v) else float(v)
            if out[k] is None:
                why[k] = "no message was sent" if k == "drop_fraction" else "no message was queued"
        else:
            out[k] = int(v)
    if why:
        out["null_reasons"] = why
    return out


def ranging_rate(log: dict[str, np.ndarray], duration: float) -> float | None:
    """UWB links served per second by a [sensors.uwb.schedule] (two-way exchanges, lost or not)
    over a run of `duration` s; None when the run has no schedule (every link every sample)."""
    if "uwb/served" not in log:
        return None
    return float(log["uwb/served"].sum()) / duration


def anees_over_runs(runs: list[dict], key: str, level: float = 0.99) -> dict:
    """anees_keys of the mean over R independent runs (their own seeds) of per-run ANEES: runs, each
    run's keys as anees_keys wrote them (KEY, KEY_dof, the n_eff and n_eff_nu keys, KEY_null_reason
    when one run cannot decide). When every run decides: the effective samples combined by
    runs_effective_samples, their degrees of freedom by Satterthwaite's rule, (sum 1/n_i)^2 / sum
    (1/n_i)^2 / nu_i. When a run cannot: the spread of the per-run values decides (anees_run_interval;
    n_eff 2 dof R / s^2 and nu = R - 1 the ones it implies, KEY_interval_method says so), and with
    R = 1 the interval is null with the run's reason (docs/consistency.md, "Several runs"). Runs
    without the key are left out; {} if none has it."""
    have = [r for r in runs if r.get(key) is not None]
    if not have:
        return {}
    dof, pct = have[0][f"{key}_dof"], round(100 * level)
    per_run = np.array([r[key] for r in have])
    out = {key: float(per_run.mean()), f"{key}_dof": dof}
    n, nu = key.replace("anees", "n_eff"), key.replace("anees", "n_eff_nu")
    undecided = [r[f"{key}_null_reason"] for r in have if f"{key}_null_reason" in r]
    if not undecided:
        inv = 1.0 / np.array([r[n] for r in have])
        dofs = np.array([np.inf if r.get(nu) is None else r[nu] for r in have], float)
        n_eff, v = runs_effective_samples(1.0 / inv), satterthwaite(inv, dofs)
        return {**out, f"{key}_interval_{pct}": list(anees_interval(dof, n_eff, level, v)), n: n_eff, nu: _json_float(v)}
    if len(have) == 1:
        return {**out, f"{key}_interval_{pct}": None, n: have[0][n], nu: have[0].get(nu), f"{key}_null_reason": undecided[0]}
    var = float(per_run.var(ddof=1))
    return {**out, f"{key}_interval_{pct}": list(anees_run_interval(per_run, dof, level)),
            n: _json_float(2 * dof * len(have) / var if var > 0 else np.inf), nu: len(have) - 1,
            f"{key}_interval_method": (f"spread of the {len(have)} per-run values (Student t): "
                                       f"{len(undecided)} of {len(have)} runs not decidable from one run")}


#: Coverage tolerance (s): a truth instant is covered when an estimate lies at most this far from it
COVERAGE_TOLERANCE_S = 0.5


def coverage(truth_time: np.ndarray, time: np.ndarray, tolerance: float = COVERAGE_TOLERANCE_S) -> dict:
    """How much of a run an estimator covered for one target (docs/consistency.md, "Coverage").

    truth_time (N,) s: the instants the target's truth is known at (sorted); time (K,) s: its
    estimates' times (sorted). Returns {"coverage": fraction of truth instants with an estimate
    within `tolerance` s, "coverage_tolerance_s", "rate_hz": the output rate while it estimates,
    (K - 1) over the span of its estimates (gaps and a late start show in the coverage), and
    "first_estimate_s": time of the first estimate}; rate_hz is null for fewer than two estimate
    times, first_estimate_s for no estimate (strict JSON; the reasons under "null_reasons")."""
    tt, ts = np.asarray(truth_time, float), np.asarray(time, float)
    out: dict = {"coverage": 0.0, "coverage_tolerance_s": tolerance, "rate_hz": None, "first_estimate_s": None}
    why = {}
    if ts.size:
        j = np.clip(np.searchsorted(ts, tt), 1, max(ts.size - 1, 1))
        near = np.minimum(np.abs(tt - ts[j - 1]), np.abs(ts[np.minimum(j, ts.size - 1)] - tt))
        out["coverage"] = float(np.mean(near <= tolerance)) if tt.size else 0.0
        out["first_estimate_s"] = float(ts[0])
    else:
        why["first_estimate_s"] = "no estimate"
    span = float(ts[-1] - ts[0]) if ts.size > 1 else 0.0
    if span > 0:
        out["rate_hz"] = (ts.size - 1) / span
    else:
        why["rate_hz"] = "fewer than two estimate times"
    if why:
        out["null_reasons"] = why
    return out
