"""Monte Carlo runner: parallel runs equal the same seeds run one by one; metrics aggregate."""
import json

from testbed import scenario
from testbed.runner import run
from testbed.sweep import sweep


def test_parallel_sweep_is_bit_identical_to_serial_runs(tmp_path):
    sc = scenario.load("bandwidth", duration=1.0, seed=3)
    summary = sweep(sc, 2, tmp_path / "sweep", workers=2, progress=False)
    for i in range(2):
        run(scenario.load("bandwidth", duration=1.0, seed=3 + i), tmp_path / f"serial{i}")
        for f in ("log.npz", "metrics.json"):
            assert (tmp_path / "sweep" / f"run-{i:03d}" / f).read_bytes() == (tmp_path / f"serial{i}" / f).read_bytes()
    saved = json.loads((tmp_path / "sweep" / "summary.json").read_text())
    assert saved["seeds"] == [3, 4] and saved["scores"] == summary
    assert summary["tracking_rmse_m.0"]["n"] == 2
    assert (tmp_path / "sweep" / "summary.csv").read_text().startswith("score,mean,std,min,max,n")
