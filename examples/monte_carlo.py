"""Example 3: a Monte Carlo sweep from Python, with a summary plot and 95 % confidence intervals.

Runs N seeds of `coop-fg` with `testbed.sweep.sweep` (parallel worker processes, run i with seed
+ i, one run directory each), reads every run back with `testbed.load_run`, and plots the mean
position RMSE of each estimator with its Student-t 95 % interval over the runs
(`testbed.scoring.metrics.mean_ci`). Writes OUT/sweep/ (the runs), monte_carlo.png and prints the table.

    python examples/monte_carlo.py [OUT_DIR]       # TESTBED_EXAMPLE_SHORT=1: 2 runs of 2 s
"""
from __future__ import annotations

import shutil

import matplotlib.pyplot as plt
from _common import SHORT, out_dir

import testbed
from testbed.scoring.metrics import mean_ci
from testbed.sweep import sweep

RUNS = 2 if SHORT else 10
DURATION = 2.0 if SHORT else 60.0  # s


def main() -> None:
    out = out_dir("monte_carlo")
    shutil.rmtree(out / "sweep", ignore_errors=True)  # a rerun starts afresh (sweep refuses to overwrite)
    sc = testbed.load_scenario("coop-fg", duration=DURATION)
    sweep(sc, RUNS, out / "sweep", workers=2, progress=False, plots=False)  # the runs' own figures: not needed here
    runs = [testbed.load_run(out / "sweep" / f"run-{i:03d}") for i in range(RUNS)]
    names = list(runs[0].metrics["estimators"])
    stats = {n: mean_ci([r.metrics["estimators"][n]["rmse_position_mean_m"] for r in runs]) for n in names}
    for n, (m, lo, hi) in stats.items():
        print(f"{n:12s} RMSE {m:.3f} m, 95 % CI [{lo:.3f}, {hi:.3f}] over {RUNS} runs")
    fig, ax = plt.subplots(figsize=(6, 3.5))
    means = [stats[n][0] for n in names]
    err = [[stats[n][0] - stats[n][1] for n in names], [stats[n][2] - stats[n][0] for n in names]]
    ax.bar(names, means, yerr=err, capsize=4)
    ax.set(ylabel="position RMSE [m]", title=f"coop-fg, {RUNS} seeds, {DURATION:g} s: mean and 95 % CI")
    fig.tight_layout()
    fig.savefig(out / "monte_carlo.png", dpi=120)


if __name__ == "__main__":
    main()
