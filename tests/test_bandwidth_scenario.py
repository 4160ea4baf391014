"""Seed 000 scenario `bandwidth` end to end through the real testbed (simulate -> log -> its default
estimator bandwidth.fusion, scored with the fusion bound hook, testbed.plugins.fusion_bound).

One 30 s uwb-mode run (300 filter steps, 4 nodes) is shared by the tests of this module.
"""
import dataclasses
import json
import warnings

import numpy as np
import pytest
from scipy.stats import norm

from testbed.config import scenario as scenario_mod
from testbed.errors import ConfigError
from testbed.log import load_log
from testbed.reproduce import bandwidth_batch as pb
from testbed.errors import EstimatorsFailed
from testbed.runner import run

DURATION = 30.0


@pytest.fixture(scope="module")
def uwb_run(tmp_path_factory):
    sc = scenario_mod.load("bandwidth", duration=DURATION)
    out = tmp_path_factory.mktemp("bw") / "run"
    metrics = run(sc, out, plots=False)  # its figures: test_sweep's serial runs
    return sc, metrics, load_log(out / "log.npz"), out


def test_uwb_mode_end_to_end_metrics_and_tracking(uwb_run):
    sc, metrics, log, out = uwb_run
    assert json.loads((out / "metrics.json").read_text()) == json.loads(json.dumps(metrics))
    m = metrics["estimators"]["bandwidth"]
    assert m["entry"] == "bandwidth.fusion"
    for key in ("J_empirical", "J_bound", "rmse_position_per_vehicle_m", "bound_holds", "bytes_received_per_step"):
        assert key in m, key
    assert len(m["rmse_position_per_vehicle_m"]) == 4 and len(m["bound_holds"]) == 4 and m["within_budget"]
    # T1: each node receives 5 components of 8 bytes per step = the budget
    assert m["bytes_received_per_step"] == [8.0 * sc.pipeline.budget] * 4 == [40.0] * 4
    K = int(DURATION / sc.pipeline.dt)
    h = m["health"]
    assert h["steps"] == K and h["measurement_epochs_missing"] == 0 and h["measurements_used"] == 4 * (K + 1)
    # T1's bound recursion (eq. 15) diverges for nodes 3 and 4 on this geometry: their M_i become
    # numerically singular, are given without it and J_bound is null with its reason
    assert h["estimates_without_cov"] > 0 and m["J_bound"] is None and "J_bound" in m["null_reasons"]
    # Tracking tolerance from V and the run length: the raw pseudo-measurement y_i(k) (the naive
    # estimate; the truth has no process noise) has mean squared error mean_k tr V_i(k); its
    # realised time average over K+1 independent epochs of a 3-D error falls below that by at
    # most z sqrt(2/(3 (K+1))) relative (chi-square, 3 (K+1) dof, z = 3.3: 0.05 % one-sided).
    # The fused estimate must beat even that lower edge at every node.
    raw_ms = _raw_ms(sc, log)
    tol = raw_ms * (1 - 3.3 * np.sqrt(2 / (3 * (K + 1))))
    rmse = np.array(m["rmse_position_per_vehicle_m"])
    assert np.all(rmse ** 2 < tol), (rmse ** 2, tol)
    assert np.isfinite(m["J_empirical"]) and m["J_empirical"] == pytest.approx(
        (K + 1) * float((rmse ** 2).sum()), rel=1e-9)


def _raw_ms(sc, log) -> np.ndarray:
    """(N,) mean squared error a raw pseudo-measurement is expected to have, mean_k tr V_i(k) (m^2)."""
    meas = pb.measurements(sc, log)
    return np.trace(meas["V"], axis1=-2, axis2=-1).mean(0)


def test_pseudo_measurement_V_matches_empirical_covariance(uwb_run):
    """Whitened by its own V_i(k) (linear error propagation of the range noise, eqs. 21-23),
    the pseudo-measurement error y_i(k) - x_true(k) must be N(0, I3). With n samples, every
    entry of the sample covariance has standard error sqrt(2/n) (diagonal) or sqrt(1/n)
    (off-diagonal) and the mean sqrt(1/n); tolerance z of a 1 % Bonferroni test over the 9 numbers."""
    sc, _, log, _ = uwb_run
    assert not log["uwb/nlos"].any()  # the model has no NLOS term: the geometry must not block
    meas = pb.measurements(sc, log)
    assert meas["available"].all()
    e = meas["y"] - meas["truth"][:, None, :]  # (K+1, N, 3) m
    u = np.linalg.solve(np.linalg.cholesky(meas["V"]), e[..., None])[..., 0].reshape(-1, 3)
    n = u.shape[0]
    z = norm.ppf(1 - 0.01 / (2 * 9))
    S = u.T @ u / n
    assert np.all(np.abs(u.mean(0)) < z / np.sqrt(n)), u.mean(0)
    assert np.all(np.abs(np.diag(S) - 1) < z * np.sqrt(2 / n)), np.diag(S)
    off = S[np.triu_indices(3, 1)]
    assert np.all(np.abs(off) < z * np.sqrt(1 / n)), off
    # and V is not trivially large: a 2x overstatement would fail the diagonal test above,
    # since 0.5 is far outside 1 +/- z sqrt(2/n)
    assert z * np.sqrt(2 / n) < 0.5


def test_estimator_never_reads_truth(uwb_run):
    sc, _, log, _ = uwb_run
    est = pb.estimate(sc, log)
    fake = dict(log)
    for k in ("qpos", "qvel", "uwb/clean"):
        fake[k] = log[k] + 7.0
    fake["truth/pos"] = log["truth/pos"] + 3.0  # scoring changes, estimates must not
    est2 = pb.estimate(sc, fake)
    assert np.array_equal(est["xhat"], est2["xhat"]) and np.array_equal(est["M"], est2["M"])
    assert not np.array_equal(est["truth"], est2["truth"])


def test_same_seed_same_metrics_and_faults_option(uwb_run, tmp_path):
    sc, metrics, _, _ = uwb_run
    again = run(sc, tmp_path / "again", plots=False)
    assert again["estimators"] == metrics["estimators"]
    # dropped messages and a failed node: fewer bytes delivered, still within budget, still tracking
    faulty = scenario_mod.load("bandwidth", {"pipeline.drop_prob": "0.3", "pipeline.fail_node": "2",
                                             "pipeline.fail_time": "10.0"}, duration=DURATION)
    m = run(faulty, tmp_path / "faulty", plots=False)["estimators"]["bandwidth"]
    assert m["within_budget"]
    assert sum(m["bytes_received_per_step"]) < 0.7 * sum(metrics["estimators"]["bandwidth"]["bytes_received_per_step"])
    # node 2 is silent after 10 s of 30: at most a third of its nominal components sent
    nominal = metrics["estimators"]["bandwidth"]["health"]["components_sent_uav2"]
    assert m["health"]["components_sent_uav2"] <= nominal * (10.0 / DURATION) + 1e-9
    assert np.all(np.array(m["rmse_position_per_vehicle_m"]) ** 2 < _raw_ms(faulty, uwb_run[2]))


def test_paper_mode_is_refused_by_the_run(tmp_path):
    """measurements = "paper" draws its data from the truth: no estimator of a run may read it, so
    bandwidth.fusion refuses it (testbed reproduce bandwidth runs the paper's setup itself)."""
    sc = scenario_mod.load("bandwidth", {"pipeline.measurements": '"paper"'}, duration=1.0)
    with pytest.raises(EstimatorsFailed, match="measurements"):
        run(sc, tmp_path / "paper", plots=False)


@pytest.mark.parametrize("override,key", [
    ({"pipeline.selection": '"T9"'}, "pipeline.selection"),
    ({"pipeline.groups": "[[1, 2, 3, 4], [5, 6, 7, 8], [9, 10, 11, 12], [13, 14, 15, 99]]"}, "pipeline.groups"),
    ({"pipeline.drop_prob": "1.5"}, "pipeline.drop_prob"),
])
def test_bad_pipeline_values_name_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        scenario_mod.load("bandwidth", override)


def test_dt_not_multiple_of_uwb_period_is_a_config_error(uwb_run):
    sc = uwb_run[0]
    with pytest.raises(ConfigError, match=r"pipeline\.dt"):  # refused when the scenario is built, before any run
        dataclasses.replace(sc, pipeline=dataclasses.replace(sc.pipeline, dt=0.15))


def test_a_node_without_pseudo_measurements_is_counted_and_json_stays_strict(tmp_path):
    """An anchor of node 1's group moved 1000 km away (a case the fuzz test found): node 1 never has
    a pseudo-measurement; health counts its missing epochs, metrics.json stays strict JSON, and no
    numpy warning is raised on the way."""
    sc = scenario_mod.load("bandwidth", duration=2.0, overrides={"world.anchors[0]": "[1000000.0, 0.0, 0.0]"})
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        run(sc, tmp_path / "run", plots=False)
    m = json.loads((tmp_path / "run" / "metrics.json").read_text(), parse_constant=pytest.fail)["estimators"]["bandwidth"]
    K = int(2.0 / sc.pipeline.dt)
    assert m["health"]["measurement_epochs_missing"] == K + 1 and m["health"]["measurements_used"] == 3 * (K + 1)


def test_a_diverged_fusion_gives_no_estimate_and_says_so(tmp_path):
    """On this geometry the paper's T1 bound recursion overflows and the fused state with it at
    151.8 s: bandwidth.fusion then gives no estimate (counted in health), the run still succeeds,
    and J_empirical, no longer a sum over every epoch, is null with its reason."""
    sc = scenario_mod.load("bandwidth", duration=155.0)
    m = run(sc, tmp_path / "run", plots=False)["estimators"]["bandwidth"]
    K = int(155.0 / sc.pipeline.dt)
    assert 0 < m["health"]["estimates_not_finite"] < 4 * (K + 1) and m["J_empirical"] is None
    assert "of the" in m["null_reasons"]["J_empirical"] and np.isfinite(m["rmse_position_m"])
