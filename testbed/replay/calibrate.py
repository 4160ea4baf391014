"""`testbed calibrate SPEC --window T0,T1 --out calib.toml`: a dataset's range bias, scale and noise,
and the estimators' process noise, estimated on a calibration segment with truth (docs/calibration.md).

Per uwb link l (its two ends, either order), over the rows i of the segment with truth at both ends
(d_i the true distance between the ends, m: a site is its body's true pose plus its lever arm, an
anchor its surveyed point), the measurement equation of docs/replay.md ("Range bias"):

    e_i = r_i - d_i = b_l + s_l d_i + n_i                                          (cal. 1)

fitted by weighted least squares, w_i = 1 / sigma_i^2 (the row's declared sigma, else 1), with the
variance of n_i unknown (one per link):

    [b, s] = (A^T W A)^-1 A^T W e,   A = [1, d],                                   (cal. 2)
    cov[b, s] = tau c (A^T W A)^-1,  c = sum_i w_i res_i^2 / (n - p)
    sigma_l^2 = sum_i res_i^2 / (n - p)                (the link's range noise, m)  (cal. 3)

tau >= 1 the integrated autocorrelation time (in rows) of the link's residuals in time order
(testbed.scoring.metrics.integrated_time, docs/consistency.md): residuals that stay correlated over
tau rows (multipath changing slowly with position) carry the information of n / tau independent
ones, so the least-squares covariance, which counts n, is widened by tau (1 for white residuals).

p = 2, or p = 1 (b alone: scale 0, no sigma_scale) for a link whose scale does not predict ranges
it was not fitted on (cal. 2b: two-fold cross-validation in time within the segment, each half
fitted with and without s and tested on the other; s is kept when it lowers the summed weighted
squared error of the held-out halves), is not significant (|s| <= z sigma_s, z the two-sided
normal quantile of family-wise false alarm SCALE_ALARM over the segment's links, Bonferroni) or
lies beyond the format's bound (MAX_SCALE). A scale error of the radios' clocks holds on every part
of the segment; a "scale" that fits one half's multipath does not carry over to the other half,
nor to the replay; and a scale is applied as a correction whose error no estimator carries. A kept
scale holds on the span [min d, max d] of the true distances it was fitted on (scale_from,
scale_to): on replay its correction is held at its value at the span's nearer end beyond it (cal. 2c,
testbed.replay.calibration), never extrapolated. The range noise
default of every estimator, pooled over the links:

    range_sigma^2 = sum_l sum_i res_i^2 / sum_l (n_l - p_l)                         (cal. 4)

The time over which the range errors stay correlated (s), for an estimator that averages ranges
over time (ranging.ekf's range_correlation): one integrated time tau_p (rows) of the links'
residuals pooled, S_l(k) = sum_i d_{l,i} d_{l,i+k} each link's autocovariance sums (its residuals
d_l in time order, mean removed), rho_k = sum_l S_l(k) / sum_l S_l(0), tau_p = 1 + 2 sum rho_k
(Geyer's truncation, testbed.scoring.metrics.geyer_time), in seconds by the links' row spacing dt_l
(median) weighted by their share of the error variance:

    range_correlation = tau_p sum_l rss_l dt_l / sum_l rss_l                        (cal. 8)

A filter that treats each range as independent is right when each range's variance is multiplied
by the rows its link makes within range_correlation (tau_p at the calibration's rate; 1 for white
errors). Pooled before truncation, not a mean of per-link taus: each tau_l >= 1 is truncated on
its own noisy autocorrelation, and their mean over white links of 50 rows is about 1.2.

Process noise (the constant-velocity model's white acceleration, density q per axis, m^2/s^3;
the same for the attitude, rad^2/s^3): truth sampled at spacing h has second differences
D_k = x_{k+1} - 2 x_k + x_{k-1} of variance (2/3) q h^3 per axis (cal. 5); taken at every second k
they are independent, so

    q(h) = sum D_k^2 / ((2/3) h^3 N)                                               (cal. 6)

over the N non-overlapping second differences of every axis of every body with truth (the
centroid of its sites, or its origin; the attitude's rotation vectors Log(R_k^T R_{k+1})), a
chi-square estimate with N degrees of freedom. Truth's own noise (motion capture jitter, sigma_t)
adds 6 sigma_t^2 to each D_k^2: q(h) falls as h^-3 (a factor 8 per doubling) where that noise
dominates and stays flat where the motion does. The rule: h the smallest of h_j = 2^j T (T the
median spacing of the segment's range epochs) with q(h_j) <= 2 q(h_{j+1}) (cal. 7), else the largest
with at least MIN_SAMPLES second differences.

Device biases (cal. 9, 9b: testbed.replay.device_bias): the links' biases split into a bias per
device (site or anchor) and each link's remainder, written as device rows when the device model
predicts links left out of its fit better than no device model does.

Device time offsets (cal. 10, 10b: testbed.replay.device_offset): r(t) = d(t + c), c = gamma_src +
gamma_dst, fitted on the residuals of cal. 2 against the true range rate (central differences over
+-T, T the segment's epoch spacing; [1, d] projected out, so b, s and gamma are the joint least
squares), kept where they predict held-out rows and differ from 0; then every link is fitted again
(cal. 1-4, 2b) on e - c rdot. A device offset beyond MAX_TIME_OFFSET_S is not written. Written as
device rows (time_offset, sigma_time_offset).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2, norm

from testbed.config import MIN_MAGNITUDE
from testbed.errors import ConfigError
from testbed.outdir import new_file
from testbed.replay.calibration import FILE_FORMAT, MAX_SCALE, MAX_TIME_OFFSET_S
from testbed.replay.device_bias import device_split
from testbed.replay.device_offset import device_offsets
from testbed.replay.recording import RecordedTruth, Recording, load_recording
from testbed.replay.spec import Window
from testbed.replay.tables import find
from testbed.scoring.metrics import autocovariance_sums, geyer_time, integrated_time

#: the fewest rows a link needs in the segment (two unknowns and one degree of freedom)
MIN_ROWS = 3
#: the family-wise false-alarm probability of the scales' significance test over a segment's links
#: (cal. 2b): a scale is applied as a correction whose error no estimator carries (it grows with
#: the range), so a spurious one must be rare
SCALE_ALARM = 0.05
#: the fewest second differences a spacing needs for its q (cal. 7)
MIN_SAMPLES = 16


@dataclass(frozen=True, slots=True)
class LinkFit:
    """One link's fit (cal. 1-3): ends, rows n, bias m, scale (0 when not fitted), their sigmas
    (sigma_scale NaN when not fitted), the range noise sigma m, the residuals' sum of squares, dof,
    integrated autocorrelation time tau (rows), the median spacing of the link's rows (s), the
    autocovariance sums of its residuals (testbed.scoring.metrics.autocovariance_sums, m^2), the
    residuals (n,) m in time order, the true range rate with [1, d] projected out (n,) m/s, and the
    span (scale_from, scale_to) m of the true distances fitted (cal. 2c; NaN when no scale)."""

    src: str
    dst: str
    samples: int
    bias: float
    scale: float
    sigma_bias: float
    sigma_scale: float
    sigma: float
    rss: float
    dof: int
    tau: float
    spacing: float
    acov: np.ndarray
    res: np.ndarray
    rate_perp: np.ndarray
    scale_from: float
    scale_to: float


def _wls(e: np.ndarray, d: np.ndarray, w: np.ndarray, cols: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(x (cols,), (A^T W A)^-1) of e = A x, A = [1, d][:, :cols] (cal. 2), None if A^T W A is singular."""
    A = np.stack([np.ones_like(d), d], axis=1)[:, :cols]
    N = A.T @ (w[:, None] * A)
    if e.size <= cols or np.linalg.matrix_rank(N) < cols:
        return None
    Ninv = np.linalg.inv(N)
    return Ninv @ (A.T @ (w * e)), Ninv


def scale_predicts(e: np.ndarray, d: np.ndarray, w: np.ndarray) -> bool:
    """Does the scale predict ranges it was not fitted on (cal. 2b)? Two-fold cross-validation in
    time: each half of the rows (in time order) fitted with and without s, the weighted squared
    error of the fit on the other half summed; True when the fit with s has the smaller."""
    h = e.size // 2
    err = {1: 0.0, 2: 0.0}
    for fit, test in ((slice(0, h), slice(h, None)), (slice(h, None), slice(0, h))):
        for cols in (1, 2):
            sol = _wls(e[fit], d[fit], w[fit], cols)
            if sol is None:
                return False
            res = e[test] - np.stack([np.ones_like(d[test]), d[test]], axis=1)[:, :cols] @ sol[0]
            err[cols] += float(w[test] @ res ** 2)
    return err[2] < err[1]


@dataclass(frozen=True, slots=True)
class _Fit:
    """fit_link's result: b m, s (0 when not fitted), their sigmas (sigma_scale NaN when not fitted),
    the residuals (n,) m in time order, dof, integrated time tau (rows), autocovariance sums (n,) m^2,
    and the rate (n,) m/s with the columns [1, d] of the fit projected out (for cal. 10)."""

    bias: float
    scale: float
    sigma_bias: float
    sigma_scale: float
    res: np.ndarray
    dof: int
    tau: float
    acov: np.ndarray
    rate_perp: np.ndarray


def fit_link(e: np.ndarray, d: np.ndarray, w: np.ndarray, rate: np.ndarray, z: float = 0.0) -> _Fit:
    """The fit of e = b + s d + n (cal. 2-3) with weights w (n,), rows in time order; s = 0 (sigma
    NaN) when the scale does not predict (scale_predicts, cal. 2b), lies within z of its sigmas of 0
    (cal. 2b) or beyond the format's MAX_SCALE. rate (n,) m/s:
    the true range rate, returned with [1, d] projected out. ValueError when the rows cannot
    determine b."""
    # eq. cal. 2b: the scale only where it predicts held-out ranges and is significant
    for cols in ((2, 1) if scale_predicts(e, d, w) else (1,)):
        sol = _wls(e, d, w, cols)
        if sol is None or (cols == 2 and abs(sol[0][1]) > MAX_SCALE):
            continue
        x, Ninv = sol
        A = np.stack([np.ones_like(d), d], axis=1)[:, :cols]
        res = e - A @ x
        dof = e.size - A.shape[1]
        tau = integrated_time(res)
        # eq. cal. 2: the covariance of white residuals, widened by their correlation time
        sig = np.sqrt(np.diag(tau * float(w @ res ** 2) / dof * Ninv))
        if cols == 2 and abs(x[1]) <= z * sig[1]:
            continue
        perp = rate - A @ (Ninv @ (A.T @ (w * rate)))
        return _Fit(float(x[0]), float(x[1]) if cols == 2 else 0.0, float(sig[0]), float(sig[1]) if cols == 2 else float("nan"),
                    res, dof, tau, autocovariance_sums(res), perp)
    raise ValueError("fewer rows than unknowns")


@dataclass(frozen=True, slots=True)
class LinkRows:
    """One link's rows of the segment with truth at both ends, in time order: ends, the measured
    ranges value (n,) m, the true distance d (n,) m, the true range rate (n,) m/s (for cal. 10), the
    weights w (n,) 1/m^2 and the times (n,) s (window clock)."""

    src: str
    dst: str
    value: np.ndarray
    d: np.ndarray
    rate: np.ndarray
    w: np.ndarray
    time: np.ndarray


def link_rows(rec: Recording, truth: RecordedTruth, h: float) -> list[LinkRows]:
    """Every uwb link of the recording with MIN_ROWS or more rows with truth at both ends, sorted by
    ends, with the true distance (cal. 1) and range rate at its rows (central differences over +-h s,
    each end clipped to its body's truth span; for cal. 10)."""
    t = rec.tables["links"]
    time = t["time"] - rec.spec.window.start
    groups: dict[tuple[str, str], list[int]] = {}
    for i in np.flatnonzero(t["kind"] == "uwb").tolist():
        groups.setdefault(tuple(sorted((str(t["src"][i]), str(t["dst"][i])))), []).append(i)
    out = []
    for (a, b), rows in sorted(groups.items()):
        rows = np.array(rows)
        ok = np.ones(rows.size, bool)
        for end in (a, b):
            if end not in truth.anchors:
                lo, hi = truth.span.get(truth.body_of(end), (np.inf, -np.inf))
                ok &= (time[rows] >= lo) & (time[rows] <= hi)
        rows = rows[ok][np.argsort(time[rows[ok]], kind="stable")]
        if rows.size < MIN_ROWS:
            continue
        tr = time[rows]
        dist = lambda x: np.linalg.norm(truth.at(a, "position", x) - truth.at(b, "position", x), axis=1)  # noqa: E731
        lo = max([truth.span[truth.body_of(n)][0] for n in (a, b) if n not in truth.anchors], default=-np.inf)
        hi = min([truth.span[truth.body_of(n)][1] for n in (a, b) if n not in truth.anchors], default=np.inf)
        tm, tp = np.maximum(tr - h, lo), np.minimum(tr + h, hi)
        # the true range rate, central differences (cal. 10)
        rate = np.where(tp > tm, (dist(tp) - dist(tm)) / np.where(tp > tm, tp - tm, 1.0), 0.0)
        sigma = t["sigma"][rows]
        w = np.where(np.isfinite(sigma), 1.0 / np.where(np.isfinite(sigma), sigma, 1.0) ** 2, 1.0)
        # eq. cal. 1: d the true distance between the ends (lever arms included)
        out.append(LinkRows(a, b, t["value"][rows], dist(tr), rate, w, tr))
    return out


def link_fits(links: list[LinkRows], offsets: dict | None = None) -> list[LinkFit]:
    """The fit of every link of link_rows (cal. 1-3, cal. 2b's significance over the L links), those
    whose rows determine it. offsets {(src, dst): c s}: the fit of e - c rate (cal. 10: the biases and
    scales given the time offsets)."""
    # eq. cal. 2b: two-sided, family-wise false alarm SCALE_ALARM over the links
    z = float(norm.ppf(1.0 - SCALE_ALARM / (2 * max(len(links), 1))))
    out = []
    for k in links:
        try:
            c = (offsets or {}).get((k.src, k.dst), 0.0)
            # eq. cal. 1: e = r - d
            f = fit_link(k.value - k.d - c * k.rate, k.d, k.w, k.rate, z)
        except ValueError:
            continue
        rss = float(f.res @ f.res)
        # eq. cal. 2c: a scale holds on the span of true distances it was fitted on
        span = (float(k.d.min()), float(k.d.max())) if np.isfinite(f.sigma_scale) else (np.nan, np.nan)
        # eq. cal. 3: the link's range noise
        out.append(LinkFit(k.src, k.dst, int(k.value.size), f.bias, f.scale, f.sigma_bias, f.sigma_scale,
                           float(np.sqrt(rss / f.dof)), rss, f.dof, f.tau, float(np.median(np.diff(k.time))), f.acov, f.res,
                           f.rate_perp, *span))
    return out


def _second_differences(inc: np.ndarray) -> np.ndarray:
    """(K, 3) the non-overlapping second differences inc[1] - inc[0], inc[3] - inc[2], ... of the
    increments inc (L, 3) between consecutive samples (x[k+1] - x[k], or a rotation vector)."""
    k = inc.shape[0] // 2
    # eq. cal. 5: D_k = (x_{k+1} - x_k) - (x_k - x_{k-1}), every second k
    return inc[1::2][:k] - inc[0::2][:k]


def _tracks(rec: Recording, truth: RecordedTruth, g: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per body with truth over all of g (M,) (window clock s), the increments between consecutive
    samples: of the centroid of its sites (its origin without sites), (M - 1, 3) m world, and of
    its attitude, the rotation vectors Log(R_k^T R_{k+1}) (M - 1, 3) rad body."""
    out = []
    for body, (lo, hi) in truth.span.items():
        if g[0] < lo or g[-1] > hi:
            continue
        arms = [np.asarray(v[1], float) for v in rec.spec.sites.values() if v[0] == body]
        R = Rotation.from_quat(truth.at(body, "attitude", g), scalar_first=True)
        c = truth.at(body, "position", g) + R.apply(np.mean(arms, axis=0) if arms else np.zeros(3))
        out.append((np.diff(c, axis=0), (R[:-1].inv() * R[1:]).as_rotvec()))
    return out


def process_noise(rec: Recording, truth: RecordedTruth, t0: float, t1: float, spacing: float) -> dict:
    """{"q_translation" | "q_rotation": {q, spacing_s, samples, interval (95 %), by_spacing [[h, q, N]]}}
    (cal. 5-7) over the bodies with truth on [t0, t1] (window clock s) at spacings 2^j spacing, while
    a spacing has MIN_SAMPLES second differences; {} when none has."""
    table: dict[str, list[tuple[float, float, int]]] = {"q_translation": [], "q_rotation": []}
    h = spacing
    while h > 0:
        # the tolerance that keeps a last sample at t1 lets h k exceed t1 by rounding (h is a median of
        # rounded time differences): that sample is t1, inside the truth that ends there
        g = np.minimum(t0 + h * np.arange(int(np.floor((t1 - t0) / h + 1e-9)) + 1), t1)
        tracks = _tracks(rec, truth, g) if g.size >= 4 else []
        D = [np.concatenate([_second_differences(tr[k]) for tr in tracks]) if tracks else np.zeros((0, 3))
             for k in (0, 1)]
        if min(d.size for d in D) < MIN_SAMPLES:
            break
        for name, d in zip(table, D):
            # eq. cal. 6: non-overlapping second differences are independent, (2/3) q h^3 per axis
            table[name].append((float(np.sum(d ** 2) / (2.0 / 3.0 * h ** 3 * d.size)), h, int(d.size)))
        h *= 2
    out = {}
    for name, rows in table.items():
        if not rows:
            continue
        # eq. cal. 7: the first spacing where q stops falling as h^-3 (truth's noise no longer dominant)
        pick = next((j for j in range(len(rows) - 1) if rows[j][0] <= 2 * rows[j + 1][0]), len(rows) - 1)
        q, h, n = rows[pick]
        out[name] = {"q": q, "spacing_s": h, "samples": n,
                     "interval": [q * n / chi2.ppf(0.975, n), q * n / chi2.ppf(0.025, n)],
                     "by_spacing": [[hh, qq, nn] for qq, hh, nn in rows]}
    return out


def calibrate(spec_path: Path, window: tuple[float, float], out: Path, *, force: bool = False) -> dict:
    """Estimate the calibration of spec_path's dataset on window (T0, T1) (s, the files' clock) and
    write it to `out` (TOML, docs/calibration.md); returns what was written. ConfigError (exit 2, one
    line) on a window outside the data, without truth, or without a link to fit."""
    t0, t1 = window
    table = find(Path(spec_path).parent, "calibration")
    if table is not None:
        raise ConfigError(f"{table}: calibrate estimates what this table holds: calibrate the dataset without it "
                          "(one calibration per replay)")
    rec = load_recording(Path(spec_path), window=Window(start=t0, end=t1), window_key="--window")
    if "truth" not in rec.tables:
        raise ConfigError(f"{spec_path}: the dataset has no truth table (truth.csv): calibrate needs truth on the segment")
    truth = RecordedTruth(rec)
    epochs = np.unique(rec.tables["links"]["time"][rec.tables["links"]["kind"] == "uwb"])
    spacing = float(np.median(np.diff(epochs))) if epochs.size > 1 else t1 - t0
    links = link_rows(rec, truth, spacing)
    fits = link_fits(links)
    if not fits:
        raise ConfigError(f"--window {t0:g},{t1:g}: no uwb link has {MIN_ROWS} or more rows with truth at both ends "
                          f"in it (the truth table spans {_span(rec)})")
    # eq. cal. 10, 10b: device time offsets on the residuals (the rate with [1, d] projected out: the
    # joint least squares), kept where they predict held-out rows and differ from 0; then every link
    # fitted again given its offset (cal. 2, 2b)
    off = device_offsets([(f.src, f.dst) for f in fits], [f.res for f in fits], [f.rate_perp for f in fits],
                         np.array([1.0 / (f.tau * f.sigma ** 2) for f in fits]))
    offsets = {n: g for n, (g, _) in off.devices.items() if off.kept and abs(g) <= MAX_TIME_OFFSET_S}
    if offsets:
        fits = link_fits(links, {(f.src, f.dst): offsets.get(f.src, 0.0) + offsets.get(f.dst, 0.0) for f in fits})
    dof = sum(f.dof for f in fits)
    # eq. cal. 4: the pooled range noise
    range_sigma = float(np.sqrt(sum(f.rss for f in fits) / dof))
    # eq. cal. 8: one integrated time of the links' pooled autocovariance, in s by their row spacing
    pooled = np.zeros(max(f.acov.size for f in fits))
    for f in fits:
        pooled[:f.acov.size] += f.acov
    range_correlation = geyer_time(pooled) * sum(f.rss * f.spacing for f in fits) / sum(f.rss for f in fits)
    q = process_noise(rec, truth, 0.0, t1 - t0, spacing)
    # a density below every physical value (MIN_MAGNITUDE) is the rounding of a motion without any, e.g.
    # a prescribed constant-velocity flight: written as 0, the value every estimator parameter accepts;
    # so is a correlation time below it (rows at one time: independent errors)
    noise = {"range_sigma": range_sigma, **{k: v["q"] if v["q"] >= MIN_MAGNITUDE else 0.0 for k, v in q.items()},
             "range_correlation": range_correlation if range_correlation >= MIN_MAGNITUDE else 0.0}
    fit = {"range_rows": sum(f.samples for f in fits), "range_dof": dof,
           "range_tau_median": float(np.median([f.tau for f in fits])),
           "range_sigma_interval": [range_sigma * np.sqrt(dof / chi2.ppf(0.975, dof)),
                                    range_sigma * np.sqrt(dof / chi2.ppf(0.025, dof))],
           "epoch_spacing_s": spacing,
           **{f"{k}_{c}": v[c] for k, v in q.items() for c in ("spacing_s", "samples", "interval", "by_spacing")}}
    # eq. cal. 9, 9b: device biases, kept where they predict left-out links
    split = device_split([(f.src, f.dst) for f in fits], np.array([f.bias for f in fits]))
    fit.update(device_bias_rms=split.rms_bias, device_loo_rms=split.rms_loo, device_rows=int(split.kept))
    devices = {n: {"bias": beta} for n, beta in split.devices.items()} if split.kept else {}
    if split.kept:
        fits = [dataclasses.replace(f, bias=float(r)) for f, r in zip(fits, split.remainder)]
    fit.update(offset_cv_with=off.cv_with, offset_cv_without=off.cv_without, offset_wald=off.wald, offset_rank=off.rank,
               offset_rows=int(bool(offsets)))
    for n, g in offsets.items():
        devices.setdefault(n, {}).update(time_offset=g, sigma_time_offset=off.devices[n][1])
    written = {"window": [t0, t1], "noise": noise, "fit": fit, "devices": devices, "links": fits}
    with new_file(Path(out), force=force) as tmp:
        tmp.write_text(to_toml(spec_path, written))
    return written


def _span(rec: Recording) -> str:
    t = rec.tables["truth"]["time"]
    return f"{t.min():g} to {t.max():g} s" if t.size else "no rows"


def _num(x: float) -> str:
    return repr(float(x))


def to_toml(spec_path: Path, c: dict) -> str:
    """The calibration file's text (docs/calibration.md)."""
    lines = [f"# testbed calibrate {spec_path} --window {c['window'][0]!r},{c['window'][1]!r} (docs/calibration.md)",
             f"format = {FILE_FORMAT}",
             f"window = [{_num(c['window'][0])}, {_num(c['window'][1])}]  # s, the files' clock: never scored on replay",
             "", "[noise]  # the estimators' defaults: a parameter of this name, where the user set none",
             *[f"{k} = {_num(v)}" for k, v in c["noise"].items()],
             "", "[fit]  # how the figures above were found (a record: replay reads none of it)"]
    for k, v in c["fit"].items():
        if isinstance(v, list):
            v = "[" + ", ".join("[" + ", ".join(_num(y) for y in x) + "]" if isinstance(x, list) else _num(x) for x in v) + "]"
        lines.append(f"{k} = {v}")
    for name, dev in c["devices"].items():
        lines += ["", "[[links]]  # a device (eq. cal. 9, 10): its bias and time offset enter every link it ends",
                  f'src = "{name}"', *[f"{k} = {_num(v)}" for k, v in dev.items()]]
    for f in c["links"]:
        lines += ["", "[[links]]", f'src = "{f.src}"', f'dst = "{f.dst}"', f"bias = {_num(f.bias)}",
                  f"sigma_bias = {_num(f.sigma_bias)}"]
        if np.isfinite(f.sigma_scale):
            lines += [f"scale = {_num(f.scale)}", f"sigma_scale = {_num(f.sigma_scale)}",
                      f"scale_from = {_num(f.scale_from)}  # m: the span of true distances the scale was fitted on (eq. cal. 2c)",
                      f"scale_to = {_num(f.scale_to)}"]
        lines += [f"sigma = {_num(f.sigma)}  # m, the link's range noise (eq. cal. 3)", f"samples = {f.samples}",
                  f"tau = {_num(f.tau)}  # rows, the residuals' integrated autocorrelation time"]
    return "\n".join(lines) + "\n"
