"""Sparse, asynchronous ranging (docs/replay.md, "Sparse ranging"): the testbed's own scheduled UWB
-- one two-way exchange at a time, three UAVs with two tags each among six anchors --, exported
with `testbed export` and replayed: ranging.ekf, and graph.poses with its motion model, start every
robot within 2 s from the first ranges of a short window and stay inside their covariance between
single ranges."""
from __future__ import annotations

import json
import os
import re
import shutil

import numpy as np
import pytest

from testbed.cli import main
from testbed.config import scenario
from testbed.replay.recording import load_recording
from testbed.runner import run
from testbed.scoring.metrics import anees_interval_at, anees_over_runs

#: the circle's radius (m) and period (s), the UWB exchange rate (Hz) and the number of links
RADIUS, PERIOD, RATE, LINKS = 4.0, 20.0, 240.0, 48
#: seed 12 is judged; the rule below was checked on seed 11 only (never on the judged run)
SCENARIO = f"""
name = "sparse-uwb"
description = "three UAVs round a circle, tags on both wing tips, six anchors, one UWB exchange at a time"
seed = 12
duration = 20.0
motion = "prescribed"

[world]
timestep = {1 / RATE!r}
control_rate = {RATE!r}
antenna_b = 0.3
anchors = [[-8.0, -8.0, 0.5], [8.0, -8.0, 3.0], [8.0, 8.0, 0.5], [-8.0, 8.0, 3.0], [0.0, -10.0, 5.0], [0.0, 10.0, 1.0]]

[trajectory]
kind = "circle"
center = [0.0, 0.0, 2.0]
radius = {RADIUS!r}
period = {PERIOD!r}
count = 3
layer = 0.5

[sensors.uwb]
preset = "ideal"
noise = 0.05
rate_hz = {RATE!r}
tags = ["ant2", "ant3"]
los_groups = [0]

[sensors.uwb.schedule]
policy = "round_robin"
slot_s = {1 / RATE!r}
"""


def rule_q_translation() -> float:
    """The white-acceleration density of the followers' common motion (m^2/s^3) by a rule: the
    constant-velocity model misses a dt^2 / 2 of position over dt under an acceleration a, and the
    white-acceleration model's position variance over dt is q dt^3 / 3; they agree at
    q = 3 a^2 dt / 4, with a the trajectory's largest acceleration (the circle's centripetal
    radius (2 pi / period)^2) and dt the cycle in which every link is ranged once (LINKS / RATE:
    the span over which ranges determine a position)."""
    a = RADIUS * (2 * np.pi / PERIOD) ** 2
    return 0.75 * a ** 2 * LINKS / RATE


def rule_q_rotation() -> float:
    """The white angular-acceleration density of a vehicle (rad^2/s^3) by the same rule,
    q = 3 alpha^2 dt / 4: a vehicle on the circle leans into it by atan(a / g) (a its centripetal
    acceleration), and that tilt turns with the circle at w = 2 pi / period, an angular
    acceleration alpha = tilt w^2."""
    w = 2 * np.pi / PERIOD
    alpha = float(np.arctan(RADIUS * w ** 2 / 9.81)) * w ** 2
    return 0.75 * alpha ** 2 * LINKS / RATE


def export(d, seed: int = 12):
    """The scenario at `seed`, run and exported into d: the dataset's spec.toml."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "sparse.toml").write_text(re.sub(r"(?m)^seed = .*$", f"seed = {seed}", SCENARIO, count=1))
    run(scenario.load(str(d / "sparse.toml")), d / "run", plots=False)
    assert main(["export", str(d / "run"), "--out", str(d / "data")]) == 0
    return d / "data" / "spec.toml"


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    return export(tmp_path_factory.mktemp("sparse"))


def test_the_export_has_one_range_per_timestamp_over_every_link(exported):
    links = load_recording(exported).tables["links"]
    _, per_time = np.unique(links["time"], return_counts=True)
    assert per_time.max() == 1  # one slot at a time
    pairs = set(zip(links["src"].tolist(), links["dst"].tolist()))
    assert len(pairs) == LINKS  # 6 tags x 6 anchors, and the 12 tag pairs of different vehicles
    assert {s.split("/")[1] for s, _ in pairs} == {"ant2", "ant3"}


def replay_ekf(spec, out) -> dict:
    """`testbed replay --estimator ranging.ekf` on the export, every vehicle a follower (no params but
    the rule's q_translation), its metrics.json entry, after checking: the antennas are the declared
    tags (the six tag sites are its targets, nothing else); each one's first estimate comes within
    2 s and it covers the run; no range rejected."""
    assert main(["replay", str(spec), "--out", str(out), "--estimator", "ranging.ekf",
                 "--param", f"q_translation={rule_q_translation()!r}", "--no-plots"]) == 0
    e = json.loads((out / "metrics.json").read_text())["estimators"]["ranging.ekf"]
    tags = {f"uav{i}/ant{j}" for i in (1, 2, 3) for j in (2, 3)}
    assert set(e["targets"]) == tags
    for site in tags:
        pos = e["targets"][site]["position"]
        assert pos["first_estimate_s"] <= 2.0 and pos["coverage"] == 1.0, site
    assert e["health"]["rejected_measurements"] == 0
    return e


def replay_graph(spec, work) -> dict:
    """`testbed replay --estimator graph.poses` on the export's first GRAPH_WINDOW_S seconds with its
    motion model at the rules' q_translation and q_rotation (no other params), its metrics.json
    entry, after checking: each UAV (two tags on one line: a pose with no attitude published) gets
    its first estimate within 2 s and every epoch after it converges."""
    data = work / "data"
    shutil.copytree(spec.parent, data)
    spec = data / "spec.toml"
    spec.write_text(re.sub(r"(?m)^end = .*$", f"end = {GRAPH_WINDOW_S!r}", spec.read_text(), count=1))
    assert main(["replay", str(spec), "--out", str(work / "rep"), "--no-plots", "--estimator", "graph.poses",
                 "--param", f"q_translation={rule_q_translation()!r}", "--param", f"q_rotation={rule_q_rotation()!r}"]) == 0
    e = json.loads((work / "rep" / "metrics.json").read_text())["estimators"]["graph.poses"]
    assert set(e["targets"]) == {"uav1", "uav2", "uav3"}
    for body, target in e["targets"].items():
        assert set(target) == {"position"}, body
        assert target["position"]["first_estimate_s"] <= 2.0, body
    h = e["health"]
    assert h["nonconverged_epochs"] == 0 and h["unobservable_epochs"] == 0 and h["flagged_epochs"] == 0
    return e


def test_ranging_ekf_starts_within_two_seconds_and_stays_inside_its_covariance(exported, tmp_path):
    """`testbed replay --estimator ranging.ekf` on the export, every vehicle a follower (no params but
    the rule's q_translation): the antennas are the declared tags (the six tag sites are its
    targets, nothing else); each one's first estimate comes within 2 s; the position ANEES of the
    six, pooled as the replay scores it, lies in its 99 % interval for correlated samples
    (testbed.scoring.metrics: n_eff from the autocorrelation)."""
    e = replay_ekf(exported, tmp_path / "rep")
    if "anees_position_null_reason" in e:  # one run cannot decide (docs/consistency.md, "Decidable from one run")
        pytest.xfail(e["anees_position_null_reason"])
    lo, hi = anees_interval_at(e, "anees_position", 0.99)
    assert lo <= e["anees_position"] <= hi, (e["anees_position"], lo, hi)


#: graph.poses solves one epoch at a time with its motion model: its replay is judged on the
#: export's first GRAPH_WINDOW_S seconds (1 200 single-range epochs) to keep the test cheap
GRAPH_WINDOW_S = 5.0


def test_graph_poses_with_its_motion_model_starts_within_two_seconds_and_stays_inside_its_covariance(exported, tmp_path):
    """`testbed replay --estimator graph.poses` on the export's first GRAPH_WINDOW_S seconds, with
    its motion model at the rules' q_translation and q_rotation (no other params): each UAV (two
    tags on one line: a pose with no attitude published) gets its first estimate within 2 s, every
    epoch after it converges, and the pooled position ANEES of the three bodies lies in its 99 %
    interval for correlated samples."""
    e = replay_graph(exported, tmp_path)
    if "anees_position_null_reason" in e:  # one run cannot decide (docs/consistency.md, "Decidable from one run")
        pytest.xfail(e["anees_position_null_reason"])
    lo, hi = anees_interval_at(e, "anees_position", 0.99)
    assert lo <= e["anees_position"] <= hi, (e["anees_position"], lo, hi)


#: the judged seeds of the runs' verdict (never looked at before it: the rules were tried on seed 11)
#: and how many: R = 10 keeps the run-spread interval's Student quantile t_9(0.995) = 3.25 within
#: 1.3 times the normal 2.58
LONG_SEEDS = tuple(range(301, 311))


@pytest.mark.skipif(not os.environ.get("SPARSE_LONG"), reason="10 sparse runs, ~80 s CPU: SPARSE_LONG=1")
def test_both_estimators_stay_inside_their_covariance_over_runs(tmp_path):
    """The verdict one 20-s run cannot give (its NEES span fewer than MIN_SPAN correlation times):
    on each of LONG_SEEDS the scenario run, exported and replayed as the two tests above (every
    assertion of theirs on every run), and the position ANEES of each estimator over the runs
    (testbed.scoring.metrics.anees_over_runs: the runs' combined effective samples when every run
    decides, else the spread of the per-run values, Student t) inside its 99 % interval."""
    runs: dict[str, list[dict]] = {"ranging.ekf": [], "graph.poses": []}
    for seed in LONG_SEEDS:
        spec = export(tmp_path / str(seed), seed)
        runs["ranging.ekf"].append(replay_ekf(spec, tmp_path / str(seed) / "ekf"))
        runs["graph.poses"].append(replay_graph(spec, tmp_path / str(seed) / "graph"))
    for name, keys in runs.items():
        v = anees_over_runs(keys, "anees_position", 0.99)
        lo, hi = v["anees_position_interval_99"]
        print(f"{name}: per run {[round(k['anees_position'], 3) for k in keys]}, RMSE "
              f"{[round(k['rmse_position_m'], 4) for k in keys]}; over the runs {v['anees_position']:.3f} in "
              f"[{lo:.3f}, {hi:.3f}] ({v.get('anees_position_interval_method', 'combined effective samples')})")
        assert lo <= v["anees_position"] <= hi, (name, v)
