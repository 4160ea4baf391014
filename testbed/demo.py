"""`make demo`: run the paper scenarios briefly, write results and a video.

Writes into OUT (default runs/demo): one run directory per paper scenario (short horizons),
the closed loop (`coop-denied` flown on the distributed cooperative estimate, briefly), the
bandwidth paper-mode reproduction with a small Monte Carlo, a video of the carrier-phase formation
flown under MuJoCo dynamics and one of the closed loop beside it, and `OUT/summary.md` listing what
was produced. OUT follows testbed.outdir: an earlier demo is replaced (never a directory the
testbed did not write), other testbed outputs only with force.
"""
from __future__ import annotations

import time
from pathlib import Path

from testbed.config import scenario
from testbed.outdir import Output, marker
from testbed.outputs.report import fmt
from testbed.outputs.render import render_run
from testbed.reproduce import reproduce
from testbed.reproduce.denied import variant
from testbed.runner import run

# (scenario, motion, seconds): brief runs of every paper's scenario.
DEMO_RUNS = [
    ("phase-cross-h000", "flown", 30.0),
    ("phase-line-h000", "prescribed", 30.0),
    ("visnav", "flown", 20.0),
    ("bandwidth", "prescribed", 20.0),
    ("coop-fg", "prescribed", 20.0),
]
# the closed loop: coop-denied flown on coop.ins_distributed (reproduce denied's variant), seconds
CLOSED_LOOP = ("coop-denied", "coop_distributed", 10.0)
VIDEO_RUNS = ("phase-cross-h000", "coop-denied-distributed")  # the run directories rendered, 640 x 360


def demo(out: Path, *, force: bool = False) -> None:
    final = Path(out)
    again = (marker(final) or {}).get("kind") == "demo"
    with Output(final, kind="demo", force=force or again) as o:
        _demo(o.path)
        o.commit()
    print(f"demo results in {final}/summary.md")


def _demo(out: Path) -> None:
    lines = ["# Demo results", ""]
    loop, estimate, loop_s = CLOSED_LOOP
    runs = [(name, motion, seconds, scenario.load(name, motion=motion, duration=seconds)) for name, motion, seconds in DEMO_RUNS]
    runs.append((f"{loop}-distributed", f"flown on its {estimate} estimate", loop_s, variant(scenario.load(loop, duration=loop_s), estimate)))
    for directory, how, seconds, sc in runs:
        t0 = time.perf_counter()
        metrics = run(sc, out / directory, progress=True)
        rmse = ", ".join(f"{x:.3g}" for x in metrics["tracking_rmse_m"])
        lines.append(f"- `{directory}` ({how}, {seconds:g} s, {time.perf_counter() - t0:.1f} s wall): tracking RMSE [m] {rmse}")
        for est, scores in metrics["estimators"].items():
            keys = [k for k in scores if k.startswith("rmse_")]
            lines.append(f"  - {est}: " + ", ".join(f"{k} = {fmt(scores[k])}" for k in keys))
        print(lines[-1], flush=True)
    reproduce("bandwidth", out / "reproduce-bandwidth", runs=20)
    lines.append("- seed 000 reproduction, paper and uwb modes (20 runs each): `reproduce-bandwidth/table.md`, `claims.json`")
    for directory in VIDEO_RUNS:
        video = render_run(out / directory, width=640, height=360, max_seconds=30.0, progress=True)
        lines.append(f"- video: `{video.relative_to(out)}`")
    (out / "summary.md").write_text("\n".join(lines) + "\n")
