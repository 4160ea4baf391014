"""The Python API (docs/api.md runs as written), `--set` on list elements, `testbed schema`
(docs/scenario.md current, every key covered) and the README's command-line synopsis."""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import testbed
from testbed.config import schema
from testbed.config import scenario
from testbed.cli import build_parser, main
from testbed.config import parse_key, to_dict
from testbed.errors import ConfigError, RunError

ROOT = Path(__file__).resolve().parent.parent


def test_import_testbed_is_light_and_exposes_the_api_lazily():
    code = "import sys, testbed; heavy = [m for m in ('numpy', 'mujoco') if m in sys.modules]; print(heavy, sorted(testbed.__all__))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.startswith("[] ") and "load_scenario" in out and "run" in out
    assert testbed.load_run.__module__ == "testbed.api"
    with pytest.raises(AttributeError):
        testbed.no_such_thing  # noqa: B018


def test_docs_api_code_blocks_run_in_order(tmp_path, monkeypatch):
    text = (ROOT / "docs" / "api.md").read_text()
    blocks = re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)
    assert len(blocks) >= 6
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "docs/api.md", "exec"), namespace)  # noqa: S102
    assert (tmp_path / "run-a" / "metrics.json").is_file()


def test_site_truth_is_the_body_pose_moved_by_the_lever_arm(tmp_path):
    sc = testbed.load_scenario("phase-vacute-h000", duration=2.0, motion="flown")
    with testbed.run(sc, plots=False) as r:
        body, nose = r.truth("uav2"), r.truth("uav2/ant1")
    R = Rotation.from_quat(body.quat, scalar_first=True)
    assert np.abs(nose.pos - (body.pos + R.apply([sc.world.antenna_a, 0, 0]))).max() < 1e-9
    # v_site = v_body + omega x r (omega in the body frame, rotated to world)
    assert np.abs(nose.vel - (body.vel + np.cross(R.apply(body.omega), R.apply([sc.world.antenna_a, 0, 0])))).max() < 1e-9
    assert np.abs(nose.omega - body.omega).max() < 1e-9  # the site is fixed on the body, axes aligned
    with pytest.raises(KeyError, match="uav9"):
        r.truth("uav9")
    with pytest.raises(KeyError, match="streams: phase"):
        r.stream("uwb")


def test_load_run_refuses_a_directory_that_is_not_a_run(tmp_path):
    with pytest.raises(RunError, match="missing scenario.toml, scene.xml, log.npz, metrics.json"):
        testbed.load_run(tmp_path)


# ---------------------------------------------------------------------------- --set on lists


def test_parse_key_brackets_and_dotted_numbers():
    assert parse_key("world.obstacles[0].size") == ["world", "obstacles", 0, "size"]
    assert parse_key("world.anchors[1][2]") == ["world", "anchors", 1, 2]
    assert parse_key("world.anchors.1") == ["world", "anchors", 1]
    for bad in ("world..x", "world.anchors[x]", "world.anchors[1", "[0]", "world.anchors]1["):
        assert parse_key(bad) is None, bad


def test_set_addresses_list_elements_with_the_same_validation():
    sc = scenario.load("bandwidth", {"trajectory.offsets[2]": "[1, 0, 0]", "world.anchors[1][2]": "7.5"})
    assert sc.trajectory.offsets[2] == (1.0, 0.0, 0.0)
    assert sc.world.anchors[1][2] == 7.5
    base = scenario.load("bandwidth")
    assert sc.trajectory.offsets[:2] == base.trajectory.offsets[:2] and sc.world.anchors[0] == base.world.anchors[0]
    obst = {"world.obstacles": '[{type = "box", pos = [0.0, 0.0, 5.0], size = [1.0, 1.0, 1.0]}]'}
    sc = scenario.load("bandwidth", {**obst, "world.obstacles[0].size": "[1, 2, 3]"})
    assert sc.world.obstacles[0].size == (1.0, 2.0, 3.0)
    with pytest.raises(ConfigError, match=r"bandwidth.toml: world.obstacles\[0\].size: must be positive, got \[1.0, -2.0, 3.0\]"):
        scenario.load("bandwidth", {**obst, "world.obstacles[0].size": "[1, -2, 3]"})
    with pytest.raises(ConfigError, match=r"no key 'trajectory.offsets\[9\]' in the scenario \(trajectory.offsets has 4 elements\)"):
        scenario.load("bandwidth", {"trajectory.offsets[9]": "[1, 0, 0]"})
    with pytest.raises(ConfigError, match=r"trajectory.offsets\[2\]: expected 3 values"):
        scenario.load("bandwidth", {"trajectory.offsets[2]": "[1, 0]"})
    with pytest.raises(ConfigError, match="no key 'world.obstacles.size'"):
        scenario.load("bandwidth", {"world.obstacles.size": "1"})


def test_set_list_element_on_the_command_line_exit_2_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "bandwidth", "--out", str(out), "--duration", "1", "--set", "trajectory.offsets[7]=[1,0,0]"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "trajectory.offsets[7]" in err and "4 elements" in err and not out.exists()


# ----------------------------------------------------------------------------- testbed schema


def test_docs_scenario_md_is_the_current_schema(capsys):
    assert main(["schema"]) == 0
    printed = capsys.readouterr().out
    assert printed == schema.markdown()
    assert (ROOT / "docs" / "scenario.md").read_text() == printed, "docs/scenario.md is stale: testbed schema > docs/scenario.md"


def _leaf_keys(table: object, prefix: str = "") -> set[str]:
    if isinstance(table, dict):
        return {k for key, v in table.items() for k in _leaf_keys(v, f"{prefix}.{key}" if prefix else key)}
    if isinstance(table, list) and table and isinstance(table[0], dict):
        return {k for v in table for k in _leaf_keys(v, f"{prefix}[i]")}
    return {prefix}


def test_schema_lists_every_key_of_every_builtin_scenario_with_type_and_default():
    rows = {r[0]: r for s in schema.sections() for r in s["rows"]}
    keys = set().union(*(_leaf_keys(to_dict(scenario.load(n))) for n in scenario.builtin_names()))
    free = {r for r, row in rows.items() if row[1] == "dict"}  # free tables (an estimator's params): their keys are the plugin's
    missing = {k for k in keys - set(rows) if not any(r.startswith(f"{k}[i].") for r in rows)  # [] of tables
               and not any(k.startswith(f"{f}.") for f in free)}
    assert not missing, sorted(missing)
    assert rows["world.timestep"][1:] == ("float", "s", "0.0025", "in [1e-06, 0.01]")
    assert rows["sensors.uwb.loss_prob"][3:] == ("preset", "in [0, 1)")
    assert rows["world.obstacles[i].type"][4] == 'one of "box", "cylinder"'


# ----------------------------------------------------------------------- README command line


def _command_line_section() -> str:
    text = (ROOT / "README.md").read_text()
    return text.split("## Command line", 1)[1].split("\n## ", 1)[0]


def test_readme_synopsis_names_every_subcommand_and_option():
    section = _command_line_section()
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = []
    for name, p in sub.choices.items():
        if f"testbed {name}" not in section:
            missing.append(f"testbed {name}")
        for action in p._actions:
            missing += [f"{name} {o}" for o in action.option_strings if o not in ("-h", "--help") and o not in section]
            missing += [f"{name} {c}" for c in (action.choices or []) if action.option_strings == [] and str(c) not in section]
    assert not missing, f"README 'Command line' lacks: {missing}"


@pytest.mark.parametrize("page", ["README.md", *sorted(p.name for p in (ROOT / "docs").glob("*.md"))])
def test_docs_refer_to_nothing_outside_the_repository(page):
    text = (ROOT / page if page == "README.md" else ROOT / "docs" / page).read_text()
    for outside in ("../", "SPEC.md", "DESIGN.md", "http://", "https://"):
        assert outside not in text, f"{page} sends the reader outside the repository: {outside!r}"


# ------------------------------------------------------------------------------------ examples

EXAMPLES = {
    "nlos_study.py": ["nlos_study.png", "nlos_study.csv"],
    "monte_carlo.py": ["monte_carlo.png", "sweep/summary.csv"],
    "six_on_a_circle.py": ["six_on_a_circle.png", "run/metrics.json"],
    "uwb_analysis.py": ["uwb_analysis.png", "run/log.npz"],
}


#: the example run as a user runs it, `python examples/NAME.py OUT` in a new interpreter; the others
#: run as the same script (`__main__`, its folder first on sys.path, OUT its argument) in this
#: process, which saves an interpreter start and its imports each
SUBPROCESS_EXAMPLE = "six_on_a_circle.py"


@pytest.mark.parametrize("script", sorted(EXAMPLES))
def test_example_runs_on_a_short_horizon(script, tmp_path, monkeypatch):
    import runpy

    import matplotlib.pyplot as plt

    path = ROOT / "examples" / script
    assert path.read_text().startswith('"""Example '), "each example starts with a header saying what it shows"
    if script == SUBPROCESS_EXAMPLE:
        env = {**os.environ, "TESTBED_EXAMPLE_SHORT": "1", "PYTHONPATH": str(ROOT)}
        done = subprocess.run([sys.executable, str(path), str(tmp_path)], env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
    else:
        monkeypatch.setenv("TESTBED_EXAMPLE_SHORT", "1")
        monkeypatch.syspath_prepend(str(path.parent))
        monkeypatch.setattr(sys, "argv", [str(path), str(tmp_path)])
        monkeypatch.delitem(sys.modules, "_common", raising=False)  # its SHORT is read when imported
        try:
            runpy.run_path(str(path), run_name="__main__")  # an exception fails the test, as a traceback would
        finally:
            plt.close("all")
            sys.modules.pop("_common", None)
    for name in EXAMPLES[script]:
        assert (tmp_path / name).is_file(), name


def test_six_on_a_circle_toml_runs_from_the_command_line(tmp_path, capsys):
    assert main(["run", str(ROOT / "examples" / "six_on_a_circle.toml"), "--duration", "1", "--out", str(tmp_path / "c"),
                 "--no-plots"]) == 0
    sc = testbed.load_run(tmp_path / "c").scenario
    assert sc.vehicles == 6 and len(sc.world.anchors) == 4 and sc.world.obstacles[0].type == "box"
    r = np.hypot(*np.array(sc.trajectory.offsets)[:, :2].T)
    assert np.allclose(r, 15.0, atol=1e-5)
