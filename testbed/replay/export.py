"""`testbed export RUN --out DIR`: a simulated run directory written as a recorded dataset (docs/replay.md).

What goes where (every number written with Python's shortest round-tripping repr, so a replay reads
back exactly the floats the run fed its estimators):
- spec.toml: the vehicles and every one of their sites with its lever arm (from the compiled
  model, testbed.plugins.context.lever_arms), the anchors, the declared sensor tables (Context.sensors
  of the run), the scenario's [[estimators]], its seed, and the window [0, duration];
- links.csv: uwb rows (range m, the declared sigma); phase rows as kind phase (the stream's range
  column, m) and kind range-rate (its eq. 7 rate, m/s, rows where it is defined);
- poses.csv: the GNSS fixes (kind gnss, of the antenna site, declared sigma per axis);
- imu.csv: the IMU samples with the declared sigmas (when the run has an IMU stream);
- truth.csv: every vehicle's base pose and twist at every log instant.
The camera stream has no table in the format and is left out (a note says so).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import tomli_w

from testbed import world
from testbed.api import load_run
from testbed.config import to_dict
from testbed.outdir import Output
from testbed.plugins.context import lever_arms
from testbed.replay.spec import FORMAT
from testbed.stream import declared_sigma, stream_arrays


def _cells(col: np.ndarray) -> list[str]:
    """One column as CSV cells: strings as they are, numbers by repr (exact), NaN as empty."""
    if col.dtype.kind in "US":
        return [str(x) for x in col.tolist()]
    return ["" if x != x else repr(float(x)) for x in np.asarray(col, float).tolist()]


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> None:
    """A CSV file with one column per entry (all of one length)."""
    cells = [_cells(np.asarray(c)) for c in columns.values()]
    lines = [",".join(columns)] + [",".join(row) for row in zip(*cells)]
    Path(path).write_text("\n".join(lines) + "\n")


def _stack(*parts: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Concatenate column dicts with the same keys."""
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else {}


def _links(log: dict, scenario) -> dict[str, np.ndarray] | None:
    parts = []
    for name in ("uwb", "phase"):
        if f"{name}/value" not in log:
            continue
        a = stream_arrays(name, log)
        sigma = declared_sigma(name, a, scenario)
        cols = [("uwb", 0)] if name == "uwb" else [("phase", 1), ("range-rate", 2)]
        for kind, c in cols:
            ok = np.isfinite(a["value"][:, c])
            sig = sigma[:, c] if sigma is not None else np.full(ok.size, np.nan)
            sig = np.where(np.isfinite(sig), sig, np.nan)
            parts.append({"time": a["time"][ok], "src": a["src"][ok], "dst": a["dst"][ok],
                          "kind": np.full(ok.sum(), kind), "value": a["value"][ok, c], "sigma": sig[ok], "arrival": a["arrival"][ok]})
    return _stack(*parts) if parts else None


def _vec(p) -> str:
    """A point as a one-line TOML array of exact floats."""
    return "[" + ", ".join(repr(float(x)) for x in p) + "]"


def spec_toml(scenario, run_dir: Path, arms: dict, n: int) -> str:
    """The spec.toml of an exported run (one line per site and anchor; the rest by tomli_w)."""
    lines = [tomli_w.dumps({
        "format": FORMAT,
        "description": f"exported from the run {run_dir.name}: scenario {scenario.name}, seed {scenario.seed}, "
                       f"{scenario.motion} motion, {scenario.duration:g} s",
        "seed": scenario.seed,
        "estimators": [{"entry": s.entry, **({"name": s.name} if s.name else {}), "params": dict(s.params)}
                       for s in scenario.estimators],
        "window": {"start": 0.0, "end": scenario.duration},
        "sensors": {name: to_dict(cfg) for name, cfg in scenario.sensors.streams().items()},
    })]
    for i in range(1, n + 1):
        lines.append(f"[bodies.uav{i}.sites]  # lever arms, m, body frame FLU")
        lines += [f"{site.partition('/')[2]} = {_vec(arm)}" for site, (body, arm) in arms.items() if body == f"uav{i}"]
        lines.append("")
    if scenario.world.anchors:
        lines.append("[anchors]  # m, world ENU")
        lines += [f"anchor{k} = {_vec(p)}" for k, p in enumerate(scenario.world.anchors, start=1)]
        lines.append("")
    return "\n".join(lines)


def tables(scenario, log: dict) -> dict[str, dict[str, np.ndarray]]:
    """The dataset's tables of a run, {table: {column: (n,) array}} in the columns of docs/replay.md:
    links, poses (GNSS fixes), imu (when the run has one) and truth; what `export` writes as CSV and
    testbed.replay.bag_export as ROS 2 messages."""
    out = {}
    links = _links(log, scenario)
    if links is not None:
        out["links"] = links
    if "gnss/value" in log:
        g = stream_arrays("gnss", log)
        sig = declared_sigma("gnss", g, scenario)
        out["poses"] = {"time": g["time"], "body": g["src"], "kind": np.full(g["time"].size, "gnss"),
                        **{c: g["value"][:, k] for k, c in enumerate("xyz")},
                        **{f"sigma_{c}": sig[:, k] for k, c in enumerate("xyz")}, "arrival": g["arrival"]}
    if "imu/value" in log:
        m = stream_arrays("imu", log)
        sig = declared_sigma("imu", m, scenario)
        out["imu"] = {"time": m["time"], "site": m["src"],
                      **{c: m["value"][:, k] for k, c in enumerate(("ax", "ay", "az", "gx", "gy", "gz"))},
                      "sigma_accel": sig[:, 0], "sigma_gyro": sig[:, 3], "arrival": m["arrival"]}
    T, V = log["truth/pos"].shape[:2]
    cols = {"time": np.repeat(log["time"], V), "body": np.tile([f"uav{i}" for i in range(1, V + 1)], T)}
    for key, names in (("truth/pos", ("x", "y", "z")), ("truth/quat", ("qw", "qx", "qy", "qz")),
                       ("truth/vel", ("vx", "vy", "vz")), ("truth/omega", ("wx", "wy", "wz"))):
        cols.update({c: log[key][:, :, k].ravel() for k, c in enumerate(names)})
    out["truth"] = cols
    return out


def note_camera(run_dir: Path, log: dict) -> None:
    """The one-line note that a run's camera stream has no place in the format."""
    if "camera/value" in log:
        print(f"testbed: note: {run_dir}: the camera stream is not exported (the format has no camera table)", file=sys.stderr)


def export(run_dir: Path, out: Path, *, force: bool = False) -> list[str]:
    """Write the run at run_dir as a dataset directory at out (testbed.outdir); returns the files written."""
    run = load_run(run_dir)
    sc, log = run.scenario, run.log
    arms = lever_arms(world.build(sc))
    note_camera(Path(run_dir), log)
    with Output(Path(out), kind="dataset", force=force) as o:
        (o.path / "spec.toml").write_text(spec_toml(sc, Path(run_dir), arms, sc.vehicles))
        written = ["spec.toml"]
        for name, columns in tables(sc, log).items():
            write_csv(o.path / f"{name}.csv", columns)
            written.append(f"{name}.csv")
        o.commit()
    return written
