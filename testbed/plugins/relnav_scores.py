"""Seed 004 (kind "visnav") scoring side: the start the runtime gives the relative filters, and the
relative-frame scores and figures of ANY estimator that estimates the follower's position,
velocity and attitude relative to the leader: a scoring hook (testbed.plugins.score.Hook), `RelNav`.

Truth (read here, never by an estimator): the follower's state relative to the leader in the
leader's body frame FLU, p = R_L^T (p_F - p_L) m, v = R_L^T (v_F - v_L) m/s, q = q_L^* q_F
(`true_relative_state`; the runtime's own truth, testbed.plugins.truth, is the same quantity,
Estimate.frame "uavL").

Start (`start_prior`, Context.prior["uavF"]): at the first IMU sample of the leader, the true
relative state (+) a draw from the initial covariance P0 (stream "init"; estimators.visnav
RelNavModel.initial_cov with the [pipeline] init_sigma_*), biases at their nominal 0: (22,)
state, (21, 21) covariance.

Keys (`RelNav.summary`), over the E instants where the estimator gave all three quantities of the
follower relative to the leader (the per-quantity RMSEs and 3-dof ANEES are the generic scores,
testbed.plugins.score): `epochs` = E, `final_position_error_m` |e_p| at the last one (m),
`finite` (every error finite); with the joint covariance of the three at every one of them
(EstimateBatch.cov_joint of a batch of the follower's position, velocity and attitude, the visnav.*
filters' (9, 9)), the ANEES of the 9-dim navigation error (p, v, theta; the NEES e^T P^-1 e of the
three errors stacked): `anees` (`anees_dof` 9) with its 99 % interval over its effective samples
(`anees_interval_99`, `n_eff`: testbed.scoring.metrics.anees_keys, docs/consistency.md) and `final_nees`
at the last instant.
Figures (`RelNav.plot`): {name}_position.png, {name}_velocity.png, {name}_attitude.png, each
fitting estimator's errors against time with its own +/-3 sigma.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimators.core import nees
from estimators.sigma_filters import ManifoldGaussian
from estimators.so3 import quat_conj, quat_mul, quat_to_rotmat
from estimators.visnav import RelNavModel
from testbed.scoring.metrics import anees_keys
from testbed.plugins.builtin_visnav import estimator_config
from testbed.plugins.collect import Track
from testbed.plugins.score import Hook, common_times, fitting
from testbed.rng import stream_rng

QUANTITIES = (("position", "m", 1.0), ("velocity", "m/s", 1.0), ("attitude", "deg", 180.0 / math.pi))


def true_relative_state(log: dict, leader: int, follower: int, idx: np.ndarray) -> np.ndarray:
    """True relative state (len(idx), 22) at log rows idx: p, v in the leader frame, q = q_L^* q_F,
    biases 0 (scoring and the start prior only)."""
    L, F = leader - 1, follower - 1
    qL, qF = log["truth/quat"][idx, L], log["truth/quat"][idx, F]
    RL = quat_to_rotmat(qL)
    dp = log["truth/pos"][idx, F] - log["truth/pos"][idx, L]
    dv = log["truth/vel"][idx, F] - log["truth/vel"][idx, L]
    X = np.zeros((idx.size, 22))
    X[:, 0:3] = np.einsum("nji,nj->ni", RL, dp)
    X[:, 3:6] = np.einsum("nji,nj->ni", RL, dv)
    q = quat_mul(quat_conj(qL), qF)
    X[:, 6:10] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return X


def start_prior(scenario, log: dict) -> ManifoldGaussian:
    """The relative filters' start (module docstring) on a visnav run log."""
    cfg, cam = scenario.pipeline, scenario.sensors.camera
    model = RelNavModel(estimator_config(cfg, scenario.seed, cam.focal_length))
    t0 = log["imu/time"][log["imu/vehicle"] == cam.leader][0]
    truth0 = true_relative_state(log, cam.leader, cam.follower, np.array([int(np.argmin(np.abs(log["time"] - t0)))]))[0]
    P0 = model.initial_cov(cfg.init_sigma_pos, cfg.init_sigma_vel, cfg.init_sigma_att_deg * math.pi / 180.0)
    d = np.zeros(P0.shape[0])
    d[:9] = stream_rng(scenario.seed, "init").standard_normal(9) * np.sqrt(np.diag(P0)[:9])
    x0 = truth0.copy()
    x0[10:] = 0.0
    return ManifoldGaussian(model.boxplus(x0[None], d[None])[0], P0)


@dataclass(frozen=True, slots=True)
class RelNav(Hook):
    """The relative-frame scores of `target` ("uavF") relative to `frame` ("uavL")."""

    target: str
    frame: str

    def fit(self, track: Track, errs: dict) -> tuple[np.ndarray, list, list] | None:
        """(t (E,) s, [errors (E, 3)], [sigma (E, 3)]) in QUANTITIES order at the instants with all
        three quantities, or None when the estimator's outputs do not fit."""
        series = [track.get((self.target, q)) for q, _, _ in QUANTITIES]
        if any(s is None or s.frame != self.frame for s in series):
            return None
        common = common_times(series)
        if common is None:
            return None
        t, idx = common
        e = [errs[(self.target, q)][j] for (q, _, _), j in zip(QUANTITIES, idx)]
        sig = [np.sqrt(np.clip(np.diagonal(s.cov[j], axis1=1, axis2=2), 0, None)) for s, j in zip(series, idx)]
        return t, e, sig

    def summary(self, track: Track, errs: dict, health: dict) -> dict:
        got = self.fit(track, errs)
        if got is None:
            return {}
        t, e, _ = got
        out = {"epochs": int(t.size), "final_position_error_m": float(np.linalg.norm(e[0][-1])),
               "finite": bool(all(np.isfinite(x).all() for x in e))}
        ne = self.joint_nees(track, t, e)
        if ne is not None:
            out.update({**anees_keys(ne, 9), "final_nees": float(ne[-1])})
        return out

    def joint_nees(self, track: Track, t: np.ndarray, e: list) -> np.ndarray | None:
        """(E,) NEES of the 9-dim navigation error at the instants t (E,) s with the estimator's
        joint covariance (9, 9) of the three quantities, errors e [(E, 3)] in QUANTITIES order;
        None unless it gave one at every instant (1e-9 s)."""
        names = [q for q, _, _ in QUANTITIES]
        at = {}
        for key, joints in getattr(track, "joint", {}).items():
            if isinstance(key, str) or sorted(key) != sorted(names):
                continue
            for j in joints:
                if j.frame == self.frame and set(j.targets) == {self.target}:
                    at[round(j.time, 9)] = (key, j.cov)
        got = [at.get(round(float(x), 9)) for x in t.tolist()]
        if not got or any(g is None for g in got):
            return None
        err = np.stack([np.concatenate([e[names.index(q)][k] for q in key]) for k, (key, _) in enumerate(got)])
        return nees(err, np.stack([C for _, C in got]))

    def plot(self, shown: dict, plots_dir: Path) -> list[Path]:
        from testbed.outputs.plots import error_envelope  # lazy: matplotlib, only when plots are written

        paths = []
        for name, (t, e, sig) in fitting(self, shown):
            for (q, unit, k), eq, sq in zip(QUANTITIES, e, sig):
                where = "follower" if q == "attitude" else "leader"
                paths.append(error_envelope(t, k * eq, None if not np.isfinite(sq).any() else k * sq,
                                            plots_dir / f"{name}_{q}.png",
                                            title=f"{name} relative {q} error ({where} frame)", ylabel=unit))
        return paths


def relnav_hook(scenario) -> RelNav:
    """The hook of a visnav run: the camera's follower relative to its leader."""
    cam = scenario.sensors.camera
    return RelNav(f"uav{cam.follower}", f"uav{cam.leader}")
