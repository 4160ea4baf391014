"""`testbed bench estimators`: per-step cost of our estimators next to reference libraries.

- phase_ekf: seed 003 EKF update with 90 measurement rows (5 masters) vs filterpy's
  ExtendedKalmanFilter doing the same update (same h, Jacobian, R);
- factor_graph: seed 001 centralized solve vs GTSAM for 18, 100 and 1000 UAVs, and distributed
  rounds to converge (estimators.gtsam_reference.bench).
Timings are the median of repeated calls on one core (single-threaded BLAS).
"""
from __future__ import annotations

import time

import numpy as np


def _median_time(fn, repeats: int) -> float:
    fn()  # warm-up
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return float(np.median(samples))


# ---- seed 003 (phase) -------------------------------------------------------------------------
def bench_phase_ekf(repeats: int = 200) -> list[dict]:
    """One 90-row EKF update: ours (with and without the w-test gate) vs filterpy."""
    from filterpy.kalman import ExtendedKalmanFilter

    from estimators import phase_ekf as pe
    from estimators.core import Gaussian
    from estimators.phase_model import antenna_offsets, measurement_model

    rng = np.random.default_rng(0)
    bodies = np.array([[100, 0, 0], [0, 100, 0], [0, 0, 0], [0, -100, 0], [-100, 0, 0]], float)
    master_pos = bodies[:, None, :] + antenna_offsets()[None]
    master_vel = np.zeros_like(master_pos)
    x_true = np.concatenate([(np.array([-150.0, 180, 160]) + antenna_offsets()).ravel(), np.tile([4.0, -4, 3], 3)])
    z_true, _ = measurement_model(x_true, master_pos, master_vel, jacobian=False)
    sig = np.where(np.arange(90) % 18 < 9, 0.05, 0.1)
    z = z_true + sig * rng.standard_normal(90)
    prior = Gaussian(x_true + 0.3 * rng.standard_normal(18), np.eye(18) * 0.5)
    ranges, rates = z.reshape(5, 2, 3, 3)[:, 0], z.reshape(5, 2, 3, 3)[:, 1]
    meas = pe.PhaseMeasurement(ranges, rates, master_pos, master_vel, 0.05, 0.1)

    ekf = ExtendedKalmanFilter(dim_x=18, dim_z=90)
    ekf.R = np.diag(sig**2)

    def filterpy_update():
        ekf.x, ekf.P = prior.mean.copy(), prior.cov.copy()
        ekf.update(
            z,
            HJacobian=lambda x: measurement_model(x, master_pos, master_vel)[1],
            Hx=lambda x: measurement_model(x, master_pos, master_vel, jacobian=False)[0],
        )

    ours_gate = _median_time(lambda: pe.update(prior, meas), repeats)
    ours = _median_time(lambda: pe.update(prior, meas, gate=pe.NO_GATE), repeats)
    ref = _median_time(filterpy_update, repeats)
    filterpy_update()
    post, _ = pe.update(prior, meas, gate=pe.NO_GATE)
    return [{
        "rows": 90,
        "ours_ms": ours * 1e3,
        "ours_with_gate_ms": ours_gate * 1e3,
        "filterpy_ms": ref * 1e3,
        "speedup": ref / ours,
        "max_state_diff": float(np.abs(post.mean - ekf.x.ravel()).max()),
    }]


# ---- seed 004 (visnav) ------------------------------------------------------------------------


# ---- seed 001 (coop) --------------------------------------------------------------------------
def bench_factor_graph() -> list[dict]:
    from estimators.gtsam_reference import bench

    return bench(n_list=(18, 100, 1000), seed=0)


# ---- all ---------------------------------------------------------------------------------------
def bench_estimators() -> dict[str, list[dict]]:
    """All estimator benchmarks available: {family: rows}."""
    return {"phase_ekf": bench_phase_ekf(), "factor_graph": bench_factor_graph()}
