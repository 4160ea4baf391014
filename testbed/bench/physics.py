"""`testbed bench physics [--vehicles 18,100,300,1000]`: flown mode next to bare `mj_step`.

Per swarm size (the benchmark swarm, testbed.bench.swarm): scene build time; flown mode
(controller in the loop, no sensors, simulate() on the compiled scene) and bare `mj_step` on the
same model with constant hover thrust (with the joint rotor route the hover force is held in
xfrc_applied: the vehicles stay level, so it stays along body z), as steps per second and
real-time factors, wall clock and CPU time (time.process_time: the machine may be shared) side
by side. The simulated duration shrinks with the size (short runs on a shared machine). The
growth exponent b of CPU cost ~ N^b is fitted over the sizes >= 18. Single process, one core.
"""
from __future__ import annotations

import time

import mujoco
import numpy as np

from testbed.bench.swarm import swarm_scenario
from testbed.reference import GRAVITY
from testbed.config.scenario import Scenario
from testbed.sim.simulate import simulate
from testbed.sim.world import Physics, build

SIZES = (1, 6, 18, 50)
VEHICLE_SECONDS = 360.0  # simulated vehicle-seconds per timed run (duration = this / N, within 1..20 s)


def duration_for(n: int) -> float:
    """Simulated seconds of the timed runs for n vehicles (s)."""
    return float(np.clip(VEHICLE_SECONDS / n, 1.0, 20.0))


def _timed(fn) -> tuple[float, float]:
    """(wall s, CPU s) of fn()."""
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def hover(physics: Physics) -> None:
    """Constant hover thrust on every rotor (and, with the joint route, its force in xfrc_applied)."""
    weight = physics.vehicle_mass * GRAVITY
    physics.data.ctrl[physics.actuator_idx] = weight / 4
    if physics.rotor_route == "joint":
        mujoco.mj_forward(physics.model, physics.data)
        physics.views().xfrc[:, :3] = weight * physics.rotation[:, :, 2]


def bare_times(scenario: Scenario, physics: Physics | None = None) -> tuple[float, float]:
    """(wall s, CPU s) of plain mj_step over the scenario's duration, hover thrust."""
    physics = physics or build(scenario)
    hover(physics)
    steps = int(round(scenario.duration / physics.model.opt.timestep))
    return _timed(lambda: mujoco.mj_step(physics.model, physics.data, nstep=steps))


def growth_exponent(n: list[int], cost: list[float]) -> float:
    """b of the least-squares fit log cost = a + b log n."""
    return float(np.polyfit(np.log(n), np.log(cost), 1)[0])


def bench_physics(sizes=SIZES, repeats: int = 2) -> dict:
    """Rows per size (best of `repeats`, flown and bare runs alternated so load hits both) and
    the fitted growth exponents. Keys of a row: vehicles, rotor_route, duration_s, build_s,
    build_cpu_s, flown_rtf, bare_rtf (wall clock), flown_cpu_rtf, bare_cpu_rtf, ratio (flown /
    bare, CPU), flown_ticks_per_s, bare_steps_per_s (CPU), flown_cpu_s_per_s (CPU seconds per
    simulated second)."""
    rows = []
    for n in sizes:
        sc = swarm_scenario(n, duration_for(n))
        w, c = time.perf_counter(), time.process_time()
        physics = build(sc)
        build_w, build_c = time.perf_counter() - w, time.process_time() - c
        flown, bare = [], []
        for k in range(repeats):
            physics = build(sc) if k else physics
            flown.append(_timed(lambda: simulate(sc, physics)))
            bare.append(bare_times(sc))
        fw, fc = min(f[0] for f in flown), min(f[1] for f in flown)
        bw, bc = min(b[0] for b in bare), min(b[1] for b in bare)
        T = sc.duration
        rows.append({"vehicles": n, "rotor_route": physics.rotor_route, "duration_s": T, "build_s": build_w, "build_cpu_s": build_c,
                     "flown_rtf": T / fw, "bare_rtf": T / bw, "flown_cpu_rtf": T / fc, "bare_cpu_rtf": T / bc,
                     "ratio": bc / fc, "flown_ticks_per_s": T * sc.world.control_rate / fc,
                     "bare_steps_per_s": T / sc.world.timestep / bc, "flown_cpu_s_per_s": fc / T})
    fit = [r for r in rows if r["vehicles"] >= 18]
    growth = {}
    if len({r["vehicles"] for r in fit}) >= 2:
        n = [r["vehicles"] for r in fit]
        growth = {"sizes": n, "flown_cpu": growth_exponent(n, [r["flown_cpu_s_per_s"] for r in fit]),
                  "bare_cpu": growth_exponent(n, [1 / r["bare_cpu_rtf"] for r in fit]),
                  "build_cpu": growth_exponent(n, [r["build_cpu_s"] for r in fit])}
    return {"rows": rows, "growth_exponent": growth}
