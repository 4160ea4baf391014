"""The benchmark swarm: one builder of swarm-box scenarios for every `testbed bench` family."""
from __future__ import annotations

import math

from testbed.config import from_dict
from testbed.config.scenario import Scenario

Vec3 = tuple[float, float, float]


def swarm_scenario(n: int, duration: float, *, spacing: Vec3 = (40.0, 40.0, 40.0), origin: Vec3 = (20.0, 20.0, 20.0),
                   sensors: dict | None = None, world: dict | None = None, rtk: tuple[int, ...] = ()) -> Scenario:
    """n vehicles flown (controller in the loop) about bases on a grid, each oscillating (swarm-box).

    The bases are the first n points of a side^3 grid, side = ceil(n^(1/3)), x fastest, then y,
    then z: base = origin + spacing * (i, j, k) (m, world). sensors, world: the scenario's
    [sensors] and [world] tables (None: no sensors, default world); rtk: 1-based RTK vehicles.
    """
    side = max(1, math.ceil(round(n ** (1 / 3), 9)))
    grid = [(i, j, k) for k in range(side) for j in range(side) for i in range(side)][:n]
    bases = [[o + s * g for o, s, g in zip(origin, spacing, ijk)] for ijk in grid]
    table: dict = {
        "name": f"bench-swarm-{n}",
        "description": f"{n}-vehicle benchmark swarm",
        "duration": duration,
        "motion": "flown",
        "trajectory": {"kind": "swarm-box", "bases": bases, "rtk": list(rtk)},
    }
    if sensors:
        table["sensors"] = sensors
    if world:
        table["world"] = world
    return from_dict(Scenario, table, "bench")
