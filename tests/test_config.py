"""Configuration validation cannot be skipped: every config dataclass checks itself in
`__post_init__` (so `dataclasses.replace` re-checks), and an error names the file and exactly the
key it tests, with its full dotted path."""
from __future__ import annotations

import dataclasses

import pytest

from testbed.config import scenario
from testbed.cli import main
from testbed.errors import FieldError

HOVER = """
name = "hover"
description = "one vehicle hovering"
duration = 3.0
[trajectory]
kind = "waypoints"
points = [[0.0, 0.0, 10.0], [0.0, 0.0, 10.0]]
times = [0.0, 10.0]
"""


def test_replace_rechecks_every_kind_of_config():
    sc = scenario.load("phase-cross-h000")
    with pytest.raises(FieldError) as e:
        dataclasses.replace(sc.world, timestep=-1)
    assert e.value.key == "timestep" and e.value.value == -1
    with pytest.raises(FieldError, match="q_flown"):
        dataclasses.replace(sc.pipeline, q_flown=0.0)
    with pytest.raises(FieldError, match="phase_noise"):
        dataclasses.replace(sc.sensors.phase, phase_noise=-1.0)
    with pytest.raises(FieldError, match="accel_density"):
        dataclasses.replace(sc.disturbance, accel_density=-1.0)
    with pytest.raises(FieldError) as e:  # cross-checks of the whole scenario run again too
        dataclasses.replace(sc, disturbance=dataclasses.replace(sc.disturbance, vehicles=(7,)))
    assert e.value.key == "disturbance.vehicles"


def test_nested_bad_value_in_a_toml_names_the_file_and_the_full_dotted_key(tmp_path):
    path = tmp_path / "nested.toml"
    path.write_text(HOVER + '[[world.obstacles]]\ntype = "box"\npos = [5.0, 0.0, 1.0]\nsize = [1.0, 1.0, 1.0]\n'
                    '[[world.obstacles]]\ntype = "box"\npos = [9.0, 0.0, 1.0]\nsize = [1.0, -2.0, 1.0]\n'
                    '[sensors.imu.accel]\nnoise_density = 0.1\n')
    with pytest.raises(FieldError) as e:
        scenario.load(str(path))
    assert (e.value.file, e.value.key, e.value.value) == (str(path), "world.obstacles[1].size", (1.0, -2.0, 1.0))
    assert str(e.value).startswith(f"{path}: world.obstacles[1].size: ")
    path.write_text(HOVER + "[sensors.imu.accel]\nnoise_density = -0.1\n")
    with pytest.raises(FieldError) as e:
        scenario.load(str(path))
    assert (e.value.file, e.value.key) == (str(path), "sensors.imu.accel.noise_density")


# (scenario, override key, value, the key the message must name): each check names exactly the
# key it tests (several named a neighbouring key before).
CASES = [
    ("phase-cross-h000", "control.kv", "-1.0", "control.kv"),
    ("phase-cross-h000", "control.kw", "0.0", "control.kw"),
    ("phase-cross-h000", "world.antenna_b", "-1.0", "world.antenna_b"),
    ("phase-cross-h000", "world.timestep", "0.02", "world.timestep"),
    ("phase-cross-h000", "pipeline.q_flown", "-1.0", "pipeline.q_flown"),
    ("phase-cross-h000", "pipeline.init_vel_var", "[1.0, -1.0, 1.0]", "pipeline.init_vel_var"),
    ("phase-cross-h000", "pipeline.antenna_b", "0.0", "pipeline.antenna_b"),
    ("phase-cross-h000", "pipeline.last_window", "0.0", "pipeline.last_window"),
    ("phase-cross-h000", "sensors.phase.follower", "3", "sensors.phase.follower"),
    ("phase-cross-h000", "sensors.phase.masters", "[1, 2, 3, 4, 9]", "sensors.phase.masters"),
    ("coop-fg", "sensors.gnss.vehicles", "[0]", "sensors.gnss.vehicles"),
    ("coop-fg", "sensors.gnss.rtk_vehicles", "[99]", "sensors.gnss.rtk_vehicles"),
    ("coop-fg", "sensors.gnss.receiver.bias_tau", "-1.0", "sensors.gnss.receiver.bias_tau"),
    ("coop-fg", "sensors.uwb.tag_links", "false", "sensors.uwb.tag_links"),
    ("coop-fg", "trajectory.period_max", "30.0", "trajectory.period_max"),
    ("coop-fg", "pipeline.plot_uavs", "[1, 2, 3, 99]", "pipeline.plot_uavs"),
    ("visnav", "sensors.camera.leader", "0", "sensors.camera.leader"),
    ("visnav", "sensors.camera.d", "-1.0", "sensors.camera.d"),
    ("visnav", "sensors.camera.glint_factor", "0.5", "sensors.camera.glint_factor"),
    ("visnav", "trajectory.yaw_period", "0.0", "trajectory.yaw_period"),
    ("visnav", "pipeline.mc_max_iter", "0", "pipeline.mc_max_iter"),
    ("bandwidth", "pipeline.offset_error", "-1.0", "pipeline.offset_error"),
    ("bandwidth", "pipeline.groups", "[[1, 2, 3, 4], [5, 6, 7, 8], [9, 10, 11, 12], [13, 14, 15, 99]]", "pipeline.groups[3]"),
    ("bandwidth", "sensors.uwb.outlier_prob", "1.0", "sensors.uwb.outlier_prob"),
]


@pytest.mark.parametrize("name, key, value, named", CASES, ids=[c[1] for c in CASES])
def test_each_check_names_exactly_the_key_it_tests(name, key, value, named):
    with pytest.raises(FieldError) as e:
        scenario.load(name, overrides={key: value})
    assert e.value.key == named and e.value.file == f"{name}.toml"
    assert f"{name}.toml: {named}: " in str(e.value) and "\n" not in str(e.value)


def test_cli_reports_the_full_key_in_one_line(capsys, tmp_path):
    out = tmp_path / "out"
    assert main(["run", "visnav", "--out", str(out), "--set", "sensors.camera.d=-1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("testbed: error: visnav.toml") and "sensors.camera.d: must be >= 0, got -1" in err
    assert not out.exists()
