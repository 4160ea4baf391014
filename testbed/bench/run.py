"""`testbed bench physics|sensors|estimators|replay|loop|denied|swarm-loop [--json FILE]`: run one family, print, save as JSON.

The JSON holds the family's figures, the machine's load average before and after, and under
"provenance" the record of testbed.provenance (versions, git commit, BLAS kernel, CPU, wall and
CPU time). It is kept in the same file, not beside it as for an output directory: a bench file is
itself the record of one measurement on one machine, never compared across machines byte for
byte, and its figures mean nothing without the machine that made them.
"""
from __future__ import annotations

import os
from pathlib import Path

from testbed import provenance
from testbed.bench.estimators import bench_estimators
from testbed.bench.physics import SIZES, bench_physics
from testbed.bench.sensors import bench_sensors
from testbed.outdir import write_json


def _print_table(title: str, rows: list[dict]) -> None:
    print(title)
    keys = list(rows[0])
    print("  ".join(f"{k:>18s}" for k in keys))
    for r in rows:
        print("  ".join(f"{r[k]:>18.4g}" if isinstance(r[k], float) else f"{str(r[k]):>18s}" for k in keys))


def bench(what: str, json_path: Path | None = None, vehicles: tuple[int, ...] | None = None) -> dict:
    """Run one benchmark family, print its table, optionally write JSON; returns the figures.
    vehicles: swarm sizes (physics, sensors; None: the family's default)."""
    started = provenance.start()
    load_before = os.getloadavg()  # the machine may be shared: the load, beside the CPU-time figures
    if what == "physics":
        out = bench_physics(vehicles or SIZES)
        _print_table("physics: flown mode (Lee controller, 200 Hz) vs bare mj_step; wall-clock and CPU real-time factors (one core)", out["rows"])
        print(f"growth exponent of CPU cost ~ N^b: {out['growth_exponent']}")
        result = {"physics": out["rows"], "physics_growth_exponent": out["growth_exponent"]}
    elif what == "sensors":
        runs = [bench_sensors(vehicles=n, repeat=3 if n <= 18 else 1) for n in vehicles or (18,)]
        result = {"sensors": runs[0] if len(runs) == 1 else runs}
        for out in runs:
            for k, rows in out.items():
                print(f"sensors ({out['vehicles']} vehicles): {k}: {rows}")
    elif what == "estimators":
        result = {"estimators": bench_estimators()}
        for k, rows in result["estimators"].items():
            _print_table(f"estimators: {k}", rows)
    elif what == "denied":
        from testbed.bench.denied import bench_denied  # lazy: this family runs a whole scenario

        rows = [bench_denied(name=v) for v in ("coop_distributed", "coop", "window", "window_distributed")]
        result = {"denied": rows}
        _print_table("denied: coop-denied flown on the cooperative estimate (filters and window cascades; all sensors, network); one core", rows)
    elif what == "swarm-loop":
        from testbed.bench.swarm_loop import bench_swarm_loop  # lazy, as denied

        rows = [bench_swarm_loop()]
        result = {"swarm_loop": rows}
        _print_table("swarm-loop: swarm-100 flown on coop.ins_distributed over the network (IMU, GNSS, UWB); one core", rows)
    elif what == "replay":
        from testbed.bench.replay import bench_replay  # lazy: only this family needs the replay package

        out = bench_replay()
        result = {"replay": out}
        for k in ("factor_graph", "plugin_path"):
            print(f"replay ({out['robots']} robots x {out['antennas_per_robot']} antennas, {out['rate_hz']:g} Hz, "
                  f"batch {out['batch']}): {k}: {out[k]}")
    elif what == "loop":
        from testbed.bench.loop import SIZES as LOOP_SIZES, bench_loop  # lazy, as replay

        out = bench_loop(vehicles or LOOP_SIZES)
        _print_table("loop: flown with IMU 100 Hz, GNSS 5 Hz, UWB 10 Hz; CPU s per simulated s, truth vs estimator in the loop", out["rows"])
        print(f"twice the duration: {out['duration_scale']}; CPU (hold) ~ N^{out['growth_exponent_hold']}")
        result = {"loop": out}
    else:
        raise ValueError(what)
    result["machine"] = {"load_average_1_5_15min": {"before": list(load_before), "after": list(os.getloadavg())}}
    print(f"load average (1, 5, 15 min) before {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}, "
          f"after {result['machine']['load_average_1_5_15min']['after'][0]:.2f}")
    if json_path is not None:
        write_json(Path(json_path), {**result, "provenance": provenance.record(started, output=f"bench-{what}")})
    return result
