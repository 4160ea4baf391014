"""`testbed bench physics`: real-time factor of flown mode next to bare `mj_step`.

Flown mode (controller in the loop, no sensors) for N = 1, 6, 18, 50 vehicles of the benchmark
swarm (testbed.bench.swarm), next to bare `mj_step` on the same model with constant hover thrust.
Single process, single thread: one core.
"""
from __future__ import annotations

import time

import mujoco

from testbed.bench.swarm import swarm_scenario
from testbed.scenario import Scenario
from testbed.simulate import simulate
from testbed.world import build


def bare_rtf(scenario: Scenario) -> float:
    """Real-time factor of plain mj_step on the scenario's model, constant hover thrust."""
    physics = build(scenario)
    m, d = physics.model, physics.data
    d.ctrl[:] = physics.vehicle_mass * 9.81 / 4
    steps = int(round(scenario.duration / m.opt.timestep))
    t0 = time.perf_counter()
    mujoco.mj_step(m, d, nstep=steps)
    return scenario.duration / (time.perf_counter() - t0)


def flown_rtf(scenario: Scenario) -> float:
    """Real-time factor of simulate() (flown, controller in the loop), scene compiled beforehand."""
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
