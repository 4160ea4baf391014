"""One scoring function for every plugin estimator, and its error plots.

Per (target, quantity), at the estimate times against interpolated truth (testbed.plugins.truth):
RMSE total (root mean of |e|^2) and per axis; with a covariance, NEES e^T P^-1 e per sample, their
mean (ANEES, 3 dof) and the two-sided chi-square 95 % interval of a consistent estimator's ANEES.
Summaries over targets, per quantity q with unit u (position m, velocity m_s, attitude deg):
`rmse_{q}_mean_{u}` (mean over targets of the per-target RMSE, as the built-in coop scores),
`rmse_{q}_{u}` (pooled over all samples), `rmse_{q}_axis_{u}`, `anees_{q}` (all samples with a
covariance), `anees_{q}_interval_95`. No PCRB: a bound needs the estimator's own state model,
which a plugin does not declare (the phase pipeline reports its PCRB under its own name).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from estimators.core import chi2_interval, nees
from testbed.metrics import rmse
from testbed.plugins.collect import Series, Track, natural
from testbed.plugins.truth import Truth, errors

UNIT = {"position": "m", "velocity": "m_s", "attitude": "deg"}
SCALE = {"position": 1.0, "velocity": 1.0, "attitude": float(np.degrees(1.0))}


def _axis(e: np.ndarray) -> list[float]:
    return [float(x) for x in np.sqrt(np.mean(e**2, axis=0))]


def score_series(err: np.ndarray, s: Series, quantity: str) -> tuple[dict, np.ndarray]:
    """Scores of one series (see module docstring); returns (dict, NEES of the samples with a cov)."""
    u, k = UNIT[quantity], SCALE[quantity]
    out = {"samples": int(s.time.size), f"rmse_{u}": rmse(err) * k, f"rmse_axis_{u}": [x * k for x in _axis(err)]}
    ne = nees(err[s.has_cov], s.cov[s.has_cov]) if s.has_cov.any() else np.zeros(0)
    if ne.size:
        lo, hi = chi2_interval(3, int(ne.size), 0.95)
        out.update({"anees": float(np.mean(ne)), "anees_interval_95": [lo, hi], "nees_samples": int(ne.size)})
    return out, ne


def score(track: Track, truth: Truth) -> tuple[dict, dict]:
    """metrics.json scores of one estimator, and its errors {(target, quantity): (K, 3)} for plots."""
    targets: dict = {}
    errs: dict = {}
    pooled: dict[str, list] = {}
    for (target, q), s in track.items():
        e = errors(truth, target, q, s.time, s.value, s.frame)
        errs[(target, q)] = e
        sc, ne = score_series(e, s, q)
        if s.frame != "world":
            sc["frame"] = s.frame
        targets.setdefault(target, {})[q] = sc
        pooled.setdefault(q, []).append((e, ne, sc[f"rmse_{UNIT[q]}"]))
    out: dict = {"estimates": int(sum(s.time.size for s in track.values()))}
    for q, rows in pooled.items():
        u, k = UNIT[q], SCALE[q]
        e_all = np.concatenate([r[0] for r in rows])
        ne_all = np.concatenate([r[1] for r in rows])
        out[f"rmse_{q}_mean_{u}"] = float(np.mean([r[2] for r in rows]))
        out[f"rmse_{q}_{u}"] = rmse(e_all) * k
        out[f"rmse_{q}_axis_{u}"] = [x * k for x in _axis(e_all)]
        if ne_all.size:
            lo, hi = chi2_interval(3, int(ne_all.size), 0.95)
            out[f"anees_{q}"] = float(np.mean(ne_all))
            out[f"anees_{q}_interval_95"] = [lo, hi]
    out["targets"] = targets
    return out, errs


def plot_errors(tracks: dict[str, tuple[Track, dict]], plots_dir: Path, max_targets: int = 2) -> list[Path]:
    """Per quantity and for the first `max_targets` targets (sorted): every estimator's error per
    axis against time with its own 3-sigma envelope, overlaid. tracks: {name: (track, errors)}."""
    from testbed.plots import figure, save  # lazy: matplotlib, only when plots are written

    keys = sorted({k for track, _ in tracks.values() for k in track}, key=lambda k: (k[1], k[0]))
    paths = []
    for q in UNIT:
        for target in sorted({t for t, qq in keys if qq == q}, key=natural)[:max_targets]:
            fig = figure(figsize=(8, 6.2))
            axes = fig.subplots(3, 1, sharex=True)
            for c, (name, (track, errs)) in enumerate(tracks.items()):
                if (target, q) not in track:
                    continue
                s, e = track[(target, q)], errs[(target, q)] * SCALE[q]
                sig = np.sqrt(np.clip(np.diagonal(s.cov, axis1=1, axis2=2), 0, None)) * SCALE[q]
                for a, ax in enumerate(axes):
                    ax.plot(s.time, e[:, a], lw=0.8, color=f"C{c}", label=name)
                    if s.has_cov.any():
                        ax.fill_between(s.time, -3 * sig[:, a], 3 * sig[:, a], color=f"C{c}", alpha=0.15, lw=0)
            for a, ax in enumerate(axes):
                ax.set_ylabel(f"{'xyz'[a]} [{UNIT[q].replace('_', '/')}]")
                ax.grid(alpha=0.3)
            axes[0].set_title(f"{target} {q} error, shaded: each estimator's ±3σ")
            axes[0].legend(fontsize=7, ncol=4, loc="upper right")
            axes[-1].set_xlabel("time [s]")
            paths.append(save(fig, plots_dir / f"estimators_{q}_{target.replace('/', '_')}.png"))
    return paths
