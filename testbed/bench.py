"""Benchmarks (`testbed bench physics|sensors|estimators [--json FILE]`): printed and saved as JSON.

physics: real-time factor of flown mode (controller in the loop, no sensors) for N = 1, 6, 18, 50
vehicles of a swarm-box scene, next to bare `mj_step` on the same model with constant hover
thrust. Single process, single thread: one core.
"""
from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import mujoco
import numpy as np

from testbed.config import from_dict
from testbed.scenario import Scenario


def swarm_scenario(n: int, duration: float, sensors: dict | None = None) -> Scenario:
    """n vehicles on a 3-D grid 40 m apart, each oscillating about its base (swarm-box)."""
    side = int(np.ceil(n ** (1 / 3)))
    grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)[:n]
    bases = [tuple(float(v) for v in 40.0 * g + [20.0, 20.0, 20.0]) for g in grid]
    table = {
        "name": f"bench-swarm-{n}",
        "description": "benchmark swarm",
        "duration": duration,
        "motion": "flown",
        "trajectory": {"kind": "swarm-box", "bases": bases},
    }
    if sensors:
        table["sensors"] = sensors
    return from_dict(Scenario, table, "bench")


def bare_rtf(scenario: Scenario) -> float:
    """Real-time factor of plain mj_step on the scenario's model, constant hover thrust."""
    from testbed.world import build

    physics = build(scenario)
    m, d = physics.model, physics.data
    d.ctrl[:] = physics.vehicle_mass * 9.81 / 4
    steps = int(round(scenario.duration / m.opt.timestep))
    t0 = time.perf_counter()
    mujoco.mj_step(m, d, nstep=steps)
    return scenario.duration / (time.perf_counter() - t0)


def flown_rtf(scenario: Scenario) -> float:
    """Real-time factor of simulate() (flown, controller in the loop), scene compiled beforehand."""
    from testbed.simulate import simulate
    from testbed.world import build

    physics = build(scenario)
    t0 = time.perf_counter()
    simulate(scenario, physics)
    return scenario.duration / (time.perf_counter() - t0)


def bench_physics(sizes=(1, 6, 18, 50), duration: float = 20.0, repeats: int = 3) -> list[dict]:
    """Best-of-`repeats` real-time factors, flown (controller) and bare mj_step run alternately,
    per swarm size."""
    rows = []
    for n in sizes:
        sc = swarm_scenario(n, duration)
        runs = [(flown_rtf(sc), bare_rtf(sc)) for _ in range(repeats)]  # interleaved: same load
        flown, bare = (max(r) for r in zip(*runs))
        rows.append({"vehicles": n, "flown_rtf": flown, "bare_rtf": bare, "ratio": flown / bare,
                     "flown_ticks_per_s": flown * sc.world.control_rate, "bare_steps_per_s": bare / sc.world.timestep})
    return rows


def _print_table(title: str, rows: list[dict]) -> None:
    print(title)
    keys = list(rows[0])
    print("  ".join(f"{k:>18s}" for k in keys))
    for r in rows:
        print("  ".join(f"{r[k]:>18.4g}" if isinstance(r[k], float) else f"{str(r[k]):>18s}" for k in keys))


def bench(what: str, json_path: Path | None = None) -> dict:
    """Run one benchmark family, print its table, optionally write JSON; returns the figures."""
    if what == "physics":
        rows = bench_physics()
        _print_table("physics: flown mode (Lee controller, 200 Hz) vs bare mj_step, real-time factor (one core)", rows)
        result = {"physics": rows}
    elif what == "sensors":
        from testbed.sensors.bench import bench_sensors

        result = {"sensors": bench_sensors(repeat=3)}
        for k, rows in result["sensors"].items():
            if isinstance(rows, list) and rows:
                _print_table(f"sensors: {k}", rows)
            else:
                print(f"sensors: {k}: {rows}")
    elif what == "estimators":
        from testbed.bench_estimators import bench_estimators

        result = {"estimators": bench_estimators()}
        for k, rows in result["estimators"].items():
            _print_table(f"estimators: {k}", rows)
    else:
        raise ValueError(what)
    result["machine"] = {"python": platform.python_version(), "mujoco": mujoco.__version__, "processor": platform.processor() or platform.machine()}
    if json_path is not None:
        Path(json_path).write_text(json.dumps(result, indent=2) + "\n")
    return result
