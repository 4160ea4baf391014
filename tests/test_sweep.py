"""Monte Carlo runner: parallel runs equal the same seeds run one by one; metrics aggregate."""
import json

import numpy as np
from scipy.stats import t as student_t

from testbed.config import scenario
from testbed.runner import run
from testbed.sweep import sweep


def test_parallel_sweep_is_bit_identical_to_serial_runs(tmp_path):
    """Parallel runs equal the same seeds run one by one, byte for byte; the sweep's runs, without
    figures (plots=False, `--no-plots`), have none and the same log and metrics as the plotted ones."""
    sc = scenario.load("bandwidth", duration=1.0, seed=3)
    summary = sweep(sc, 2, tmp_path / "sweep", workers=2, progress=False, plots=False)
    for i in range(2):
        run(scenario.load("bandwidth", duration=1.0, seed=3 + i), tmp_path / f"serial{i}")
        for f in ("log.npz", "metrics.json"):
            assert (tmp_path / "sweep" / f"run-{i:03d}" / f).read_bytes() == (tmp_path / f"serial{i}" / f).read_bytes()
        assert list((tmp_path / "sweep" / f"run-{i:03d}" / "plots").iterdir()) == []
        assert any((tmp_path / f"serial{i}" / "plots").glob("*.png"))
    saved = json.loads((tmp_path / "sweep" / "summary.json").read_text())
    assert saved["seeds"] == [3, 4] and saved["scores"] == summary
    assert summary["tracking_rmse_m.0"]["n"] == 2
    assert (tmp_path / "sweep" / "summary.csv").read_text().startswith("score,mean,std,min,max,n,ci95_lo,ci95_hi")
    # ci95: the Student t 95 % interval of the mean over the runs, from the runs' own values
    from testbed.sweep import flatten
    flat = [flatten(json.loads((tmp_path / "sweep" / f"run-{i:03d}" / "metrics.json").read_text())) for i in range(2)]
    key = next(k for k, s in sorted(summary.items()) if s["n"] == 2 and s["std"] > 0)
    x = np.array([f[key] for f in flat])
    want = student_t.interval(0.95, 1, loc=x.mean(), scale=x.std(ddof=1) / np.sqrt(2))
    np.testing.assert_allclose(summary[key]["ci95"], want, rtol=1e-12)
    assert summary[key]["ci95"][0] < x.mean() < summary[key]["ci95"][1]


def test_the_summary_gives_a_null_anees_interval_its_reason_and_a_spread_one_its_method():
    """summary.json: an ANEES whose runs cannot decide has its interval null with the reason beside it
    (one run), and from two runs on the interval from the runs' spread says so (anees_over_runs)."""
    from testbed.scoring.metrics import anees_keys
    from testbed.sweep import summarize

    rng = np.random.default_rng(3)
    runs = [{"estimators": {"ekf": anees_keys(rng.chisquare(3, 8), 3)}} for _ in range(3)]  # 8 samples: undecidable
    one = summarize(runs[:1])["estimators.ekf.anees"]
    assert one["interval"] is None and one["null_reason"].startswith("not decidable from one run")
    three = summarize(runs)["estimators.ekf.anees"]
    assert len(three["interval"]) == 2 and "spread of the 3 per-run values" in three["interval_method"]
    assert "null_reason" not in three
