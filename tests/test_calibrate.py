"""`testbed calibrate` (docs/calibration.md): on a small simulated dataset with a known per-link bias,
scale and range noise and a truth that is a known white-acceleration motion, the calibration file
gives them back within bounds derived from the sample size; `testbed replay --calibration` applies it
(ranges corrected, noise defaults, the window not scored); bad input is one line and exit 2."""
from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import chi2, norm, t as t_dist

from testbed.cli import main
from testbed.replay.export import write_csv
from testbed.replay.recording import RecordedTruth, load_recording

T = 0.1          # s, epoch spacing
DURATION = 30.0  # s
SIGMA = 0.05     # m, range noise injected
Q_T = 0.02       # m^2/s^3, white acceleration of the body (per axis)
Q_R = 0.05       # rad^2/s^3, white angular acceleration
TAG_OFFSET = 0.15  # s, tag "a"'s time offset (cal. 10): 0.15 s at the rover's 0.9 m/s, up to 0.14 m of range
#: m, beside the rover's path (about 25 m from (-8, -5) towards (16, 10)): each range spans metres
ANCHORS = np.array([[-12.0, 0.0, 0.0], [-6.0, -6.0, 3.0], [0.0, 5.0, 0.5], [3.0, -2.0, 4.0],
                    [8.0, 12.0, 2.0], [12.0, 4.0, 1.0]])
ARMS = {"a": [0.15, 0.0, 0.0], "b": [-0.075, 0.13, 0.0], "c": [-0.075, -0.13, 0.0]}  # centroid at the origin


def _cv_path(rng, n: int, q: float, v0: np.ndarray) -> np.ndarray:
    """(n, 3) samples at spacing T of a constant-velocity process with white acceleration q: the
    exact discretization, [[T^3/3, T^2/2], [T^2/2, T]] q per axis (docs/calibration.md, cal. 5)."""
    L = np.linalg.cholesky(q * np.array([[T ** 3 / 3, T ** 2 / 2], [T ** 2 / 2, T]]))
    x, v, out = np.zeros(3), v0.astype(float), []
    for _ in range(n):
        out.append(x.copy())
        w = L @ rng.standard_normal((2, 3))
        x, v = x + T * v + w[0], v + w[1]
    return np.array(out)


def _ar1(rng, n: int, phi: float) -> np.ndarray:
    """(n,) a stationary AR(1) series of variance SIGMA^2 and lag-one correlation phi (white for 0):
    x_k = phi x_{k-1} + sqrt(1 - phi^2) SIGMA w_k; its integrated time is (1 + phi) / (1 - phi) rows."""
    w = SIGMA * rng.standard_normal(n)
    if phi == 0.0:
        return w
    x = np.empty(n)
    x[0] = w[0]
    for k in range(1, n):
        x[k] = phi * x[k - 1] + np.sqrt(1 - phi * phi) * w[k]
    return x


def _write_dataset(out: Path, seed: int, duration: float, corr: float, timed: bool = False) -> dict:
    """A rover (three tags) among six anchors, spacing T for `duration` s; per link a bias (|b| < 0.3 m), a
    scale (2 to 4 %, either sign: over each link's span of metres of range, several SIGMA) and noise
    _ar1(corr) added to the true range; timed: tag "a"'s radio stamps its ranges TAG_OFFSET s late, so
    its links measure the distance at t + TAG_OFFSET (cal. 10), the others at t; truth at every epoch;
    written to directory out (spec.toml and the tables). Returns {link: (b, s, c)}."""
    rng = np.random.default_rng(seed)
    n = int(round(duration / T)) + 1
    t = np.round(T * np.arange(n), 9)
    pos = _cv_path(rng, n, Q_T, np.array([0.8, 0.5, 0.0])) + [-8.0, -5.0, 1.0]
    phi = _cv_path(rng, n, Q_R, np.array([0.0, 0.0, 0.3]))  # increments of phi are the body rotation vectors
    R = [Rotation.identity()]
    for d in np.diff(phi, axis=0):
        R.append(R[-1] * Rotation.from_rotvec(d))
    R = Rotation.concatenate(R)
    at = lambda x: (np.stack([np.interp(x, t, pos[:, k]) for k in range(3)], axis=1),  # noqa: E731
                    Slerp(t, R)(np.clip(x, t[0], t[-1])))
    truth_bias = {}
    rows = {k: [] for k in ("time", "src", "dst", "kind", "value")}
    for i, X in enumerate(ANCHORS):
        for s, arm in ARMS.items():
            b, sc = rng.uniform(-0.3, 0.3), rng.choice([-1, 1]) * rng.uniform(0.02, 0.04)
            c = TAG_OFFSET if timed and s == "a" else 0.0
            truth_bias[(f"anchor{i}", f"rover/{s}")] = (b, sc, c)
            p_c, R_c = at(t + c)
            d = np.linalg.norm(p_c + R_c.apply(arm) - X, axis=1)
            rows["time"] += t.tolist()
            rows["src"] += [f"anchor{i}"] * n
            rows["dst"] += [f"rover/{s}"] * n
            rows["kind"] += ["uwb"] * n
            rows["value"] += ((1 + sc) * d + b + _ar1(rng, n, corr)).tolist()
    out.mkdir()
    q = R.as_quat(scalar_first=True)
    write_csv(out / "links.csv", {k: np.array(v) for k, v in rows.items()})
    write_csv(out / "truth.csv", {"time": t, "body": np.full(n, "rover"), "x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2],
                                  "qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3]})
    anchors = "\n".join(f"anchor{i} = [{', '.join(map(repr, a.tolist()))}]" for i, a in enumerate(ANCHORS))
    sites = "\n".join(f"{s} = {arm}" for s, arm in ARMS.items())
    (out / "spec.toml").write_text(f"format = 1\nseed = 0\n\n[[estimators]]\nentry = \"ranging.ekf\"\n"
                                   f"params = {{ range_sigma = 0.05 }}\n\n[window]\nstart = 0.0\nend = {duration}\n\n"
                                   f"[bodies.rover.sites]\n{sites}\n\n[anchors]\n{anchors}\n")
    return truth_bias


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """_write_dataset over DURATION with white range noise and time offsets. Returns (spec path,
    {link: (b, s, c)})."""
    d = tmp_path_factory.mktemp("calib") / "data"
    return d / "spec.toml", _write_dataset(d, 7, DURATION, 0.0, timed=True)


@pytest.fixture(scope="module")
def calibrated(dataset, tmp_path_factory):
    """`testbed calibrate` on the whole 30 s: the file and its TOML."""

    out = tmp_path_factory.mktemp("cal") / "calib.toml"
    assert main(["calibrate", str(dataset[0]), "--window", f"0,{DURATION}", "--out", str(out)]) == 0
    return out, tomllib.loads(out.read_text())


def _link_rows(c: dict) -> dict:
    """The calibration file's link rows {(src, dst): row}, each row's bias the link's total: its own
    and its two devices' rows (docs/calibration.md, cal. 9)."""
    dev = {r["src"]: r.get("bias", 0.0) for r in c["links"] if "dst" not in r}
    return {(r["src"], r["dst"]): {**r, "bias": r["bias"] + dev.get(r["src"], 0.0) + dev.get(r["dst"], 0.0)}
            for r in c["links"] if "dst" in r}


def test_calibrate_recovers_the_injected_bias_scale_offset_and_noise_within_their_sampling_error(dataset, calibrated):
    """Per link, b and s each alone: (estimate - true) / its sigma is Student's t with n - 2 dof (the
    noise variance estimated from the residuals), inside its central 99.9 % with Bonferroni over the
    54 coordinates; the device time offsets are kept (cal. 10b) and each link's total (its two
    devices' rows) lies within that bound of its true offset, in the sum of the two devices' sigmas
    (at least its own sigma); the pooled range sigma, sigma^2 dof / SIGMA^2 ~ chi2(dof), inside its
    central 99.9 %."""
    _, truth_bias = dataset
    _, c = calibrated
    links = _link_rows(c)
    assert set(links) == set(truth_bias)
    assert c["fit"]["offset_rows"] == 1
    dev = {r["src"]: r for r in c["links"] if "dst" not in r}
    for key, (b, s, off) in truth_bias.items():
        r = links[key]
        n = r["samples"]
        assert n == int(round(DURATION / T)) + 1 and "scale" in r, key  # a real scale predicts (cal. 2b)
        lim = t_dist.ppf(1 - 0.0005 / (3 * len(truth_bias)), n - 2)
        assert abs(r["bias"] - b) < lim * r["sigma_bias"], key
        assert abs(r["scale"] - s) < lim * r["sigma_scale"], key
        total, sigma = (sum(dev[e][k] for e in key) for k in ("time_offset", "sigma_time_offset"))
        assert abs(total - off) < lim * sigma, key
    dof = c["fit"]["range_dof"]
    assert dof == len(truth_bias) * (int(round(DURATION / T)) + 1 - 2)
    stat = c["noise"]["range_sigma"] ** 2 * dof / SIGMA ** 2
    assert chi2.ppf(0.0005, dof) < stat < chi2.ppf(0.9995, dof)


def test_calibrate_recovers_the_process_noise_of_a_white_acceleration_truth(calibrated):
    """Truth is exactly the constant-velocity model with white acceleration Q_T (and Q_R for the
    attitude): the rule picks the epoch spacing (no truth noise to fall off), and q N / q_true is
    chi-square with the N non-overlapping second differences reported: inside its central 99.9 %."""
    _, c = calibrated
    for name, q_true in (("q_translation", Q_T), ("q_rotation", Q_R)):
        n = c["fit"][f"{name}_samples"]
        assert abs(c["fit"][f"{name}_spacing_s"] - T) < 1e-9
        assert n == 3 * (int(round(DURATION / T)) // 2)
        stat = c["noise"][name] * n / q_true
        assert chi2.ppf(0.0005, n) < stat < chi2.ppf(0.9995, n), name


def test_a_window_ending_at_the_last_row_keeps_the_process_noise(tmp_path):
    """A 6 s dataset calibrated on 0,6: the epoch spacing (a median of rounded time differences) times
    the rows overshoots 6 s by rounding; the grid still lies within the truth, and both densities are written."""
    spacing = float(np.median(np.diff(np.round(T * np.arange(61), 9))))
    assert spacing * 60 > 6.0  # the case: a grid of spacing * k would end past the truth's last row
    _write_dataset(tmp_path / "d", 3, 6.0, 0.0)
    out = tmp_path / "c.toml"
    assert main(["calibrate", str(tmp_path / "d" / "spec.toml"), "--window", "0,6", "--out", str(out)]) == 0
    noise = tomllib.loads(out.read_text())["noise"]
    assert {"q_translation", "q_rotation"} <= set(noise), sorted(noise)


def _tau_half_width(tau: float, rows: int, links: int) -> float:
    """Half-width (rows) of the central 99.9 % of the pooled integrated time (cal. 8) of `links` links
    of `rows` rows each with true time tau and equal noise (equal weights): per link, Madras and
    Sokal's var = 2 (2M + 1) tau^2 / rows for a sum over M lags, M = 6 tau (an exponential
    autocorrelation summed to e^-6 of its start), averaged over the independent links."""
    return norm.ppf(0.9995) * tau * np.sqrt(2 * (2 * 6 * tau + 1) / (rows * links))


def test_white_range_noise_gives_a_correlation_time_of_one_row(dataset, calibrated):
    """White noise: range_correlation (cal. 8) is one row's spacing, so ranging.ekf's ranges keep
    their sigma (factor max(1, range_correlation / T) = 1 within the bound)."""
    _, c = calibrated
    rows = int(round(DURATION / T)) + 1
    assert 1.0 - 1e-9 <= c["noise"]["range_correlation"] / T <= 1.0 + _tau_half_width(1.0, rows, len(dataset[1]))


def test_ar1_range_noise_gives_its_integrated_time(tmp_path):
    """AR(1) range errors of lag-one correlation 0.8 (integrated time 9 rows, 0.9 s) over 100 s: the
    pooled range_correlation (cal. 8) is 9 T within _tau_half_width, and the range sigma's
    sigma^2 (dof / tau) / SIGMA^2 lies in the central 99.9 % of chi2(dof / tau) (dof / tau
    effectively independent residuals): a filter's effective sigma, range_sigma sqrt(9), follows."""
    corr, duration = 0.8, 100.0
    tau = (1 + corr) / (1 - corr)
    truth_bias = _write_dataset(tmp_path / "data", 11, duration, corr)
    out = tmp_path / "calib.toml"
    assert main(["calibrate", str(tmp_path / "data" / "spec.toml"), "--window", f"0,{duration}", "--out", str(out)]) == 0
    c = tomllib.loads(out.read_text())
    rows = int(round(duration / T)) + 1
    assert abs(c["noise"]["range_correlation"] / T - tau) <= _tau_half_width(tau, rows, len(truth_bias))
    dof = c["fit"]["range_dof"] / tau
    stat = c["noise"]["range_sigma"] ** 2 * dof / SIGMA ** 2
    assert chi2.ppf(0.0005, dof) < stat < chi2.ppf(0.9995, dof)


def test_replay_with_the_calibration_corrects_ranges_sets_noise_defaults_and_skips_its_window(dataset, tmp_path, capsys):
    """calibrate on the first 15 s, replay all 30 s: ranging.ekf gets range_sigma, q_translation and
    q_rotation from the file but its range_sigma set in the spec stays, no estimate inside [0, 15] s is
    scored (counted apart), and every range fed is the recorded one with the file's bias and scale
    of its link removed."""

    spec, _ = dataset
    cal = tmp_path / "calib.toml"
    assert main(["calibrate", str(spec), "--window", "0,15", "--out", str(cal)]) == 0
    c = tomllib.loads(cal.read_text())
    assert main(["replay", str(spec), "--out", str(tmp_path / "r"), "--calibration", str(cal), "--no-plots"]) == 0
    assert "window 0-15 s not scored" in capsys.readouterr().out
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["calibration"]["window_s"] == [0.0, 15.0]
    assert m["calibration"]["defaults"] == {"ranging.ekf": {k: v for k, v in c["noise"].items() if k != "range_sigma"}}
    e = m["estimators"]["ranging.ekf"]
    assert e["unscored_estimates"]["rover position in the calibration window"] == 151
    assert e["targets"]["rover"]["position"]["samples"] == 150
    # the ranges fed are the recorded ones with the file's bias and scale removed, row for row, each
    # scale held at its value at the nearer end of its span beyond it (cal. 2c): the span is the true
    # distances of the link's rows in 0-15 s, and the replay's rows reach beyond it
    rec = load_recording(spec)
    raw = rec.tables["links"]
    fed = load_recording(spec, calibration=cal).tables["links"]
    inf = float("inf")
    fits = {frozenset(k): (r["bias"], r.get("scale", 0.0), r.get("scale_from", -inf), r.get("scale_to", inf))
            for k, r in _link_rows(c).items()}
    b, s, lo, hi = np.array([fits[frozenset(k)] for k in zip(raw["src"], raw["dst"])]).T
    truth, beyond = RecordedTruth(rec), 0
    for (src, dst), r in _link_rows(c).items():
        if "scale" in r:
            rows = (raw["src"] == src) & (raw["dst"] == dst)
            t = raw["time"][rows]
            d = np.linalg.norm(truth.at(src, "position", t) - truth.at(dst, "position", t), axis=1)
            assert (r["scale_from"], r["scale_to"]) == pytest.approx((d[t <= 15].min(), d[t <= 15].max()), abs=1e-9)
            beyond += int(np.sum((d < r["scale_from"] - 0.5) | (d > r["scale_to"] + 0.5)))
    assert beyond > 100
    # r = d + b + s clamp(d, lo, hi): d = r - b - s clamp(d_lin, lo, hi), d_lin = (r - b) / (1 + s) within the span
    want = raw["value"] - b - s * np.clip((raw["value"] - b) / (1 + s), lo, hi)
    np.testing.assert_allclose(fed["value"], want, rtol=1e-12)
    # the time offsets are not applied at load: the estimators get each link's (its devices' rows summed;
    # cal. 10), both orders
    offsets = load_recording(spec, calibration=cal).context("x", {}).sensors["uwb"]["time_offset"]
    dev = {r["src"]: r.get("time_offset", 0.0) for r in c["links"] if "dst" not in r}
    for a, b in _link_rows(c):
        assert offsets[a][b] == offsets[b][a] == dev.get(a, 0.0) + dev.get(b, 0.0) != 0.0


def _one_line_exit_2(capsys, argv: list[str], needle: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("testbed: error: ") and needle in err, err


def test_bad_input_is_one_line_and_exit_2_with_nothing_written(dataset, calibrated, tmp_path, capsys):
    spec, _ = dataset
    out = tmp_path / "c.toml"
    _one_line_exit_2(capsys, ["calibrate", str(spec), "--window", "100,200", "--out", str(out)],
                     "--window 100,200: outside the data")
    _one_line_exit_2(capsys, ["calibrate", str(spec), "--window", "5", "--out", str(out)], "expected T0,T1")
    _one_line_exit_2(capsys, ["calibrate", str(spec), "--window", "5,1", "--out", str(out)], "T0 < T1")
    # truth that stops before the window: no link with truth at both ends in it
    short = tmp_path / "short"
    short.mkdir()
    for name in ("spec.toml", "links.csv"):
        (short / name).write_text((spec.parent / name).read_text())
    truth = (spec.parent / "truth.csv").read_text().splitlines()
    (short / "truth.csv").write_text("\n".join(truth[:52]) + "\n")  # 0 to 5 s
    _one_line_exit_2(capsys, ["calibrate", str(short / "spec.toml"), "--window", "10,20", "--out", str(out)],
                     "no uwb link has 3 or more rows with truth")
    assert not out.exists()
    # malformed calibration files: the replay writes nothing
    good, c = calibrated
    text = good.read_text()
    for bad, needle in ((text.replace("format = 1", "format = 2"), "format: expected 1"),
                        (text.replace("range_sigma = ", "range_sigma = -"), "noise.range_sigma"),
                        (re.sub(r"\nq_rotation = .*", "\nq_rotation = 1e-20", text), "noise.q_rotation: must be 0 or in"),
                        (text.replace('src = "anchor0"', 'src = "anchor99"', 1), "'anchor99' is not a site"),
                        (text + "\nextra = 1\n", "extra: unknown key"),
                        (re.sub(r"\ntime_offset = [^\n]*", "\ntime_offset = 1.5", text, count=1), "time_offset: must be at most 1"),
                        ("window = [", "not valid TOML")):
        f = tmp_path / "bad.toml"
        f.write_text(bad)
        _one_line_exit_2(capsys, ["replay", str(spec), "--out", str(tmp_path / "r"), "--calibration", str(f)], needle)
        assert not (tmp_path / "r").exists()
    # one calibration per replay: a calibration.csv beside the spec and a file
    both = tmp_path / "both"
    both.mkdir()
    for name in ("spec.toml", "links.csv", "truth.csv"):
        (both / name).write_text((spec.parent / name).read_text())
    (both / "calibration.csv").write_text("src,bias\nanchor0,0.1\n")
    _one_line_exit_2(capsys, ["replay", str(both / "spec.toml"), "--out", str(tmp_path / "r"), "--calibration", str(good)],
                     "keep one calibration")
    _one_line_exit_2(capsys, ["calibrate", str(both / "spec.toml"), "--window", "0,5", "--out", str(out)],
                     "calibrate estimates what this table holds")
    assert not out.exists() and not (tmp_path / "r").exists()


def test_device_biases_split_each_link_and_are_kept_only_where_they_predict_left_out_links():
    """cal. 9, 9b (testbed.replay.device_bias): biases made of device parts (plus a tag-tag link, which
    fixes the anchors-tags gauge) are split back into those parts, exactly; every link keeps its total
    (device parts plus remainder); the device rows are kept. Biases with no device structure (each
    link its own, alternating in sign) are not kept: leaving a link out, the devices predict it worse
    than no device model."""
    from testbed.replay.device_bias import device_split

    beta = {"a0": 0.10, "a1": -0.05, "a2": 0.20, "t0": 0.03, "t1": 0.12}
    ends = [(a, t) for a in ("a0", "a1", "a2") for t in ("t0", "t1")] + [("t0", "t1")]
    b = np.array([beta[x] + beta[y] for x, y in ends])
    split = device_split(ends, b)
    assert split.kept and np.abs(split.remainder).max() < 1e-12
    assert all(abs(split.devices[k] - v) < 1e-12 for k, v in beta.items())
    noise = np.array([0.2, -0.2, -0.2, 0.2, 0.2, -0.2, 0.0])
    split = device_split(ends, b + noise)
    totals = np.array([split.devices[x] + split.devices[y] for x, y in ends]) + split.remainder
    np.testing.assert_allclose(totals, b + noise, atol=1e-12)
    assert not device_split(ends[:6], noise[:6]).kept


@pytest.mark.parametrize("entry", ["ranging.ekf", "graph.poses"])
def test_time_offsets_from_the_calibration_lower_the_error_of_the_filters(dataset, calibrated, entry):
    """cal. 10 on replay: the links of tag "a" measure the distance TAG_OFFSET s late; ranging.ekf (its
    velocity states) and graph.poses's motion model (mo. 4, its prediction's range rate) given the
    calibration's time offsets track the rover's tags closer than with the offsets taken away, over
    the first 10 s of the dataset with the file's noise figures."""
    from testbed.plugins import EstimatorSpec
    from testbed.plugins.feed import run_plugin
    from testbed.plugins.loading import resolve
    from testbed.replay.recording import RecordedTruth
    from testbed.replay.spec import Window

    spec, _ = dataset
    cal, c = calibrated
    rec = load_recording(spec, calibration=cal, window=Window(start=0.0, end=10.0))
    params = {k: v for k, v in c["noise"].items() if k != "range_sigma" or entry != "ranging.ekf"}
    rmse = {}
    for timed in (True, False):
        ctx = rec.context("k", params)
        if not timed:
            del ctx.sensors["uwb"]["time_offset"]
        track, _, _ = run_plugin(resolve([EstimatorSpec(entry=entry, params=params)])[0], ctx, rec.feed)
        s = track[("rover", "position")]
        err = s.value - RecordedTruth(rec).at("rover", "position", s.time)
        rmse[timed] = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
    assert rmse[True] < rmse[False], rmse
