"""The simulated export's Monte Carlo of docs/calibration.md ("On a simulated export"), one seed per run.

Per seed: `bandwidth` for 20 s (4 UAVs ranging to 16 anchors at 10 Hz, white range noise 0.1 m, NLOS
rows dropped), `testbed export`, a constant bias drawn uniformly from 0.05-0.3 m (numpy seed: the
simulation's) added to each link's ranges in links.csv, `testbed calibrate --window 0,5`, then
`testbed replay --calibration` over 5-20 s (the segment is never fed) of:
graph.poses, graph.poses with bias states, ranging.ekf (follower uav1, its uwb site, no known body)
and ranging.lsq. Prints, per estimator, each run's position ANEES (graph.poses, ranging.lsq: the 4
UAVs pooled; ranging.ekf: uav1's tag) and position RMSE, and their mean over the runs with the 95 %
Student-t interval of the mean (testbed.scoring.metrics.mean_ci): the runs' spread judges, since one
run's errors are dominated by its constant calibration errors.

    python examples/replay/bias_monte_carlo.py --seeds 201-208 --work DIR [--json FILE]

DIR keeps each seed's dataset and calibration (a second call reuses them; delete a calib.toml to
calibrate again). About 30 s of CPU a seed.
"""
from __future__ import annotations

import argparse
import csv
import json
import re
import sys
from pathlib import Path

import numpy as np

from testbed.cli import main
from testbed.config import scenario
from testbed.runner import run
from testbed.scoring.metrics import mean_ci

#: s: the calibration segment and the replay's end
SEGMENT, END = 5.0, 20.0
#: m: the range of the constant bias drawn per link
BIAS = (0.05, 0.3)
ESTIMATORS = """
[[estimators]]
entry = "graph.poses"

[[estimators]]
entry = "graph.poses"
name = "graph.poses.bias"
params = { bias_states = true }

[[estimators]]
entry = "ranging.ekf"
params = { follower = "uav1", known = [], antennas = ["uav1/uwb"] }

[[estimators]]
entry = "ranging.lsq"
"""


def dataset(seed: int, work: Path) -> Path:
    """The seed's biased export (spec window SEGMENT-END) and its calibration file, made once."""
    d = work / str(seed)
    spec, calib = d / "data" / "spec.toml", d / "calib.toml"
    if not spec.exists():
        export(seed, d)
    if not calib.exists():
        assert main(["calibrate", str(spec), "--window", f"0,{SEGMENT!r}", "--out", str(calib)]) == 0
    return d


def export(seed: int, d: Path) -> None:
    """The seed's run exported into d / "data", its links biased, its spec's window and estimators set."""
    spec = d / "data" / "spec.toml"
    sc = scenario.load("bandwidth", {"sensors.uwb.nlos": "drop"}, duration=END, seed=seed)
    run(sc, d / "run", plots=False)
    assert main(["export", str(d / "run"), "--out", str(d / "data")]) == 0
    with open(d / "data" / "links.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    links = sorted({tuple(sorted((r["src"], r["dst"]))) for r in rows})
    bias = dict(zip(links, np.random.default_rng(seed).uniform(*BIAS, len(links))))
    for r in rows:
        r["value"] = repr(float(r["value"]) + float(bias[tuple(sorted((r["src"], r["dst"])))]))
    with open(d / "data" / "links.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    text = re.sub(r"(?ms)^\[\[estimators\]\].*?(?=^\[(?!\[?estimators[\].])|\Z)", "", spec.read_text())
    text = re.sub(r"(?m)^start = .*$", f"start = {SEGMENT!r}", text, count=1)
    spec.write_text(text + ESTIMATORS)


def replay(d: Path, out: str) -> dict:
    """{estimator: (position ANEES, position RMSE m)} of the seed's calibrated replay."""
    rep = d / out
    if not (rep / "metrics.json").exists():
        assert main(["replay", str(d / "data" / "spec.toml"), "--out", str(rep), "--calibration", str(d / "calib.toml"),
                     "--no-plots"]) == 0
    m = json.loads((rep / "metrics.json").read_text())["estimators"]
    return {k: (e["anees_position"], e["rmse_position_m"]) for k, e in m.items()}


def seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def cli(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=seeds, required=True, help="A-B: the simulation seeds")
    ap.add_argument("--work", type=Path, required=True, help="directory of the seeds' datasets and replays")
    ap.add_argument("--out", default="replay", help="name of each seed's replay directory")
    ap.add_argument("--json", type=Path, help="write the per-run figures here")
    a = ap.parse_args(argv)
    runs = {s: replay(dataset(s, a.work), a.out) for s in a.seeds}
    names = list(next(iter(runs.values())))
    table = {}
    for k in names:
        anees, rmse = np.array([runs[s][k][0] for s in a.seeds]), np.array([runs[s][k][1] for s in a.seeds])
        m, lo, hi = mean_ci(anees)
        table[k] = {"anees": anees.tolist(), "anees_mean": m, "anees_ci95": [lo, hi], "rmse_mean_m": float(rmse.mean())}
        print(f"{k:18s} ANEES " + " ".join(f"{x:.2f}" for x in anees) + f"  mean {m:.2f} [{lo:.2f}, {hi:.2f}]"
              f"  RMSE {rmse.mean():.4f} m")
    if a.json:
        a.json.write_text(json.dumps({"seeds": a.seeds, "estimators": table}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(cli())
