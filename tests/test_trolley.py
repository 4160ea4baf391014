"""The worked example on real data: examples/replay/trolley.py converts the LIAS UWB trolley
dataset (examples/replay/trolley/) and `testbed replay` runs every ranging estimator on it."""
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

from testbed.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _trolley():
    spec = importlib.util.spec_from_file_location("trolley_example", ROOT / "examples" / "replay" / "trolley.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_frame_convention_found_makes_the_ranges_agree_with_the_truth():
    """On the calibration segment, with q_body = q_mocap (x) (0, 1, 0, 0) every link's residual
    scatter is below 0.15 m, and every link is biased long (+0.05 to +0.4 m: UWB delays only add);
    with the motion capture quaternion taken as it is, the scatter grows (the tags' y is flipped)."""
    t = _trolley()
    tu, r = t.read_uwb(t.RAW / t.UWB_FILE)
    tm, p, q = t.read_mocap(t.RAW / t.MOCAP_FILE)
    assert np.all(np.diff(tm) > 0)  # duplicated timestamps merged
    end = tu[0] + t.CALIBRATION_FRACTION * (tu[-1] - tu[0])
    bias, sigma = t.calibration(tu, r, tm, p, q, end)
    assert bias.shape == (8, 3) and np.all((bias > 0.05) & (bias < 0.4)) and np.all(sigma < 0.15)
    from estimators.so3 import quat_conj, quat_mul
    _, sigma_as_is = t.calibration(tu, r, tm, p, quat_mul(q, quat_conj(t.MOCAP_TO_BODY)), end)
    assert sigma_as_is.mean() > 1.3 * sigma.mean()


def test_convert_then_replay_every_ranging_estimator(tmp_path, capsys):
    """Two seconds after the calibration segment, calibrated by `testbed calibrate` on the first 5 s
    of the segment: graph.poses, ranging.ekf and the ranging.lsq baseline all give the trolley's
    position, scored, with health counts; the window starts after the calibration segment (scoring
    never sees it). ranging.ekf estimates the body and each tag: the headline is the body's, the
    tags' summary is apart (`sites`)."""
    t = _trolley()
    spec = t.convert(tmp_path / "data", seconds=2.0)
    assert main(["calibrate", str(spec), "--window", "0,5", "--out", str(tmp_path / "calib.toml")]) == 0
    assert main(["replay", str(spec), "--out", str(tmp_path / "out"), "--calibration", str(tmp_path / "calib.toml"), "--no-plots"]) == 0
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    start, end = m["window_s"]
    assert end - start == 2.0 and start > 0.19 * 134.8
    assert m["calibration"]["window_s"] == [0.0, 5.0] and set(m["calibration"]["defaults"]) == {
        "graph.poses", "ranging.ekf", "ranging.lsq"}
    for key in ("graph.poses", "ranging.ekf", "ranging.lsq"):
        e = m["estimators"][key]
        pos = e["targets"]["trolley"]["position"]
        assert pos["samples"] >= 150, key  # 100 Hz epochs
        assert np.isfinite(pos["rmse_m"]) and pos["rmse_m"] < 1.0, key
        assert e["health"], key
    ekf = m["estimators"]["ranging.ekf"]  # the body and its three tags: the body's headline, the tags' apart
    assert ekf["rmse_position_m"] == ekf["targets"]["trolley"]["position"]["rmse_m"]
    tags = [ekf["targets"][f"trolley/tag{k}"]["position"] for k in range(3)]
    pooled = np.sqrt(sum(t["rmse_m"] ** 2 * t["samples"] for t in tags) / sum(t["samples"] for t in tags))
    assert np.isclose(ekf["sites"]["rmse_position_m"], pooled, rtol=1e-12)


def test_an_estimator_that_gives_nothing_says_why_in_health_and_on_stderr(tmp_path, capsys):
    """coop.one_shot on the trolley data (no GNSS, no sites it knows): exit 0, no estimate, and one
    line saying what it was fed and what it counted, in metrics.json's health block and on stderr."""
    spec = _trolley().convert(tmp_path / "data", seconds=0.3)
    assert main(["replay", str(spec), "--out", str(tmp_path / "out"), "--estimator", "coop.one_shot", "--no-plots"]) == 0
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    reason = m["estimators"]["coop.one_shot"]["health"]["no_estimates"]
    assert reason.startswith("coop.one_shot: no estimates from the rows fed (uwb ") and "health counts" in reason
    err = capsys.readouterr().err
    assert f"testbed: note: {reason}\n" in err and err.count("no estimates") == 1


def test_range_fit_jacobian_matches_central_differences_and_recovers_a_pose(monkeypatch):
    """estimators.range_lsq: the analytic Jacobian of the range residuals (position and rotation
    vector, away from zero) equals central differences to 1e-6; from a start 0.5 m and 0.3 rad off,
    exact ranges from three tags to eight anchors give the pose back to 1e-6."""
    from scipy import optimize

    from estimators.range_lsq import fit_ranges
    from estimators.so3 import quat_exp, quat_to_rotmat

    t = _trolley()
    R_true = quat_to_rotmat(quat_exp(np.array([0.05, -0.03, 1.2])))
    p_true = np.array([0.4, -0.7, 0.96])
    arms = np.repeat(t.TAGS, 8, axis=0)
    X = np.tile(t.ANCHORS, (3, 1))
    d = np.linalg.norm(p_true + arms @ R_true.T - X, axis=1)
    R0 = quat_to_rotmat(quat_exp(np.array([0.1, 0.1, 1.5])))
    fit = fit_ranges(arms, X, d, np.full(d.size, 0.05), p_true + [0.5, 0.0, 0.0], R0)
    assert fit.converged and fit.observable
    np.testing.assert_allclose(fit.p, p_true, atol=1e-6)
    np.testing.assert_allclose(fit.R, R_true, atol=1e-6)
    # the Jacobian least_squares is given: compare at a point with a rotation vector far from 0
    seen, solve = {}, optimize.least_squares

    def spy(fun, x0, jac, **kw):
        seen["res"], seen["jac"] = fun, jac
        return solve(fun, x0, jac=jac, **kw)

    monkeypatch.setattr(optimize, "least_squares", spy)
    fit_ranges(arms, X, d, np.full(d.size, 0.05), p_true, R0)
    x = np.array([0.3, -0.5, 0.9, 0.4, -0.2, 0.7])
    num = np.stack([(seen["res"](x + h) - seen["res"](x - h)) / 2e-6 for h in np.eye(6) * 1e-6], axis=1)
    np.testing.assert_allclose(seen["jac"](x), num, atol=1e-6 * np.abs(num).max())


def test_the_checks_fit_at_the_truth_is_the_linearised_pose_fit(monkeypatch):
    """examples/replay/trolley_checks.py: the pose Jacobian of the ranges (origin and a small world
    rotation) equals central differences to 1e-6, and the fit at the truth takes ranges of a pose
    moved by 10 um and 10 urad back to that move (to second order, which the flat geometry's weak roll
    and pitch amplify: 1e-8), with a missing range."""
    from scipy.spatial.transform import Rotation

    t = _trolley()
    monkeypatch.setitem(sys.modules, "trolley", t)
    spec = importlib.util.spec_from_file_location("trolley_checks", ROOT / "examples" / "replay" / "trolley_checks.py")
    checks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(checks)

    def tags(x, rot):
        turned = Rotation.from_rotvec(x[3:]).as_matrix() @ rot
        return (np.array([0.4, -0.7, 0.96]) + x[:3] + t.TAGS @ turned.T)[None], turned[None]

    rot = Rotation.from_rotvec([0.05, -0.03, 1.2]).as_matrix()
    rng, jac = checks.pose_jacobian(*tags(np.zeros(6), rot))
    num = np.stack([(checks.pose_jacobian(*tags(h, rot))[0] - checks.pose_jacobian(*tags(-h, rot))[0]).ravel() / 2e-6
                    for h in np.eye(6) * 1e-6], axis=1)
    np.testing.assert_allclose(jac[0], num, atol=1e-6)
    move = np.array([1e-5, -1e-5, 5e-6, 1e-5, -1e-5, 1e-5])
    e = (checks.pose_jacobian(*tags(move, rot))[0] - rng).reshape(1, 24)
    e[0, 5] = np.nan
    dx, cov = checks.fit_at_truth(e, jac)
    np.testing.assert_allclose(dx[0], move, atol=1e-8)
    assert cov.shape == (1, 6, 6) and np.all(np.linalg.eigvalsh(cov[0]) > 0)
