"""Recorded data: the format's checks, `testbed replay` / `testbed export` round trips, the shipped
example, the batched factor graph against estimators.graph.model, graph.poses on multi-antenna robots."""
import dataclasses
import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from estimators.graph import model as gm
from estimators.graph.batch import EpochFactors, solve_epochs
from estimators.so3 import so3_exp
from testbed.config import scenario
from testbed.sim import world
from testbed.cli import main
from testbed.config import to_dict
from testbed.scoring.metrics import anees_interval, sample_size
from testbed.plugins import EstimatorSpec
from testbed.plugins.context import make_context
from testbed.sim.world import lever_arms
from testbed.plugins.feed import measurements, run_plugin
from testbed.plugins.loading import resolve
from testbed.replay.recording import load_recording
from testbed.runner import run

ROOT = Path(__file__).resolve().parents[1]
GRAPH = "testbed.replay.graph:PoseGraph"  # registered as graph.poses once the package is reinstalled


def _tracks_equal(a: dict, b: dict) -> None:
    assert set(a) == set(b) and a
    for key in a:
        np.testing.assert_array_equal(a[key].time, b[key].time)
        np.testing.assert_allclose(a[key].value, b[key].value, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a[key].cov, b[key].cov, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("name, entries", [
    ("coop-fg", ["coop.gnss_only", "coop.one_shot", "coop.iterated", "coop.centralized", GRAPH]),
    ("bandwidth", [GRAPH]),
])
def test_export_then_replay_gives_the_estimates_of_the_simulation(tmp_path, name, entries):
    """Every estimator the format drives gives, on the exported run, the estimates it gave inside the run."""
    sc = scenario.load(name, duration=4.0)
    params = {k: v for k, v in to_dict(sc.pipeline).items() if k != "kind"} if name == "coop-fg" else {}
    specs = tuple(EstimatorSpec(entry=e, params=params if e.startswith("coop.") else {}) for e in entries)
    sc = dataclasses.replace(sc, estimators=specs)
    metrics = run(sc, tmp_path / "run", plots=False)
    assert main(["export", str(tmp_path / "run"), "--out", str(tmp_path / "data")]) == 0
    assert main(["replay", str(tmp_path / "data" / "spec.toml"), "--out", str(tmp_path / "rep"), "--no-plots"]) == 0
    replayed = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    # the estimates themselves, fed from the log inside the simulation and from the files
    from testbed.api import load_run

    log = load_run(tmp_path / "run").log
    physics = world.build(sc)
    feed_sim = list(measurements(sc, log))
    rec = load_recording(tmp_path / "data" / "spec.toml")
    assert len(rec.measurements()) == len(feed_sim) > len(rec.feed)  # runs of rows are batches
    for p in resolve(specs):
        sim, _, _ = run_plugin(p, make_context(sc, lever_arms(physics), p.key, p.params), feed_sim)
        rep, _, _ = run_plugin(p, rec.context(p.key, p.params), rec.feed)
        _tracks_equal(sim, rep)
        a, b = metrics["estimators"][p.key], replayed["estimators"][p.key]
        assert a["estimates"] == b["estimates"] > 0
        np.testing.assert_allclose(b["rmse_position_m"], a["rmse_position_m"], rtol=1e-12)
        if "anees_position" in a:
            np.testing.assert_allclose(b["anees_position"], a["anees_position"], rtol=1e-12)
    # per-link statistics against truth: the residual of an exported range is its simulated error
    uwb = replayed["links"]["uwb"]
    assert sum(s["samples"] for s in uwb.values()) == log["uwb/value"].shape[0]
    err = log["uwb/value"][:, 0] - log["uwb/clean"][:, 0]
    pooled = np.sqrt(sum(s["rmse_m"] ** 2 * s["samples"] for s in uwb.values()) / err.size)
    np.testing.assert_allclose(pooled, np.sqrt(np.mean(err ** 2)), rtol=1e-9)


def test_the_shipped_example_replays(tmp_path, capsys):
    out = tmp_path / "D"
    assert main(["replay", str(ROOT / "examples/replay/spec.toml"), "--out", str(out), "--no-plots"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["truth"] and m["measurements"] == {"gnss": 90, "uwb": 345}
    assert set(m["estimators"]) == {"coop.gnss_only", "coop.one_shot", "coop.iterated", "coop.centralized", "PoseGraph"}
    for est in m["estimators"].values():
        assert est["estimates"] == 18 * 5 and est["unscored_estimates"] == {}
    # cooperation helps: every cooperative estimator beats GNSS alone on this example
    gnss = m["estimators"]["coop.gnss_only"]["rmse_position_mean_m"]
    assert all(e["rmse_position_mean_m"] < gnss for k, e in m["estimators"].items() if k != "coop.gnss_only")
    assert (out / "estimates.npz").is_file() and (out / "spec.toml").is_file() and (out / ".testbed").is_file()
    assert "PoseGraph: rmse_position_mean_m" in capsys.readouterr().out


def test_a_replay_with_one_failing_estimator_still_scores_the_others(tmp_path, capsys):
    """An estimator that raises at its 10th measurement is reported in metrics.json (time and
    reason) and on stderr in one line; the spec's five estimators are scored; exit 1, the
    directory written and marked incomplete."""
    (tmp_path / "bad.py").write_text(
        "class Bad:\n"
        "    def __init__(self, context, params): self.n = 0\n"
        "    def process(self, m):\n"
        "        self.n += 1\n"
        "        if self.n == 10: raise FloatingPointError('overflow')\n"
        "        return []\n")
    out = tmp_path / "D"
    assert main(["replay", str(ROOT / "examples/replay/spec.toml"), "--out", str(out), "--estimator", f"{tmp_path / 'bad.py'}:Bad"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "estimator 'Bad'" in err and "raised FloatingPointError: overflow" in err
    m = json.loads((out / "metrics.json").read_text())
    assert m["incomplete"] is True and m["failed_estimators"] == ["Bad"]
    failed = m["estimators"]["Bad"]["failed"]
    tenth = sorted(x.time for x in load_recording(ROOT / "examples/replay/spec.toml").measurements())[9]
    assert failed["time_s"] == pytest.approx(tenth) and f"at t = {tenth:.6g} s" in failed["reason"]
    assert all(m["estimators"][k]["estimates"] == 18 * 5 for k in m["estimators"] if k != "Bad")
    assert (out / ".testbed").is_file()


def _dataset(tmp_path: Path) -> Path:
    d = tmp_path / "data"
    shutil.copytree(ROOT / "examples/replay", d)
    return d


@pytest.mark.parametrize("table, line, cell, message", [
    ("links.csv", 3, (4, "abc"), "links.csv: row 2 (line 3), column value: expected a number, got 'abc'"),
    ("links.csv", 2, (4, "nan"), "links.csv: row 1 (line 2), column value: must be a finite number, got 'nan'"),
    ("links.csv", 5, (1, "uav99/uwb"), "links.csv: row 4 (line 5), column src: 'uav99/uwb' is not a site (body/site) or an anchor"),
    ("links.csv", 2, (3, "lidar"), "links.csv: row 1 (line 2), column kind: 'lidar' is not a link kind"),
    ("links.csv", 2, (5, "-0.1"), "links.csv: row 1 (line 2), column sigma: must be positive"),
    ("poses.csv", 4, (6, ""), "poses.csv: row 3 (line 4), column sigma_x: a GNSS fix needs its 1-sigma"),
    ("truth.csv", 2, (5, "2.0"), "truth.csv: row 1 (line 2), column qw: a unit quaternion wxyz is needed"),
])
def test_a_bad_cell_is_one_line_naming_file_row_and_column(tmp_path, capsys, table, line, cell, message):
    d = _dataset(tmp_path)
    lines = (d / table).read_text().splitlines()
    cells = lines[line - 1].split(",")
    cells[cell[0]] = cell[1]
    lines[line - 1] = ",".join(cells)
    (d / table).write_text("\n".join(lines) + "\n")
    assert main(["replay", str(d / "spec.toml"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("testbed: error: ") and "\n" not in err and message in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("edit, message", [
    (lambda s: s.replace("end = 4.0", "end = -1.0"), "window.end: must be after window.start"),
    (lambda s: s.replace("[bodies.uav1.sites]", "[bodies.uav1.sites]\nbad = [1.0, 2.0]"), "bodies.uav1.sites.bad: expected a lever arm"),
    (lambda s: "colour = 1\n" + s, "colour: unknown key"),
])
def test_a_bad_spec_is_one_line_naming_the_key(tmp_path, capsys, edit, message):
    d = _dataset(tmp_path)
    (d / "spec.toml").write_text(edit((d / "spec.toml").read_text()))
    assert main(["replay", str(d / "spec.toml"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err and str(d / "spec.toml") in err
    assert not (tmp_path / "out").exists()


def test_missing_columns_unknown_columns_and_parquet(tmp_path, capsys):
    d = _dataset(tmp_path)
    text = (d / "links.csv").read_text()
    (d / "links.csv").write_text(text.replace("time,src,dst,kind,value,sigma,arrival", "time,src,dst,kind,valu,sigma,arrival", 1))
    assert main(["replay", str(d / "spec.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "links.csv: unknown column 'valu'" in capsys.readouterr().err
    (d / "links.csv").write_text(text)
    (d / "height.parquet").write_bytes(b"PAR1")
    has_pyarrow = importlib.util.find_spec("pyarrow") is not None
    want = "height.parquet: " + ("not a readable Parquet file" if has_pyarrow else "reading Parquet needs pyarrow")
    assert main(["replay", str(d / "spec.toml"), "--out", str(tmp_path / "o")]) == 2
    assert want in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_optional_columns_may_be_absent_and_sigma_empty(tmp_path):
    """A links table with only the required columns; its rows feed sigma None, arrival = time."""
    d = _dataset(tmp_path)
    rows = [r.split(",") for r in (d / "links.csv").read_text().splitlines()]
    (d / "links.csv").write_text("\n".join(",".join(r[:5]) for r in rows) + "\n")
    rec = load_recording(d / "spec.toml")
    uwb = [m for m in rec.measurements() if m.stream == "uwb"]
    assert len(uwb) == 345 and all(m.sigma is None and m.arrival == m.time for m in uwb)


def _random_problem(rng, E=3):
    """Epochs with a pose (4 antennas), a point, fixed anchors, a height and lever-arm-free priors."""
    arms = rng.normal(size=(4, 3)) * 0.5
    anchors = np.column_stack([rng.uniform(-10, 10, (5, 2)), rng.uniform(0, 3, 5)])
    pt = rng.normal(size=(E, 2, 3)) * 3 + [0, 0, 5]
    Rt = so3_exp(rng.normal(size=(E, 3)) * 0.5)
    r = []  # (epoch, a, b, arm_a, arm_b, d)
    for e in range(E):
        site = lambda i: pt[e, 0] + Rt[e] @ arms[i]  # noqa: E731
        r += [(e, 0, -1, arms[i], anchors[j], np.linalg.norm(site(i) - anchors[j])) for i in range(4) for j in range(5)]
        r += [(e, 0, 1, arms[i], np.zeros(3), np.linalg.norm(site(i) - pt[e, 1])) for i in range(4)]
        r += [(e, -1, 1, anchors[j], np.zeros(3), np.linalg.norm(pt[e, 1] - anchors[j])) for j in range(3)]
    d = np.array([x[5] for x in r]) + 0.05 * rng.normal(size=len(r))
    f = EpochFactors(
        kinds=("pose", "point"), r_epoch=np.array([x[0] for x in r]), r_a=np.array([x[1] for x in r]),
        r_b=np.array([x[2] for x in r]), r_arm_a=np.array([x[3] for x in r]), r_arm_b=np.array([x[4] for x in r]),
        r_d=d, r_sigma=np.full(len(r), 0.05),
        h_epoch=np.arange(E), h_var=np.ones(E, int), h_arm=np.zeros((E, 3)), h_z=pt[:, 1, 2] + 0.1 * rng.normal(size=E),
        h_sigma=np.full(E, 0.1), q_epoch=np.arange(E), q_var=np.zeros(E, int), q_arm=np.zeros((E, 3)),
        q_z=pt[:, 0] + rng.normal(size=(E, 3)), q_cov=np.tile(np.diag([1.0, 2.0, 3.0]), (E, 1, 1)))
    p0 = pt + rng.normal(size=pt.shape) * 0.5
    R0 = np.tile(np.eye(3), (E, 2, 1, 1))
    R0[:, 0] = Rt @ so3_exp(rng.normal(size=(E, 3)) * 0.2)
    return f, p0, R0, anchors


def test_batched_epochs_equal_the_general_graph_epoch_by_epoch():
    """solve_epochs on three epochs at once = estimators.graph.model.solve_graph on each epoch
    (same factors: lever-arm ranges to fixed anchors and to a point, a height, a pose position prior)."""
    f, p0, R0, anchors = _random_problem(np.random.default_rng(3))
    res = solve_epochs(f, p0, R0, step_tol=1e-12, cost_tol=1e-15)
    assert res.converged.all() and res.observable.all()
    for e in range(p0.shape[0]):
        g = gm.Graph()
        g.add_variable("r", "pose")
        g.add_variable("q", "point")
        init = {"r": (p0[e, 0], R0[e, 0]), "q": p0[e, 1]}
        for j, a in enumerate(anchors):
            g.add_variable(f"a{j}", "point", fixed=True)
            init[f"a{j}"] = a
        key = {0: "r", 1: "q"}
        for k in np.flatnonzero(f.r_epoch == e):
            a = key.get(f.r_a[k]) or f"a{int(np.argmin(np.linalg.norm(anchors - f.r_arm_a[k], axis=1)))}"
            b = key.get(f.r_b[k]) or f"a{int(np.argmin(np.linalg.norm(anchors - f.r_arm_b[k], axis=1)))}"
            g.add(gm.Range(a, b, f.r_d[k], f.r_sigma[k], lever_a=f.r_arm_a[k] if a == "r" else None))
        g.add(gm.Height("q", f.h_z[e], f.h_sigma[e]))
        g.add(gm.PosePositionPrior("r", f.q_z[e], f.q_cov[e]))
        ref = gm.solve_graph(g, init, step_tol=1e-12, cost_tol=1e-15)
        np.testing.assert_allclose(res.p[e, 0], ref.values["r"][0], atol=1e-8)
        np.testing.assert_allclose(res.R[e, 0], ref.values["r"][1], atol=1e-8)
        np.testing.assert_allclose(res.p[e, 1], ref.values["q"], atol=1e-8)
        np.testing.assert_allclose(res.cost[e], ref.cost, rtol=1e-9)
        for block, key in ((slice(0, 6), "r"), (slice(6, 9), "q")):  # to 1e-6 of the block's scale
            np.testing.assert_allclose(res.cov[e][block, block], ref.cov[key], rtol=0, atol=1e-6 * np.abs(ref.cov[key]).max())


def test_an_unobservable_epoch_is_flagged_not_raised():
    f, p0, R0, _ = _random_problem(np.random.default_rng(4), E=2)
    keep = f.r_epoch == 0  # epoch 1 keeps only its prior and height: the pose's attitude is free
    g = EpochFactors(**{**{k: getattr(f, k) for k in EpochFactors.__slots__},
                        **{k: getattr(f, k)[keep] for k in EpochFactors.__slots__ if k.startswith("r_")}})
    res = solve_epochs(g, p0, R0)
    assert res.observable.tolist() == [True, False] and np.isnan(res.cov[1]).all() and np.isfinite(res.cov[0]).all()


def test_graph_poses_on_two_multi_antenna_robots_with_a_height_aid():
    """Three robots with flat six-antenna arrays, robot 1 known (mocap), robots 2 and 3 poses: the
    position errors are consistent with the covariances (NEES mean in its chi-square 99.9 % interval)."""
    from testbed.bench import replay as bench
    from testbed.plugins.loading import Plugin

    data = bench.robots(5.0)
    params = {"batch": 8, "initial": {f"r{a + 1}": [*(data["pos"][0, a] + 0.3).tolist(),
                                                    *bench.rotmat_to_quat(data["rot"][0, a]).tolist()] for a in (1, 2)}}
    track, health, _ = run_plugin(Plugin("g", GRAPH, bench.PoseGraph, params), bench.context(data), list(bench.feed(data)))
    assert health["nonconverged_epochs"] == 0 and health["unobservable_epochs"] == 0 and health["epochs"] == 51
    nees = []
    for a in (1, 2):
        s = track[(f"r{a + 1}", "position")]
        err = s.value - data["pos"][np.rint(s.time * bench.RATE_HZ).astype(int), a]
        nees.append([e @ np.linalg.solve(c, e) for e, c in zip(err, s.cov)])
        assert (f"r{a + 1}", "attitude") in track
    # the epochs of a graph (and its two robots) are correlated: the interval counts effective samples
    nees = np.array(nees).T  # (epochs, 2 robots), the same epochs
    size = sample_size(nees)
    lo, hi = anees_interval(3, size.n_eff, 0.999, size.nu)
    assert size.decidable and lo < np.mean(nees) < hi, size


def test_graph_poses_gives_the_same_estimates_fed_in_batches_or_row_by_row():
    """MeasurementBatch (process_batch) and one Measurement per row (process) are the same feed:
    identical estimates and health, with one epoch per time and with 0.25 s bins."""
    from testbed.bench import replay as bench
    from testbed.plugins.loading import Plugin

    data = bench.robots(3.0)
    for epoch in (0.0, 0.25):
        params = {"batch": 4, "epoch": epoch, "initial": {f"r{a + 1}": [*(data["pos"][0, a] + 0.3).tolist(),
                                                                         *bench.rotmat_to_quat(data["rot"][0, a]).tolist()] for a in (1, 2)}}
        plugin = Plugin("g", GRAPH, bench.PoseGraph, params)
        rows, h_rows, _ = run_plugin(plugin, bench.context(data), bench.feed(data, batched=False))
        batches, h_batches, _ = run_plugin(plugin, bench.context(data), bench.feed(data))
        assert h_rows == h_batches and h_rows["epochs"] == (31 if epoch == 0 else 13)
        _tracks_equal(rows, batches)


def test_graph_poses_reports_convergence_iterations_and_cost_per_epoch(tmp_path):
    """The shipped example through graph.poses: estimates.npz holds one row per solved epoch (time,
    iterations, cost, converged, observable, flagged), metrics.json their summary, consistent with health."""
    from testbed.replay.run import replay

    out = tmp_path / "rep"
    metrics = replay(ROOT / "examples/replay/spec.toml", out, plots=False)
    g = metrics["estimators"]["PoseGraph"]
    with np.load(out / "estimates.npz") as z:
        d = {k.split("/")[-1]: z[k] for k in z.files if k.startswith("PoseGraph/diagnostics/")}
    assert set(d) == {"time", "iterations", "cost", "converged", "observable", "flagged"}
    assert d["time"].size == g["diagnostics"]["epochs"] > 0 and np.all(np.diff(d["time"]) >= 0)
    assert int(d["iterations"].sum()) == g["health"]["lm_iterations"]
    assert int((d["converged"] == 0).sum()) == g["health"]["nonconverged_epochs"] + g["health"]["flagged_epochs"]
    assert int(d["flagged"].sum()) == g["health"]["flagged_epochs"]
    assert np.all(d["cost"] >= 0) and np.all(d["iterations"] >= 1)


def test_link_statistics_are_the_truth_of_each_link_row_by_row(tmp_path):
    """metrics.json `links` against a direct evaluation of the truth per link (ranges and range rates,
    uwb rows duplicated as range-rate rows with value 0.25 m/s, some rows outside the truth span)."""
    from testbed.replay.linkstats import link_statistics
    from testbed.replay.recording import RecordedTruth

    d = _dataset(tmp_path)
    lines = (d / "links.csv").read_text().splitlines()
    rates = [",".join(c[:3] + ["range-rate", "0.25"] + c[5:]) for c in (r.split(",") for r in lines[1:40])]
    (d / "links.csv").write_text("\n".join(lines + rates) + "\n")
    truth_lines = (d / "truth.csv").read_text().splitlines()
    (d / "truth.csv").write_text("\n".join(truth_lines[:1] + [r for r in truth_lines[1:] if float(r.split(",")[0]) >= 1.0]) + "\n")
    rec = load_recording(d / "spec.toml")
    truth = RecordedTruth(rec)
    stats = link_statistics(rec, truth)
    t = rec.tables["links"]
    assert set(stats) == {"uwb", "range-rate"}
    for kind, links in stats.items():
        for link, s in links.items():
            src, dst = link.split("->")
            rows = (t["kind"] == kind) & (t["src"] == src) & (t["dst"] == dst)
            time = t["time"][rows]
            ok = (time >= truth.span[truth.body_of(src)][0]) & (time >= truth.span[truth.body_of(dst)][0])
            diff = truth.at(src, "position", time[ok]) - truth.at(dst, "position", time[ok])
            dist = np.linalg.norm(diff, axis=1)
            if kind == "uwb":
                true = dist
            else:
                dv = truth.at(src, "velocity", time[ok]) - truth.at(dst, "velocity", time[ok])
                true = np.einsum("ni,ni->n", diff / dist[:, None], dv)
            res = t["value"][rows][ok] - true
            assert s["samples"] == res.size and s["unscored"] == int((~ok).sum())
            if res.size:
                u = "m_s" if kind == "range-rate" else "m"
                np.testing.assert_allclose(s[f"rmse_{u}"], np.sqrt(np.mean(res ** 2)), rtol=1e-12)
                np.testing.assert_allclose(s[f"mean_{u}"], res.mean(), rtol=1e-12, atol=1e-15)
    assert any(s["unscored"] for links in stats.values() for s in links.values())


def test_an_attitude_its_own_covariance_calls_unobserved_is_flagged():
    """score: an attitude series whose covariance gives a 1-sigma above UNOBSERVED_ATTITUDE_DEG on
    more than half of its samples is listed in `attitude_unobserved` (its `unobserved` fraction per
    target); a well-determined one is not."""
    from testbed.plugins.collect import Series, Track
    from testbed.plugins.score import UNOBSERVED_ATTITUDE_DEG, score

    class Level:  # truth: level, at rest, for every target
        def times(self, target):
            return np.arange(4.0)

        def at(self, target, quantity, t, frame="world"):
            return np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))

    big, small = np.radians(UNOBSERVED_ATTITUDE_DEG) * 1.2, np.radians(UNOBSERVED_ATTITUDE_DEG) * 0.8
    track = Track()
    for target, sigmas in (("flat", [big, big, big, small]), ("solid", [small] * 4)):
        c = np.stack([np.diag([s ** 2, 1e-4, 1e-4]) for s in sigmas])
        track[(target, "attitude")] = Series(np.arange(4.0), np.tile([1.0, 0.0, 0.0, 0.0], (4, 1)), c, np.ones(4, bool))
    out, _ = score(track, Level())
    assert out["targets"]["flat"]["attitude"]["unobserved"] == 0.75
    assert out["targets"]["solid"]["attitude"]["unobserved"] == 0.0
    assert out["attitude_unobserved"] == ["flat"]
