"""Example 4: run a scenario written from scratch in TOML (examples/six_on_a_circle.toml).

Loads the file by path, runs it (flown: rotors and controller in the loop), prints how well the
six vehicles tracked their circle and how many UWB links the wall blocked, and draws a top view:
the flown paths, the anchors and the wall. Writes OUT/run/ (the run directory) and
six_on_a_circle.png.

    python examples/six_on_a_circle.py [OUT_DIR]   # TESTBED_EXAMPLE_SHORT=1: 3 s
"""
from __future__ import annotations

import shutil
from pathlib import Path

import matplotlib.pyplot as plt
from _common import SHORT, out_dir

import testbed

TOML = Path(__file__).with_name("six_on_a_circle.toml")


def main() -> None:
    out = out_dir("six_on_a_circle")
    shutil.rmtree(out / "run", ignore_errors=True)
    sc = testbed.load_scenario(TOML, duration=3.0 if SHORT else None)
    r = testbed.run(sc, out / "run", plots=False)
    print(f"{sc.name}: {sc.vehicles} vehicles, {sc.duration:g} s {sc.motion}")
    print("tracking RMSE [m]:", ", ".join(f"{x:.3f}" for x in r.metrics["tracking_rmse_m"]))
    uwb = r.stream("uwb")
    to_anchor = uwb.dst.astype(str).tolist()
    blocked = [n for n, d in zip(uwb.nlos, to_anchor) if d.startswith("anchor")]
    print(f"UWB: {len(uwb)} ranges, NLOS {100 * uwb.nlos.mean():.1f} % ({100 * sum(blocked) / max(len(blocked), 1):.1f} % to anchors)")
    fig, ax = plt.subplots(figsize=(5, 5))
    for i in range(1, sc.vehicles + 1):
        p = r.truth(f"uav{i}").pos
        ax.plot(p[:, 0], p[:, 1], label=f"uav{i}")
    for k, a in enumerate(sc.world.anchors, start=1):
        ax.plot(a[0], a[1], "k^")
        ax.annotate(f"anchor{k}", a[:2])
    for ob in sc.world.obstacles:
        ax.add_patch(plt.Rectangle((ob.pos[0] - ob.size[0], ob.pos[1] - ob.size[1]), 2 * ob.size[0], 2 * ob.size[1], color="grey"))
    ax.set(xlabel="east [m]", ylabel="north [m]", aspect="equal", title=sc.name)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "six_on_a_circle.png", dpi=120)


if __name__ == "__main__":
    main()
