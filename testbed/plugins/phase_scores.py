"""Seed 003 scores (kind "phase-ekf") from the run's truth: the navigation-frame truth and the PCRB
(scoring only; the estimators never see these).

- `truth_in_nav`: the follower's true body state, attitude and 18-state in the navigation frame N
  of the nav master's TRUE pose (truth/pos, truth/vel, truth/quat, truth/omega);
- `phase_pcrb`: the posterior Cramer-Rao bound (Tichavsky 1998) along that true trajectory with the
  filter's own rows, measurement model, q and P0 (testbed.plugins.builtin_phase.prepare);
- `position_bound`: its body-position block in world axes, the `Bound` hook of
  testbed.plugins.hooks;
- `attitude_nees`, `window_keys`: the attitude NEES and the names of the last-window scores.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from estimators.core import nees
from estimators.phase_ekf import ProcessNoise, pcrb
from estimators.phase_frames import BODY_POS, to_nav
from estimators.phase_model import antenna_state_from_body, body_from_antennas
from estimators.so3 import euler_from_rotation, skew
from testbed.pipelines.config import PhasePipelineConfig
from testbed.plugins.builtin_phase import PhaseInputs, prepare


def truth_in_nav(log: dict, idx: np.ndarray, nav_master: int, follower: int, a: float, b: float):
    """Truth at log rows idx (K,) in N from master nav_master's TRUE pose (scoring only).

    Returns body (K, 12) [p, v, yaw, pitch, roll, their rates], R_N_follower (K, 3, 3) and the
    18-state (K, 18) with the true lever arms a, b (m).
    """
    def pose(u):
        R = Rotation.from_quat(log["truth/quat"][idx, u - 1], scalar_first=True).as_matrix()
        om = log["truth/omega"][idx, u - 1]
        return log["truth/pos"][idx, u - 1], log["truth/vel"][idx, u - 1], R, R @ skew(om)

    p3, v3, R3, R3d = pose(nav_master)
    p6, v6, R6, R6d = pose(follower)
    pN, vN = to_nav(p6, v6, p3, v3, R3, R3d)
    RN = np.einsum("kji,kjl->kil", R3, R6)
    RNd = np.einsum("kji,kjl->kil", R3d, R6) + np.einsum("kji,kjl->kil", R3, R6d)
    K = idx.size
    states = np.array([antenna_state_from_body(pN[k], vN[k], RN[k], RNd[k], a, b) for k in range(K)])
    eul = np.array([euler_from_rotation(R) for R in RN])
    # Euler rates are not scored (left 0)
    body = np.concatenate([pN, vN, eul, np.zeros_like(eul)], axis=1)
    return body, RN, states


def true_states(scenario, log: dict, cfg: PhasePipelineConfig, inp: PhaseInputs):
    """truth_in_nav at the phase epochs (scoring only): body (K, 12), R_N_follower, 18-states."""
    return truth_in_nav(log, inp.state_index, cfg.nav_master, inp.follower, scenario.world.antenna_a, scenario.world.antenna_b)


def phase_pcrb(cfg: PhasePipelineConfig, q: float | ProcessNoise, states: np.ndarray, inp: PhaseInputs, meas: list, P0: np.ndarray) -> np.ndarray:
    """PCRB (K, 18, 18) along the true 18-state trajectory with the filter's own rows and model."""
    valid = np.array([m.stacked()[2] for m in meas])
    sig_rate = np.array([np.broadcast_to(m.sigma_range_rate, (len(inp.masters), 3, 3)) for m in meas])
    sig_rate = np.where(np.isfinite(sig_rate), sig_rate, 1.0)
    W = np.where(np.isfinite(inp.windows), inp.windows, 1.0) if cfg.rate_rows == "window" else None
    return pcrb(states, inp.times, inp.master_pos, inp.master_vel, P0, cfg.sigma_range, sig_rate, q,
                valid=valid, rate_window=W)


def position_bound(scenario, log: dict) -> tuple[np.ndarray, np.ndarray, int]:
    """The PCRB of the follower's body position for plugin scores (scoring only): epoch times
    (K,) s, bound (K, 3, 3) m^2 in world axes (N rotated by the nav master's true attitude), the
    follower's number."""
    cfg, inp, q, _, P0, meas = prepare(scenario, log)
    bound = BODY_POS @ phase_pcrb(cfg, q, true_states(scenario, log, cfg, inp)[2], inp, meas, P0) @ BODY_POS.T
    R = Rotation.from_quat(log["truth/quat"][inp.state_index, cfg.nav_master - 1], scalar_first=True).as_matrix()
    return inp.times, R @ bound @ np.swapaxes(R, 1, 2), inp.follower


def attitude_nees(x: np.ndarray, P: np.ndarray, x_true: np.ndarray) -> float:
    """NEES of the follower's attitude and attitude rates (yaw, pitch, roll and their rates, 6 dof)
    at one epoch: x, x_true (18,) estimated and true antenna states in N, P (18, 18) the filter's
    covariance. Eq. 30 from the antennas (phase_model.body_from_antennas), covariance J P J^T
    linearized at the estimate, angle errors wrapped to [-pi, pi)."""
    (y, J), (y_true, _) = body_from_antennas(x), body_from_antennas(x_true)
    e = y[6:] - y_true[6:]
    e[:3] = (e[:3] + np.pi) % (2 * np.pi) - np.pi
    return float(nees(e, J[6:] @ P @ J[6:].T))


def window_keys(window_s: float) -> dict[str, str]:
    """metrics.json names of the window scores over the last `window_s` seconds:
    {"rmse", "pcrb_rmse", "max_abs_position", "max_abs_velocity"} -> key (e.g. window 100:
    "rmse_position_last_100s_m")."""
    w = f"last_{window_s:g}s"
    return {"rmse": f"rmse_position_{w}_m", "pcrb_rmse": f"pcrb_rmse_position_{w}_m",
            "max_abs_position": f"max_abs_position_error_{w}_m", "max_abs_velocity": f"max_abs_velocity_error_{w}_mps"}
