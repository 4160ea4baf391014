"""Draw the picture of every trajectory kind in docs/scenario.md: docs/images/trajectory-KIND.png.

Each picture is the reference of one scenario (SOURCES: a built-in scenario, or a file under
examples/trajectories/), evaluated with testbed.reference.evaluate over its whole duration: the
paths seen from above (x east, y north, m), a dot where each vehicle starts and, for the
waypoint kinds, the waypoints as crosses. Run from the repository root:

    PYTHONPATH=. python docs/trajectory_pictures.py
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from testbed.outputs import plots
from testbed.reference import evaluate
from testbed.config.scenario import load

ROOT = Path(__file__).resolve().parent.parent
IMAGES = ROOT / "docs" / "images"
EXAMPLES = ROOT / "examples" / "trajectories"
SAMPLES = 2000  # reference instants per picture
# kind -> the scenario its picture is drawn from
SOURCES = {
    "phase-formation": "phase-cross-h000",
    "straight-line": "bandwidth",
    "swarm-box": "coop-fg",
    "swarm-grid": "swarm-100",
    "leader-follower": "visnav",
    **{k: str(EXAMPLES / f"{k}.toml") for k in ("waypoints", "spline", "circle", "lemniscate", "hover")},
}


def draw(kind: str, source: str) -> Path:
    """Write docs/images/trajectory-KIND.png from scenario `source`; returns its path."""
    sc = load(source)
    t = np.linspace(0.0, sc.duration, SAMPLES)
    pos = evaluate(sc.trajectory, t, rates=False).pos  # (K, N, 3) m
    fig = plots.figure(figsize=(4.0, 3.2), dpi=90)
    ax = fig.add_subplot()
    for i in range(pos.shape[1]):
        ax.plot(pos[:, i, 0], pos[:, i, 1], lw=1.0)
    ax.plot(pos[0, :, 0], pos[0, :, 1], "k.", ms=4, label="start")
    points = getattr(sc.trajectory, "points", None)
    if points is not None:
        p = np.array(points)
        ax.plot(p[:, 0], p[:, 1], "kx", ms=5, label="waypoints")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title(f'kind = "{kind}" ({sc.name}, {sc.duration:g} s)', fontsize=8)
    ax.legend(fontsize=7, loc="best")
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    out = IMAGES / f"trajectory-{kind}.png"
    fig.savefig(out)
    return out


def main() -> None:
    for kind, source in SOURCES.items():
        print(draw(kind, source).relative_to(ROOT))


if __name__ == "__main__":
    main()
