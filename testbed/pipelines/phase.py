"""Seed 003 estimator pipeline (kind "phase-ekf"): run log -> estimates, metrics, plots.

The filter's inputs (the phase stream, the masters' own navigation solution, this [pipeline]
table, the phase period) and its prior (the planned initial state plus the initial error):
testbed.plugins.builtin_phase (`prepare`); the navigation frame N (the body frame FLU of master
`nav_master`, its pose from its own antennas): estimators.phase_frames; the truth in N and the
PCRB: testbed.plugins.phase_scores.
Ranges are frame-free. The truth for scoring is the follower in N of master 3's TRUE pose
(truth/pos, truth/vel, truth/quat, truth/omega). In prescribed mode master 3 hovers level with yaw
0 at trajectory.nav_origin, so N is the world frame shifted; in flown mode it is the frame of the
hovering quadrotor (its small motion, if any, is carried by R, p and their rates).

Range-rate rows (eq. 7 as the sensor really measures it): the reported rate is the mean over the
window W = rate_periods T (0.7 s by default) ending at the epoch, i.e. (r(t) - r(t - W)) / W; it
lags the instantaneous rate by ~W / 2. `rate_rows = "window"` predicts exactly that mean
from the constant-velocity state (phase_model.measurement_model, rate_window), `"instantaneous"`
is the paper's eq. 10 (biased by the lag), `"off"` (default) uses ranges only. The rate noise is
sqrt(2) range_sigma / W per row (W shorter during the first 0.7 s).
Correlation: because the phase tracker telescopes, the reported rate equals
(r_hat(t) - r_hat(t - W)) / W to round-off (checked in tests/test_phase_scenario.py): its error is
the difference of the range errors at t and t - W. So a rate row is correlated with the same
epoch's range row (rho = +0.71) and with the range row W earlier (rho = -0.71), and consecutive
rates are NOT correlated with each other (the window's inner phase samples cancel). The paper's
EKF treats all 90 rows as independent, which counts the range information twice in velocity:
with ranges at every epoch the rate rows carry no information the ranges do not, and `"off"` is
the consistent choice, hence the default (derivation: docs/models.md, "Seed 003 range-rate
rows"). Measured on the model-matched truth of
tests/test_phase_scenario.py (phase-cross-h000 with the follower's [disturbance] equal to the
filter's q_translation / q_rotation, 30 runs, 20 s, final epoch): body ANEES 5.78 with `"off"`,
9.65 with `"window"` (over-confident), 99 % interval [4.50, 7.75] (9.64 under the former q = 1e-7).

Scores (estimators.ekf in metrics.json), body = mean of wing tips (eq. 29), frame N:
rmse_position_m, rmse_velocity_mps, rmse_attitude_deg over t >= score_start;
window scores over the last W = last_window seconds (default 100), named by W:
rmse_position_last_<W>s_m, pcrb_rmse_position_last_<W>s_m; max_abs_position_error_last_<W>s_m,
max_abs_velocity_error_last_<W>s_mps (per axis x, y, z of N: x forward, y left, z up). A window
score exists only when the run covers its window (t_last - t_first >= W): on a shorter run they are
omitted (`last_window_s` and `last_window_omitted_reason` say so), never computed over a shorter
span under the longer name (`window_keys` gives the names for a W); anees: mean over t >= score_start of the NEES
of the body position and velocity (6 dof, linear in the state, so its covariance is exact);
anees_state18: the same for the 18-state; each with its dof (`anees_dof`, ...) and its 99 %
interval (`anees_interval_99`, ...) over its effective samples (`n_eff`, ...: the epochs' errors
are correlated, docs/consistency.md); nees_final, nees_body6_final, nees_attitude6_final: the
final epoch's NEES of the 18-state, of the body position and velocity (6 dof) and of the attitude
and its rates (yaw, pitch, roll and their rates, 6 dof, eq. 30 linearized: `attitude_nees`);
pcrb_rmse_position_m: sqrt of the mean over the same
epochs of trace(body-position block of the PCRB) along the true trajectory (Tichavsky 1998, same
measurement model, same rows, same q and P0 as the filter); gate statistics; the driver's health
counts (core.Track.health: covariance_repairs, rejected_measurements, nonconverged_steps).
"""
from __future__ import annotations

import numpy as np

from estimators.core import Epoch, Gate, Gaussian, Track, drive, nees
from estimators.phase_ekf import AnalyzedGaussian, PhaseEkfCovarianceAnalysis, ProcessNoise
from estimators.phase_frames import BODY_POS, BODY_PV
from estimators.phase_model import rotation_from_antennas
from testbed.config.pipelines import PhasePipelineConfig
from testbed.plugins.builtin_phase import prepare
from testbed.plugins.phase_scores import attitude_nees, phase_pcrb, true_states, window_keys


def run_filter(cfg: PhasePipelineConfig, q: float | ProcessNoise, prior: Gaussian, meas: list,
               times: np.ndarray) -> Track:
    """The seed 003 EKF over all epochs through the library's driver (core.drive): one epoch per
    measurement, the prior at the first one. The beliefs are AnalyzedGaussian: besides the
    filter's mean and cov they carry the ACTUAL error covariance of this filter if the truth had
    no random acceleration (phase_ekf.PhaseEkfCovarianceAnalysis), for the NEES against it.
    Gate rejections per epoch are the track's rejected_measurements.
    """
    filt = PhaseEkfCovarianceAnalysis(q, Gate(alpha=cfg.gate_alpha, enabled=cfg.gate), cfg.iterations)
    epochs = [Epoch(float(t), m) for t, m in zip(times, meas)]
    return drive(filt, AnalyzedGaussian(prior.mean, prior.cov, prior.cov), epochs)


def score(cfg: PhasePipelineConfig, track: Track, states_true, body_true, R_true, bound) -> dict:
    """metrics.json `estimators.ekf` (module docstring) and the series the plots need."""
    # lazy: testbed.scoring.metrics imports scipy.stats (seconds on a cold cache); only scoring needs it
    from testbed.scoring.metrics import anees_keys, attitude_error_vector, rmse

    t, means, covs = track.t, track.mean, track.cov
    acts = np.stack([b.actual for b in track.beliefs])
    pv = means @ BODY_PV.T
    Ppv = BODY_PV @ covs @ BODY_PV.T
    e = pv - body_true[:, :6]
    R_est = np.array([rotation_from_antennas(x) for x in means])
    att = np.degrees(np.linalg.norm(attitude_error_vector(R_est, R_true), axis=-1))
    sc = t >= t[0] + cfg.score_start
    if not sc.any():  # a run shorter than score_start: score every epoch
        sc[:] = True
    last = t >= t[-1] - cfg.last_window + 1e-9
    nees6 = nees(e, Ppv)
    nees18 = nees(means - states_true, covs)
    nees6_act = nees(e, BODY_PV @ acts @ BODY_PV.T)
    Bp = BODY_POS @ bound @ BODY_POS.T
    rejected = track.rejected_measurements
    mid = int(np.argmin(np.abs(t - (t[0] + 0.5 * (t[-1] - t[0])))))
    out = {
        "rmse_position_m": rmse(e[sc, :3]),
        "rmse_velocity_mps": rmse(e[sc, 3:]),
        "rmse_attitude_deg": float(np.sqrt(np.mean(att[sc] ** 2))),
        "position_error_mid_m": e[mid, :3].tolist(),
        "position_error_final_m": e[-1, :3].tolist(),
        "sigma_position_final_m": np.sqrt(np.diag(Ppv[-1])[:3]).tolist(),
        **anees_keys(nees6[sc], 6),
        **anees_keys(nees18[sc], 18, "anees_state18"),
        **anees_keys(nees6_act[sc], 6, "anees_body6_actual_cov"),
        "nees_final": float(nees18[-1]),
        "nees_body6_final": float(nees6[-1]),
        "nees_attitude6_final": attitude_nees(means[-1], covs[-1], states_true[-1]),
        "nees_body6_actual_cov_final": float(nees6_act[-1]),
        "pcrb_rmse_position_m": float(np.sqrt(np.mean(np.trace(Bp[sc], axis1=1, axis2=2)))),
        "pcrb_sigma_position_final_m": np.sqrt(np.diag(Bp[-1])).tolist(),
        "gate_rejected_rows": int(rejected.sum()),
        "gate_epochs_with_rejection": int((rejected > 0).sum()),
        "epochs": int(t.size),
        "score_start_s": float(t[sc][0]),
        **track.health(),
        "last_window_s": float(cfg.last_window),
    }
    if t[-1] - t[0] >= cfg.last_window - 1e-9:
        k = window_keys(cfg.last_window)
        out[k["rmse"]] = rmse(e[last, :3])
        out[k["max_abs_position"]] = np.abs(e[last, :3]).max(axis=0).tolist()
        out[k["max_abs_velocity"]] = np.abs(e[last, 3:]).max(axis=0).tolist()
        out[k["pcrb_rmse"]] = float(np.sqrt(np.mean(np.trace(Bp[last], axis1=1, axis2=2))))
    else:
        out["last_window_omitted_reason"] = (f"the run covers {t[-1] - t[0]:g} s, shorter than last_window = "
                                             f"{cfg.last_window:g} s: no window scores")
    series = {"t": t, "err": e, "sigma": np.sqrt(np.diagonal(Ppv, axis1=1, axis2=2)), "att_deg": att}
    return out, series


def plot(series: dict, plots_dir, name: str) -> None:
    """Figures like the paper's figs. 4-15: position and velocity error per axis, +/-3 sigma."""
    # lazy: matplotlib, only when plots are written
    from testbed.outputs.plots import error_envelope

    t, e, s = series["t"], series["err"], series["sigma"]
    lab = ("x (fwd)", "y (left)", "z (up)")
    error_envelope(t, e[:, :3], s[:, :3], plots_dir / "position_error.png", title=f"{name}: body position error (nav frame)", ylabel="m", labels=lab)
    error_envelope(t, e[:, 3:], s[:, 3:], plots_dir / "velocity_error.png", title=f"{name}: body velocity error (nav frame)", ylabel="m/s", labels=lab)


def estimate(scenario, log: dict) -> tuple[dict, dict]:
    """Run the seed 003 EKF on a run log and score it: (estimators.ekf metrics, plot series)."""
    cfg, inp, q, prior, P0, meas = prepare(scenario, log)
    track = run_filter(cfg, q, prior, meas, inp.times)
    body, RN, states = true_states(scenario, log, cfg, inp)
    bound = phase_pcrb(cfg, q, states, inp, meas, P0)
    metrics, series = score(cfg, track, states, body, RN, bound)
    metrics = {"q_m2ps3": q.antenna, "q_translation_m2ps3": q.translation, "q_rotation_rad2ps3": q.rotation, "rate_rows": cfg.rate_rows, "init": cfg.init, **metrics}
    return metrics, series


def run(scenario, log, plots_dir):
    metrics, series = estimate(scenario, log)
    if plots_dir is not None:
        plot(series, plots_dir, scenario.name)
    return {"ekf": metrics}
