"""One scoring function for every plugin estimator, and its error plots.

Per (target, quantity), at the estimate times against interpolated truth (testbed.plugins.truth):
RMSE total (root mean of |e|^2) and per axis; with a covariance, NEES e^T P^-1 e per sample, their
mean (ANEES, `anees_dof` = 3), `n_eff` the effective number of independent samples behind it and
`anees_interval_95` the two-sided 95 % interval of a consistent estimator's ANEES over n_eff
samples (testbed.scoring.metrics.sample_size: a filter's errors are correlated in time,
docs/consistency.md); coverage (testbed.scoring.metrics.coverage): `coverage` the fraction of the
target's truth instants with an estimate within `coverage_tolerance_s`, `rate_hz` and
`first_estimate_s`. An attitude series with a covariance also gets `unobserved`: the fraction of
its samples whose covariance gives a 1-sigma above UNOBSERVED_ATTITUDE_DEG along some axis (the
square root of its largest eigenvalue): the geometry did not determine that attitude, by the
estimator's own account; the targets with `unobserved` above one half are listed in the
estimator's `attitude_unobserved` (absent when none).
Summaries over targets, per quantity q with unit u (position m, velocity m_s, attitude deg):
`rmse_{q}_mean_{u}` (mean over targets of the per-target RMSE, as the built-in coop scores),
`rmse_{q}_{u}` (pooled over all samples), `rmse_{q}_axis_{u}`, `anees_{q}` (all samples with a
covariance), `n_eff_{q}` (the targets' NEES at common instants averaged, then as for one target),
`anees_{q}_interval_95`, `coverage_{q}` (mean over the targets estimated). An estimator that
estimates a quantity of bodies and of sites (e.g. a body's position and each antenna's) has the
bodies' in these headlines and the sites' apart, under `sites` with the same keys; with bodies only
or sites only, they are the headline.
Scoring hooks (`Hook`): the extra scores a paper defines (a PCRB, a joint ANEES, ...) are given to
ANY estimator whose outputs fit, never to a named one. A hook is built per run from the scenario
and its log (testbed.plugins.hooks.scenario_hooks) and is asked, for every estimator: `series`
(extra keys of one (target, quantity) series, beside its scores under `targets`), `summary`
(extra top-level keys of the estimator, from its Track, errors and health(); {} when its outputs
do not fit), and, once per run, `plot` (figures of its own) and `overlay` (lines drawn on the
shared error plots). A hook reads the log's truth; the estimators never do.
PCRB (`Bound`, seed 003 phase-ekf: the posterior Cramer-Rao bound of the follower's body position,
with the scenario's measurement and motion model, computed along the true trajectory by
testbed.plugins.phase_scores.phase_hooks): a world-frame position series of that body gets
`pcrb_rmse_m` = sqrt(mean trace B) over its estimates at the bound's epochs (`pcrb_samples` of
them; `rmse_at_pcrb_epochs_m` is its RMSE over the same samples), and the summary
`pcrb_rmse_position_m`; the error plot overlays +/-3 sqrt(diag B).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimators.core import nees
from estimators.phase_model import ATTITUDE_SD_LIMIT_RAD
from testbed.scoring.metrics import anees_keys, coverage, rmse
from testbed.plugins.collect import Series, Track, natural
from testbed.plugins.truth import Truth, errors

UNIT = {"position": "m", "velocity": "m_s", "attitude": "deg"}
#: deg: an attitude whose 1-sigma exceeds this along some axis is not observed: beyond it a
#: linearized attitude covariance no longer describes the error (the rule of phase.ekf's
#: unobserved rotation axes, estimators.phase_model.ATTITUDE_SD_LIMIT_RAD: one limit for both)
UNOBSERVED_ATTITUDE_DEG = float(np.degrees(ATTITUDE_SD_LIMIT_RAD))
SCALE = {"position": 1.0, "velocity": 1.0, "attitude": float(np.degrees(1.0))}


class Hook:
    """A scoring hook (module docstring). Every method is optional: the defaults add nothing."""

    def series(self, target: str, quantity: str, s: Series, err: np.ndarray) -> dict:
        """Extra keys of one series: s its estimates (K samples), err (K, 3) its errors."""
        return {}

    def summary(self, track: Track, errs: dict, health: dict) -> dict:
        """Extra top-level keys of one estimator: its Track, errors {(target, quantity): (K, 3)}
        and health() counts; {} when its outputs do not fit."""
        return {}

    def first(self, quantity: str) -> tuple[str, ...]:
        """Targets of `quantity` the shared error plots should show first."""
        return ()

    def overlay(self, axes, target: str, quantity: str) -> None:
        """Draw on the three axes (x, y, z) of the shared error plot of (target, quantity)."""

    def plot(self, shown: dict, plots_dir: Path) -> list[Path]:
        """Figures of the hook's own: shown {name: (Track, errors)} of every scored estimator."""
        return []


def common_times(series: list[Series]) -> tuple[np.ndarray, list[np.ndarray]] | None:
    """The instants t (E,) s every one of `series` has an estimate at and, per series, the indices
    (E,) of those estimates; None when there is none."""
    t = series[0].time
    for s in series[1:]:
        t = np.intersect1d(t, s.time)
    return (t, [np.searchsorted(s.time, t) for s in series]) if t.size else None


def fitting(hook, shown: dict):
    """(name, hook.fit(track, errors)) of each estimator of shown {name: (Track, errors)} whose
    outputs fit a hook that has a `fit` (None when they do not)."""
    for name, (track, errs) in shown.items():
        got = hook.fit(track, errs)
        if got is not None:
            yield name, got


def at_epochs(epochs: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(indices into times, the matching indices into epochs) of the times within 1e-9 s of one
    of the sorted epochs (K,) s."""
    j = np.minimum(np.searchsorted(epochs, times - 1e-9), epochs.size - 1)
    hit = np.flatnonzero(np.abs(epochs[j] - times) < 1e-9)
    return hit, j[hit]


@dataclass(frozen=True, slots=True)
class Bound(Hook):
    """A scenario's PCRB of one target's world position: time (K,) s, cov (K, 3, 3) m^2."""

    target: str
    time: np.ndarray
    cov: np.ndarray

    def at(self, s: Series, target: str, quantity: str) -> tuple[np.ndarray, np.ndarray]:
        """(indices into s, bound (k, 3, 3)) of the samples of s at the bound's epochs (1e-9 s);
        empty unless s is the bound's target's world position."""
        if target != self.target or quantity != "position" or s.frame != "world":
            return np.zeros(0, int), np.zeros((0, 3, 3))
        hit, j = at_epochs(self.time, s.time)
        return hit, self.cov[j]

    def series(self, target: str, quantity: str, s: Series, err: np.ndarray) -> dict:
        hit, B = self.at(s, target, quantity)
        if not hit.size:
            return {}
        return {"pcrb_rmse_m": float(np.sqrt(np.mean(np.trace(B, axis1=1, axis2=2)))), "pcrb_samples": int(hit.size),
                "rmse_at_pcrb_epochs_m": rmse(err[hit])}

    def summary(self, track: Track, errs: dict, health: dict) -> dict:
        s = track.get((self.target, "position"))
        if s is None:
            return {}
        hit, B = self.at(s, self.target, "position")
        return {"pcrb_rmse_position_m": float(np.sqrt(np.mean(np.trace(B, axis1=1, axis2=2))))} if hit.size else {}

    def first(self, quantity: str) -> tuple[str, ...]:
        return (self.target,) if quantity == "position" else ()

    def overlay(self, axes, target: str, quantity: str) -> None:
        if target != self.target or quantity != "position":
            return
        pc = 3 * np.sqrt(np.clip(np.diagonal(self.cov, axis1=1, axis2=2), 0, None))
        for a, ax in enumerate(axes):
            ax.plot(self.time, pc[:, a], "k--", lw=0.8, label="PCRB ±3σ" if a == 0 else None)
            ax.plot(self.time, -pc[:, a], "k--", lw=0.8)


def _axis(e: np.ndarray) -> list[float]:
    return [float(x) for x in np.sqrt(np.mean(e**2, axis=0))]


def score_series(err: np.ndarray, s: Series, quantity: str) -> tuple[dict, np.ndarray]:
    """Scores of one series (see module docstring); returns (dict, NEES of the samples with a cov)."""
    u, k = UNIT[quantity], SCALE[quantity]
    out = {"samples": int(s.time.size), f"rmse_{u}": rmse(err) * k, f"rmse_axis_{u}": [x * k for x in _axis(err)]}
    ne = nees(err[s.has_cov], s.cov[s.has_cov]) if s.has_cov.any() else np.zeros(0)
    if ne.size:
        out.update({**anees_keys(ne, 3, "anees", 0.95), "nees_samples": int(ne.size)})
        if quantity == "attitude":
            worst = np.sqrt(np.linalg.eigvalsh(s.cov[s.has_cov])[:, -1])
            out["unobserved"] = float(np.mean(worst > np.radians(UNOBSERVED_ATTITUDE_DEG)))
    return out, ne


def score(track: Track, truth: Truth, hooks: tuple[Hook, ...] | list[Hook] = (), health: dict | None = None) -> tuple[dict, dict]:
    """metrics.json scores of one estimator, and its errors {(target, quantity): (K, 3)} for plots.
    hooks: the run's scoring hooks (module docstring); health: the estimator's health() counts."""
    targets: dict = {}
    errs: dict = {}
    pooled: dict[str, list] = {}
    for (target, q), s in track.items():
        e = errors(truth, target, q, s.time, s.value, s.frame)
        errs[(target, q)] = e
        sc, ne = score_series(e, s, q)
        sc.update(coverage(truth.times(target), s.time))
        if s.frame != "world":
            sc["frame"] = s.frame
        for h in hooks:
            sc.update(h.series(target, q, s, e))
        targets.setdefault(target, {})[q] = sc
        pooled.setdefault(q, {}).setdefault("/" in target, []).append(
            (e, ne, sc[f"rmse_{UNIT[q]}"], s.time[s.has_cov], sc["coverage"]))
    out: dict = {"estimates": int(sum(s.time.size for s in track.values()))}
    for q, kinds in pooled.items():
        apart = len(kinds) == 2  # bodies and sites: the bodies' headline, the sites' apart
        out.update(_summary(q, kinds[False] if apart else next(iter(kinds.values()))))
        if apart:
            out.setdefault("sites", {}).update(_summary(q, kinds[True]))
    for h in hooks:
        out.update(h.summary(track, errs, health or {}))
    blind = [t for t, qs in targets.items() if qs.get("attitude", {}).get("unobserved", 0.0) > 0.5]
    if blind:
        out["attitude_unobserved"] = blind
    out["targets"] = targets
    return out, errs


def _summary(q: str, rows: list[tuple]) -> dict:
    """The summary keys of quantity q over targets' rows (errors (K, 3), NEES (K',), RMSE, the
    times of the NEES samples (K',) s, coverage)."""
    u, k = UNIT[q], SCALE[q]
    e_all = np.concatenate([r[0] for r in rows])
    out = {f"rmse_{q}_mean_{u}": float(np.mean([r[2] for r in rows])), f"rmse_{q}_{u}": rmse(e_all) * k,
           f"rmse_{q}_axis_{u}": [x * k for x in _axis(e_all)], f"coverage_{q}": float(np.mean([r[4] for r in rows]))}
    with_cov = [(r[3], r[1]) for r in rows if r[1].size]
    if with_cov:
        # the targets' samples at common instants are averaged (sample_size, sparse layout)
        instant = np.unique(np.concatenate([r[0] for r in with_cov]), return_inverse=True)[1]
        target = np.repeat(np.arange(len(with_cov)), [r[0].size for r in with_cov])
        out.update(anees_keys(np.concatenate([r[1] for r in with_cov]), 3, f"anees_{q}", 0.95,
                              instant=instant, target=target))
    return out


def plot_errors(tracks: dict[str, tuple[Track, dict]], plots_dir: Path, max_targets: int = 2,
                hooks: tuple[Hook, ...] | list[Hook] = ()) -> list[Path]:
    """Per quantity and for the first `max_targets` targets (sorted, the hooks' first targets
    first): every estimator's error per axis against time with its own 3-sigma envelope, overlaid,
    and the hooks' overlays (the scenario's +/-3 sqrt(diag PCRB) where it has one); then each
    hook's own figures. tracks: {name: (track, errors)}."""
    from testbed.outputs.plots import figure, save  # lazy: matplotlib, only when plots are written

    keys = sorted({k for track, _ in tracks.values() for k in track}, key=lambda k: (k[1], k[0]))
    paths = []
    for q in UNIT:
        first = tuple(t for h in hooks for t in h.first(q))
        for target in sorted({t for t, qq in keys if qq == q}, key=lambda t: (t not in first, natural(t)))[:max_targets]:
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
            for h in hooks:
                h.overlay(axes, target, q)
            for a, ax in enumerate(axes):
                ax.set_ylabel(f"{'xyz'[a]} [{UNIT[q].replace('_', '/')}]")
                ax.grid(alpha=0.3)
            axes[0].set_title(f"{target} {q} error, shaded: each estimator's ±3σ")
            axes[0].legend(fontsize=7, ncol=4, loc="upper right")
            axes[-1].set_xlabel("time [s]")
            paths.append(save(fig, plots_dir / f"estimators_{q}_{target.replace('/', '_')}.png"))
    for h in hooks:
        paths += h.plot(tracks, plots_dir)
    return paths
