"""`testbed bench denied`: coop-denied flown on the distributed estimate, everything on.

One run of the built-in `coop-denied` (18 UAVs, IMU, GNSS with sky visibility, UWB among
vehicles and to anchors, [network]) for `duration` s, the controller flying on
`coop.ins_distributed` whose broadcasts travel over the scenario's network (the
`coop_distributed` variant of `testbed reproduce denied`, testbed.reproduce.denied.variant),
and for comparison on the centralized `coop.ins` (variant `coop`) and on the two window cascades
(variants `window`, `window_distributed`: coop.window_ins, coop.window_distributed_ins). Measured around the
whole run (build, simulation with the estimator in the loop, scoring, writing; plots off),
`repeat` runs one after the other in this process: wall and CPU seconds (time.process_time,
this process: one core) of the median run, the real-time factors simulated seconds / second,
the CPU seconds of every run (`cpu_s_runs`: the first carries the process's one-time costs,
its memory growing to the run's size, so it is also given alone: `realtime_factor_cpu_first`),
and the estimator's share of the run: its wall time in the loop
(timing.json `wall_ms`, testbed.plugins.online) over the run's wall time, and its CPU time,
measured by feeding the run's log to a fresh instance of the same estimator (the same
measurements in the same order give the same estimates: testbed.plugins.feed) over the run's
CPU time. On a shared machine the CPU figures are the ones to read. Beside the whole run, the
flown loop alone (`loop_cpu_s`: the world built, then every tick of the simulation with the
sensors and the estimator in the loop, the log kept in memory; no scoring, no writing), timed
on the same scenario again: the real-time factor of the step and the estimator's share of it.
"""
from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from testbed.log import LogWriter, load_log
from testbed.plugins.context import make_context
from testbed.plugins.feed import batched, run_plugin
from testbed.plugins.loading import resolve
from testbed.plugins.online import in_the_loop
from testbed.reproduce.denied import COOP, variant
from testbed.runner import run
from testbed.config.scenario import Scenario, load
from testbed.sim.simulate import record
from testbed.sim.world import build, lever_arms

DURATION_S = 10.0
REPEAT = 3  # runs per variant: the median is reported (a shared machine's noise), the first too


def bench_denied(duration: float = DURATION_S, name: str = "coop_distributed", repeat: int = REPEAT) -> dict:
    """The figures of `repeat` runs (module docstring); name: the reproduce variant flown."""
    figures = bench_flown(variant(load("coop-denied", duration=duration), name), repeat)
    return {"scenario": figures["scenario"], "variant": name, **figures}


def bench_flown(sc: Scenario, repeat: int = REPEAT) -> dict:
    """The figures of `repeat` runs of scenario sc (module docstring), flown on its estimator
    named COOP ([control] feedback = "estimate:coop")."""
    duration = sc.duration
    runs = []  # (wall s, CPU s, estimator wall ms, metrics) of each run
    with tempfile.TemporaryDirectory(prefix="bench-denied-") as tmp:
        for k in range(repeat):
            out = Path(tmp) / f"run-{k}"
            w0, c0 = time.perf_counter(), time.process_time()
            metrics = run(sc, out, plots=False)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            runs.append((wall, cpu, json.loads((out / "timing.json").read_text())["estimators"][COOP]["wall_ms"], metrics))
        feed = list(batched(sc, load_log(out)))
    cpu_runs = [r[1] for r in runs]
    wall, cpu, est_ms, metrics = runs[int(np.argsort(cpu_runs)[len(runs) // 2])]  # the median run by CPU (of two, the slower)
    plugin = next(p for p in resolve(sc.estimators) if p.key == COOP)
    ctx = make_context(sc, lever_arms(build(sc)), plugin.key, plugin.params)
    c1 = time.process_time()
    run_plugin(plugin, ctx, feed)
    est_cpu = time.process_time() - c1
    c2 = time.process_time()
    physics = build(sc)
    online = in_the_loop(sc, physics, resolve(sc.estimators))
    record(sc, LogWriter(), physics, feedback=online)
    online.finish()
    loop_cpu = time.process_time() - c2
    return {"scenario": sc.name, "vehicles": sc.vehicles, "simulated_s": duration,
            "runs": repeat, "wall_s": wall, "cpu_s": cpu, "realtime_factor_wall": duration / wall, "realtime_factor_cpu": duration / cpu,
            "cpu_s_runs": cpu_runs, "realtime_factor_cpu_first": duration / cpu_runs[0],
            "estimator_wall_s": est_ms / 1e3, "estimator_share_wall": est_ms / 1e3 / wall,
            "estimator_cpu_s": est_cpu, "estimator_share_cpu": est_cpu / cpu,
            "loop_cpu_s": loop_cpu, "realtime_factor_loop_cpu": duration / loop_cpu, "estimator_share_loop_cpu": est_cpu / loop_cpu,
            "estimation_rmse_m": metrics["estimators"][COOP]["rmse_position_mean_m"]}
