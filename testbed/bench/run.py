"""`testbed bench physics|sensors|estimators [--json FILE]`: run one family, print, save as JSON."""
from __future__ import annotations

import json
import platform
from pathlib import Path

import mujoco

from testbed.bench.estimators import bench_estimators
from testbed.bench.physics import bench_physics
from testbed.bench.sensors import bench_sensors


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
        result = {"sensors": bench_sensors(repeat=3)}
        for k, rows in result["sensors"].items():
            if isinstance(rows, list) and rows:
                _print_table(f"sensors: {k}", rows)
            else:
                print(f"sensors: {k}: {rows}")
    elif what == "estimators":
        result = {"estimators": bench_estimators()}
        for k, rows in result["estimators"].items():
            _print_table(f"estimators: {k}", rows)
    else:
        raise ValueError(what)
    result["machine"] = {"python": platform.python_version(), "mujoco": mujoco.__version__, "processor": platform.processor() or platform.machine()}
    if json_path is not None:
        Path(json_path).write_text(json.dumps(result, indent=2) + "\n")
    return result
