"""Range bias (docs/replay.md, "Range bias"): the calibration table of the recorded-data format and
the bias states of ranging.ekf, on an exported simulated run with a known bias added to some links."""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from testbed.config import scenario
from testbed.cli import main
from testbed.plugins import EstimatorSpec
from testbed.plugins.feed import run_plugin
from testbed.plugins.loading import resolve
from testbed.replay.recording import RecordedTruth, load_recording
from testbed.runner import run

#: m: the bias added to uav1's ranges to three of its sixteen anchors (three times the declared
#: 0.1 m range sigma, of both signs)
BIAS = {"anchor1": 0.3, "anchor6": -0.3, "anchor11": 0.3}
TAG = "uav1/uwb"
PARAMS = {"follower": "uav1", "known": [], "antennas": [TAG]}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """bandwidth for 10 s (4 UAVs ranging to 16 anchors at 10 Hz, 0.1 m white range noise; NLOS
    rows dropped, so that the only bias is the one added), exported; its links.csv as rows."""
    d = tmp_path_factory.mktemp("bias")
    sc = scenario.load("bandwidth", {"sensors.uwb.nlos": "drop"}, duration=10.0)
    run(sc, d / "run", plots=False)
    assert main(["export", str(d / "run"), "--out", str(d / "data")]) == 0
    return d / "data"


def _copy(exported: Path, to: Path, bias: dict[str, float], calibration: str | None = None) -> Path:
    """The export with `bias` added to uav1's ranges to those anchors, and calibration.csv."""
    shutil.copytree(exported, to)
    if bias:  # else links.csv stays as exported
        with open(exported / "links.csv", newline="") as fh:
            rows = list(csv.DictReader(fh))
        for r in rows:
            if r["src"] == TAG and r["dst"] in bias:
                r["value"] = repr(float(r["value"]) + bias[r["dst"]])
        with open(to / "links.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    if calibration is not None:
        (to / "calibration.csv").write_text(calibration)
    return to / "spec.toml"


def _run(spec: Path, **params):
    """(position RMSE m of uav1's tag, its errors (K, 3) and covariances (K, 3, 3), the estimator)."""
    rec = load_recording(spec)
    p = {**PARAMS, **params}
    keep: list = []
    track, _, _ = run_plugin(resolve([EstimatorSpec(entry="ranging.ekf", params=p)])[0], rec.context("ekf", p),
                             rec.feed, keep=keep)
    s = track[(TAG, "position")]
    err = s.value - RecordedTruth(rec).at(TAG, "position", s.time)
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1)))), err, s.cov, keep[0]


def test_bias_states_recover_the_added_biases_within_their_covariance_and_beat_the_bias_free_filter(exported, tmp_path):
    spec = _copy(exported, tmp_path / "d", BIAS)
    rmse_plain, _, _, _ = _run(spec)
    rmse_bias, err, cov, est = _run(spec, bias_states=True)
    assert rmse_bias < rmse_plain
    # every link's bias, jointly: the error of the bias vector (true: BIAS, 0 elsewhere) in its own
    # covariance, chi2 with one dof per link (false alarm 1 %)
    o = 6 * est.n
    keys = sorted(est.bias_index.items(), key=lambda kv: kv[1])
    assert len(keys) == 16
    e = np.array([est.belief.mean[o + k] - BIAS.get(other, 0.0) for (_, _, other), k in keys])
    nees = float(e @ np.linalg.solve(est.belief.cov[o:, o:], e))
    assert nees < chi2.ppf(0.99, e.size)
    # and the biases were found, not merely covered: each added one is far outside its sigma from 0
    for (_, _, other), (b, sigma) in est.bias_estimates().items():
        if other in BIAS:
            assert abs(b) > 3 * sigma and np.sign(b) == np.sign(BIAS[other])


def test_a_calibration_table_removes_the_known_bias_and_gives_its_sigma_as_the_prior(exported, tmp_path):
    rows = "".join(f"{TAG},{a},{b},,0.02,\n" for a, b in BIAS.items())
    spec = _copy(exported, tmp_path / "d", BIAS, "src,dst,bias,scale,sigma_bias,sigma_scale\n" + rows)
    clean = load_recording(exported / "spec.toml").tables["links"]["value"]
    rec = load_recording(spec)
    np.testing.assert_allclose(rec.tables["links"]["value"], clean, rtol=0, atol=1e-9)
    assert rec.context("x", {}).sensors["uwb"]["bias_sigma"] == {
        TAG: {a: 0.02 for a in BIAS}, **{a: {TAG: 0.02} for a in BIAS}}
    _, _, _, est = _run(spec, bias_states=True, bias_sigma=0.5)
    # the calibrated links' states start at sigma 0.02 m, the others at bias_sigma: posterior <= prior
    for (_, _, other), (_, sigma) in est.bias_estimates().items():
        assert sigma <= (0.02 if other in BIAS else 0.5)
    assert max(s for (_, _, o), (_, s) in est.bias_estimates().items() if o in BIAS) <= 0.02


def test_time_offset_rows_add_up_and_reach_the_estimators_unapplied(exported, tmp_path):
    """A device row's and a link row's time offsets add up per link (cal. 10), both orders, in
    Context.sensors["uwb"]["time_offset"]; the ranges stay as recorded."""
    spec = _copy(exported, tmp_path / "d", {}, "src,dst,time_offset\nuav1/uwb,,0.05\nanchor1,uav1/uwb,-0.02\n")
    rec = load_recording(spec)
    off = rec.context("x", {}).sensors["uwb"]["time_offset"]
    assert off[TAG]["anchor1"] == off["anchor1"][TAG] == pytest.approx(0.03, abs=1e-15)
    assert off[TAG]["anchor2"] == 0.05 and "anchor1" not in off.get("uav2/uwb", {})
    np.testing.assert_array_equal(rec.tables["links"]["value"], load_recording(exported / "spec.toml").tables["links"]["value"])


def test_device_and_link_rows_add_up_and_scale_divides(exported, tmp_path):
    """d_meas = (1 + s) d + b_src + b_dst + b_link: a device row of the tag (0.1 m, scale 1e-3) and
    a link row (0.2 m, scale 2e-3) on anchor1."""
    spec = _copy(exported, tmp_path / "d", {}, "src,dst,bias,scale\nuav1/uwb,,0.1,0.001\nanchor1,uav1/uwb,0.2,0.002\n")
    raw = load_recording(exported / "spec.toml").tables["links"]
    got = load_recording(spec).tables["links"]
    tag = raw["src"] == TAG
    link = tag & (raw["dst"] == "anchor1")
    want = np.where(link, (raw["value"] - 0.3) / 1.003, np.where(tag, (raw["value"] - 0.1) / 1.001, raw["value"]))
    np.testing.assert_allclose(got["value"], want, rtol=0, atol=1e-12)


def test_a_scale_is_never_extrapolated_beyond_its_span(exported, tmp_path):
    """cal. 2c: a link whose error is a constant 0.2 m, calibrated with a spurious scale (-5 %, as a
    fit on a short span can keep) fitted on the middle 2 m of its true ranges only, its line through
    the truth at the span's middle. Within the span the correction's error is |s| |d - mid| / (1 + s);
    beyond, the correction is held at its value at the span's nearer end, so no fed range is off by
    more than |s| (to - from) / 2 = 0.05 m. Extrapolated, the link's farthest ranges would be off by
    several times that."""
    s, beta = -0.05, 0.2
    clean = load_recording(exported / "spec.toml").tables["links"]
    link = (clean["src"] == TAG) & (clean["dst"] == "anchor1") & (clean["kind"] == "uwb")
    mid = float(np.median(clean["value"][link]))
    lo, hi = mid - 1.0, mid + 1.0
    row = f"{TAG},anchor1,{beta - s * mid!r},{s},{lo!r},{hi!r}\n"
    spec = _copy(exported, tmp_path / "d", {"anchor1": beta}, "src,dst,bias,scale,scale_from,scale_to\n" + row)
    fed = load_recording(spec).tables["links"]
    # the clean ranges (no bias added) stand for the truth: the link's rows as the calibration sees them
    err = np.abs(fed["value"][link] - clean["value"][link])
    assert err.max() <= abs(s) * (hi - lo) / 2 + 1e-12
    beyond = np.abs(clean["value"][link] - mid) - (hi - lo) / 2
    # the span is narrower than the use: extrapolated, the farthest rows would be off by over 3 times the bound
    assert (beyond > 0).sum() > 10 and beyond.max() > hi - lo
    np.testing.assert_array_equal(fed["value"][~link], clean["value"][~link])


@pytest.mark.parametrize("table, says", [
    ("src,dst,bias\nuav1/nope,,0.1\n", "column src: 'uav1/nope' is not a site"),
    ("src,dst,bias\nuav1/uwb,anchor1,nan\n", "column bias: must be a finite number"),
    ("src,dst,bias\nuav1/uwb,anchor1,0.1\nanchor1,uav1/uwb,0.2\n", "is calibrated twice (also row 1)"),
    ("src,dst,bias\nuav1/uwb,,0.1\nuav1/uwb,,0.2\n", "the device uav1/uwb is calibrated twice"),
    ("src,dst,scale\nuav1/uwb,,0.5\n", "column scale: must be at most 0.1"),
    ("src,dst,bias,sigma_bias\nuav1/uwb,,0.1,0\n", "column sigma_bias: must be positive"),
    ("src,dst,time_offset\nuav1/uwb,anchor1,-2\n", "column time_offset: must be at most 1"),
    ("src,dst,time_offset,sigma_time_offset\nuav1/uwb,,0.1,-1\n", "column sigma_time_offset: must be positive"),
    ("src,dst,bias,offset\nuav1/uwb,,0.1,1\n", "unknown column 'offset'"),
    ("src,dst,scale,scale_from\nuav1/uwb,anchor1,0.01,5\n", "column scale_to: a scale's span needs both"),
    ("src,dst,bias,scale_from,scale_to\nuav1/uwb,anchor1,0.1,5,8\n", "column scale_from: a span without a scale"),
    ("src,dst,scale,scale_from,scale_to\nuav1/uwb,anchor1,0.01,8,5\n", "column scale_to: must exceed scale_from (8)"),
])
def test_a_bad_calibration_table_is_one_line_and_exit_2(exported, tmp_path, capsys, table, says):
    spec = _copy(exported, tmp_path / "d", {}, table)
    capsys.readouterr()
    assert main(["replay", str(spec), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "calibration.csv" in err and says in err, err
    assert not (tmp_path / "out").exists()


def test_graph_poses_bias_states_recover_the_added_biases_within_their_covariance(exported, tmp_path):
    """graph.poses with bias_states: every uav1 link's bias (true: BIAS, 0 elsewhere) within the
    joint covariance of the fused belief (chi2 with one dof per link, 1 % false alarm); each added
    bias found (beyond 3 sigma, its sign); the tag's RMSE below the bias-free graph's."""
    spec = _copy(exported, tmp_path / "d", BIAS)
    rec = load_recording(spec)
    rmse = {}
    for states in (False, True):
        p = {"bias_states": states}
        keep: list = []
        track, _, _ = run_plugin(resolve([EstimatorSpec(entry="graph.poses", params=p)])[0], rec.context("g", p), rec.feed, keep=keep)
        s = track[(TAG, "position")]
        err = s.value - RecordedTruth(rec).at(TAG, "position", s.time)
        rmse[states] = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
    est = keep[0]
    assert rmse[True] < rmse[False]
    mine = {k: i for k, i in est.bias_index.items() if TAG in k}
    assert len(mine) == 16
    idx = np.array(list(mine.values()))
    e = est.bias_mean[idx] - np.array([BIAS.get(next(n for n in k[1:] if n != TAG), 0.0) for k in mine])
    assert float(e @ np.linalg.solve(est.bias_cov[np.ix_(idx, idx)], e)) < chi2.ppf(0.99, e.size)
    for k, (b, sigma) in est.bias_estimates().items():
        other = next(n for n in k[1:] if n != TAG) if TAG in k else None
        if other in BIAS:
            assert abs(b) > 3 * sigma and np.sign(b) == np.sign(BIAS[other])


def test_solve_epochs_biases_fused_over_independent_epochs_find_the_biases():
    """estimators.graph.batch with bias unknowns: 200 epochs of one point among five anchors, two
    links biased (+0.3, -0.2 m, prior sigma 0.3 m, range noise 0.05 m); the epochs' likelihoods of
    the biases, added in information form as graph.poses does, give the biases within their
    covariance (chi2, 2 dof, 1 % false alarm), each far from 0."""
    from estimators.graph.batch import EpochFactors, solve_epochs

    rng = np.random.default_rng(0)
    X = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10], [10, 10, 5.0]])
    E, bias = 200, np.array([0.3, -0.2])
    true = rng.uniform(2, 8, (E, 1, 3))
    ep, k = np.repeat(np.arange(E), 5), np.tile(np.arange(5), E)
    d = np.linalg.norm(true[ep, 0] - X[k], axis=1) + np.where(k < 2, bias[np.minimum(k, 1)], 0.0) + rng.normal(0, 0.05, ep.size)
    f = EpochFactors(kinds=("point",), r_epoch=ep, r_a=np.zeros(ep.size, int), r_b=np.full(ep.size, -1),
                     r_arm_a=np.zeros((ep.size, 3)), r_arm_b=X[k], r_d=d, r_sigma=np.full(ep.size, 0.05),
                     **EpochFactors.empty_rows(), r_bias=np.where(k < 2, k, -1), b_mean=np.zeros(2), b_cov=0.09 * np.eye(2))
    res = solve_epochs(f, true + 0.5, np.tile(np.eye(3), (E, 1, 1, 1)))
    assert res.converged.all() and res.observable.all() and res.b.shape == (E, 2) and res.cov.shape == (E, 5, 5)
    L0 = np.linalg.inv(f.b_cov)
    Le = np.linalg.inv(res.cov[:, 3:, 3:])
    Lam = L0 + (Le - L0).sum(axis=0)
    b = np.linalg.solve(Lam, (np.einsum("eij,ej->ei", Le, res.b)).sum(axis=0))
    e = b - bias
    assert e @ Lam @ e < chi2.ppf(0.99, 2)
    assert np.all(np.abs(b) > 10 / np.sqrt(np.diag(Lam)))


def test_graph_poses_motion_model_carries_bias_states_found_within_their_covariance(exported, tmp_path):
    """graph.poses with its motion model (q_translation; the prescribed flight is constant velocity,
    so 0) and bias_states: the biases are states of the joint belief (estimators.graph.motion), a
    random constant per link; uav1's sixteen biases (true: BIAS, 0 elsewhere) lie within their joint
    covariance (chi2, 16 dof, 1 % false alarm), each added one beyond 3 sigma with its sign, and the
    tag's RMSE is below the same filter's without bias states."""
    spec = _copy(exported, tmp_path / "d", BIAS)
    rec = load_recording(spec)
    rmse, est = {}, None
    for states in (False, True):
        p = {"bias_states": states, "q_translation": 0.0, "q_rotation": 0.0}
        keep: list = []
        track, _, _ = run_plugin(resolve([EstimatorSpec(entry="graph.poses", params=p)])[0], rec.context("g", p), rec.feed, keep=keep)
        s = track[(TAG, "position")]
        err = s.value - RecordedTruth(rec).at(TAG, "position", s.time)
        rmse[states], est = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1)))), keep[0]
    assert rmse[True] < rmse[False], rmse
    b = est.belief
    mine = [k for k in b.bias_at if TAG in k]
    assert len(mine) == 16
    idx = np.array([b.bias_at[k] for k in mine])
    e = b.biases(mine) - np.array([BIAS.get(next(n for n in k[1:] if n != TAG), 0.0) for k in mine])
    assert float(e @ np.linalg.solve(b.cov[np.ix_(idx, idx)], e)) < chi2.ppf(0.99, e.size)
    for k, (bias, sigma) in est.bias_estimates().items():
        other = next(n for n in k[1:] if n != TAG) if TAG in k else None
        if other in BIAS:
            assert abs(bias) > 3 * sigma and np.sign(bias) == np.sign(BIAS[other])
