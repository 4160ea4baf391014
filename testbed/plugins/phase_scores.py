"""Seed 003 scores (kind "phase-ekf") from the run's truth: the navigation-frame truth and the PCRB
(scoring only; the estimators never see these).

- `truth_in_nav`: the follower's true body state, attitude and 18-state in the navigation frame N
  of the nav master's TRUE pose (truth/pos, truth/vel, truth/quat, truth/omega);
- `phase_pcrb`: the posterior Cramer-Rao bound (Tichavsky 1998) along that true trajectory with the
  filter's own rows, measurement model, q and P0 (testbed.plugins.builtin_phase.prepare);
- `phase_hooks`: the run's hooks (testbed.plugins.hooks): `Bound`, the PCRB's body-position block
  in world axes, `PhaseWindow`, the scores in N of any estimator of the follower's body, and
  `PhaseScored`, the scores from score_start on (the 6-dof ANEES from a joint covariance of
  position and velocity, the 18-state ones from an estimator's navigation states);
- `attitude_nees`, `window_keys`: the attitude NEES and the names of the last-window scores.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from estimators.core import nees
from estimators.phase_ekf import ProcessNoise, pcrb
from estimators.phase_frames import BODY_POS, BODY_PV, to_nav
from estimators.phase_model import (antenna_state_from_body, body_from_antennas, line_rotation, masters_line,
                                    unobserved_rotation_axes)
from estimators.so3 import euler_from_rotation, skew
from testbed.config.pipelines import PhasePipelineConfig
from testbed.scoring.metrics import anees_keys, rmse
from testbed.plugins.builtin_phase import PhaseInputs, prepare
from testbed.plugins.collect import Track
from testbed.plugins.score import Bound, Hook, at_epochs


#: s: the attitude is scored at one epoch per this period (PhaseScored._attitude)
ATTITUDE_PERIOD_S = 1.0


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
    return pcrb(states, inp.times, inp.master_pos, inp.master_vel, P0, cfg.range_sigma, sig_rate, q,
                valid=valid, rate_window=W)


@dataclass(frozen=True, slots=True)
class PhaseWindow(Hook):
    """The seed 003 scores in the navigation frame N for ANY estimator giving the follower's body
    position (and velocity) in the world at the phase epochs (summary keys; axes of N: x forward,
    y left, z up):
    `position_error_mid_m`, `position_error_final_m` (3,) the error at mid-run (the epoch nearest
    the middle of the span) and at the end; `sigma_position_final_m` (3,) the estimator's own
    1-sigma at the end; `pcrb_sigma_position_final_m` (3,) the PCRB's; `last_window_s` W and, when
    the span covers W, over the epochs of the last W seconds (names: window_keys(W)): the position
    RMSE, the max |error| per axis of position and velocity, the PCRB RMSE; else
    `last_window_omitted_reason`. Figures: `plot`.
    An error e_W (world) is moved to N with the nav master's TRUE pose: e_N = R^T e_W and, for the
    velocity, e_vN = R^T (e_vW - dR/dt e_N) (the derivative of X_N = R^T (X - p)).

    target: the follower; time (K,) s the phase epochs; R, Rd (K, 3, 3) R_world_from_N of the nav
    master's true attitude and its rate (1/s); bound (K, 3, 3) m^2 the PCRB of the body position
    in N; last_window s (the [pipeline]'s)."""

    target: str
    time: np.ndarray
    R: np.ndarray
    Rd: np.ndarray
    bound: np.ndarray
    last_window: float

    def _in_nav(self, track: Track, errs: dict) -> tuple[np.ndarray, ...] | None:
        """(epoch indices k, times, e_N (k, 3), e_vN (k, 3) or None, P_N (k, 3, 3) or None) of the
        follower's world position estimates at the epochs; None when there are none."""
        s = track.get((self.target, "position"))
        if s is None or s.frame != "world":
            return None
        hit, k = at_epochs(self.time, s.time)
        if not hit.size:
            return None
        R, Rd = self.R[k], self.Rd[k]
        e = np.einsum("kji,kj->ki", R, errs[(self.target, "position")][hit])
        P = np.swapaxes(R, 1, 2) @ s.cov[hit] @ R if s.has_cov[hit].all() else None
        v = track.get((self.target, "velocity"))
        ev = None
        if v is not None and v.frame == "world" and np.array_equal(v.time, s.time):
            ev_w = errs[(self.target, "velocity")][hit]
            ev = np.einsum("kji,kj->ki", R, ev_w - np.einsum("kij,kj->ki", Rd, e))
        return k, s.time[hit], e, ev, P

    def summary(self, track: Track, errs: dict, health: dict) -> dict:
        got = self._in_nav(track, errs)
        if got is None:
            return {}
        k, t, e, ev, P = got
        B = self.bound[k]
        mid = int(np.argmin(np.abs(t - (t[0] + 0.5 * (t[-1] - t[0])))))
        out = {"position_error_mid_m": e[mid].tolist(), "position_error_final_m": e[-1].tolist(),
               **({"sigma_position_final_m": np.sqrt(np.diag(P[-1])).tolist()} if P is not None else {}),
               "pcrb_sigma_position_final_m": np.sqrt(np.diag(B[-1])).tolist(), "last_window_s": float(self.last_window)}
        if t[-1] - t[0] < self.last_window - 1e-9:
            out["last_window_omitted_reason"] = (f"the run covers {t[-1] - t[0]:g} s, shorter than last_window = "
                                                 f"{self.last_window:g} s: no window scores")
            return out
        last = t >= t[-1] - self.last_window + 1e-9
        w = window_keys(self.last_window)
        out[w["rmse"]] = rmse(e[last])
        out[w["max_abs_position"]] = np.abs(e[last]).max(axis=0).tolist()
        if ev is not None:
            out[w["max_abs_velocity"]] = np.abs(ev[last]).max(axis=0).tolist()
        out[w["pcrb_rmse"]] = float(np.sqrt(np.mean(np.trace(B[last], axis1=1, axis2=2))))
        return out

    def plot(self, shown: dict, plots_dir: Path) -> list[Path]:
        """Per fitting estimator NAME, like the paper's figs. 4-15, errors per axis of N against
        time: NAME_position_error.png (+/-3 sigma of its own covariance when it gave one) and, with a
        velocity, NAME_velocity_error.png (+/-3 sigma when it gave the joint covariance of position
        and velocity at every epoch, moved to N as the errors: T C T^T, T = [[R^T, 0],
        [-R^T dR/dt R^T, R^T]])."""
        from testbed.outputs.plots import error_envelope  # lazy: matplotlib, only when plots are written

        paths, lab = [], ("x (fwd)", "y (left)", "z (up)")
        for name, (track, errs) in shown.items():
            got = self._in_nav(track, errs)
            if got is None:
                continue
            k, t, e, ev, P = got
            sig = None if P is None else np.sqrt(np.diagonal(P, axis1=1, axis2=2))
            paths.append(error_envelope(t, e, sig, plots_dir / f"{name}_position_error.png",
                                        title=f"{name}: body position error (nav frame)", ylabel="m", labels=lab))
            if ev is not None:
                paths.append(error_envelope(t, ev, self._velocity_sigma(track, k, t), plots_dir / f"{name}_velocity_error.png",
                                            title=f"{name}: body velocity error (nav frame)", ylabel="m/s", labels=lab))
        return paths

    def _velocity_sigma(self, track: Track, k: np.ndarray, t: np.ndarray) -> np.ndarray | None:
        """(E, 3) m/s 1-sigma of the velocity in N at the epochs k (E,) (times t) from the joint
        covariance of the follower's world position and velocity; None unless it has one at each."""
        at = {round(j.time, 9): j.cov for j in track.joint.get(("position", "velocity"), ())
              if j.frame == "world" and j.targets == (self.target, self.target)}
        C = [at.get(round(float(x), 9)) for x in t.tolist()]
        if not C or any(c is None for c in C):
            return None
        Rt = np.swapaxes(self.R[k], 1, 2)
        T = np.zeros((t.size, 6, 6))
        T[:, :3, :3] = T[:, 3:, 3:] = Rt
        T[:, 3:, :3] = -Rt @ self.Rd[k] @ Rt
        PN = T @ np.stack(C) @ np.swapaxes(T, 1, 2)
        return np.sqrt(np.diagonal(PN[:, 3:, 3:], axis1=1, axis2=2))


@dataclass(frozen=True, slots=True)
class PhaseScored(Hook):
    """The seed 003 scores over the scored epochs t >= t_0 + score_start (every epoch when the run
    is shorter; t_0 the first phase epoch), for ANY estimator whose outputs fit (summary keys):
    with the follower's world position (velocity, attitude) at the phase epochs: `epochs` their
    number, `score_start_s` the first scored one, `rmse_position_after_start_m` (`rmse_velocity_after_start_m_s`,
    `rmse_attitude_after_start_deg`, the attitude error's angle) and `pcrb_rmse_position_after_start_m`
    = sqrt(mean trace) of the PCRB's body-position block over the same epochs; with the joint
    covariance of the follower's position and velocity at every scored epoch (EstimateBatch.cov_joint
    of a batch of the two, world): `anees` of the 6-dof body NEES (linear in the state, so the
    NEES is the same in N and in the world), with its dof, 99 % interval and n_eff
    (testbed.scoring.metrics.anees_keys), and `nees_body6_final` at the last epoch; with the estimator's
    navigation states in N in the phase-18 layout (testbed.plugins.api.NavigationStates, frame
    "phase-N": phase.ekf): `anees_state18` (18 dof, the filter's covariance), `nees_final` and
    `nees_attitude6_final` (attitude_nees) at the last epoch, the attitude where the filter observes
    it and the share and axes where it does not (`_attitude`), and, with the actual covariance,
    `anees_body6_actual_cov` (the body position and velocity against the covariance analysis'
    actual covariance) and `nees_body6_actual_cov_final`.

    target: the follower; time (K,) s the phase epochs; score_start s (the [pipeline]'s); body (K, 6)
    the true body position and velocity in N, states (K, 18) the true 18-state in N (truth_in_nav);
    bound (K, 3, 3) m^2 the PCRB of the body position in N."""

    target: str
    time: np.ndarray
    score_start: float
    body: np.ndarray
    states: np.ndarray
    bound: np.ndarray
    line: np.ndarray | None = None

    def _scored(self, t: np.ndarray) -> np.ndarray:
        """(len(t),) bool: the scored ones of times t (all when none is)."""
        sc = t >= self.time[0] + self.score_start
        return sc if sc.any() else np.ones_like(sc)

    def summary(self, track: Track, errs: dict, health: dict) -> dict:
        out = {}
        s = track.get((self.target, "position"))
        if s is not None and s.frame == "world":
            hit, k = at_epochs(self.time, s.time)
            if hit.size:
                sc = self._scored(s.time[hit])
                out["epochs"] = int(hit.size)
                out["score_start_s"] = float(s.time[hit][sc][0])
                out["rmse_position_after_start_m"] = rmse(errs[(self.target, "position")][hit][sc])
                out["pcrb_rmse_position_after_start_m"] = float(np.sqrt(np.mean(np.trace(self.bound[k[sc]], axis1=1, axis2=2))))
        for q, key, scale in (("velocity", "rmse_velocity_after_start_m_s", 1.0),
                              ("attitude", "rmse_attitude_after_start_deg", float(np.degrees(1.0)))):
            v = track.get((self.target, q))
            if v is not None and v.frame == "world":
                hit, _ = at_epochs(self.time, v.time)
                if hit.size:
                    e = errs[(self.target, q)][hit][self._scored(v.time[hit])]
                    out[key] = float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))) * scale
        out.update(self._joint(track, errs))
        out.update(self._navigation(track))
        return out

    def _joint(self, track: Track, errs: dict) -> dict:
        """The 6-dof body NEES from the joint covariance of position and velocity (world)."""
        joints = [j for j in track.joint.get(("position", "velocity"), ())
                  if j.frame == "world" and j.targets == (self.target, self.target)]
        p, v = track.get((self.target, "position")), track.get((self.target, "velocity"))
        if not joints or p is None or v is None or not np.array_equal(p.time, v.time):
            return {}
        tj = np.array([j.time for j in joints])
        hit, k = at_epochs(p.time, tj)  # joints -> rows of the position (and velocity) series
        if hit.size != tj.size or np.unique(k).size != p.time.size:
            return {}
        C = np.stack([joints[i].cov for i in hit])[np.argsort(k)]
        e = np.concatenate([errs[(self.target, "position")], errs[(self.target, "velocity")]], axis=1)
        ne, sc = nees(e, C), self._scored(p.time)
        out = {"nees_body6_final": float(ne[-1])}
        if self.line is None:
            return {**anees_keys(ne[sc], 6), **out}
        # a line of masters: the NEES along the turn about it (1 dof) apart from the rest (5 dof)
        _, kp = at_epochs(self.time, p.time)
        est = np.concatenate([p.value, v.value], axis=1)
        n = np.array([line_rotation(x[:3], x[3:], (ln[:3], ln[3:6], ln[6:])) for x, ln in zip(est, self.line[kp])])
        nu = nees_along(e, C, n)
        return {**anees_keys(ne[sc] - nu[sc], 5), **anees_keys(nu[sc], 1, "anees_unobserved"), **out,
                "unobserved_line_axis": self.line[kp[-1], 6:].tolist()}

    def _navigation(self, track: Track) -> dict:
        """The 18-state scores from the estimator's navigation states (frame phase-N, layout phase-18)."""
        nav = track.navigation
        if nav is None or nav.frame != "phase-N" or nav.layout != "phase-18":
            return {}
        hit, k = at_epochs(self.time, np.asarray(nav.time, float))
        if not hit.size:
            return {}
        x, P, x_true = np.asarray(nav.mean)[hit], np.asarray(nav.cov)[hit], self.states[k]
        sc = self._scored(np.asarray(nav.time, float)[hit])
        n18 = nees(x - x_true, P)
        out = {**anees_keys(n18[sc], 18, "anees_state18"), "nees_final": float(n18[-1]),
               "nees_attitude6_final": attitude_nees(x[-1], P[-1], x_true[-1])}
        out.update(self._attitude(np.asarray(nav.time, float)[hit], x, P, x_true, sc))
        if nav.actual is not None:
            e = x @ BODY_PV.T - self.body[k]
            n6 = nees(e, BODY_PV @ np.asarray(nav.actual)[hit] @ BODY_PV.T)
            out.update({**anees_keys(n6[sc], 6, "anees_body6_actual_cov"), "nees_body6_actual_cov_final": float(n6[-1])})
        return out

    @staticmethod
    def _attitude(t: np.ndarray, x: np.ndarray, P: np.ndarray, x_true: np.ndarray, sc: np.ndarray) -> dict:
        """The attitude's scores where the filter observes it. At the scored epochs, one per
        ATTITUDE_PERIOD_S (eq. 30 per epoch is the costly part; the NEES stays correlated over many
        seconds, so its effective samples hardly change, docs/consistency.md), the filter's covariance says
        which rotation axes it does not observe (estimators.phase_model.unobserved_rotation_axes,
        the filter's mean and covariance only): `attitude_unobserved_fraction`, the share of those
        epochs with at least one; `attitude_unobserved_axes_final`, the axes (unit vectors in N) at
        the last epoch; `anees_attitude6` (yaw, pitch, roll and their rates, 6 dof, attitude_nees)
        over the epochs whose attitude is observed in every direction (absent when none is).
        t (K,) s; x, x_true (K, 18); P (K, 18, 18); sc (K,) bool the scored epochs."""
        k = np.flatnonzero(sc)
        k = k[np.unique(np.floor((t[k] - t[k[0]]) / ATTITUDE_PERIOD_S), return_index=True)[1]]
        seen = [i for i in k if not len(unobserved_rotation_axes(x[i], P[i]))]
        out = {"attitude_unobserved_fraction": 1.0 - len(seen) / k.size,
               "attitude_unobserved_axes_final": unobserved_rotation_axes(x[-1], P[-1]).tolist()}
        if seen:
            out.update(anees_keys(np.array([attitude_nees(x[i], P[i], x_true[i]) for i in seen]), 6, "anees_attitude6"))
        return out


def phase_hooks(scenario, log: dict) -> list[Hook]:
    """The scoring hooks of a phase-ekf run (scoring only): the PCRB of the follower's body
    position in world axes (N rotated by the nav master's true attitude; testbed.plugins.score.Bound),
    the frame-N scores (PhaseWindow) and the scores from score_start on (PhaseScored)."""
    cfg, inp, q, _, P0, meas = prepare(scenario, log)
    body, _, states = true_states(scenario, log, cfg, inp)
    bound = BODY_POS @ phase_pcrb(cfg, q, states, inp, meas, P0) @ BODY_POS.T
    idx, u = inp.state_index, cfg.nav_master - 1
    R = Rotation.from_quat(log["truth/quat"][idx, u], scalar_first=True).as_matrix()
    Rd = R @ np.array([skew(w) for w in log["truth/omega"][idx, u]])
    target = f"uav{inp.follower}"
    return [Bound(target, inp.times, R @ bound @ np.swapaxes(R, 1, 2)),
            PhaseWindow(target, inp.times, R, Rd, bound, float(cfg.last_window)),
            PhaseScored(target, inp.times, float(cfg.score_start), body[:, :6], states, bound, masters_line_world(inp))]


def masters_line_world(inp: PhaseInputs) -> np.ndarray | None:
    """(K, 9) per phase epoch the masters' line (estimators.phase_model.masters_line) in world axes,
    [c (m), c_dot (m/s), e], from the masters' own antennas and the nav master's measured pose (the
    inputs, as phase.ekf maps N to the world: c_W = p + R c, c_dot_W = v + R c_dot + dR/dt c,
    e_W = R e); None unless the masters lie along a line at every epoch."""
    lines = [masters_line(X, V) for X, V in zip(inp.master_pos, inp.master_vel)]
    if any(ln is None for ln in lines):
        return None
    p, v, R, Rd = inp.nav_pose
    c, cd, e = (np.array(a) for a in zip(*lines))
    return np.concatenate([p + np.einsum("kij,kj->ki", R, c), v + np.einsum("kij,kj->ki", R, cd) + np.einsum("kij,kj->ki", Rd, c),
                           np.einsum("kij,kj->ki", R, e)], axis=1)


def nees_along(e: np.ndarray, C: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(K,) the part of the NEES e^T C^-1 e of errors e (K, d) with covariances C (K, d, d) that lies
    along the directions n (K, d):
        (n^T C^-1 e)^2 / (n^T C^-1 n),
    chi-square with 1 dof for a consistent estimator; the rest of the NEES is chi-square with d - 1
    dof, the NEES of the error in the directions the ones along n leave (any T (d - 1, d) with
    T n = 0: (T e)^T (T C T^T)^-1 T e)."""
    Ci_n = np.linalg.solve(C, n[..., None])[..., 0]
    return np.einsum("ki,ki->k", Ci_n, e) ** 2 / np.einsum("ki,ki->k", Ci_n, n)


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
