"""Example 5: analysis of a run directory. UWB range error against distance, LOS against NLOS.

Opens a run directory with `testbed.load_run` (any run with a `uwb` stream; without an argument
it first runs `coop-fg` with two buildings so that some links are blocked), takes each range's
error (value - clean, m), its true distance (clean, m) and its LOS/NLOS flag, and draws the error
against distance and the two error histograms, with the declared 1-sigma noise for reference.
Writes uwb_analysis.png.

    python examples/uwb_analysis.py [OUT_DIR [RUN_DIR]]   # TESTBED_EXAMPLE_SHORT=1: a 3 s run
"""
from __future__ import annotations

import shutil
import sys

import matplotlib.pyplot as plt
import numpy as np
from _common import SHORT, out_dir

import testbed

BUILDINGS = [{"type": "box", "pos": [100.0, 100.0, 50.0], "size": [15.0, 15.0, 50.0]},
             {"type": "cylinder", "pos": [60.0, 140.0, 50.0], "size": [8.0, 50.0, 0.0]}]


def main() -> None:
    out = out_dir("uwb_analysis")
    if len(sys.argv) > 2:
        r = testbed.load_run(sys.argv[2])
    else:
        shutil.rmtree(out / "run", ignore_errors=True)
        # the buildings stand on prescribed paths (vehicles pass through them in prescribed motion, their
        # ranges blocked): accepted on purpose for the NLOS analysis, so the clearance check is off
        sc = testbed.load_scenario("coop-fg", overrides={"world.obstacles": BUILDINGS, "world.clearance": "off"},
                                   duration=3.0 if SHORT else 120.0)
        testbed.run(sc, out / "run", plots=False)
        r = testbed.load_run(out / "run")
    uwb = r.stream("uwb")
    err, dist, nlos = uwb.error[:, 0], uwb.clean[:, 0], uwb.nlos
    sigma = float(uwb.sigma[0, 0])
    for label, sel in (("LOS", ~nlos), ("NLOS", nlos)):
        if sel.any():
            print(f"{label:4s}: {sel.sum():5d} ranges, error mean {err[sel].mean():+.3f} m, std {err[sel].std():.3f} m")
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    ax1.plot(dist[~nlos], err[~nlos], ".", ms=2, label="LOS")
    ax1.plot(dist[nlos], err[nlos], ".", ms=3, label="NLOS")
    ax1.axhline(3 * sigma, color="k", lw=0.5)
    ax1.axhline(-3 * sigma, color="k", lw=0.5, label=f"3 sigma declared ({sigma:g} m)")
    ax1.set(xlabel="true distance [m]", ylabel="range error [m]")
    ax1.legend(fontsize=8)
    bins = np.linspace(min(err.min(), -4 * sigma), max(err.max(), 4 * sigma), 60)
    ax2.hist(err[~nlos], bins=bins, alpha=0.6, density=True, label="LOS")
    if nlos.any():
        ax2.hist(err[nlos], bins=bins, alpha=0.6, density=True, label="NLOS")
    ax2.set(xlabel="range error [m]", ylabel="density")
    ax2.legend(fontsize=8)
    fig.suptitle(f"{r.scenario.name}: UWB error, {len(uwb)} ranges")
    fig.tight_layout()
    fig.savefig(out / "uwb_analysis.png", dpi=120)


if __name__ == "__main__":
    main()
