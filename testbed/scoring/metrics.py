"""Scores shared by every pipeline: RMSE, attitude error on SO(3), NEES/ANEES, run statistics.

Conventions: errors are estimate minus truth; RMSE is the root of the mean over samples of the
squared error norm (the 3-D error for positions); attitude errors are the angle of the relative
rotation R_true^T R_est (never a difference of Euler angles or quaternions).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
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


def anees_interval(dof: int, samples: float, level: float = 0.99) -> tuple[float, float]:
    """Interval a consistent filter's ANEES falls in with probability `level`: the chi-square
    interval of `samples` independent NEES samples of `dof` degrees each (estimators.core.chi2_interval).
    For the NEES of a filter, whose errors are correlated in time, `samples` is their effective
    number (effective_samples), not their count (docs/consistency.md)."""
    return chi2_interval(dof, samples, level)


def autocovariance_sums(x: np.ndarray) -> np.ndarray:
    """(T,) the sums S_k = sum_i d_i d_{i+k}, k = 0 .. T - 1, of d = x - mean(x), x (T,) (FFT,
    zero-padded: the linear, not circular, autocovariance). Series of one process add up."""
    x = np.asarray(x, float)
    n = x.size
    d = x - x.mean()
    f = np.fft.rfft(d, 2 * n)
    return np.fft.irfft(f * np.conj(f), 2 * n)[:n]


def geyer_time(acov: np.ndarray) -> float:
    """Integrated autocorrelation time tau = 1 + 2 sum_{k>=1} rho_k (in lags) of autocovariance sums
    acov (K,) (autocovariance_sums, or their sum over series of one process), rho_k = acov_k / acov_0,
    the sum truncated by Geyer's initial monotone sequence (pairs G_m = rho_2m + rho_2m+1 summed while
    positive, each capped by the one before). Returns tau >= 1 (1 when K < 4 or acov_0 = 0)."""
    n = acov.size
    if n < 4 or not acov[0] > 0:
        return 1.0
    rho = acov / acov[0]
    pairs = rho[0 : n - 1 : 2] + rho[1:n:2]  # G_m, m = 0 .. n//2 - 1
    stop = np.flatnonzero(pairs <= 0)
    pairs = np.minimum.accumulate(pairs[: stop[0] if stop.size else pairs.size])
    return max(1.0, float(2 * pairs.sum() - 1))


def integrated_time(x: np.ndarray) -> float:
    """Integrated autocorrelation time tau = 1 + 2 sum_{k>=1} rho_k of a stationary series x (T,)
    in its index (docs/consistency.md): rho_k its sample autocorrelation at lag k (FFT), the sum
    truncated by Geyer's initial monotone sequence (geyer_time). Returns tau >= 1 (1 for a constant
    series or T < 4)."""
    x = np.asarray(x, float)
    if x.size < 4 or not np.any(x - x.mean()):
        return 1.0
    return geyer_time(autocovariance_sums(x))


def effective_samples(ne: np.ndarray, instant: np.ndarray | None = None, target: np.ndarray | None = None) -> float:
    """Effective number of independent samples behind the ANEES (mean of the finite entries) of
    NEES samples ne (T,) of one target in time order, or (T, m) of m targets at T common instants
    (NaN: no sample of that target at that instant), or (N,) samples with instant (N,) int, the
    index of each sample's instant in time order, and target (N,) int, its target's (the same
    layout without the T x m array): n_eff with Var(ANEES) = 2 dof / n_eff for a consistent
    estimator, so that anees_interval(dof, n_eff) holds (docs/consistency.md):

        n_eff = min(N, T / (tau_y r), sum_i T_i / tau_i),   r = Var(y) / mean_i Var(ne_i)

    y (T,) the per-instant mean over the targets, tau_y its integrated_time, r the share of a
    single target's variance the per-instant mean keeps (1/m for independent targets, 1 for
    targets that share their errors: a cooperative filter's), N the number of samples; T_i / tau_i
    the effective samples of target i alone, whose sum (the targets taken as independent) bounds
    n_eff when the targets' instants do not coincide (then y interleaves them and hides their own
    correlation). Scale free: an over-confident filter's NEES, scaled up, gets the same n_eff.
    0 for no sample.
    """
    x = np.asarray(ne, float)
    if instant is None:
        x = x.reshape(len(x), -1)
        instant, target = np.nonzero(np.isfinite(x))
        x = x[instant, target]
    keep = np.isfinite(x)
    x, instant, target = x[keep], np.asarray(instant)[keep], np.asarray(target)[keep]
    if x.size < 2:
        return float(x.size)
    _, at = np.unique(instant, return_inverse=True)
    y = np.bincount(at, x) / np.bincount(at)  # (T,) the per-instant mean
    order = np.lexsort((instant, target))  # by target, each in time order
    series = np.split(x[order], np.flatnonzero(np.diff(target[order])) + 1)
    var = np.array([s.var() for s in series])
    r = float(np.var(y) / var.mean()) if var.mean() > 0 else 1.0
    alone = sum(s.size / integrated_time(s) for s in series)
    return float(min(x.size, y.size / (integrated_time(y) * max(r, 1.0 / len(series))), alone))


def runs_effective_samples(n_eff: np.ndarray) -> float:
    """Effective samples of the mean over R independent runs (their own seeds) of per-run ANEES
    with effective samples n_eff (R,): R^2 / sum(1 / n_eff), from Var = (2 dof / R^2) sum 1/n_eff.
    Independent-sample arithmetic is right here: runs share no noise (docs/consistency.md)."""
    n = np.asarray(n_eff, float)
    return float(n.size**2 / np.sum(1.0 / n))


def anees_keys(ne: np.ndarray, dof: int, key: str = "anees", level: float = 0.99, **layout) -> dict:
    """metrics.json keys of the ANEES of NEES samples ne (at least one; layout of
    effective_samples, `layout` its instant and target): {key: the mean of the samples, KEY_dof:
    dof, KEY_interval_PCT: its interval at `level` (PCT = 100 level, e.g. anees_interval_99), the
    key with "anees" -> "n_eff": effective_samples}."""
    n_eff = effective_samples(ne, **layout)
    return {key: float(np.nanmean(ne)), f"{key}_dof": dof,
            f"{key}_interval_{round(100 * level)}": list(anees_interval(dof, n_eff, level)),
            key.replace("anees", "n_eff"): n_eff}


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
    """anees_keys of the mean over independent runs (their own seeds) of per-run ANEES: runs, each
    run's keys as anees_keys wrote them (KEY, KEY_dof and the n_eff key); the effective samples
    combined by runs_effective_samples. Runs without the key are left out; {} if none has it."""
    have = [r for r in runs if r.get(key) is not None]
    if not have:
        return {}
    dof = have[0][f"{key}_dof"]
    n_eff = runs_effective_samples(np.array([r[key.replace("anees", "n_eff")] for r in have]))
    return {key: float(np.mean([r[key] for r in have])), f"{key}_dof": dof,
            f"{key}_interval_{round(100 * level)}": list(anees_interval(dof, n_eff, level)),
            key.replace("anees", "n_eff"): n_eff}


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
