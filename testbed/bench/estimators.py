"""`testbed bench estimators`: per-step cost of our estimators next to reference libraries.

- phase_ekf: seed 003 EKF update with 90 measurement rows (5 masters) vs filterpy's
  ExtendedKalmanFilter doing the same update (same h, Jacobian, R);
- visnav: seed 004 CKF and HCKF step (predict + 4-LED update, n = 21) vs filterpy's
  CubatureKalmanFilter and UnscentedKalmanFilter on the same model (bench_visnav);
- factor_graph: seed 001 centralized solve (and with marginal covariances) vs GTSAM for 18, 100 and
  1000 UAVs, and the rounds of the distributed schemes, the accelerated one included (bench_factor_graph).
Timings are the median of repeated calls on one core (single-threaded BLAS).
"""
from __future__ import annotations

import time

import numpy as np
from filterpy.kalman import CubatureKalmanFilter, ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter

from estimators import phase_ekf as pe
from estimators.core import NO_GATE, Gaussian
from estimators.factor_graph import solve_centralized, solve_distributed
from estimators.graph.flooding import solve_flooding
from estimators.gtsam_reference import solve_gtsam as reference
from estimators.phase_model import antenna_offsets, measurement_model, stack_rows
from estimators.sigma_filters import ManifoldGaussian, make_filter
from estimators.visnav import RelNavModel, imu_input, make_state, quat_exp
from testbed.config import scenario
from testbed.plugins.builtin_visnav import estimator_config
from testbed.synthetic.coop import epoch_factory


def _median_time(fn, repeats: int) -> float:
    fn()  # warm-up
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return float(np.median(samples))


# ---- seed 003 (phase) -------------------------------------------------------------------------
def _interleaved_median_times(fns: dict, repeats: int) -> dict[str, float]:
    """Median wall time (s) of each callable in fns, called round-robin (one call of each per
    round, rotating the order) so that load changes on a shared machine hit all of them alike."""
    for fn in fns.values():
        fn()  # warm-up
    names = list(fns)
    samples = {name: [] for name in names}
    for k in range(repeats):
        for name in names[k % len(names):] + names[:k % len(names)]:
            t0 = time.perf_counter()
            fns[name]()
            samples[name].append(time.perf_counter() - t0)
    return {name: float(np.median(v)) for name, v in samples.items()}


def bench_phase_ekf(repeats: int = 200) -> list[dict]:
    """One 90-row EKF update: ours (with and without the w-test gate) vs filterpy.

    Same work on both sides, from the same epoch (ranges and range rates, (5, 3, 3) each): the
    timed call stacks them into z, evaluates h and the Jacobian (ours once, as phase_ekf.measurement_update
    does; filterpy through its HJacobian and Hx callbacks, the same
    phase_model.measurement_model), then the gain, the state and the Joseph-form covariance.
    filterpy's R is built once outside (constant sigmas); ours rebuilds its variances and masks
    in every call (PhaseMeasurement.stacked). The speedup compares ours without the gate to
    filterpy (which has none); ours with the gate is reported next to it. The three are timed
    interleaved in one process.
    """
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
            stack_rows(meas.ranges, meas.range_rates),
            HJacobian=lambda x: measurement_model(x, master_pos, master_vel)[1],
            Hx=lambda x: measurement_model(x, master_pos, master_vel, jacobian=False)[0],
        )

    # ours: gain in information form (18 x 18 Cholesky, R diagonal), Joseph-form covariance; the
    # w-test gate reuses the same factor (Woodbury), so it costs little
    t = _interleaved_median_times({
        "ours": lambda: pe.measurement_update(prior, meas, gate=NO_GATE),
        "ours_gate": lambda: pe.measurement_update(prior, meas),
        "filterpy": filterpy_update,
    }, repeats)
    filterpy_update()
    post, _ = pe.measurement_update(prior, meas, gate=NO_GATE)
    post_gate, info_gate = pe.measurement_update(prior, meas)
    return [{
        "rows": 90,
        "ours_ms": t["ours"] * 1e3,
        "ours_with_gate_ms": t["ours_gate"] * 1e3,
        "filterpy_ms": t["filterpy"] * 1e3,
        "speedup": t["filterpy"] / t["ours"],
        "speedup_with_gate": t["filterpy"] / t["ours_gate"],
        "max_state_diff": float(np.abs(post.mean - ekf.x.ravel()).max()),
        "max_cov_diff": float(np.abs(post.cov - ekf.P).max()),
        "gate_rejections": int(info_gate.rejected.size),
        "gate_max_state_diff": float(np.abs(post_gate.mean - ekf.x.ravel()).max()),
    }]


# ---- seed 004 (visnav) ------------------------------------------------------------------------
def _visnav_problem():
    """The seed 004 model (n = 21, the visnav scenario's camera and LEDs, paper IMU figures) at a
    formation state 10 m behind the leader, one 20 Hz IMU input and a 4-LED LOS measurement."""
    sc = scenario.load("visnav")
    model = RelNavModel(estimator_config(sc.pipeline, 0, 1.0))
    rng = np.random.default_rng(0)
    truth = make_state([-10.0, 0.5, 0.2], [0.1, -0.05, 0.0], quat_exp(np.array([0.01, -0.02, 0.1])))
    P0 = model.initial_cov(0.5, 0.1, np.radians(2.0))
    prior = ManifoldGaussian(model.boxplus(truth[None], (np.sqrt(np.diag(P0)) * rng.standard_normal(21))[None])[0], P0)
    u = imu_input([0.01, 0.0, 0.02], [0.05, 0.0, 9.81], [0.0, 0.01, -0.03], [0.0, 0.1, 9.80])
    b = model.los(truth[None])[0] + 3.5e-3 * rng.standard_normal((4, 3))
    return model, prior, u, b / np.linalg.norm(b, axis=1, keepdims=True), 0.05


def bench_visnav(repeats: int = 30) -> list[dict]:
    """One predict (dt = 0.05 s) + one 4-LED LOS update (m = 8) on the n = 21 model: our CKF and
    HCKF (all points as one batch) next to filterpy's CubatureKalmanFilter and
    UnscentedKalmanFilter (Merwe points, alpha 1, beta 2, kappa 0) on the same model, written in
    the tangent chart at the prior mean (x_vec -> mean (+) x_vec, one point per fx/hx call, which
    is filterpy's interface). Same Q (model.Q at the mean), R and tangent-plane measurement."""
    model, prior, u, b_meas, dt = _visnav_problem()
    ref = prior.mean
    Q = model.Q(ref, u, dt)
    meas0 = model.los_measurement(ref, b_meas)

    def fx(x, dt_):
        X = model.boxplus(ref[None], x[None])
        return model.boxminus(model.f(X, u, dt_), ref[None])[0]

    def hx(x):
        return meas0.h(model.boxplus(ref[None], x[None]))[0]

    ours = {}
    for name in ("ckf", "hckf"):
        filt = make_filter(name, model)

        def step(filt=filt):
            bp = filt.predict(prior, dt, u)
            return filt.update(bp, model.los_measurement(bp.mean, b_meas))

        ours[name] = (_median_time(step, repeats), step())

    def run_ref(kf):
        def step():
            kf.x, kf.P = np.zeros(21), prior.cov.copy()
            kf.Q, kf.R = Q, meas0.R
            kf.predict()
            # filterpy's CKF works with column vectors after its predict ((n, 1) mean): z as (m, 1)
            kf.update(meas0.y[:, None] if isinstance(kf, CubatureKalmanFilter) else meas0.y)
            return np.asarray(kf.x, float).ravel().copy()
        return step

    ckf_ref = run_ref(CubatureKalmanFilter(dim_x=21, dim_z=8, dt=dt, hx=hx, fx=fx))
    ukf_ref = run_ref(UnscentedKalmanFilter(dim_x=21, dim_z=8, dt=dt, hx=hx, fx=fx,
                                            points=MerweScaledSigmaPoints(21, alpha=1.0, beta=2.0, kappa=0.0)))
    t_ckf_ref = _median_time(ckf_ref, repeats)
    t_ukf_ref = _median_time(ukf_ref, repeats)
    x_ref = model.boxplus(ref[None], ckf_ref()[None])[0]
    diff = float(np.abs(model.boxminus(ours["ckf"][1].mean[None], x_ref[None])[0, :3]).max())
    x_ukf = model.boxplus(ref[None], ukf_ref()[None])[0]
    diff_ukf = float(np.abs(model.boxminus(ours["ckf"][1].mean[None], x_ukf[None])[0, :3]).max())
    return [{
        "n": 21, "m": 8, "dt_s": dt,
        "ours_ckf_ms": ours["ckf"][0] * 1e3,
        "ours_hckf_ms": ours["hckf"][0] * 1e3,
        "hckf_points": 2 * 21 ** 2 + 1,
        "filterpy_ckf_ms": t_ckf_ref * 1e3,
        "filterpy_ukf_ms": t_ukf_ref * 1e3,
        "speedup_ckf_vs_filterpy_ckf": t_ckf_ref / ours["ckf"][0],
        "speedup_ckf_vs_filterpy_ukf": t_ukf_ref / ours["ckf"][0],
        "target_speedup": 3.0,
        "ckf_position_diff_vs_filterpy_ckf_m": diff,
        "ckf_position_diff_vs_filterpy_ukf_m": diff_ukf,
    }]


# ---- seed 001 (coop) --------------------------------------------------------------------------
def bench_factor_graph(n_list=(18, 100, 1000), seed: int = 0, *, tol: float = 1e-4, max_rounds: int = 3000,
                       repeats: int = 3) -> list[dict]:
    """Seed 001, random connected swarms of 18, 100 and 1000 UAVs (testbed.synthetic.coop, density of 18
    UAVs in 200 x 200 x 100 m, 3 RTK): our centralized Gauss-Newton solve (dense Cholesky up to 600
    unknowns, banded Cholesky after reverse Cuthill-McKee above) and the same with marginal
    covariances (selected inverse), next to GTSAM's (Gauss-Newton; gtsam.Marginals), timed
    interleaved (median of `repeats`, one call of each per round, so load changes hit both alike);
    their largest position difference and accuracy against the generated positions. Distributed:
    the rounds the paper's scheme ("prior", undamped) and the consistent block-Jacobi ("fixed",
    damping 0.5) need (every change < tol m, cap max_rounds), and the accelerated option (flooding,
    estimators.graph.flooding: rounds until every UAV holds the centralized answer, bytes sent), each
    with its gap to the centralized solution. Times in seconds; not a test."""
    make_epoch = epoch_factory()
    out = []
    for n in n_list:
        truth, prob = make_epoch(n, seed)
        c = solve_centralized(prob, covariance="none")
        t = _interleaved_median_times({
            "ours": lambda: solve_centralized(prob, covariance="none"),
            "ours_cov": lambda: solve_centralized(prob, covariance="marginal"),
            "gtsam": lambda: reference(prob, marginals=False),
            "gtsam_cov": lambda: reference(prob, marginals=True),
        }, repeats)
        row = {
            "n": n, "m": prob.m, "mean_degree": 2 * prob.m / n,
            "ours_solve_s": t["ours"], "ours_solve_with_cov_s": t["ours_cov"], "ours_iterations": c.iterations,
            "gtsam_solve_s": t["gtsam"], "gtsam_solve_with_cov_s": t["gtsam_cov"],
            "speedup_vs_gtsam": t["gtsam"] / t["ours"], "speedup_with_cov_vs_gtsam": t["gtsam_cov"] / t["ours_cov"],
            "rmse_gnss_m": float(np.sqrt(np.mean(np.sum((prob.gnss_pos - truth) ** 2, 1)))),
            "rmse_centralized_m": float(np.sqrt(np.mean(np.sum((c.positions - truth) ** 2, 1)))),
        }
        Xg, _ = reference(prob, marginals=False)
        row["max_pos_diff_vs_gtsam_m"] = float(np.abs(Xg - c.positions).max())
        runs = {
            "prior": lambda: solve_distributed(prob, neighbour_model="prior", damping=1.0, max_rounds=max_rounds, tol=tol),
            "fixed": lambda: solve_distributed(prob, neighbour_model="fixed", damping=0.5, max_rounds=max_rounds, tol=tol),
            "flooding": lambda: solve_flooding(prob, covariance="none"),
        }
        for name, solve in runs.items():
            t0 = time.perf_counter()
            dres = solve()
            row[f"dist_{name}_s"] = time.perf_counter() - t0
            row[f"dist_{name}_rounds"] = dres.rounds
            row[f"dist_{name}_converged"] = dres.converged
            row[f"dist_{name}_bytes"] = dres.bytes_sent
            row[f"dist_{name}_gap_to_central_m"] = float(np.linalg.norm(dres.positions - c.positions, axis=1).max())
            row[f"dist_{name}_rmse_m"] = float(np.sqrt(np.mean(np.sum((dres.positions - truth) ** 2, 1))))
        out.append(row)
    return out


# ---- all ---------------------------------------------------------------------------------------
def bench_estimators() -> dict[str, list[dict]]:
    """All estimator benchmarks available: {family: rows}."""
    return {"phase_ekf": bench_phase_ekf(), "visnav": bench_visnav(), "factor_graph": bench_factor_graph()}
