"""Typed estimator parameters (testbed.plugins.params): every registered estimator declares its
Params, `testbed estimators NAME` prints them, docs/estimators.md's tables are generated from them,
and `--estimator NAME --param KEY=VALUE` sets them, a mistake exiting 2 before anything runs."""
from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import pytest

from testbed.cli import _estimator_specs, build_parser, main
from testbed.plugins import params
from testbed.plugins.loading import load_class, registered

ROOT = Path(__file__).resolve().parent.parent


def test_every_registered_estimator_declares_documented_params():
    for name in registered():
        Params = params.params_class(load_class(name))
        assert Params is not None, name
        rows = params.rows(Params)
        assert rows and all(doc for *_, doc in rows), (name, [r[0] for r in rows if not r[5]])
        if len(params.fields(Params)) == len(dataclasses.fields(Params)):  # not a pipeline config
            Params()  # the defaults are valid


def test_estimators_name_prints_every_parameter(capsys):
    assert main(["estimators", "nav.eskf"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["name", "type", "unit", "default", "range", "doc"]
    rows = {line.split()[0]: line for line in out[1:]}
    assert set(rows) == {f.name for f in params.fields(params.params_class(load_class("nav.eskf")))}
    assert rows["gate_prob"].split()[:5] == ["gate_prob", "float", "0.0001", "in", "[0,"]
    assert main(["estimators", "no.such"]) == 2


def test_docs_estimators_md_parameter_tables_are_current(capsys):
    assert main(["estimators", "--markdown"]) == 0
    generated = capsys.readouterr().out
    assert generated == params.markdown({n: load_class(n) for n in registered()})
    doc = (ROOT / "docs" / "estimators.md").read_text()
    assert params.BEGIN in doc and params.END in doc
    assert params.splice(doc, generated) == doc, \
        "docs/estimators.md is stale: put the output of `testbed estimators --markdown` between its generated markers"


def test_param_options_belong_to_the_estimator_before_them():
    args = build_parser().parse_args(["run", "coop-fg", "--out", "x", "--estimator", "nav.eskf", "--param", "gate_prob=0.01",
                                      "--param", "yaw0 = 1", "--estimator", "coop.window", "--estimator", "graph.poses",
                                      "--param", "loss=huber", "--param", "initial={ uav1 = [1, 2, 3] }"])
    specs = _estimator_specs(args)
    assert [(s.entry, s.params) for s in specs] == [
        ("nav.eskf", {"gate_prob": 0.01, "yaw0": 1}), ("coop.window", {}),
        ("graph.poses", {"loss": "huber", "initial": {"uav1": [1, 2, 3]}})]


def test_param_values_reach_the_run(tmp_path):
    out = tmp_path / "run"
    assert main(["run", "coop-fg", "--duration", "0.5", "--out", str(out), "--estimator", "coop.centralized",
                 "--param", "robust=huber", "--param", "huber_delta=2", "--no-plots"]) == 0
    written = tomllib.loads((out / "scenario.toml").read_text())["estimators"]
    assert written == [{"entry": "coop.centralized", "name": "", "params": {"robust": "huber", "huber_delta": 2}}]


@pytest.mark.parametrize("entry, param, shown", [
    ("nav.eskf", "gate=0.1", "params: gate = 0.1: unknown key (known: divergence_prob, gate_prob,"),
    ("nav.eskf", "gate_prob=often", "params: gate_prob = 'often': expected a number, got 'often'"),
    ("nav.eskf", "gate_prob=1.5", "params: gate_prob = 1.5: must be in [0, 1), got 1.5"),
    ("nav.eskf", "output_every=2.5", "params: output_every = 2.5: expected an integer, got 2.5"),
    ("coop.centralized", "range_sigma=0", "params: range_sigma = 0.0: must be positive, got 0.0"),
    ("coop.centralized", "twr_mode=tof", "params: twr_mode = 'tof': invalid value 'tof'"),
    ("coop.centralized", "kind=visnav", "params: kind = 'visnav': unknown key"),
    ("graph.poses", "loss=l1", "params: loss = 'l1': invalid value 'l1'"),
    ("coop.window_distributed", "network={ loss_prob = 2 }", "params: network.loss_prob = 2.0: must be in [0, 1"),
])
def test_a_bad_param_exits_2_naming_estimator_key_and_value_before_simulating(tmp_path, capsys, entry, param, shown):
    out = tmp_path / "run"
    assert main(["run", "coop-fg", "--duration", "1", "--out", str(out), "--estimator", entry, "--param", param]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"estimator '{entry}' ({entry}) {shown}" in err, err
    assert not out.exists()


@pytest.mark.parametrize("argv, shown", [
    (["--param", "q=1"], "--param 'q=1': give it after the --estimator it sets"),
    (["--estimator", "nav.eskf", "--param", "q"], "--param 'q': expected KEY=VALUE"),
])
def test_a_malformed_param_option_exits_2(tmp_path, capsys, argv, shown):
    out = tmp_path / "run"
    assert main(["run", "coop-fg", "--duration", "1", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and shown in err and not out.exists()


# --------------------------------------------------------------- the assumed sensor models


def test_the_assumed_range_model_is_the_declared_one_unless_set():
    from testbed.config import scenario

    fg = scenario.load("coop-fg")
    u = fg.sensors.uwb
    assert (fg.pipeline.range_sigma, fg.pipeline.twr_mode, fg.pipeline.clock_ppm, fg.pipeline.reply_time,
            fg.pipeline.antenna_delay_sigma) == (u.noise, u.mode, u.clock_ppm, u.reply_time, u.antenna_delay_sigma)
    moved = scenario.load("coop-fg", {"sensors.uwb.noise": "0.25", "sensors.uwb.mode": '"ss-twr"'})
    assert (moved.pipeline.range_sigma, moved.pipeline.twr_mode) == (0.25, "ss-twr")
    mismatch = scenario.load("coop-fg", {"sensors.uwb.noise": "0.25", "pipeline.range_sigma": "0.3"})
    assert (mismatch.pipeline.range_sigma, mismatch.pipeline.twr_mode) == (0.3, u.mode)
    assert scenario.load("phase-line-h000", {"sensors.phase.phase_noise": "0.07"}).pipeline.range_sigma == 0.07
    assert (fg.pipeline.gnss_sigma_h, fg.pipeline.gnss_sigma_v, fg.pipeline.rtk_sigma_h, fg.pipeline.rtk_sigma_v) == (1.5, 3.0, 0.02, 0.03)
    gnss = scenario.load("coop-fg", {"sensors.gnss.receiver.noise_h": "1.2", "sensors.gnss.receiver.bias_h": "0.5",
                                      "sensors.gnss.receiver.bias_tau": "60"}).pipeline
    assert gnss.gnss_sigma_h == pytest.approx(1.3, rel=1e-12) and gnss.gnss_sigma_v == 3.0
    assert scenario.load("bandwidth", {"sensors.uwb.noise": "0.2"}).pipeline.range_sigma == 0.2


def test_a_paper_builtin_on_another_scenario_assumes_its_declared_sensors():
    from types import SimpleNamespace

    from testbed.config.pipelines import CoopPipelineConfig
    from testbed.plugins.settings import settings

    uwb = {"noise": 0.3, "mode": "ss-twr", "clock_ppm": 5.0, "reply_time": 1e-3, "antenna_delay_sigma": 0.01}
    context = SimpleNamespace(pipeline={"kind": "tracking"}, sensors={"uwb": uwb})
    cfg = settings(CoopPipelineConfig, context, {"clock_ppm": 7.0}, "coop.centralized")
    assert (cfg.range_sigma, cfg.twr_mode, cfg.clock_ppm, cfg.reply_time, cfg.antenna_delay_sigma) == (0.3, "ss-twr", 7.0, 1e-3, 0.01)


def test_the_estimator_runtime_takes_its_sensor_models_from_estimators_not_the_simulator():
    import ast

    for path in [*(ROOT / "testbed" / "plugins").glob("*.py"), ROOT / "testbed" / "replay" / "graph.py"]:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert not (node.module or "").startswith("testbed.sensors"), f"{path.name} imports {node.module}"


@pytest.mark.parametrize("command", [["sweep", "coop-fg", "--runs", "2"], ["reproduce", "coop", "--runs", "2"]])
def test_sweep_and_reproduce_refuse_a_bad_param_before_running(tmp_path, capsys, command):
    out = tmp_path / "out"
    assert main([*command, "--duration", "1", "--out", str(out), "--estimator", "nav.eskf", "--param", "gate_prob=-1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "estimator 'nav.eskf' (nav.eskf) params: gate_prob = -1.0: must be in [0, 1)" in err, err
    assert not out.exists()
