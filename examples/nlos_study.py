"""Example 2: an NLOS study. How do pillars in the airspace change UWB cooperative navigation?

Builds variants of the seed 001 scenario `coop-fg` (18 UAVs, GNSS + UWB tag-to-tag ranges,
factor-graph estimators) in Python, each with a different number of cylindrical pillars placed
at random in the 200 x 200 m box (the `world.obstacles` key, given as an override), runs each and
plots against the pillar count: the fraction of UWB ranges that were NLOS (blocked, by mj_ray)
and the position RMSE of GNSS alone and of the centralized factor graph (least squares: NLOS
biases pull it). Writes nlos_study.png and nlos_study.csv.

    python examples/nlos_study.py [OUT_DIR]        # TESTBED_EXAMPLE_SHORT=1: 2 s runs, 2 counts
"""
from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from _common import SHORT, out_dir

import testbed

COUNTS = [0, 12] if SHORT else [0, 4, 8, 16, 32]
DURATION = 2.0 if SHORT else 60.0  # s


def pillars(n: int, rng: np.random.Generator) -> list[dict]:
    """n cylinders (radius 4-8 m, 100 m tall) at uniform random places in the box (m, world)."""
    return [{"type": "cylinder", "pos": [*rng.uniform(10.0, 190.0, 2), 50.0], "size": [rng.uniform(4.0, 8.0), 50.0, 0.0]}
            for _ in range(n)]


def main() -> None:
    out = out_dir("nlos_study")
    rng = np.random.default_rng(7)
    rows = []
    for n in COUNTS:
        # random pillars may stand on a prescribed path (the vehicle passes through it, its ranges still
        # blocked by it): accepted here on purpose, so the clearance check of the reference paths is off
        sc = testbed.load_scenario("coop-fg", overrides={"world.obstacles": pillars(n, rng), "world.clearance": "off"},
                                   duration=DURATION)
        with testbed.run(sc, plots=False) as r:
            est = r.metrics["estimators"]
            nlos = float(r.stream("uwb").nlos.mean())
            rows.append((n, nlos, est["gnss_only"]["rmse_position_mean_m"], est["centralized"]["rmse_position_mean_m"]))
        print(f"{n:3d} pillars: NLOS {100 * nlos:5.1f} %, RMSE GNSS only {rows[-1][2]:.3f} m, centralized {rows[-1][3]:.3f} m")
    a = np.array(rows)
    np.savetxt(out / "nlos_study.csv", a, delimiter=",", header="pillars,nlos_fraction,rmse_gnss_only_m,rmse_centralized_m")
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.5))
    ax1.plot(a[:, 0], 100 * a[:, 1], "o-")
    ax1.set(xlabel="pillars", ylabel="NLOS UWB ranges [%]")
    ax2.plot(a[:, 0], a[:, 2], "s-", label="GNSS only")
    ax2.plot(a[:, 0], a[:, 3], "o-", label="centralized factor graph")
    ax2.set(xlabel="pillars", ylabel="position RMSE [m]")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(out / "nlos_study.png", dpi=120)
    assert a[-1, 1] > a[0, 1], "more pillars should block more links"


if __name__ == "__main__":
    main()
