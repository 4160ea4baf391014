"""Seed 000 scores (kind "bandwidth") for ANY estimator that estimates the world position of every
vehicle's `uav{i}/uwb` site with a covariance at common instants: a scoring hook
(testbed.plugins.score.Hook), `FusionBound`.

The paper's node i estimates the formation point x; the estimator reports xhat_i + o_i, the tag
with its known offset o_i, and its covariance M_i. With exact known offsets (pipeline
offset_error = 0) the tag's error is the formation point's, e_i(k) of eq. 10; the runtime's
errors (estimate minus interpolated truth of the site, testbed.plugins.truth) are used as they are.

Keys (`FusionBound.summary`), over the K instants at which every site has an estimate with a
covariance, N sites in vehicle order (e = estimate - truth, m; M the estimate's covariance, m^2):
- `J_empirical` = sum_k sum_i |e_i(k)|^2 (eq. 12 realised, m^2): one sample of the random variable
  whose mean is J (its Monte Carlo estimate: testbed reproduce bandwidth);
- `J_bound` = sum_k sum_i tr M_i(k) (eq. 16, m^2);
- `rmse_position_per_vehicle_m` (N,), `final_trace_M_m2` (N,);
- `bound_holds` (N,): per node the time-averaged check mean_k |e_i|^2 <= mean_k tr M_i (a single
  run cannot estimate a covariance; errors are correlated in time: indicative), with
  `bound_holds_basis` saying so;
- from the estimator's health() counts, when it reports them (testbed.plugins.builtin_bandwidth):
  `within_budget` (no node ever received more than its budget: `steps_over_budget` = 0) and
  `bytes_received_per_step` (N,) mean bytes each node received per step (8 per component);
- `null_reasons`: a score a diverged estimate cannot give is null, the reason beside it
  (J_empirical too when the estimator reports `steps` and gave every site's estimate at fewer
  than steps + 1 epochs).
Figures (`FusionBound.plot`): {name}_error_uav{i}.png, each fitting estimator's error of each
site with +/-3 sqrt(diag M) (the bound not drawn when it is off-scale).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimators.bandwidth import BYTES_PER_COMPONENT
from testbed.plugins.collect import Track
from testbed.plugins.score import Hook, common_times, fitting


@dataclass(frozen=True, slots=True)
class FusionBound(Hook):
    """The seed 000 scores of the sites `targets` (N,) ("uav1/uwb", ...), in node order."""

    targets: tuple[str, ...]

    def fit(self, track: Track, errs: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(t (K,) s, e (K, N, 3) m, M (K, N, 3, 3) m^2, NaN where an estimate has no covariance)
        at the instants where every site has an estimate, or None when the estimator's outputs do
        not fit (a site missing, not in the world frame, or never with a covariance)."""
        series = [track.get((t, "position")) for t in self.targets]
        if any(s is None or s.frame != "world" or not s.has_cov.any() for s in series):
            return None
        common = common_times(series)
        if common is None:
            return None
        t, idx = common
        e = np.stack([errs[(t, "position")][j] for t, j in zip(self.targets, idx)], 1)
        M = np.stack([s.cov[j] for s, j in zip(series, idx)], 1)
        return t, e, M

    def summary(self, track: Track, errs: dict, health: dict) -> dict:
        got = self.fit(track, errs)
        if got is None:
            return {}
        t, e, M = got
        n = len(self.targets)
        se = (e ** 2).sum(-1)  # (K, N), eq. 10 squared
        trM = np.trace(M, axis1=-2, axis2=-1)
        out = {
            "J_empirical": float(se.sum()),  # eq. 12
            "J_bound": float(trM.sum()),  # eq. 16
            "rmse_position_per_vehicle_m": [float(v) for v in np.sqrt(se.mean(0))],
            "final_trace_M_m2": [float(v) for v in trM[-1]],
            "bound_holds": [bool(se[:, i].mean() <= trM[:, i].mean()) for i in range(n)],
            "bound_holds_basis": "single run: time-mean |e_i|^2 <= time-mean tr M_i; per step needs a Monte Carlo",
        }
        if "steps_over_budget" in health:
            out["within_budget"] = health["steps_over_budget"] == 0
        steps = health.get("steps", 0)
        if steps and all(f"components_received_uav{i + 1}" in health for i in range(n)):
            out["bytes_received_per_step"] = [BYTES_PER_COMPONENT * health[f"components_received_uav{i + 1}"] / steps
                                              for i in range(n)]
        # strict JSON: what a diverged estimate cannot give is null, with the reason beside it
        fin_e, fin_M = np.isfinite(se).all(0), np.isfinite(trM).all(0)  # (N,) per node
        reasons = {}
        if not fin_M.all():
            lost = ~np.isfinite(trM).all(1)
            why = (f"from t = {t[np.argmax(lost)]:g} s an estimate has no usable covariance M_i "
                   "(the bound diverged: health estimates_without_cov)")
            out["J_bound"], reasons["J_bound"] = None, why
            out["final_trace_M_m2"] = [v if ok else None for v, ok in zip(out["final_trace_M_m2"], fin_M)]
            reasons["final_trace_M_m2"] = f"nodes {[i + 1 for i in np.flatnonzero(~fin_M).tolist()]}: {why}"
        epochs = health.get("steps", t.size - 1) + 1
        if t.size < epochs:  # the estimator gave no estimate at some epochs: J is not the run's sum
            out["J_empirical"], reasons["J_empirical"] = None, (
                f"estimates of every site at {t.size} of the {epochs} epochs (health estimates_not_finite)")
        if not fin_e.all():
            why = "not finite: the fusion diverged"
            out["J_empirical"], reasons["J_empirical"] = None, why
            out["rmse_position_per_vehicle_m"] = [v if ok else None for v, ok in zip(out["rmse_position_per_vehicle_m"], fin_e)]
            reasons["rmse_position_per_vehicle_m"] = f"nodes {[i + 1 for i in np.flatnonzero(~fin_e).tolist()]}: {why}"
        if not (fin_e & fin_M).all():
            out["bound_holds"] = [v if ok else None for v, ok in zip(out["bound_holds"], fin_e & fin_M)]
            reasons["bound_holds"] = f"nodes {[i + 1 for i in np.flatnonzero(~(fin_e & fin_M)).tolist()]}: no finite error or M"
        if reasons:
            out["null_reasons"] = reasons
        return out

    def plot(self, shown: dict, plots_dir: Path) -> list[Path]:
        from testbed.outputs.plots import error_envelope  # lazy: matplotlib, only when plots are written

        paths = []
        for name, (t, e, M) in fitting(self, shown):
            for i in range(len(self.targets)):
                sig = np.sqrt(np.clip(np.diagonal(M[:, i], axis1=-2, axis2=-1), 0, None))  # NaN: no M given
                given = sig[np.isfinite(sig)]
                big = given.size > 0 and float(given.max()) > 100 * max(float(np.abs(e[:, i]).max()), 1e-9)
                paths.append(error_envelope(
                    t, e[:, i], None if big else sig, plots_dir / f"{name}_error_uav{i + 1}.png",
                    title=f"{name}, UAV {i + 1}: estimate - truth of its tag"
                          + (" (bound sqrt(diag M) off-scale, not drawn)" if big else ", ±3 sqrt(diag M)"),
                    ylabel="m"))
        return paths


def fusion_bound(scenario) -> FusionBound:
    """The hook of a bandwidth run: every vehicle's uwb site, in vehicle order."""
    return FusionBound(tuple(f"uav{i}/uwb" for i in range(1, scenario.vehicles + 1)))
