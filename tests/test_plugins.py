"""Estimators as plugins: loading, feeding in arrival order, truth for scoring, errors, docs example."""
import dataclasses
import json
import math
import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

from testbed.config import scenario
from testbed.cli import main
from testbed.errors import PluginError, UsageError
from testbed.scoring.metrics import anees_over_runs, anees_run_interval
from testbed.plugins import EstimatorSpec
from testbed.plugins.context import make_context
from testbed.sim.world import lever_arms
from testbed.plugins.feed import measurements, run_plugin
from testbed.plugins.loading import Plugin, load_class
from testbed.plugins.truth import Truth
from testbed.sim.simulate import simulate

from table_checks import assert_every_anees_has_its_interval  # tests/ helper

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def coop_run():
    sc = scenario.load("coop-fg", duration=3.0, overrides={"sensors.uwb.latency": "0.05"})
    log, physics = simulate(sc)
    return sc, log, physics


def _write(tmp_path: Path, body: str, name: str = "plug.py") -> Path:
    path = tmp_path / name
    path.write_text("import numpy as np\nfrom testbed.plugins import Estimate\n\n" + textwrap.dedent(body))
    return path


def test_uwb_ekf_example_is_scored_beside_the_built_ins(tmp_path, capsys):
    out = tmp_path / "D"
    assert main(["run", "coop-fg", "--estimator", str(ROOT / "examples/uwb_ekf.py") + ":UwbEkf", "--duration", "5",
                 "--out", str(out)]) == 0
    est = json.loads((out / "metrics.json").read_text())["estimators"]
    assert {"gnss_only", "centralized", "UwbEkf"} <= set(est)
    ekf = est["UwbEkf"]
    assert ekf["estimates"] == 18 * 6  # every vehicle's uwb site at each of the 6 epochs
    assert 0 < ekf["rmse_position_mean_m"] < est["gnss_only"]["rmse_position_mean_m"]
    # 6 epochs cannot span 20 correlation times: one run does not decide (docs/consistency.md)
    assert ekf["anees_position_interval_95"] is None and np.isfinite(ekf["anees_position"])
    assert ekf["anees_position_null_reason"].startswith("not decidable from one run") and ekf["n_eff_position"] > 0
    assert set(ekf["targets"]) == {f"uav{i}/uwb" for i in range(1, 19)}
    assert "wall_ms" not in ekf and "wall_ms" in json.loads((out / "timing.json").read_text())["estimators"]["UwbEkf"]
    assert (out / "plots" / "estimators_position_uav1_uwb.png").is_file()
    assert "UwbEkf: rmse_position_mean_m" in capsys.readouterr().out


def test_site_truth_from_body_pose_and_lever_arm_equals_the_physics(coop_run):
    sc, log, physics = coop_run
    ctx = make_context(sc, lever_arms(physics), "t", {})
    truth = Truth(log, ctx)
    for v in (1, 7, 18):
        rows = log["gnss/vehicle"] == v
        got = truth.at(f"uav{v}/uwb", "position", log["gnss/time"][rows])
        np.testing.assert_allclose(got, log["gnss/clean"][rows], atol=1e-9)
    assert ctx.sites["uav2/uwb"][0] == "uav2" and np.linalg.norm(ctx.sites["uav2/uwb"][1]) > 0.05


def test_measurements_come_in_arrival_order_without_truth(coop_run):
    sc, log, _ = coop_run
    feed = list(measurements(sc, log))
    assert len(feed) == log["gnss/time"].size + log["uwb/time"].size
    arrival = np.array([m.arrival for m in feed])
    assert np.all(np.diff(arrival) >= 0)
    uwb = [m for m in feed if m.stream == "uwb"]
    np.testing.assert_allclose([m.arrival - m.time for m in uwb], 0.05, atol=1e-12)  # the configured latency
    # the first epoch's GNSS (latency 0) comes before its UWB ranges (latency 50 ms)
    assert feed[0].stream == "gnss" and feed[18].stream == "uwb"
    m = uwb[0]
    assert m.dst.startswith("uav") and m.sigma.tolist() == [sc.sensors.uwb.noise]
    assert not m.value.flags.writeable and not hasattr(m, "clean")


def test_plugin_written_from_the_docs_example_alone_runs(tmp_path):
    text = (ROOT / "docs/estimators.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    (tmp_path / "my_gnss_filter.py").write_text(code)
    toml = re.findall(r"```toml\n(.*?)```", text, re.S)[0]
    sc_file = tmp_path / "sc.toml"
    base = (ROOT / "testbed/scenarios/coop-fg.toml").read_text()
    sc_file.write_text(base + "\n" + toml.replace("my_gnss_filter.py", str(tmp_path / "my_gnss_filter.py")))
    out = tmp_path / "run"
    assert main(["run", str(sc_file), "--duration", "3", "--out", str(out), "--no-plots"]) == 0
    est = json.loads((out / "metrics.json").read_text())["estimators"]
    rw = est["rw"]
    assert rw["entry"].endswith("my_gnss_filter.py:GnssRandomWalk") and rw["estimates"] == 18 * 4
    # filtering the fixes over time beats the single fixes on the SPP vehicles
    assert rw["rmse_position_mean_m"] < est["gnss_only"]["rmse_position_mean_m"]


def test_scenario_params_reach_the_plugin(coop_run, tmp_path):
    sc, log, physics = coop_run
    path = _write(tmp_path, """
        class Echo:
            def __init__(self, context, params):
                self.offset = params["offset"]
                assert context.params == params and context.rng.random() < 1
            def process(self, m):
                if m.stream == "gnss":
                    yield Estimate(time=m.time, target=m.src, quantity="position", value=m.value + self.offset)
    """)
    spec = EstimatorSpec(entry=f"{path}:Echo", params={"offset": 2.0})
    plugin = Plugin(spec.key, spec.entry, load_class(spec.entry), spec.params)
    track, health, _ = run_plugin(plugin, make_context(sc, lever_arms(physics), spec.key, spec.params), list(measurements(sc, log)))
    s = track[("uav1/uwb", "position")]
    np.testing.assert_allclose(s.value - 2.0, log["gnss/value"][log["gnss/vehicle"] == 1])
    assert not s.has_cov.any() and health == {}


@pytest.mark.parametrize("entry, message", [
    ("nowhere.py:X", "no such file"),
    ("{p}:Missing", "has no 'Missing'"),
    ("{p}:NoProcess", "lacks the protocol: no method process"),
    ("{p}:BadInit", "cannot be called with two arguments"),
    ("no_such_package_xyz.mod:X", "cannot import no_such_package_xyz.mod: ModuleNotFoundError"),
    ("justaname", "expected a registered name"),
])
def test_bad_entries_exit_2_before_simulating(tmp_path, capsys, entry, message):
    path = _write(tmp_path, """
        class NoProcess:
            def __init__(self, context, params): pass
        class BadInit:
            def __init__(self): pass
            def process(self, m): return []
    """)
    out = tmp_path / "out"
    assert main(["run", "coop-fg", "--duration", "1", "--out", str(out), "--estimator", entry.format(p=path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("testbed: error: estimator ") and message in err and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize("body, message", [
    ("raise RuntimeError('boom')", "at t = 0 s (gnss uav1/uwb): raised RuntimeError: boom"),
    ("return [Estimate(time=m.time, target='uav1', quantity='position', value=np.full(3, np.nan))]", "value is not finite"),
    ("return [Estimate(time=m.time, target='uav1', quantity='position', value=np.zeros(2))]", "value has shape (2,), expected (3,)"),
    ("return [Estimate(time=m.time, target='uav99', quantity='position', value=np.zeros(3))]", "unknown target"),
    ("return [Estimate(time=m.time, target='uav1', quantity='position', value=np.zeros(3), cov=-np.eye(3))]", "not positive definite"),
    ("return [m]", "not a testbed.plugins.Estimate"),
])
def test_a_failing_plugin_is_its_own_result_and_exits_1(tmp_path, capsys, body, message):
    """The failing estimator is named with its time and reason on stderr (one line) and in
    metrics.json; the other plugin and the pipeline are still scored; the run directory is
    written (strict JSON, marked incomplete) and the command exits 1. The first case draws the
    run's figures (the others' estimators, beside the failed one); the rest run without them
    (--no-plots: most of a short run's CPU time is its figures), as nothing here looks at one."""
    path = _write(tmp_path, f"""
        class Bad:
            def __init__(self, context, params): pass
            def process(self, m):
                {body}
        class Good:
            def __init__(self, context, params): pass
            def process(self, m):
                if m.stream == "gnss":
                    yield Estimate(time=m.time, target=m.src, quantity="position", value=m.value)
    """)
    out = tmp_path / "out"
    plots = [] if body.startswith("raise") else ["--no-plots"]
    assert main(["run", "coop-fg", "--duration", "1", "--out", str(out), "--estimator", f"{path}:Bad",
                 "--estimator", f"{path}:Good", *plots]) == 1
    err = capsys.readouterr().err
    assert err.startswith("testbed: error: ") and f"estimator 'Bad' ({path}:Bad) at t = 0 s" in err
    assert message in err and str(out / "metrics.json") in err and err.count("\n") == 1
    metrics = json.loads((out / "metrics.json").read_text(), parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))
    assert metrics["incomplete"] is True and metrics["failed_estimators"] == ["Bad"]
    assert metrics["estimators"]["Bad"]["failed"]["time_s"] == 0.0 and message in metrics["estimators"]["Bad"]["failed"]["reason"]
    assert metrics["estimators"]["Good"]["rmse_position_m"] >= 0.0
    assert all("failed" not in v for k, v in metrics["estimators"].items() if k != "Bad") and len(metrics["estimators"]) >= 3
    assert not list(tmp_path.glob(".*out*"))


def test_a_plugin_failing_outside_the_feed_has_no_time(tmp_path, capsys):
    """A constructor that raises: time_s is null, the reason says where."""
    path = _write(tmp_path, """
        class Bad:
            def __init__(self, context, params): raise ValueError("no")
            def process(self, m): return []
    """)
    out = tmp_path / "out"
    assert main(["run", "coop-fg", "--duration", "1", "--out", str(out), "--estimator", f"{path}:Bad", "--no-plots"]) == 1
    failed = json.loads((out / "metrics.json").read_text())["estimators"]["Bad"]["failed"]
    assert failed["time_s"] is None and "constructor: raised ValueError: no" in failed["reason"]


def test_duplicate_names_are_refused():
    from testbed.plugins.loading import resolve

    with pytest.raises(UsageError, match="a second estimator named 'UwbEkf'"):
        resolve([EstimatorSpec(entry=f"{ROOT}/examples/uwb_ekf.py:UwbEkf")] * 2)


def test_plugin_error_is_exit_code_1_and_usage_error_2():
    assert PluginError("x").exit_code == 1 and UsageError("x").exit_code == 2


def _declared() -> dict[str, str]:
    import tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]["testbed.estimators"]


def test_builtins_are_installed_as_declared():
    """The installed entry points are this pyproject's (fails until `make setup` reinstalls)."""
    from testbed.plugins import loading

    declared = _declared()
    assert {k: v for k, v in loading.registered().items() if k in declared} == declared, "reinstall: make setup"


def test_every_declared_builtin_loads_and_is_listed(monkeypatch, capsys):
    from importlib.metadata import EntryPoint

    from testbed.plugins import loading

    declared = _declared()
    assert {"phase.ekf", "bandwidth.fusion"} | {f"visnav.{f}" for f in ("ekf", "ckf", "hckf", "mckf", "rhcf")} \
        | {f"coop.{w}" for w in ("gnss_only", "one_shot", "iterated", "centralized")} <= set(declared)
    eps = [EntryPoint(k, v, loading.GROUP) for k, v in declared.items()]
    monkeypatch.setattr(loading, "entry_points", lambda group: eps if group == loading.GROUP else [])
    assert main(["estimators"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in out] == sorted(declared)
    assert all(len(line.split()) > 3 for line in out)  # each with its description
    assert all(loading.load_class(k).__name__ == v.rpartition(":")[2] for k, v in declared.items())


def test_an_installed_entry_point_is_registered(monkeypatch):
    from importlib.metadata import EntryPoint

    from testbed.plugins import loading

    ep = EntryPoint("third.party", "testbed.plugins.builtin_coop:GnssOnly", loading.GROUP)
    monkeypatch.setattr(loading, "entry_points", lambda group: [ep] if group == loading.GROUP else [])
    assert loading.registered()["third.party"] == ep.value
    assert loading.load_class("third.party").__name__ == "GnssOnly"


def test_coop_builtins_under_other_names_equal_the_defaults_and_both_scorings_agree(tmp_path):
    """The four seed 001 estimators under other names than the defaults, beside them, give the
    defaults' scores (no message loss: the name's random stream is not drawn), and the seed 001
    hook's keys agree with the generic per-target scores (per-vehicle RMSE, ANEES of position)."""
    # a non-default known ranging model: the plugins take the scenario's [pipeline] without params
    sc = scenario.load("coop-fg", duration=4.0, overrides={"pipeline.twr_mode": "ds-twr", "pipeline.antenna_delay_sigma": "0.02"})
    names = ("gnss_only", "one_shot", "iterated", "centralized")
    sc = dataclasses.replace(sc, estimators=tuple(EstimatorSpec(entry=f"testbed.plugins.builtin_coop:{c}", name=f"coop.{w}")
                                                  for w, c in zip(names, ("GnssOnly", "OneShot", "Iterated", "Centralized"))))
    from testbed.runner import run

    est = run(sc, tmp_path / "r", plots=False)["estimators"]
    for w in names:
        p, d = est[f"coop.{w}"], est[w]
        assert {k: v for k, v in p.items() if k not in ("entry", "wall_ms")} == \
            {k: v for k, v in d.items() if k not in ("entry", "wall_ms")}, w
        per_uav = [p["targets"][f"uav{i}/uwb"]["position"]["rmse_m"] for i in range(1, 19)]
        np.testing.assert_allclose(per_uav, p["rmse_position_per_vehicle_m"], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(p["anees_position"], p["anees"], rtol=1e-12)
        assert p["estimates"] == 18 * 5 and p["health"]["nonconverged_epochs"] <= 5
        assert ("anees_joint" in p) == (w == "centralized")  # the one with the joint covariance


def test_sweep_and_reproduce_take_plugins(tmp_path):
    ekf = f"{ROOT}/examples/uwb_ekf.py:UwbEkf"
    assert main(["sweep", "coop-fg", "--runs", "2", "--workers", "1", "--duration", "2", "--estimator", ekf,
                 "--out", str(tmp_path / "s"), "--no-plots"]) == 0
    scores = json.loads((tmp_path / "s" / "summary.json").read_text())["scores"]
    assert scores["estimators.UwbEkf.rmse_position_mean_m"]["n"] == 2
    # an ANEES's mean over the runs with its interval over the runs (anees_over_runs): the runs' combined
    # effective samples when each run decides, else the spread of the two runs (Student t)
    runs = [json.loads((tmp_path / "s" / f"run-{i:03d}" / "metrics.json").read_text())["estimators"] for i in range(2)]
    for name, key in (("UwbEkf", "anees_position"), ("centralized", "anees_joint")):
        s, level = scores[f"estimators.{name}.{key}"], 0.95 if name == "UwbEkf" else 0.99
        per = [r[name] for r in runs]
        if any(f"{key}_null_reason" in r for r in per):
            expected = list(anees_run_interval(np.array([r[key] for r in per]), per[0][f"{key}_dof"], level))
        else:
            n = [r[key.replace("anees", "n_eff")] for r in per]
            assert s["n_eff"] == pytest.approx(4 / sum(1 / x for x in n))
            expected = anees_over_runs(per, key, level)[f"{key}_interval_{round(100 * level)}"]
        assert s["interval"] == pytest.approx(expected)
    assert "interval" not in scores["estimators.UwbEkf.rmse_position_mean_m"]


def test_reproduce_coop_gives_a_plugin_every_table_plot_and_test(tmp_path, monkeypatch):
    """`reproduce coop --estimator examples/uwb_ekf.py:UwbEkf` (2 runs of 2 s, NLOS experiment on):
    the plugin is in Table 4 (RMSE and improvement factor columns), the consistency, improvement
    and pairwise tables (a test against each built-in over the same 2 seeds), figure 6,
    rmse_mean.png and the NLOS experiment, its numbers read from the runs' metrics.json like the
    built-ins'."""
    from testbed.reproduce import coop as rep

    drawn = {}  # what the two summary figures draw
    bars, fig6 = rep.compare_bars, rep.coop_scores.plot_error_vs_time

    def record_bars(names, *a, **k):
        drawn["bars"] = list(names)
        return bars(names, *a, **k)

    def record_fig6(ep, pos, *a, **k):
        drawn["fig6"] = list(pos)
        return fig6(ep, pos, *a, **k)

    monkeypatch.setattr(rep, "compare_bars", record_bars)
    monkeypatch.setattr(rep.coop_scores, "plot_error_vs_time", record_fig6)
    out = tmp_path / "rep"
    out.mkdir()
    ekf = f"{ROOT}/examples/uwb_ekf.py:UwbEkf"
    doc = rep.reproduce(out, runs=2, duration=2.0, workers=1, nlos=True, estimators=(EstimatorSpec(entry=ekf),))
    names = ["gnss_only", "one_shot", "iterated", "centralized", "UwbEkf"]
    assert doc["estimators"] == names and drawn == {"bars": names, "fig6": names}
    assert any((out / "plots").glob("run0_UwbEkf_uav*_envelope.png"))
    # Table 4: its RMSE per UAV pooled over the runs from each run's metrics.json, and its factor
    head, *rows = (out / "table.csv").read_text().strip().splitlines()
    cols = head.split(",")
    assert "rmse_UwbEkf_m" in cols and "factor_UwbEkf" in cols and len(rows) == 18
    runs = [json.loads((out / "runs" / f"run-{i:03d}" / "metrics.json").read_text())["estimators"] for i in range(2)]
    for r in rows:
        v = dict(zip(cols, r.split(",")))
        u = int(v["uav"]) - 1
        want = np.sqrt(np.mean([m["UwbEkf"]["rmse_position_per_vehicle_m"][u] ** 2 for m in runs]))
        assert float(v["rmse_UwbEkf_m"]) == pytest.approx(want, rel=1e-12)
        assert float(v["factor_UwbEkf"]) == pytest.approx(float(v["rmse_gnss_m"]) / want, rel=1e-12)
    cons = {c["estimator"]: c for c in doc["consistency"]}
    assert cons["UwbEkf"]["runs_scored"] == 2
    assert cons["UwbEkf"]["anees"] == pytest.approx(np.mean([m["UwbEkf"]["anees"] for m in runs]), rel=1e-12)
    assert {r["estimator"] for r in doc["improvement"]} == set(names[1:])
    pairs = {(p["a"], p["b"]): p for p in doc["pairwise"]}
    assert len(pairs) == 10
    for b in names[:4]:  # a paired test against each built-in, both directions, over the same 2 runs
        p = pairs[b, "UwbEkf"]
        assert p["runs"] == 2 and p["uavs_a_better"] + p["uavs_b_better"] <= 18
        assert p["p_max_a_better"] is not None and p["p_max_b_better"] is not None
    assert set(doc["nlos_experiment"]["plugins"]) == {"UwbEkf"}
    assert doc["cap_effect"]["plugins"] == rep.CAP_NOT_PLUGINS  # a round cap is a built-in setting
    md = (out / "table.md").read_text()
    sections = md.split("\n## ")[2:6]
    assert [x.split()[0] for x in sections] == ["Table", "Consistency", "Improvement", "Pairwise"]
    for section in sections:
        assert "UwbEkf" in section, section[:60]
    assert md.count("| UwbEkf |") >= 2 and "| centralized | UwbEkf |" in md
    # the NLOS experiment's plugin ANEES with its interval and effective samples
    # one NLOS run: its interval, or "not decidable from one run" (docs/consistency.md)
    assert re.search(r"UwbEkf \(its own settings.*ANEES \S+ \[(\S+, \S+|not decidable from one run)\] \(n_eff \S+\)", md)


def test_builtin_settings_default_to_the_scenario_and_params_override(coop_run):
    from testbed.plugins.builtin_coop import Centralized

    sc, _, physics = coop_run
    sc = dataclasses.replace(sc, pipeline=dataclasses.replace(sc.pipeline, twr_mode="ss-twr", range_sigma=0.2))
    est = Centralized(make_context(sc, lever_arms(physics), "c", {}), {})
    assert (est.cfg.twr_mode, est.cfg.range_sigma) == ("ss-twr", 0.2)
    est = Centralized(make_context(sc, lever_arms(physics), "c", {"range_sigma": 0.3}), {"range_sigma": 0.3})
    assert (est.cfg.twr_mode, est.cfg.range_sigma) == ("ss-twr", 0.3)
    with pytest.raises(Exception, match="estimator coop.centralized params"):
        Centralized(make_context(sc, lever_arms(physics), "c", {}), {"range_sigma": -1.0})


def _feed(sc, log, physics, cls, key="p"):
    """Run one plugin class through the testbed's feed on a log: its Track and its scores."""
    from testbed.plugins.priors import priors
    from testbed.plugins.hooks import scenario_hooks
    from testbed.plugins.score import score

    plugin = Plugin(key, key, cls, {})
    ctx = make_context(sc, lever_arms(physics), key, {}, priors(sc, log))
    track, health, _ = run_plugin(plugin, ctx, list(measurements(sc, log)))
    return track, score(track, Truth(log, ctx), scenario_hooks(sc, log), health)[0], health


def test_phase_builtin_is_its_filter_in_the_world_with_its_pcrb_and_nav_scores():
    """phase.ekf fed row by row gives the seed 003 EKF (the library's driver over the prepared
    epochs), mapped to the world as one batch of position and velocity with their (6, 6) joint
    covariance; its navigation_states() are the filter's 18-states, covariances and actual
    covariances. Its scores: the PCRB beside it, the frame-N scores (phase_scores.PhaseWindow) and
    the NEES keys of phase_scores.PhaseScored recomputed here from the filter in N."""
    from estimators.core import Epoch, Gate, drive, nees
    from estimators.phase_ekf import AnalyzedGaussian, PhaseEkfCovarianceAnalysis
    from estimators.phase_frames import BODY_POS, BODY_PV
    from testbed.scoring.metrics import rmse
    from testbed.plugins.builtin_phase import PhaseEkf, prepare
    from testbed.plugins.phase_scores import attitude_nees, true_states, window_keys

    # shorter than score_start: every epoch scored; a last window of 2 s within the 4 s
    sc = scenario.load("phase-cross-h000", duration=4.0, overrides={"pipeline.last_window": "2.0"})
    log, physics = simulate(sc)
    cfg, inp, q, prior, _, meas = prepare(sc, log)
    filt = PhaseEkfCovarianceAnalysis(q, Gate(alpha=cfg.gate_alpha, enabled=cfg.gate), cfg.iterations, cfg.rigid)
    ref = drive(filt, AnalyzedGaussian(prior.mean, prior.cov, prior.cov), [Epoch(float(t), m) for t, m in zip(inp.times, meas)])
    p, v, R, Rd = inp.nav_pose
    track, sc_plug, health = _feed(sc, log, physics, PhaseEkf)
    pos, vel = track[("uav6", "position")], track[("uav6", "velocity")]
    np.testing.assert_array_equal(pos.time, inp.times)
    pN, vN = ref.mean @ BODY_POS.T, ref.mean @ BODY_PV[3:].T
    np.testing.assert_allclose(pos.value, p + np.einsum("kij,kj->ki", R, pN), rtol=0, atol=1e-9)
    np.testing.assert_allclose(vel.value, v + np.einsum("kij,kj->ki", R, vN) + np.einsum("kij,kj->ki", Rd, pN), rtol=0, atol=1e-9)
    np.testing.assert_allclose(pos.cov, R @ (BODY_POS @ ref.cov @ BODY_POS.T) @ np.swapaxes(R, 1, 2),
                               rtol=1e-9, atol=1e-15)
    joints = track.joint[("position", "velocity")]
    assert [j.time for j in joints] == inp.times.tolist() and joints[0].cov.shape == (6, 6)
    nav = track.navigation
    assert (nav.frame, nav.layout) == ("phase-N", "phase-18")
    np.testing.assert_array_equal(nav.mean, ref.mean)
    np.testing.assert_array_equal(nav.cov, ref.cov)
    np.testing.assert_array_equal(nav.actual, np.stack([b.actual for b in ref.beliefs]))
    # the pipeline's scores, in N from the filter itself
    body, _, states = true_states(sc, log, cfg, inp)
    e = ref.mean @ BODY_PV.T - body[:, :6]
    n6 = nees(e, BODY_PV @ ref.cov @ BODY_PV.T)
    n18 = nees(ref.mean - states, ref.cov)
    n6a = nees(e, BODY_PV @ nav.actual @ BODY_PV.T)
    want = {"rmse_position_after_start_m": rmse(e[:, :3]), "rmse_velocity_after_start_m_s": rmse(e[:, 3:]),
            "anees": n6.mean(), "nees_body6_final": n6[-1], "anees_state18": n18.mean(), "nees_final": n18[-1],
            "anees_body6_actual_cov": n6a.mean(), "nees_body6_actual_cov_final": n6a[-1],
            "nees_attitude6_final": attitude_nees(ref.mean[-1], ref.cov[-1], states[-1]),
            "position_error_final_m": e[-1, :3], "position_error_mid_m": e[np.argmin(np.abs(inp.times - inp.times[[0, -1]].mean())), :3],
            "sigma_position_final_m": np.sqrt(np.diag(BODY_POS @ ref.cov[-1] @ BODY_POS.T)),
            window_keys(2.0)["max_abs_velocity"]: np.abs(e[inp.times >= inp.times[-1] - 2.0 + 1e-9, 3:]).max(axis=0)}
    for key, value in want.items():  # world and back to N: round-off only
        np.testing.assert_allclose(sc_plug[key], value, rtol=1e-9, atol=1e-12, err_msg=key)
    assert sc_plug["anees_dof"] == 6 and sc_plug["anees_state18_dof"] == 18 and sc_plug["epochs"] == inp.times.size
    assert sc_plug["score_start_s"] == inp.times[0] and sc_plug["last_window_s"] == 2.0
    assert sc_plug["pcrb_rmse_position_after_start_m"] == pytest.approx(sc_plug["pcrb_rmse_position_m"], rel=1e-12)
    assert sc_plug["targets"]["uav6"]["position"]["pcrb_samples"] == inp.times.size
    assert health["rejected_measurements"] == int(ref.rejected_measurements.sum())
    assert health["gate_epochs_with_rejection"] == int((ref.rejected_measurements > 0).sum())
    # the attitude at one epoch per second, scored where the filter's covariance leaves no axis unobserved
    from estimators.phase_model import unobserved_rotation_axes

    sec = np.unique(np.floor(inp.times - inp.times[0]), return_index=True)[1]
    seen = [i for i in sec if not len(unobserved_rotation_axes(ref.mean[i], ref.cov[i]))]
    assert sc_plug["attitude_unobserved_fraction"] == pytest.approx(1 - len(seen) / sec.size, abs=1e-12)
    if seen:
        want_att = np.mean([attitude_nees(ref.mean[i], ref.cov[i], states[i]) for i in seen])
        np.testing.assert_allclose(sc_plug["anees_attitude6"], want_att, rtol=1e-9)
    else:
        assert "anees_attitude6" not in sc_plug


def test_phase_window_velocity_sigma_is_the_filters_in_n():
    """PhaseWindow's velocity envelope: a world joint covariance C = J P J^T of position and
    velocity (J: phase.ekf's map from the 18-state in N, any attitude R and rate dR/dt of N) moved
    back to N gives the filter's own velocity sigma sqrt(diag(BODY_PV P BODY_PV^T))[3:]."""
    from scipy.spatial.transform import Rotation
    from estimators.phase_frames import BODY_POS, BODY_PV
    from estimators.so3 import skew
    from testbed.plugins.collect import Joint, Track
    from testbed.plugins.phase_scores import PhaseWindow

    rng = np.random.default_rng(1)
    K = 5
    R = Rotation.random(K, random_state=2).as_matrix()
    Rd = R @ np.array([skew(w) for w in rng.normal(size=(K, 3))])
    A = rng.normal(size=(K, 18, 18))
    P = A @ np.swapaxes(A, 1, 2) + np.eye(18)
    J = np.concatenate([R @ BODY_POS, R @ BODY_PV[3:] + Rd @ BODY_POS], axis=1)
    C = J @ P @ np.swapaxes(J, 1, 2)
    t = np.arange(K, dtype=float)
    track = Track({}, joint={("position", "velocity"): [Joint(t[i], ("uav6", "uav6"), "world", C[i]) for i in range(K)]})
    got = PhaseWindow("uav6", t, R, Rd, np.zeros((K, 3, 3)), 100.0)._velocity_sigma(track, np.arange(K), t)
    np.testing.assert_allclose(got, np.sqrt(np.diagonal(BODY_PV @ P @ BODY_PV.T, axis1=1, axis2=2))[:, 3:], rtol=1e-12)
    assert PhaseWindow("uav6", t, R, Rd, np.zeros((K, 3, 3)), 100.0)._velocity_sigma(Track({}), np.arange(K), t) is None


def test_navigation_states_are_checked():
    """A navigation_states() of the wrong shape is one PluginError naming the estimator and the problem."""
    from testbed.plugins.api import NavigationStates
    from testbed.plugins.feed import _navigation

    plugin = Plugin("p", "p", object, {})
    ok = NavigationStates(time=np.arange(3.0), mean=np.zeros((3, 2)), cov=np.tile(np.eye(2), (3, 1, 1)), frame="f", layout="l")
    assert _navigation(plugin, ok) is ok
    for bad, why in ((dataclasses.replace(ok, cov=np.zeros((3, 2, 3))), "cov has shape"), (dataclasses.replace(ok, time=np.zeros(3)), "increasing"),
                     (dataclasses.replace(ok, actual=np.zeros((2, 2, 2))), "actual has shape"), ({"time": 0}, "expected NavigationStates"),
                     (dataclasses.replace(ok, mean=np.full((3, 2), np.nan)), "not finite")):
        with pytest.raises(PluginError, match=why):
            _navigation(plugin, bad)


@pytest.fixture(scope="module")
def visnav_run():
    """visnav, 3 s, prescribed, simulated once for both filters below: (scenario, log, physics)."""
    sc = scenario.load("visnav", duration=3.0)
    return (sc, *simulate(sc))


@pytest.mark.parametrize("name", ["ekf", "rhcf"])
def test_visnav_builtins_are_scored_relative_to_the_leader(visnav_run, name):
    """visnav.* estimate the follower relative to the leader (frame "uav1") at every camera epoch;
    the generic scores of those series are the errors against the relative truth of
    testbed.plugins.relnav_scores (position, velocity in the leader frame, attitude q_L^* q_F), and
    the hook's 9-dof ANEES is their NEES with the filter's (9, 9) covariance (EstimateBatch.cov_joint)."""
    from estimators.so3 import quat_conj, quat_mul
    from testbed.plugins import builtin_visnav
    from testbed.plugins.relnav_scores import true_relative_state

    sc, log, physics = visnav_run
    track, scores, _ = _feed(sc, log, physics, getattr(builtin_visnav, name.capitalize()))
    epochs, first = np.unique(log["camera/time"], return_index=True)
    truth = true_relative_state(log, 1, 2, log["camera/state_index"][first])
    for q, sl in (("position", slice(0, 3)), ("velocity", slice(3, 6))):
        s = track[("uav2", q)]
        assert s.frame == "uav1" and s.has_cov.all()
        np.testing.assert_array_equal(s.time, epochs)
        np.testing.assert_allclose(scores["targets"]["uav2"][q][f"rmse_{'m' if q == 'position' else 'm_s'}"],
                                   np.sqrt(np.mean(np.sum((s.value - truth[:, sl]) ** 2, 1))), rtol=1e-9)
    dq = quat_mul(quat_conj(truth[:, 6:10]), track[("uav2", "attitude")].value)
    angle = np.degrees(2 * np.arctan2(np.linalg.norm(dq[:, 1:], axis=1), np.abs(dq[:, 0])))
    np.testing.assert_allclose(scores["rmse_attitude_deg"], np.sqrt(np.mean(angle ** 2)), rtol=1e-9)
    assert scores["epochs"] == epochs.size and scores["finite"]
    # the 9-dof ANEES: the stacked (p, v, theta) errors against the same truth, with the (9, 9) cov_joint
    joints = track.joint[("position", "velocity", "attitude")]
    assert [j.time for j in joints] == epochs.tolist() and all(j.frame == "uav1" for j in joints)
    theta = 2 * np.arctan2(np.linalg.norm(dq[:, 1:], axis=1), dq[:, 0])[:, None] * dq[:, 1:] \
        / np.maximum(np.linalg.norm(dq[:, 1:], axis=1), 1e-300)[:, None]
    e = np.hstack([track[("uav2", "position")].value - truth[:, 0:3], track[("uav2", "velocity")].value - truth[:, 3:6], theta])
    ne = np.array([x @ np.linalg.solve(j.cov, x) for x, j in zip(e, joints)])
    np.testing.assert_allclose([scores["anees"], scores["final_nees"]], [ne.mean(), ne[-1]], rtol=1e-9)
    interval = scores["anees_interval_99"]  # null where the 3-s run cannot decide (docs/consistency.md)
    assert scores["anees_dof"] == 9 and (interval[0] < 9 < interval[1] if interval is not None
                                         else scores["anees_null_reason"].startswith("not decidable from one run"))


def test_bandwidth_builtin_equals_the_batch_filter():
    """bandwidth.fusion fed row by row gives the reproduction's batch filter (the former pipeline)."""
    from testbed.plugins.builtin_bandwidth import Fusion, known_config
    from testbed.reproduce import bandwidth_batch

    sc = scenario.load("bandwidth", duration=2.0)
    log, physics = simulate(sc)
    est = bandwidth_batch.estimate(sc, log)
    _, offsets = known_config(sc.pipeline, sc.seed)
    track, scores, health = _feed(sc, log, physics, Fusion)
    for i in range(4):
        s = track[(f"uav{i + 1}/uwb", "position")]
        np.testing.assert_array_equal(s.time, est["t"])
        np.testing.assert_allclose(s.value, est["xhat"][:, i] + offsets[i], rtol=0, atol=1e-12)
        np.testing.assert_allclose(s.cov, est["M"][:, i], rtol=1e-12, atol=1e-15)
    # the fusion bound hook's numbers are the batch filter's (eqs. 12, 16)
    e = est["truth"][:, None, :] - est["xhat"]
    np.testing.assert_allclose(scores["J_empirical"], (e ** 2).sum(), rtol=1e-9)
    np.testing.assert_allclose(scores["J_bound"], np.trace(est["M"], axis1=-2, axis2=-1).sum(), rtol=1e-9)
    assert health["measurements_used"] == int(est["available"].sum()) and health["steps"] == est["K"]


def _record_figures(monkeypatch, *modules) -> dict[str, set[str]]:
    """{PNG file name: every text drawn in it (legend labels, tick labels, titles)} of the figures
    the given modules save through their `save` (testbed.outputs.plots.save), filled as they are
    written: read after the save, whose drawing laid out every text (no second drawing)."""
    from matplotlib.text import Text

    from testbed.outputs import plots

    drawn: dict[str, set[str]] = {}

    def recording(save):
        def record(fig, path, *a, **k):
            saved = save(fig, path, *a, **k)
            drawn[Path(path).name] = {t.get_text() for t in fig.findobj(Text) if t.get_text()}
            return saved
        return record

    for module in (plots, *modules):
        monkeypatch.setattr(module, "save", recording(plots.save))
    return drawn


ORIGIN = """
    class Origin:
        description = "every measuring site at the world origin"
        def __init__(self, context, params): pass
        def process(self, m):
            return [Estimate(time=m.time, target=m.src, quantity="position", value=np.zeros(3))]
"""
PHASE_FITTING = EstimatorSpec(entry="phase.ekf", params={"q": 1e-8})  # the built-in under another setting


@pytest.fixture(scope="module")
def phase_reproduction(tmp_path_factory):
    """One short `testbed reproduce phase` (2 runs of 1 s) with two plugins, Origin and phase.ekf at
    q = 1e-8, shared by the report test and the plugin test: (its directory, {PNG file name: the
    texts drawn in it}). Its own figures are drawn, its runs' are not (--no-run-plots; the copies of
    run 0's: test_reproduce_phase_copies_run_0s_figures_of_every_estimator). Its q calibration runs
    the rule's code on two values of each grid instead of 6 and 7 (no test here reads the rule's
    choice; tests/test_reproduce_decide.py tests the rule), a quarter of the full grids' CPU time."""
    from testbed.reproduce import phase_q, reproduce, visnav

    tmp = tmp_path_factory.mktemp("phase")
    origin = EstimatorSpec(entry=f"{_write(tmp, ORIGIN)}:Origin")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(phase_q, "Q_GRID", (1e-11, 1e-8))
        mp.setattr(phase_q, "QR_GRID", (0.0, 1e-7))
        drawn = _record_figures(mp, visnav)
        reproduce("phase", tmp / "rep", runs=2, duration=1.0, workers=1, estimators=(origin, PHASE_FITTING),
                  run_plots=False)
    return tmp / "rep", drawn


def test_reproduce_phase_copies_run_0s_figures_of_every_estimator(tmp_path, monkeypatch):
    """`testbed reproduce phase` copies run 0's error figures of the ekf and of each plugin into its
    plots/ (<scenario>-<figure>, <scenario>-<name>_<figure>): one formation (the reproduction's
    list narrowed to it), one run of 1 s with its figures."""
    from testbed.reproduce import phase

    monkeypatch.setattr(phase, "SCENARIOS", ("phase-cross-h000",))
    (tmp_path / "plots").mkdir()
    R, _ = phase.compute(tmp_path, runs=1, motion="prescribed", duration=1.0, workers=1, estimators=(PHASE_FITTING,))
    assert list(R) == ["phase-cross-h000"]
    for fig in ("position_error.png", "velocity_error.png"):
        assert (tmp_path / "runs" / "phase-cross-h000" / "run-000" / "plots" / f"{PHASE_FITTING.key}_{fig}").is_file()
        for name in (f"phase-cross-h000-{fig}", f"phase-cross-h000-{PHASE_FITTING.key}_{fig}"):
            assert (tmp_path / "plots" / name).is_file(), name


@pytest.mark.slow  # builds the module's phase reproduction, ~45 s
def test_phase_reproduction_writes_its_report(phase_reproduction):
    """A short `testbed reproduce phase` (the module's, 2 runs of 1 s): report.md and report.html exist,
    the window is the run's last half and says so, every claim shows its test and n, RMSE vs PCRB is
    a figure."""
    out, _ = phase_reproduction
    md = (out / "report.md").read_text()
    doc = json.loads((out / "claims.json").read_text())
    table = (out / "table.md").read_text()
    assert doc["window_s"] == 0.5 and "uses the last 0.5 s instead" in table and "RMSE pos last 0.5 s" in table
    # eight formations, three ANEES each, and the attitude's where a run observed it (line H000: none),
    # for the ekf and the plugin phase.ekf; and phase.ekf's position ANEES in the plugin section
    # (Origin has no covariance); and the q rule's table: the body ANEES at each q, and the attitude and
    # the body ANEES at each q_rotation, of each of the eight formations, each value with its interval
    # over the seeds
    observed = {k: {d.parent.name for d in (out / "runs").glob("phase-*/run-*")
                    if "anees_attitude6" in json.loads((d / "metrics.json").read_text())["estimators"][k]}
                for k in ("ekf", PHASE_FITTING.entry)}
    assert "phase-line-h000" not in observed["ekf"]
    assert assert_every_anees_has_its_interval(table) == sum(8 * 3 + len(o) for o in observed.values()) + 8 + 3 * 8
    assert "last_100s" not in (out / "table.csv").read_text()
    assert "testbed reproduce phase --out" in md and "--runs 2" in md and "--duration 1" in md
    for c in doc["claims"]:
        assert c["test"]["name"] and c["test"]["n"] == 2, c["id"]
    assert (out / "plots" / "rmse_vs_pcrb.png").is_file()
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == len(list((out / "plots").glob("*.png")))
    m = json.loads((out / "runs" / "phase-cross-h000" / "run-000" / "metrics.json").read_text())["estimators"]["ekf"]
    assert m["last_window_s"] == 0.5 and np.isfinite(m["rmse_position_last_0.5s_m"])
    made = json.loads((out / "provenance.json").read_text())  # and each of its runs (testbed.provenance)
    assert made["output"] == "reproduce-phase" and made["command"]["function"] == "testbed.reproduce.reproduce"
    assert json.loads((out / "runs" / "phase-cross-h000" / "run-000" / "provenance.json").read_text())["output"] == "run"


@pytest.mark.slow  # a short visnav reproduction, ~10 s; phase's is the module's shared one
@pytest.mark.parametrize("paper, group", [("phase", "phase-cross-h000"), ("visnav", "gaussian")])
def test_reproduce_gives_a_plugin_every_table_and_figure(tmp_path, monkeypatch, request, paper, group):
    """A plugin whose outputs fit nothing of the paper (Origin) gets its generic row; one whose outputs
    fit the paper's scores (the built-in filter under another name and setting, entered like any
    --estimator) is in every table and figure that shows the built-ins' per-estimator results, with
    the paired tests against each built-in over the same 2 seeds (phase's copies of run 0's figures:
    test_reproduce_phase_copies_run_0s_figures_of_every_estimator)."""
    from testbed.reproduce import visnav

    if paper == "phase":
        out, drawn = request.getfixturevalue("phase_reproduction")
        name = PHASE_FITTING.entry
    else:
        drawn = _record_figures(monkeypatch, visnav)
        path = _write(tmp_path, ORIGIN)
        out, name = tmp_path / "rep", "visnav.ekf"
        assert main(["reproduce", paper, "--runs", "2", "--duration", "1", "--workers", "1", "--out", str(out),
                     "--estimator", f"{path}:Origin", "--estimator", name, "--no-run-plots"]) == 0
    md = (out / "table.md").read_text()
    section = md[md.index("## Plugin estimators"):]
    row = next(line for line in section.splitlines() if line.startswith(f"| {group} | Origin | 2 | "))
    assert float(row.split("|")[4].split("±")[0]) > 1.0  # metres from the origin
    assert "Plugin estimators" in (out / "report.md").read_text()
    head, *rows = (out / "table_plugins.csv").read_text().strip().splitlines()
    assert head.startswith("group,estimator,runs,rmse_position_m_mean") and any(r.startswith(f"{group},Origin,2,") for r in rows)
    # compared with each built-in of the same runs over the same 2 seeds, with the factor of the means
    _, *paired = (out / "table_plugins_paired.csv").read_text().strip().splitlines()
    builtins = ["ekf"] if paper == "phase" else list(visnav.FILTERS)
    for b in builtins:
        assert any(r.startswith(f"{group},{name},{b},2,") and float(r.split(",")[6]) > 0 for r in paired), b
    # the paper's own table and figures
    table = (out / "table.csv").read_text()
    if paper == "phase":
        assert f"\n{group},{name},2," in table and f"| {group} | {name} | 2 |" in md
        for fig in ("rmse_window.png", "rmse_vs_pcrb.png"):
            assert {name, "ekf"} <= drawn[fig], fig
    else:
        assert f"\ngaussian,{name},rmse_position_m," in table and f"| {name} | " in md
        for case in visnav.CASES:
            assert {name, "EKF", "RHCF"} <= drawn[f"rms_error_vs_time_{case}.png"]
            for q in ("position", "velocity", "attitude"):
                assert {name, "Origin", "EKF"} <= drawn[f"compare_{q}_{case}.png"]


@pytest.mark.slow  # the uwb mode of reproduce bandwidth: 2 runs of 1 s (the paper mode has no physics run)
def test_reproduce_bandwidth_gives_a_plugin_every_table_and_figure(tmp_path, monkeypatch):
    """The uwb mode of `reproduce bandwidth --estimator examples/anchor_ekf.py:AnchorEkf`: the plugin's J
    (eq. 12 over the same node-epochs as a case's) is a row of the table, a bar of J_by_case.png and a
    curve of figs. 3-4, tested against every case (paired t over the same 2 seeds, factor), and its
    runs hold the built-in too (the Plugin estimators section's comparison)."""
    from testbed.reproduce import bandwidth as rep, bandwidth_plots
    from testbed.reproduce import plugins as rows

    drawn = _record_figures(monkeypatch, bandwidth_plots)
    out = tmp_path / "uwb"
    spec = EstimatorSpec(entry=f"{ROOT}/examples/anchor_ekf.py:AnchorEkf")
    uwb = rep.compute_uwb(out, runs=2, motion="prescribed", duration=1.0, workers=1, estimators=(spec,))
    rep.write_uwb(out, uwb, rep.decide_uwb(uwb))
    runs = [json.loads((out / "runs" / f"run-{i:03d}" / "metrics.json").read_text())["estimators"] for i in range(2)]
    J = np.array([r["AnchorEkf"]["J_empirical"] for r in runs])
    assert {"AnchorEkf", "T1+P1", "Tbest_bound+P1"} <= drawn["J_by_case.png"]
    # its J from its estimates and the tags' truth is the fusion bound hook's of its runs
    row = next(line for line in (out / "table.csv").read_text().splitlines() if line.startswith("AnchorEkf,"))
    assert float(row.split(",")[1]) == pytest.approx(J.mean(), rel=1e-9) and "| AnchorEkf |" in (out / "table.md").read_text()
    for fig in ("fig3_J_vs_T.png", "fig4_J_vs_P.png"):
        assert "AnchorEkf" in drawn[fig] and "T1+P1" in drawn[fig]
    head, *tests = (out / "table_plugins_paired_J.csv").read_text().strip().splitlines()
    cases = {t.split(",")[1]: dict(zip(head.split(","), t.split(","))) for t in tests}
    assert set(cases) == {"T1+P1", "T2+P1", "T3+P1", "Tbest_bound+P1", "T1+P2", "T1+P3"}
    for c in cases.values():
        assert c["runs"] == "2" and float(c["factor"]) == pytest.approx(float(c["J_against"]) / J.mean(), rel=1e-9)
        assert 0.0 <= float(c["p_two_sided"]) <= 1.0
    assert [(r["against"], r["runs"]) for r in rows.paired({"uwb mode": runs}, ["AnchorEkf"])] == [("bandwidth", 2)]


def test_the_covariance_check_agrees_with_eigenvalues():
    """collect.cov_problem (plain floats, per estimate) against numpy: finite, symmetric, and positive
    definite exactly when the smallest eigenvalue is positive (random matrices well away from singular)."""
    from testbed.plugins.collect import cov_problem

    rng = np.random.default_rng(3)
    seen = set()
    for _ in range(3000):
        A = rng.normal(size=(3, 3))
        c = A @ A.T - rng.uniform(0.0, 2.0) * np.eye(3)
        lam = np.linalg.eigvalsh(c)[0]
        if abs(lam) < 1e-6:
            continue
        expected = None if lam > 0 else "cov is not positive definite"
        assert cov_problem(c.tolist()) == expected
        seen.add(expected)
    assert seen == {None, "cov is not positive definite"}
    c = np.eye(3)
    c[0, 1] = 1e-3
    assert cov_problem(c.tolist()) == "cov is not symmetric"
    c[1, 0] = 1e-3
    assert cov_problem(c.tolist()) is None
    c[2, 2] = np.nan
    assert cov_problem(c.tolist()) == "cov is not finite"
    # positive definite, but singular to double precision: no NEES can be computed at it
    assert cov_problem(np.diag([1.0, 1.0, 1e-20]).tolist()).startswith("cov is numerically singular")
    assert cov_problem(np.diag([1e6, 1.0, 1e-9]).tolist()).startswith("cov is numerically singular")  # condition 1e15
    assert cov_problem(np.diag([1.0, 1.0, 1e-12]).tolist()) is None


def test_covariances_are_checked_together_and_the_first_bad_one_is_named():
    """The batched check (collect.cov_problems) gives each covariance's own answer, and the
    collector, which checks them when the track is built, names the first bad one in arrival
    order with when it was returned."""
    from testbed.plugins.collect import Collector, cov_problem, cov_problems
    from testbed.plugins.api import Estimate

    rng = np.random.default_rng(4)
    C = np.stack([A @ A.T - rng.uniform(0.0, 2.0) * np.eye(3) for A in rng.normal(size=(500, 3, 3))])
    C[7, 0, 1] += 1.0
    C[9, 2, 2] = np.inf
    C[11] = np.diag([1.0, 1.0, 1e-20])
    assert cov_problems(C) == [cov_problem(c) for c in C]

    class P:
        key, entry = "x", "x"
    col = Collector(P(), {"uav1", "uav2"}, 10.0)
    col.add([Estimate(time=1.0, target="uav1", quantity="position", value=np.zeros(3), cov=np.eye(3))], "at t = 1 s")
    col.add([Estimate(time=2.0, target="uav2", quantity="velocity", value=np.zeros(3), cov=-np.eye(3))], "at t = 2 s")
    col.add([Estimate(time=3.0, target="uav1", quantity="position", value=np.zeros(3), cov=np.full((3, 3), np.nan))],
            "at t = 3 s")
    with pytest.raises(PluginError, match=r"at t = 2 s: estimate of uav2 velocity: cov is not positive definite"):
        col.track()


def test_diagnostics_are_collected_when_asked_and_checked():
    """run_plugin fills a given dict from an estimator's diagnostics(); ragged or non-finite columns
    are one PluginError naming the estimator; a batch goes row by row to an estimator without
    process_batch."""
    from testbed.plugins.api import Context, MeasurementBatch

    class Diag:
        bad = None

        def __init__(self, context, params):
            self.seen = []

        def process(self, m):
            self.seen.append((m.time, m.src, None if m.sigma is None else float(m.sigma[0])))

        def diagnostics(self):
            t = [s[0] for s in self.seen]
            return self.bad or {"time": t, "sigma": [s[2] if s[2] is not None else -1.0 for s in self.seen]}

    ctx = Context(vehicles=("uav1",), sites={}, anchors={}, sensors={}, duration=1.0, seed=0, rng=np.random.default_rng(0))
    b = MeasurementBatch(stream="uwb", time=np.array([0.1, 0.2]), arrival=np.array([0.1, 0.2]), value=np.ones((2, 1)),
                         src=np.array(["uav1/uwb", "uav1/uwb"]), dst=np.array(["a1", "a2"]), sigma=np.array([[0.3], [np.nan]]))
    d: dict = {}
    run_plugin(Plugin("d", "d", Diag, {}), ctx, [b], d)
    np.testing.assert_array_equal(d["time"], [0.1, 0.2])
    np.testing.assert_array_equal(d["sigma"], [0.3, -1.0])  # the NaN row: sigma None
    for bad in ({"a": [1.0, 2.0], "b": [1.0]}, {"a": [np.inf]}, {"a": [[1.0]]}):
        Diag.bad = bad
        with pytest.raises(PluginError, match="estimator 'd' .*diagnostics"):
            run_plugin(Plugin("d", "d", Diag, {}), ctx, [b], {})


# Bad raises at its first measurement of t >= 1 s: the runs that fly it last 1.5 s, which reach t = 1 s
FAILING_AND_GOOD = """
    class Bad:
        def __init__(self, context, params): pass
        def process(self, m):
            if m.time >= 1.0:
                raise ZeroDivisionError("diverged")
            return []
    class Good:
        def __init__(self, context, params): pass
        def process(self, m):
            if m.stream == "gnss":
                yield Estimate(time=m.time, target=m.src, quantity="position", value=m.value)
"""


def test_a_sweep_scores_the_others_and_lists_the_failed_runs(tmp_path):
    """Every run is written (its metrics.json marked incomplete), summary.json lists the failed
    estimator by run and holds the other plugin's scores; then EstimatorsFailed (exit 1)."""
    from testbed.errors import EstimatorsFailed
    from testbed.sweep import sweep

    path = _write(tmp_path, FAILING_AND_GOOD)
    sc = scenario.load("coop-fg", duration=1.5, seed=3)
    sc = dataclasses.replace(sc, estimators=(EstimatorSpec(entry=f"{path}:Bad"), EstimatorSpec(entry=f"{path}:Good")))
    with pytest.raises(EstimatorsFailed, match=r"Bad in runs 0, 1") as e:
        sweep(sc, 2, tmp_path / "sweep", workers=1, progress=False, plots=False)
    assert e.value.exit_code == 1
    summary = json.loads((tmp_path / "sweep" / "summary.json").read_text())
    assert summary["failed_estimators"] == {"Bad": [0, 1]} and summary["scores"]["estimators.Good.rmse_position_m"]["n"] == 2
    for i in range(2):
        m = json.loads((tmp_path / "sweep" / f"run-{i:03d}" / "metrics.json").read_text())
        assert m["incomplete"] is True and m["estimators"]["Bad"]["failed"]["time_s"] >= 1.0


def test_a_reproduction_writes_its_report_without_the_failed_estimator_and_exits_1(tmp_path, capsys):
    path = _write(tmp_path, FAILING_AND_GOOD)
    out = tmp_path / "rp"
    assert main(["reproduce", "coop", "--runs", "2", "--duration", "1.5", "--workers", "1", "--out", str(out), "--quiet",
                 "--estimator", f"{path}:Bad", "--estimator", f"{path}:Good", "--no-run-plots"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "estimators failed in 2 runs" in err and "runs/run-000: Bad" in err
    assert (out / "claims.json").is_file() and (out / "report.md").is_file()
    table = (out / "table.csv").read_text().splitlines()
    header = table[0].split(",")
    good, bad = header.index("rmse_Good_m"), header.index("rmse_Bad_m")
    rows = [r.split(",") for r in table[1:]]
    assert all(math.isfinite(float(r[good])) for r in rows) and all(r[bad] in ("", "nan") or math.isnan(float(r[bad])) for r in rows)


def test_a_reproduction_scored_in_process_reports_the_failed_estimator_too(tmp_path, capsys):
    """visnav scores its plugins in process (no run directories): runs.json lists the failed one
    by seed, with each run's time and reason; the report is written; exit 1."""
    path = _write(tmp_path, FAILING_AND_GOOD)
    out = tmp_path / "rv"
    assert main(["reproduce", "visnav", "--runs", "1", "--duration", "1.5", "--workers", "1", "--out", str(out), "--quiet",
                 "--estimator", f"{path}:Bad"]) == 1
    err = capsys.readouterr().err
    assert err.splitlines()[-1].startswith("testbed: error: estimators failed in 1 runs") and "seed 1: Bad" in err
    runs = json.loads((out / "runs.json").read_text())
    assert runs["failed_estimators"] == {"Bad": [1]}
    failed = runs["runs"][0]["gaussian"]["plugins"]["Bad"]["failed"]
    assert failed["time_s"] >= 1.0 and "raised ZeroDivisionError: diverged" in failed["reason"]
    assert (out / "report.md").is_file() and (out / "claims.json").is_file()


def test_plugin_rows_are_paired_with_every_other_estimator_of_the_same_runs():
    """testbed.reproduce.plugins.paired: a plugin against each other estimator with a position RMSE
    in the same runs (a run where either failed is left out of that pair), the factor of the means
    and scipy's two-sided Wilcoxon signed-rank p of the paired differences; the section and
    table_plugins_paired.csv carry them."""
    from scipy.stats import wilcoxon

    from testbed.reproduce import plugins as rows

    rng = np.random.default_rng(5)
    mine, ekf = rng.uniform(1.0, 2.0, 8), rng.uniform(1.5, 3.0, 8)
    runs = [{"mine": {"rmse_position_m": float(a)}, "ekf": {"rmse_position_m": float(b)}, "graph": {"rmse_position_m": [1.0]}}
            for a, b in zip(mine, ekf)]
    runs[3]["ekf"] = {"failed": "in process()"}
    got = rows.paired({"case": runs}, ["mine"])
    assert [(r["estimator"], r["against"], r["runs"]) for r in got] == [("mine", "ekf", 7)]  # graph's RMSE is not a number
    keep = np.arange(8) != 3
    r = got[0]
    assert r["factor"] == pytest.approx(ekf[keep].mean() / mine[keep].mean(), rel=1e-12)
    assert r["p_two_sided"] == pytest.approx(wilcoxon(mine[keep] - ekf[keep]).pvalue, rel=1e-12)
    assert rows.paired({"case": [{"mine": {"rmse_position_m": 1.0}}]}, ["mine"]) == []
    md = rows.markdown({"case": runs}, ["mine"], "case")
    assert any(line.startswith("| case | mine | ekf | 7 |") for line in md)


def test_every_estimator_is_drawn_from_the_same_runs(tmp_path, monkeypatch):
    """testbed.reproduce.plugins.bars: one score of every estimator (built-in or plugin) per group, its
    mean and 95 % Student t interval over the runs where it has the score (a failed run left out),
    each estimator in the legend, the groups on the axis."""
    from testbed.reproduce import plugins as rows
    from testbed.scoring.metrics import mean_ci

    drawn = _record_figures(monkeypatch)
    got = {}
    bars = rows.grouped_bars

    def keep(groups, names, means, lo, hi, path, **k):
        got.update(groups=groups, names=names, means=means, lo=lo, hi=hi)
        return bars(groups, names, means, lo, hi, path, **k)

    monkeypatch.setattr(rows, "grouped_bars", keep)
    runs = [{"ekf": {"rmse_position_m": 1.0 + i}, "mine": {"rmse_position_m": 0.5 * (1 + i)}} for i in range(4)]
    runs[2]["mine"] = {"failed": {"reason": "in process()"}}
    assert np.isnan(rows.column(runs, "mine", "rmse_position_m")[2]) and np.isnan(rows.column(runs, "other", "x")).all()
    rows.bars({"case A": runs, "case B": runs[:2]}, rows.estimator_names(["ekf"], ["mine", "ekf"]), "rmse_position_m",
              tmp_path / "b.png", title="t", ylabel="m")
    assert got["groups"] == ["case A", "case B"] and got["names"] == ["ekf", "mine"]
    want = mean_ci(np.array([0.5, 1.0, 2.0]))
    assert (got["means"][0, 1], got["lo"][0, 1], got["hi"][0, 1]) == pytest.approx(want, rel=1e-12)
    assert got["means"][1, 0] == pytest.approx(1.5, rel=1e-12)
    assert {"ekf", "mine", "case A", "case B"} <= drawn["b.png"]


def test_a_reproduction_command_gives_back_its_estimators_and_params():
    """testbed.reproduce.command: each --estimator with its params as --param KEY=VALUE, read back by
    the command line into the same EstimatorSpecs (a string, a number, a table, a list)."""
    import shlex

    from testbed.cli import _estimator_specs, build_parser
    from testbed.reproduce import command

    specs = (EstimatorSpec(entry="phase.ekf", params={"q": 1e-8, "label": "a b", "network": {"loss_prob": 0.1}}),
             EstimatorSpec(entry="examples/my dir/f.py:Mine", params={"xs": [1, 2.5]}), EstimatorSpec(entry="visnav.ekf"))
    line = command("phase", Path("out"), runs=2, motion="prescribed", duration=1.0, workers=1, estimators=specs)
    args = build_parser().parse_args(shlex.split(line)[1:])
    assert _estimator_specs(args) == specs
