"""Seed 001 scores (kind "coop-fg") for ANY estimator that estimates every vehicle's `uav{i}/uwb`
site position in the world at the run's GNSS epochs: a scoring hook (testbed.plugins.score.Hook).

Epochs (`epochs_from_log`). One epoch per GNSS sample instant (`gnss/time`); the UWB ranges of an
epoch are the tag-to-tag `uwb` rows taken at the same controller tick (same `state_index`). Truth
for scoring is `gnss/clean`, the physics position of the GNSS antenna, which a coop-fg scenario
puts on the uwb site (`sensors.gnss.antenna = "uwb"`); `gnss/rtk` is the receiver's fix type,
`uwb/nlos` the truth flag of each range. The estimators never see these arrays.

Keys (`CoopHook.summary`), over the K epochs x N vehicles (e = estimate - truth, NEES with the
estimate's own (3, 3) covariance, 3 dof):
- `rmse_position_per_vehicle_m` (N,) RMSE per vehicle over epochs; `rmse_position_spp_mean_m`,
  `rmse_position_rtk_mean_m` their mean over the SPP / RTK vehicles;
- `anees`, `anees_dof`, `anees_interval_99`, `n_eff` (testbed.scoring.metrics.anees_keys of the (K, N)
  NEES: the epochs and vehicles of a run are correlated, the interval counts the effective
  samples, docs/consistency.md); the same keys of the SPP and of the RTK vehicles (`anees_spp`,
  `anees_spp_dof`, `anees_spp_interval_99` or `anees_spp_null_reason`, `n_eff_spp`, `n_eff_nu_spp`;
  `anees_rtk` ...); `epochs` = K;
- `anees_joint` (with its _dof = 3N, _interval_99 and `n_eff_joint`): the NEES of all 3N coordinates
  of each epoch with the estimator's joint covariance, when it gives one (EstimateBatch.cov_joint);
- from the estimator's health() counts, when it reports them (a per-epoch solver: `epochs`,
  `rounds_total`, `rounds_max`, `messages_total`, `bytes_total`, `nonconverged_epochs`):
  `iterations_mean`, `iterations_max`, `converged_fraction`, `nonconverged_steps`,
  `messages_per_epoch`, `bytes_per_epoch`;
- `nlos_fraction`: the fraction of the epochs' tag-to-tag ranges that were NLOS (truth);
- `null_reasons`: a score that cannot exist (no SPP or no RTK vehicle) is null, the reason here.
Figures (`CoopHook.plot`, every fitting estimator overlaid): fig6_error_vs_time.png (the error
norm of four vehicles, `choose_four`), {name}_uav{i}_envelope.png (the first chosen vehicle's
error against the estimator's own 3-sigma) and rmse_mean.png.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimators.core import nees
from testbed.errors import ConfigError
from testbed.scoring.metrics import anees_keys, rmse
from testbed.plugins.collect import Track
from testbed.plugins.score import Hook

# health() counts of a per-epoch solver, read by CoopHook.summary
SOLVER_COUNTS = ("epochs", "rounds_total", "rounds_max", "messages_total", "bytes_total", "nonconverged_epochs")


@dataclass(frozen=True, slots=True)
class Epochs:
    """The measurements of a run grouped by GNSS epoch (K epochs, N UAVs, UAV order 1..N).

    time: (K,) s; gnss: (K, N, 3) m ENU fixes; is_rtk: (N,) bool (receiver fix type);
    truth: (K, N, 3) m ENU physics position of the uwb sites (scoring only);
    edges: list of K (m_k, 2) int arrays (0-based UAV indices); ranges: list of K (m_k,) m;
    nlos: list of K (m_k,) bool (truth flag, diagnostics only).
    """

    time: np.ndarray
    gnss: np.ndarray
    is_rtk: np.ndarray
    truth: np.ndarray
    edges: list
    ranges: list
    nlos: list


def _uav_index(names: np.ndarray, label: str) -> np.ndarray:
    """'uav7/uwb' -> 6 (0-based). Raises ConfigError on a site that is not a UAV tag."""
    out = np.empty(len(names), dtype=np.int64)
    for k, s in enumerate(names):
        head, _, site = str(s).partition("/")
        if not head.startswith("uav") or site != "uwb":
            raise ConfigError(f"pipeline coop-fg: {label} site {s!r} is not a UAV uwb tag")
        out[k] = int(head[3:]) - 1
    return out


def epochs_from_log(log: dict[str, np.ndarray], n: int) -> Epochs:
    """Group the gnss and uwb streams of a run log into epochs (see Epochs). n: number of UAVs."""
    gi = log["gnss/state_index"]
    ticks = np.unique(gi)
    K = ticks.size
    gnss = np.full((K, n, 3), np.nan)
    truth = np.full((K, n, 3), np.nan)
    veh = log["gnss/vehicle"] - 1
    row = np.searchsorted(ticks, gi)
    gnss[row, veh] = log["gnss/value"]
    truth[row, veh] = log["gnss/clean"]
    if np.isnan(gnss).any():
        raise ConfigError("pipeline coop-fg: every UAV needs a GNSS fix at every epoch (sensors.gnss.vehicles = [] : all)")
    is_rtk = np.zeros(n, bool)
    is_rtk[veh] = log["gnss/rtk"]
    ui = log["uwb/state_index"]
    tag = np.char.endswith(log["uwb/src"].astype(str), "/uwb") & np.char.startswith(log["uwb/src"].astype(str), "uav") \
        & np.char.startswith(log["uwb/dst"].astype(str), "uav")
    src = _uav_index(log["uwb/src"][tag], "uwb/src")
    dst = _uav_index(log["uwb/dst"][tag], "uwb/dst")
    ui, val, nl = ui[tag], log["uwb/value"][tag, 0], log["uwb/nlos"][tag]
    order = np.argsort(ui, kind="stable")
    bounds = np.searchsorted(ui[order], np.concatenate([ticks, [np.iinfo(np.int64).max]]))
    edges, ranges, nlos = [], [], []
    for k in range(K):
        sel = order[bounds[k]:bounds[k + 1]]
        edges.append(np.stack([src[sel], dst[sel]], axis=1))
        ranges.append(val[sel].astype(float))
        nlos.append(nl[sel].astype(bool))
    t = log["time"][ticks]
    return Epochs(t, gnss, is_rtk, truth, edges, ranges, nlos)


def masked_mean(x: np.ndarray, mask: np.ndarray) -> float | None:
    """Mean of x[..., mask] (mask: (N,) bool over vehicles, the last axis of x); None if mask is empty."""
    return float(np.mean(x[..., mask])) if mask.any() else None


def neighbour_counts(epochs: Epochs) -> tuple[np.ndarray, np.ndarray]:
    """Mean over epochs of each UAV's number of UWB neighbours and of RTK neighbours: (N,), (N,)."""
    K, n = epochs.gnss.shape[:2]
    nb = np.zeros(n)
    nr = np.zeros(n)
    for e in epochs.edges:
        np.add.at(nb, e[:, 0], 1.0)
        np.add.at(nb, e[:, 1], 1.0)
        np.add.at(nr, e[:, 0], epochs.is_rtk[e[:, 1]].astype(float))
        np.add.at(nr, e[:, 1], epochs.is_rtk[e[:, 0]].astype(float))
    return nb / K, nr / K


def choose_four(epochs: Epochs) -> list[int]:
    """Four SPP UAVs (1-based) with different neighbour counts, like the paper's UAVs 1, 7, 12, 13:
    the SPP UAVs sorted by (mean neighbours, RTK neighbours, number), taken at the 0, 1/3, 2/3 and
    1 quantiles of that order."""
    nb, nr = neighbour_counts(epochs)
    spp = np.flatnonzero(~epochs.is_rtk)
    order = spp[np.lexsort((spp, nr[spp], nb[spp]))]
    picks = np.round(np.linspace(0, order.size - 1, 4)).astype(int)
    return [int(order[p]) + 1 for p in picks]


def position_scores(err: np.ndarray, cov: np.ndarray, is_rtk: np.ndarray) -> dict:
    """The seed 001 position keys (module docstring) of errors err (K, N, 3) m with covariances
    cov (K, N, 3, 3) m^2; is_rtk (N,) the vehicles' fix type."""
    K = err.shape[0]
    spp = ~is_rtk
    per_uav = rmse(err, axis=0)  # (N,)
    ne = nees(err, cov)  # (K, N)
    s = {
        "rmse_position_per_vehicle_m": [float(x) for x in per_uav],
        "rmse_position_mean_m": float(np.mean(per_uav)),
        "rmse_position_spp_mean_m": masked_mean(per_uav, spp),
        "rmse_position_rtk_mean_m": masked_mean(per_uav, ~spp),
        **anees_keys(ne, 3),
        "epochs": int(K),
    }
    # strict JSON: a score that cannot exist is null, with the reason beside it
    why = {}
    for g, m in (("spp", spp), ("rtk", ~spp)):
        if m.any():  # the group's ANEES with its interval (or why one run cannot decide it) and n_eff
            s.update(anees_keys(ne[:, m], 3, f"anees_{g}"))
        else:
            s[f"anees_{g}"] = s[f"n_eff_{g}"] = None
            why.update({k: f"no {g.upper()} vehicle in this scenario"
                        for k in (f"rmse_position_{g}_mean_m", f"anees_{g}", f"n_eff_{g}")})
    if why:
        s["null_reasons"] = why
    return s


def solver_scores(health: dict) -> dict:
    """The solver keys (module docstring) of a per-epoch solver's health() counts; {} without them."""
    if not all(k in health for k in SOLVER_COUNTS) or health["epochs"] <= 0:
        return {}
    K = health["epochs"]
    return {"iterations_mean": health["rounds_total"] / K, "iterations_max": int(health["rounds_max"]),
            "converged_fraction": 1.0 - health["nonconverged_epochs"] / K, "nonconverged_steps": int(health["nonconverged_epochs"]),
            "messages_per_epoch": health["messages_total"] / K, "bytes_per_epoch": health["bytes_total"] / K}


@dataclass(frozen=True, slots=True)
class CoopHook(Hook):
    """The seed 001 scores and figures of a run (module docstring): epochs from its log, uavs the
    four vehicles (1-based) its figures show."""

    epochs: Epochs
    uavs: tuple[int, ...]

    def positions(self, track: Track) -> tuple[np.ndarray, np.ndarray] | None:
        """(pos (K, N, 3) m, cov (K, N, 3, 3) m^2) of the track at the epochs, or None when it does not
        estimate every vehicle's uwb site position in the world, with a covariance, at every epoch (1e-9 s)."""
        K, n = self.epochs.gnss.shape[:2]
        pos, cov = np.empty((K, n, 3)), np.empty((K, n, 3, 3))
        for i in range(n):
            s = track.get((f"uav{i + 1}/uwb", "position"))
            if s is None or s.frame != "world" or s.time.size == 0:
                return None
            j = np.minimum(np.searchsorted(s.time, self.epochs.time - 1e-9), s.time.size - 1)
            if np.any(np.abs(s.time[j] - self.epochs.time) >= 1e-9) or not s.has_cov[j].all():
                return None
            pos[:, i], cov[:, i] = s.value[j], s.cov[j]
        return pos, cov

    def summary(self, track: Track, errs: dict, health: dict) -> dict:
        got = self.positions(track)
        if got is None:
            return {}
        pos, cov = got
        err = pos - self.epochs.truth
        out = {**position_scores(err, cov, self.epochs.is_rtk), **solver_scores(health)}
        nl = np.concatenate(self.epochs.nlos) if self.epochs.nlos else np.zeros(0, bool)
        out["nlos_fraction"] = float(nl.mean()) if nl.size else 0.0
        joint = self.joint_nees(track, err)
        if joint is not None:
            out.update(anees_keys(joint, 3 * err.shape[1], "anees_joint"))
        return out

    def joint_nees(self, track: Track, err: np.ndarray) -> np.ndarray | None:
        """(K,) NEES of all 3N coordinates of each epoch with the estimator's joint covariance
        (EstimateBatch.cov_joint, 3N dof), errors err (K, N, 3) m; None unless it gave one of every
        vehicle's uwb site in the world at every epoch (1e-9 s)."""
        K, n = err.shape[:2]
        order = {f"uav{i + 1}/uwb": i for i in range(n)}
        at = {}
        for j in getattr(track, "joint", {}).get("position", []):
            if j.frame == "world" and sorted(j.targets) == sorted(order):
                at[round(j.time, 9)] = j
        out = np.empty(K)
        for k, t in enumerate(self.epochs.time):
            j = at.get(round(float(t), 9))
            if j is None:
                return None
            e = err[k, [order[s] for s in j.targets]].reshape(-1)  # the joint covariance's block order
            out[k] = float(nees(e, j.cov))
        return out

    def plot(self, shown: dict, plots_dir: Path) -> list[Path]:
        from testbed.outputs.plots import compare_bars, error_envelope  # lazy: matplotlib, only when plots are written

        fits = {name: got for name, (track, _) in shown.items() if (got := self.positions(track)) is not None}
        if not fits:
            return []
        ep = self.epochs
        paths = [plot_error_vs_time(ep, {w: p for w, (p, _) in fits.items()}, list(self.uavs),
                                    plots_dir / "fig6_error_vs_time.png", "Position error of four UAVs")]
        u = self.uavs[0] - 1
        for w, (pos, cov) in fits.items():
            sig = np.sqrt(np.diagonal(cov[:, u], axis1=1, axis2=2))
            paths.append(error_envelope(ep.time, pos[:, u] - ep.truth[:, u], sig, plots_dir / f"{w}_uav{u + 1}_envelope.png",
                                        title=f"{w}: UAV {u + 1} position error and its own 3-sigma", ylabel="m",
                                        labels=("E", "N", "U")))
        names = list(fits)
        means = np.array([float(np.mean(rmse(fits[w][0] - ep.truth, axis=0))) for w in names])
        paths.append(compare_bars(names, means, means, means, plots_dir / "rmse_mean.png", title="Mean per-UAV position RMSE",
                                  ylabel="RMSE [m]"))
        return paths


def plot_error_vs_time(epochs: Epochs, pos: dict, uavs: list[int], path: Path, title: str) -> Path:
    """Figure 6: position error norm (m) against time for four UAVs (1-based) of each estimator's
    positions pos {name: (K, N, 3) m}."""
    from testbed.outputs.plots import figure, save  # lazy: matplotlib, only when plots are written

    nb, nr = neighbour_counts(epochs)
    fig = figure(figsize=(8, 2.0 * len(uavs) + 0.6))
    axes = fig.subplots(len(uavs), 1, sharex=True)
    for ax, u in zip(np.atleast_1d(axes), uavs):
        for c, (w, p) in enumerate(pos.items()):
            e = np.linalg.norm(p[:, u - 1] - epochs.truth[:, u - 1], axis=1)
            ax.plot(epochs.time, e, lw=0.8, color=f"C{c}", label=w)
        ax.set_yscale("log")
        ax.set_ylabel("|error| [m]")
        ax.set_title(f"UAV {u}: {nb[u - 1]:.1f} neighbours, {nr[u - 1]:.1f} RTK neighbours", fontsize=9)
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].legend(fontsize=7, ncol=4, loc="upper right")
    np.atleast_1d(axes)[-1].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=10)
    return save(fig, path)


def coop_hook(scenario, log: dict[str, np.ndarray]) -> CoopHook:
    """The hook of a coop-fg run: its epochs and the four vehicles of its figures ([pipeline]
    plot_uavs, else choose_four)."""
    ep = epochs_from_log(log, scenario.vehicles)
    return CoopHook(ep, tuple(scenario.pipeline.plot_uavs) or tuple(choose_four(ep)))
