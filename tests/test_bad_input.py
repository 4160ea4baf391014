"""Bad input is refused at the boundary: one line `testbed: error: ...` naming the file (or the
flag) and the key, exit 2, nothing written, before anything is simulated. A table of every case
of issue 13's "Bad input" section, plus the checks behind them (finite numbers, name resolution,
the physics step bound, clearance of the reference paths)."""
from __future__ import annotations

import csv
import dataclasses
import math
import os
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

from testbed.config import scenario
from testbed.cli import main
from testbed.config import MAX_MAGNITUDE, set_dotted
from testbed.errors import ConfigError, FieldError
from testbed.reference import AIRFRAME_RADIUS, _close_pair, clearance
from testbed.runner import run
from testbed.sim.world import MODELS

ROOT = Path(__file__).resolve().parents[1]

HOVER = """
name = "hover"
description = "one vehicle hovering near a box"
duration = 2.0
[world]
obstacles = [{ type = "box", pos = [50.0, 0.0, 10.0], size = [1.0, 1.0, 1.0] }]
[trajectory]
kind = "waypoints"
points = [[0.0, 0.0, 10.0], [0.0, 0.0, 10.0]]
times = [0.0, 10.0]
"""


def _set(name: str, *pairs: str, extra: tuple[str, ...] = ("--duration", "1")) -> list[str]:
    argv = ["run", name, "--out", "out", *extra]
    for p in pairs:
        argv += ["--set", p]
    return argv


# (id, argv, what the one line must name). Every case exits 2 before any simulation.
CASES = [
    ("non-utf8-toml", ["run", "./latin1.toml", "--out", "out"], "latin1.toml: not UTF-8 text"),
    ("duration-inf", ["run", "visnav", "--out", "out", "--duration", "inf"], "argument --duration"),
    ("duration-1e12", ["run", "visnav", "--out", "out", "--duration", "1e12"], "argument --duration"),
    ("duration-nan", ["run", "visnav", "--out", "out", "--duration", "nan"], "argument --duration"),
    ("duration-neg", ["run", "visnav", "--out", "out", "--duration", "-1"], "argument --duration"),
    ("steps-over-1e9", ["run", "visnav", "--out", "out", "--duration", "1e7"], "duration: 1e+07 s is 4e+09 physics steps"),
    ("timestep-denormal", _set("visnav", "world.timestep=5e-324"), "visnav.toml: world.timestep"),
    ("timestep-tiny-rate-huge", _set("visnav", "world.timestep=1e-300", "world.control_rate=1e298"), "world.timestep"),
    ("velocity-nan", _set("visnav", "trajectory.leader_velocity=[nan, 0.0, 0.0]"), "trajectory.leader_velocity[0]"),
    ("velocity-inf", _set("bandwidth", "trajectory.velocity=[inf, 0.5, 0.5]"), "trajectory.velocity[0]"),
    ("follower-velocity-nan", _set("phase-cross-h000", "trajectory.follower_velocity=[0.0, nan, 0.0]"), "trajectory.follower_velocity[1]"),
    ("kv-nan", _set("visnav", "control.kv=nan", extra=("--duration", "1", "--motion", "flown")), "control.kv"),
    ("kx-inf", _set("visnav", "control.kx=inf", extra=("--duration", "1", "--motion", "flown")), "control.kx"),
    ("process-noise-nan", _set("bandwidth", "pipeline.process_noise=[nan, 0.05, 0.03]"), "pipeline.process_noise[0]"),
    ("q-translation-inf", _set("phase-cross-h000", "pipeline.q_translation=inf"), "pipeline.q_translation"),
    ("init-pos-var-inf", _set("phase-cross-h000", "pipeline.init_pos_var=[inf, 1.0, 1.0]"), "pipeline.init_pos_var[0]"),
    ("m0-nan", _set("bandwidth", "pipeline.M0=[nan, 0.09, 0.08]"), "pipeline.M0[0]"),
    ("init-sigma-inf", _set("visnav", "pipeline.init_sigma_pos=inf"), "pipeline.init_sigma_pos"),
    ("anchor-nan", _set("bandwidth", "world.anchors[0]=[nan, 0.0, 0.0]"), "world.anchors[0][0]"),
    ("obstacle-pos-inf", _set("./hover.toml", "world.obstacles[0].pos=[inf, 0.0, 10.0]"), "hover.toml: world.obstacles[0].pos[0]"),
    ("obstacle-size-nan", _set("./hover.toml", "world.obstacles[0].size=[nan, 1.0, 1.0]"), "world.obstacles[0].size[0]"),
    ("obstacle-size-inf", _set("./hover.toml", "world.obstacles.0.size=[1.0, inf, 1.0]"), "world.obstacles[0].size[1]"),
    ("truth-rate-nan", _set("visnav", "world.truth_rate=nan"), "world.truth_rate"),
    ("truth-rate-inf", _set("visnav", "world.truth_rate=inf"), "world.truth_rate"),
    ("truth-rate-over-control", _set("visnav", "world.truth_rate=400.0"), "world.truth_rate"),
    ("uwb-noise-nan", _set("bandwidth", "sensors.uwb.noise=nan"), "sensors.uwb.noise"),
    ("uwb-noise-inf", _set("bandwidth", "sensors.uwb.noise=inf"), "sensors.uwb.noise"),
    ("latency-nan", _set("visnav", "sensors.camera.latency=nan"), "sensors.camera.latency"),
    ("latency-inf", _set("visnav", "sensors.imu.latency=inf"), "sensors.imu.latency"),
    ("start-nan", _set("bandwidth", "trajectory.start=[nan, 10.0, 10.0]"), "trajectory.start[0]"),
    ("leader-start-inf", _set("visnav", "trajectory.leader_start=[0.0, 0.0, inf]"), "trajectory.leader_start[2]"),
    ("score-start-inf", _set("phase-cross-h000", "pipeline.score_start=inf"), "pipeline.score_start"),
    ("fail-time-nan", _set("bandwidth", "pipeline.fail_time=nan"), "pipeline.fail_time"),
    ("accel-density-nan", _set("visnav", "disturbance.accel_density=nan"), "disturbance.accel_density"),
    ("accel-density-inf", _set("visnav", "disturbance.angular_accel_density=inf"), "disturbance.angular_accel_density"),
    ("imu-noise-density-1e308", _set("visnav", "sensors.imu.accel.noise_density=1e308"), "sensors.imu.accel.noise_density"),
    ("lever-arm-inf", _set("phase-cross-h000", "world.antenna_a=inf"), "world.antenna_a"),
    ("known-lever-arm-inf", _set("phase-cross-h000", "pipeline.antenna_b=inf"), "pipeline.antenna_b"),
    ("q-inf", _set("phase-cross-h000", "pipeline.q=inf"), "pipeline.q"),
    ("follower-offset-neg-inf", _set("visnav", "trajectory.follower_offset=[-inf, 0.0, 0.0]"), "trajectory.follower_offset[0]"),
    ("render-width-0", ["render", "r", "--width", "0"], "argument --width"),
    ("render-width-neg", ["render", "r", "--width", "-640"], "argument --width"),
    ("render-width-huge", ["render", "r", "--width", "100000"], "argument --width"),
    ("render-height-0", ["render", "r", "--height", "0"], "argument --height"),
    ("render-height-odd", ["render", "r", "--height", "541"], "argument --height"),
    ("render-fps-0", ["render", "r", "--fps", "0"], "argument --fps"),
    ("render-speed-0", ["render", "r", "--speed", "0"], "argument --speed"),
    ("render-speed-nan", ["render", "r", "--speed", "nan"], "argument --speed"),
    ("render-speed-inf", ["render", "r", "--speed", "inf"], "argument --speed"),
    ("render-max-seconds-0", ["render", "r", "--max-seconds", "0"], "argument --max-seconds"),
    ("render-max-seconds-neg", ["render", "r", "--max-seconds", "-2"], "argument --max-seconds"),
    ("render-links-all", ["render", "r", "--links", "all"], "argument --links"),
    ("render-nearest-0", ["render", "r", "--nearest", "0"], "argument --nearest"),
    ("render-error-scale-0", ["render", "r", "--error-scale", "0"], "argument --error-scale"),
    ("sweep-workers-0", ["sweep", "visnav", "--runs", "2", "--workers", "0", "--out", "out"], "argument --workers"),
    ("sweep-workers-neg", ["sweep", "visnav", "--runs", "2", "--workers", "-3", "--out", "out"], "argument --workers"),
    ("sweep-runs-0", ["sweep", "visnav", "--runs", "0", "--out", "out"], "argument --runs"),
    ("sweep-seed-neg", ["sweep", "visnav", "--runs", "2", "--seed", "-1", "--out", "out"], "argument --seed"),
    ("reproduce-workers-0", ["reproduce", "phase", "--out", "out", "--workers", "0"], "argument --workers"),
    ("reproduce-duration-neg", ["reproduce", "phase", "--out", "out", "--runs", "1", "--duration", "-1"], "argument --duration"),
    ("reproduce-duration-nan", ["reproduce", "phase", "--out", "out", "--runs", "1", "--duration", "nan"], "argument --duration"),
    ("bench-json-unusable", ["bench", "physics", "--json", "/proc/nonexistent/x.json"], "argument --json"),
    ("bench-json-directory", ["bench", "physics", "--json", "."], "argument --json"),
    ("bandwidth-one-offset", _set("bandwidth", "trajectory.offsets=[[3.0, 0.0, 0.0]]"), "bandwidth.toml: trajectory.offsets"),
    ("nav-master-not-a-master", _set("phase-cross-h000", "pipeline.nav_master=9"), "phase-cross-h000.toml: pipeline.nav_master"),
    ("visnav-imu-missing-follower", _set("visnav", "sensors.imu.vehicles=[1]"), "visnav.toml: sensors.imu.vehicles"),
    ("visnav-predict-rate", _set("visnav", "pipeline.predict_rate_hz=15.0"), "pipeline.predict_rate_hz"),
    ("visnav-led-count", _set("visnav", "pipeline.led_pos=[[0.4, 0.3, 0.06]]"), "pipeline.led_pos"),
    ("bandwidth-budget-paper-set", _set("bandwidth", "pipeline.budget=6"), "bandwidth.toml: pipeline.budget"),
    ("coop-gnss-not-all", _set("coop-fg", "sensors.gnss.vehicles=[1, 2]"), "coop-fg.toml: sensors.gnss.vehicles"),
    ("int-huge", _set("visnav", "pipeline.mc_max_iter=100000000000"), "pipeline.mc_max_iter"),
    ("set-unknown-index", _set("bandwidth", "world.anchors[99]=[0.0, 0.0, 0.0]"), "no key 'world.anchors[99]'"),
    ("unknown-builtin-with-local-file", ["run", "hover", "--out", "out"], "a scenario file is named by a path: ./hover"),
    ("path-through-floor", _set("visnav", "trajectory.leader_start=[0.0, 0.0, -5.0]"), "visnav.toml: trajectory: vehicle 1's reference is at z = -5.00 m"),
    ("path-through-obstacle", _set("./hover.toml", "world.obstacles[0].pos=[0.0, 0.5, 10.0]"), "hover.toml: world.obstacles[0]: vehicle 1"),
    ("uwb-rate-0", _set("bandwidth", "sensors.uwb.rate_hz=0"), "bandwidth.toml: sensors.uwb.rate_hz"),
    ("uwb-tag-not-an-antenna", _set("bandwidth", 'sensors.uwb.tags=["uwb", "led1"]'), "bandwidth.toml: sensors.uwb.tags"),
    ("vehicles-too-close", _set("visnav", "trajectory.follower_offset=[-0.3, 0.0, 0.0]"), "visnav.toml: trajectory: vehicles 1 and 2 are 0.30 m apart"),
]


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A working directory holding the inputs of the cases; returns it."""
    (tmp_path / "latin1.toml").write_bytes('name = "caf\xe9"\n'.encode("latin-1"))
    (tmp_path / "hover.toml").write_text(HOVER)
    (tmp_path / "hover").write_text("not a scenario")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("argv, named", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_each_bad_input_exits_2_with_one_line_naming_the_key(argv, named, workdir, capsys):
    before = sorted(os.listdir(workdir))
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("testbed: error: "), err
    assert named in lines[0], lines[0]
    assert sorted(os.listdir(workdir)) == before  # nothing written, no MUJOCO_LOG.TXT


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A tiny run directory (one hovering vehicle, 0.5 s) to corrupt."""
    root = tmp_path_factory.mktemp("render")
    (root / "hover.toml").write_text(HOVER)
    run(scenario.load(str(root / "hover.toml"), duration=0.5), root / "run", plots=False)
    return root / "run"


@pytest.mark.parametrize("victim, content, named", [
    ("log.npz", b"garbage", "log.npz: not a readable run log"),
    ("scene.xml", b"<mujoco><oops", "scene.xml: not a readable MuJoCo model"),
    ("estimates.npz", b"garbage", "estimates.npz: not readable as a run's estimates"),
])
def test_render_of_a_corrupt_run_directory_is_one_line(run_dir, tmp_path, capsys, victim, content, named):
    bad = tmp_path / "bad"
    shutil.copytree(run_dir, bad)
    (bad / victim).write_bytes(content)
    assert main(["render", str(bad), "--out", str(tmp_path / "v.mp4")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and named in lines[0], lines
    assert not (tmp_path / "v.mp4").exists()


# ------------------------------------------------------------------------- the checks themselves


def test_no_float_field_can_be_nan_or_inf_even_when_set_in_code():
    sc = scenario.load("visnav")
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(FieldError) as e:
            dataclasses.replace(sc.world, truth_rate=bad)
        assert e.value.key == "truth_rate" and "finite" in e.value.reason
    with pytest.raises(FieldError, match="finite"):
        dataclasses.replace(sc.pipeline, init_sigma_pos=math.nan)


@pytest.mark.parametrize("key, value", [("pipeline.tol", "nan"), ("pipeline.tol", "inf"), ("pipeline.tol", "-inf"),
                                        ("pipeline.tol", "1e10"), ("pipeline.max_rounds", "10000000000")])
def test_every_number_from_a_file_is_finite_and_bounded(key, value):
    with pytest.raises(FieldError) as e:
        scenario.load("coop-fg", overrides={key: value})
    assert (e.value.file, e.value.key) == ("coop-fg.toml", key)
    assert f"{MAX_MAGNITUDE:g}" in str(e.value)


def test_set_addresses_list_elements_both_ways():
    data = {"world": {"anchors": [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]}}
    set_dotted(data, "world.anchors[1]", "[2.0, 2.0, 2.0]", "f")
    set_dotted(data, "world.anchors.0", "[3.0, 3.0, 3.0]", "f")
    assert data["world"]["anchors"] == [[3.0, 3.0, 3.0], [2.0, 2.0, 2.0]]
    set_dotted(data, "world.anchors[1][2]", "7.0", "f")
    assert data["world"]["anchors"][1] == [2.0, 2.0, 7.0]
    with pytest.raises(ConfigError, match="no key"):
        set_dotted(data, "world.anchors[2]", "1.0", "f")


def test_a_bare_name_is_the_builtin_even_when_a_local_directory_shares_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bandwidth").mkdir()  # e.g. an earlier run directory
    (tmp_path / "bandwidth" / "metrics.json").write_text("{}")
    assert scenario.resolve("bandwidth") == (True, "bandwidth.toml")
    assert scenario.load("bandwidth").name == "bandwidth"
    assert scenario.resolve("./bandwidth") == (False, "./bandwidth")
    with pytest.raises(ConfigError, match="is a directory"):
        scenario.load("./bandwidth")
    (tmp_path / "mine.toml").write_text(HOVER)
    assert scenario.resolve("mine.toml") == (False, "mine.toml") and scenario.load("mine.toml").name == "hover"


def test_cli_says_which_scenario_was_taken(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "visnav").mkdir()
    assert main(["run", "visnav", "--out", "out", "--duration", "0.2", "--set", "pipeline.filters=[\"ekf\"]",
                 "--no-plots"]) == 0
    err = capsys.readouterr().err
    assert "'visnav' is the built-in scenario" in err and "./visnav" in err
    assert (tmp_path / "out" / "metrics.json").is_file()


def test_step_bound_counts_physics_steps():
    assert scenario.load("visnav", duration=1e6).duration == 1e6  # 4e8 steps of 2.5 ms: allowed
    with pytest.raises(FieldError) as e:
        scenario.load("visnav", duration=2.6e6)
    assert e.value.key == "duration" and "1.04e+09 physics steps" in e.value.reason


def test_airframe_radius_is_the_collision_box_of_the_model():
    m = mujoco.MjModel.from_xml_path(str(MODELS / "quadrotor.xml"))
    boxes = [g for g in range(m.ngeom) if m.geom_group[g] == 3 and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
    corner = max(np.linalg.norm(np.abs(m.geom_pos[g]) + m.geom_size[g]) for g in boxes)
    assert AIRFRAME_RADIUS == pytest.approx(corner, abs=0.005)


def test_close_pair_matches_brute_force():
    rng = np.random.default_rng(3)
    pos = rng.uniform(0, 20, size=(50, 30, 3))
    d = np.linalg.norm(pos[:, :, None] - pos[:, None], axis=-1) + np.eye(30) * 1e9
    r = 1.5
    hits = np.argwhere(d < r)
    got = _close_pair(pos, r)
    assert hits.size and got is not None
    k, i, j = got
    assert d[k, i, j] < r and k == hits[:, 0].min()
    assert _close_pair(pos * 100, r) is None or np.linalg.norm(pos[got[0], got[1]] - pos[got[0], got[2]]) * 100 < r


def test_clearance_of_the_builtin_scenarios_and_of_rotated_obstacles():
    for name in scenario.builtin_names():
        assert clearance(scenario.load(name)) is None, name
    sc = scenario.load("visnav")
    # a yawed box: 10 m long along its own x, turned 90 deg so it lies along world y, 3 m beside the leader's start
    box = scenario.Obstacle(type="box", pos=(0.0, 3.0, 30.0), size=(10.0, 0.5, 0.5), yaw_deg=90.0)
    hit = clearance(dataclasses.replace(sc, world=dataclasses.replace(sc.world, obstacles=(box,))))
    assert hit is not None and hit[0] == "world.obstacles[0]" and "at t = 0 s" in hit[1]
    unturned = dataclasses.replace(box, yaw_deg=0.0)  # along world x at y = 3: 2.5 m from both paths
    assert clearance(dataclasses.replace(sc, world=dataclasses.replace(sc.world, obstacles=(unturned,)))) is None


def test_clearance_warn_runs_with_one_warning_and_off_is_silent(workdir, capsys):
    argv = _set("./hover.toml", "world.obstacles[0].pos=[0.0, 1.2, 10.0]", extra=("--duration", "0.2"))
    assert main(argv + ["--set", 'world.clearance="warn"']) == 0
    err = capsys.readouterr().err
    assert err.startswith("testbed: warning: ./hover.toml: world.obstacles[0]: vehicle 1's reference passes 0.20 m") and err.count("\n") == 1
    shutil.rmtree(workdir / "out")
    assert main(argv + ["--set", 'world.clearance="off"']) == 0
    assert capsys.readouterr().err == ""
    assert (workdir / "out" / "metrics.json").is_file()


def test_the_python_api_checks_clearance_like_the_command_line(workdir, capsys):
    import testbed
    from testbed.errors import ConfigError

    path = "world.obstacles[0].pos"
    assert main(["run", "./hover.toml", "--out", "out", "--set", f"{path}=[0.0, 0.5, 10.0]"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    with pytest.raises(ConfigError) as e:
        testbed.load_scenario("./hover.toml", {path: [0.0, 0.5, 10.0]})
    assert line == f"testbed: error: {e.value}"  # the same message
    ok = testbed.load_scenario("./hover.toml")
    moved = dataclasses.replace(ok, world=dataclasses.replace(ok.world, obstacles=(
        dataclasses.replace(ok.world.obstacles[0], pos=(0.0, 0.5, 10.0)),)))
    with pytest.raises(ConfigError, match=r"world\.obstacles\[0\]: vehicle 1's reference passes"):
        testbed.run(moved, out=workdir / "api-run")
    assert not (workdir / "api-run").exists()
    with pytest.warns(UserWarning, match=r"world\.obstacles\[0\]: vehicle 1's reference passes .* \"warn\""):
        testbed.load_scenario("./hover.toml", {path: [0.0, 0.5, 10.0], "world.clearance": "warn"})


# ------------------------------------------------------- bad input that still got through (a user found each case)


def _one_line(capsys, argv: list[str], code: int = 2) -> str:
    """Run the CLI in-process with every warning an error; assert the exit code and one stderr line; return it."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning reaching the terminal fails the test
        got = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert got == code and len(lines) == 1 and lines[0].startswith("testbed: error: "), (got, err)
    return lines[0]


def test_render_into_a_read_only_folder_is_one_line_without_ffmpeg_output(run_dir, tmp_path, capfd):
    """The output's folder is tried before ffmpeg starts; nothing of ffmpeg's reaches the terminal."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    if os.access(ro, os.W_OK):  # root ignores the mode: /sys refuses new files even to root
        ro = Path("/sys")
    assert main(["render", str(run_dir), "--out", str(ro / "video.mp4"), "--max-seconds", "0.2"]) == 2
    lines = capfd.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"testbed: error: {ro / 'video.mp4'}: "), lines
    assert not any(p.name.startswith(".video.mp4") for p in ro.iterdir())


def test_an_ffmpeg_failure_is_one_line_with_its_reason_and_no_file(run_dir, tmp_path):
    """ffmpeg (here a stand-in that fails as a full disk makes it fail) writes to a temporary file,
    not the terminal; its last line is the reason; no video is left."""
    fake = tmp_path / "ffmpeg"
    fake.write_text('#!/bin/sh\necho "[out#0/mp4 @ 0x1] Error opening output: No space left on device" >&2\n'
                    'echo "Error opening output files: No space left on device" >&2\nexit 1\n')
    fake.chmod(0o755)
    env = {**os.environ, "IMAGEIO_FFMPEG_EXE": str(fake),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    p = subprocess.run([sys.executable, "-m", "testbed", "render", str(run_dir), "--out", str(tmp_path / "v.mp4"),
                        "--max-seconds", "0.2", "--width", "64", "--height", "48"], capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 2 and p.stderr == (f"testbed: error: {tmp_path / 'v.mp4'}: ffmpeg could not write the video: "
                                              "Error opening output files: No space left on device\n"), p.stderr
    assert sorted(os.listdir(tmp_path)) == ["ffmpeg"]


def test_export_of_a_truncated_log_is_one_line(run_dir, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(run_dir, bad)
    with open(bad / "log.npz", "r+b") as fh:
        fh.truncate((bad / "log.npz").stat().st_size // 2)
    assert "log.npz: not a readable run log" in _one_line(capsys, ["export", str(bad), "--out", str(tmp_path / "d")])
    assert sorted(os.listdir(tmp_path)) == ["bad"]


@pytest.fixture
def dataset(tmp_path) -> Path:
    """A copy of examples/replay (coop-fg, 18 UAVs, uwb links) to spoil; returns its directory."""
    shutil.copytree(ROOT / "examples/replay", tmp_path / "data")
    return tmp_path / "data"


def _edit_links(d: Path, row: int, column: str, value: str) -> None:
    """Set one cell of links.csv (row 1 = the first data row)."""
    with open(d / "links.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    rows[row][rows[0].index(column)] = value
    with open(d / "links.csv", "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)


@pytest.mark.parametrize("kind, value", [("uwb", "1e6"), ("phase", "2e5"), ("range-rate", "-5e3")])
def test_a_range_beyond_the_physical_bound_is_refused_at_load_naming_row_and_column(dataset, capsys, kind, value):
    """Refused at load, before any estimator computes with it: no overflow warning can follow."""
    from testbed.replay.recording import MAX_RANGE_M, MAX_RANGE_RATE_M_S

    bound = MAX_RANGE_RATE_M_S if kind == "range-rate" else MAX_RANGE_M
    assert abs(float(value)) > bound
    _edit_links(dataset, 3, "kind", kind)
    _edit_links(dataset, 3, "value", value)
    line = _one_line(capsys, ["replay", str(dataset / "spec.toml"), "--out", str(dataset.parent / "o")])
    assert f"{dataset / 'links.csv'}: row 3 (line 4), column value: " in line and f"{bound:g}" in line, line
    assert not (dataset.parent / "o").exists()


@pytest.mark.parametrize("table, column, value, named", [
    ("links.csv", "value", "1e308", "at most 1e+10 in magnitude"),
    ("poses.csv", "x", "1e308", "at most 1e+10 in magnitude"),
    ("links.csv", "sigma", "1e-300", "at least 1e-09"),
    ("links.csv", "time", "-1e11", "at most 1e+10 in magnitude"),
])
def test_a_number_that_would_overflow_a_computation_is_refused_at_load(dataset, capsys, table, column, value, named):
    """Each of these fed graph.poses or the scoring overflow warnings before the bounds (docs/replay.md)."""
    with open(dataset / table, newline="") as fh:
        rows = list(csv.reader(fh))
    rows[2][rows[0].index(column)] = value
    with open(dataset / table, "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    line = _one_line(capsys, ["replay", str(dataset / "spec.toml"), "--out", str(dataset.parent / "o")])
    assert f"{dataset / table}: row 2 (line 3), column {column}: " in line and named in line, line
    assert not (dataset.parent / "o").exists()


def test_csv_header_naming_a_column_twice_names_it(dataset, capsys):
    text = (dataset / "links.csv").read_text().split("\n", 1)
    (dataset / "links.csv").write_text(text[0].replace("sigma", "value") + "\n" + text[1])
    assert "links.csv: the header names column 'value' twice" in _one_line(
        capsys, ["replay", str(dataset / "spec.toml"), "--out", str(dataset.parent / "o")])


def test_csv_cell_over_the_field_limit_names_row_and_column(dataset, capsys):
    _edit_links(dataset, 5, "src", "x" * (csv.field_size_limit() + 1))
    line = _one_line(capsys, ["replay", str(dataset / "spec.toml"), "--out", str(dataset.parent / "o")])
    assert f"{dataset / 'links.csv'}: row 5 (line 6), column src: " in line and str(csv.field_size_limit()) in line, line
    assert not (dataset.parent / "o").exists()


def _spec_estimators(d: Path, table: str) -> None:
    """Replace the [[estimators]] of the dataset's spec.toml by `table` (TOML array of tables)."""
    text = (d / "spec.toml").read_text()
    start, end = text.index("[[estimators]]"), text.index("[window]")
    (d / "spec.toml").write_text(text[:start] + table + "\n\n" + text[end:])


@pytest.mark.parametrize("table, named", [
    ('estimators = [{ entry = "graph.poses", params = { epoch = -1 } }]', ("graph.poses", "epoch", "-1")),
    ('estimators = [{ entry = "graph.poses", params = { loss = "bogus" } }]', ("graph.poses", "loss", "'bogus'")),
    ('estimators = [{ entry = "graph.poses", params = { bias_sigma = 0.0, q_translation = 0.01 } }]',
     ("graph.poses", "bias_sigma", "0.0")),
    ('estimators = [{ entry = "nav.eskf", params = { bogus = 1 } }]', ("nav.eskf", "bogus", "1")),
    ('estimators = [{ entry = "coop.window", params = { windw = 3 } }]', ("coop.window", "windw", "3")),
    ('estimators = [{ entry = "coop.centralized", params = { huber_k = 2.0 } }]', ("coop.centralized", "huber_k", "2.0")),
])
def test_a_mistake_in_an_estimators_params_is_exit_2_before_it_runs(dataset, capsys, monkeypatch, table, named):
    """Replay: refused before the dataset is fed; the line names the estimator, the key and the value."""
    import testbed.replay.run as replay_run

    monkeypatch.setattr(replay_run, "replay_recording", lambda *a, **k: pytest.fail("the estimators ran"))
    _spec_estimators(dataset, table)
    line = _one_line(capsys, ["replay", str(dataset / "spec.toml"), "--out", str(dataset.parent / "o")])
    estimator, key, value = named
    assert f"estimator {estimator!r}" in line and f"{key} = {value}" in line, line
    assert not (dataset.parent / "o").exists()


def test_a_mistake_in_a_scenarios_estimator_params_is_exit_2_before_anything_is_simulated(workdir, capsys, monkeypatch):
    import testbed.runner

    monkeypatch.setattr(testbed.runner, "record", lambda *a, **k: pytest.fail("simulated"))
    (workdir / "est.toml").write_text(HOVER + '[[estimators]]\nentry = "nav.eskf"\nparams = { yaw = 0.5 }\n')
    line = _one_line(capsys, ["run", "./est.toml", "--out", "out"])
    assert "estimator 'nav.eskf'" in line and "yaw = 0.5" in line and "yaw0" in line, line
    assert not (workdir / "out").exists()


def test_ray_at_an_unreachable_address_is_one_line_within_the_stated_timeout(tmp_path):
    """A subprocess, so that Ray's own C++ log lines (written to the process's stderr) would show."""
    from testbed.cluster import CONNECT_TIMEOUT_S

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    t0 = time.monotonic()
    p = subprocess.run([sys.executable, "-m", "testbed", "sweep", "bandwidth", "--runs", "2", "--duration", "0.5",
                        "--backend", "ray", "--address", "127.0.0.1:1", "--out", str(tmp_path / "s")],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=CONNECT_TIMEOUT_S + 50)
    took = time.monotonic() - t0
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "127.0.0.1:1" in lines[0], p.stderr
    assert took < CONNECT_TIMEOUT_S + 30, took
    assert os.listdir(tmp_path) == []


def test_ray_authentication_failure_says_what_to_set():
    """The line Ray 2.60's driver wrote (49 times, then "Failed to connect to Ray cluster") against
    `ray start --head` without RAY_AUTH_MODE=token in its environment, and the one line made of it."""
    from testbed.cluster import failure

    seen = ("[2026-11-27 23:59:50,287 W 24666 24666] gcs_client.cc:210: Failed to get cluster ID from GCS server: "
            "Unauthenticated: RPC error: InvalidAuthToken: Authentication token is missing or incorrect\n")
    line = failure("192.0.2.2:6391", seen, "Failed to connect to Ray cluster at 192.0.2.2:6391")
    assert "192.0.2.2:6391" in line and "RAY_AUTH_MODE=token" in line and "docs/cluster.md" in line and "\n" not in line
    assert "RAY_AUTH_MODE" not in failure("192.0.2.2:6391", "", "Failed to connect to Ray cluster at 192.0.2.2:6391")
