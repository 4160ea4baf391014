"""`testbed export RUN --out DIR`: a simulated run directory written as a recorded dataset (docs/replay.md).

What goes where (every number written with Python's shortest round-tripping repr, so a replay reads
back exactly the floats the run fed its estimators):
- spec.toml: what makes each estimator's Context on replay the one it had in the run
  (testbed.plugins.context.make_context): the vehicles and every one of their sites with its lever
  arm (from the compiled model, testbed.plugins.context.lever_arms), the anchors, the declared
  sensor tables (Context.sensors), the motion, the built-ins' prior (Context.prior), the seed (each
  Context.rng is the stream "estimator/KEY" of it, KEY kept) and the window [0, duration]; and the
  run's estimators (`exported_estimators`): the built-ins of its [pipeline] and its [[estimators]],
  each with its resolved params, so Context.pipeline (left empty on replay) is never needed;
  With a [network], the scenario's [network] too (each estimator's Context.channel on replay);
- links.csv: uwb rows (range m, the declared sigma; with a [network], the nlos flag its
  geometry reads); none without a uwb stream;
- poses.csv: the GNSS fixes (kind gnss, of the antenna site, declared sigma per axis);
- imu.csv: the IMU samples with the declared sigmas (when the run has an IMU stream);
- phase.csv: the phase stream whole (when the run has one): carrier phase, range, rate, the
  masters' navigation solution, rate windows, wavelength, slip flags, declared sigmas;
- camera.csv: the camera rows (when the run has a camera stream): focal-plane coordinates and line
  of sight of each seen LED;
- truth.csv: every vehicle's base pose and twist at every log instant.
What the export cannot carry is a note on stderr (left_out): a phase row's infinite rate sigma (no
rate yet) becomes none; a bag (testbed.replay.bag_export) has no phase or camera topic (the phase
stream goes as links of its range and range rate), and the estimators that read them are left
out of its spec (unreproducible: a note on stderr and a comment in spec.toml name each).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import tomli_w

from testbed.sim import world
from testbed.api import load_run
from testbed.config import to_dict
from testbed.outdir import Output
from testbed.plugins import builtin_phase, builtin_visnav
from testbed.plugins.context import make_context
from testbed.plugins.priors import priors
from testbed.sim.world import lever_arms
from testbed.plugins.defaults import estimator_specs
from testbed.plugins.loading import resolve
from testbed.plugins.params import NOT_PARAMS, params_class, pipeline_kind
from testbed.plugins.settings import settings
from testbed.config.estimators import EstimatorSpec
from testbed.replay.spec import FORMAT
from testbed.replay.tables import CAMERA_COLUMNS, PHASE_MASTER_COLUMNS
from testbed.stream import declared_sigma, stream_arrays


def _cells(col: np.ndarray) -> list[str]:
    """One column as CSV cells: strings as they are, integers and booleans as integers, other
    numbers by repr (exact), NaN as empty."""
    if col.dtype.kind in "US":
        return [str(x) for x in col.tolist()]
    if col.dtype.kind in "iub":
        return [str(int(x)) for x in col.tolist()]
    return ["" if x != x else repr(float(x)) for x in np.asarray(col, float).tolist()]


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> None:
    """A CSV file with one column per entry (all of one length)."""
    cells = [_cells(np.asarray(c)) for c in columns.values()]
    lines = [",".join(columns)] + [",".join(row) for row in zip(*cells)]
    Path(path).write_text("\n".join(lines) + "\n")


def _stack(*parts: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Concatenate column dicts with the same keys."""
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _links(log: dict, scenario, bag: bool) -> dict[str, np.ndarray]:
    """The links table: uwb rows (bag: and the phase stream as phase and range-rate rows); no row
    when the run has no such stream (the table is required: an empty one says so); the nlos
    column only with a [network] (the one reader of it)."""
    empty, text = np.zeros(0), np.zeros(0, str)
    parts = [{"time": empty, "src": text, "dst": text, "kind": text, "value": empty, "sigma": empty, "arrival": empty,
              "nlos": empty}]
    for name in ("uwb", "phase") if bag else ("uwb",):
        if f"{name}/value" not in log:
            continue
        a = stream_arrays(name, log)
        sigma = declared_sigma(name, a, scenario)
        cols = [("uwb", 0)] if name == "uwb" else [("phase", 1), ("range-rate", 2)]
        for kind, c in cols:
            ok = np.isfinite(a["value"][:, c])
            sig = sigma[:, c] if sigma is not None else np.full(ok.size, np.nan)
            sig = np.where(np.isfinite(sig), sig, np.nan)
            nlos = a["nlos"].astype(float) if name == "uwb" and "nlos" in a else np.zeros(ok.size)
            parts.append({"time": a["time"][ok], "src": a["src"][ok], "dst": a["dst"][ok],
                          "kind": np.full(ok.sum(), kind), "value": a["value"][ok, c], "sigma": sig[ok], "arrival": a["arrival"][ok],
                          "nlos": nlos[ok]})
    out = _stack(*parts)
    return out if scenario.network is not None else {k: v for k, v in out.items() if k != "nlos"}


_VISNAV = (builtin_visnav.Ekf, builtin_visnav.Ckf, builtin_visnav.Hckf, builtin_visnav.Mckf, builtin_visnav.Rhcf)
#: the built-ins a replay of a bag export cannot drive, and why: what they read has no topic
BAG_UNREPRODUCIBLE = (
    ((builtin_phase.PhaseEkf,), "it reads the phase stream's carrier phase, master navigation solution, rate windows "
                                "and slip flags, which a bag export does not carry (export as csv)"),
    (_VISNAV, "it reads the camera stream, which a bag export does not carry (export as csv)"),
)


def unreproducible(cls: type, bag: bool = False) -> str:
    """Why a replay of a CSV export (bag: of a bag export) cannot drive the estimator class cls
    ("" when it can: a CSV export carries every stream a built-in reads)."""
    return next((why for classes, why in BAG_UNREPRODUCIBLE if issubclass(cls, classes)), "") if bag else ""


def exported_estimators(scenario, physics, prior: dict, bag: bool = False) -> tuple[list[EstimatorSpec], list[str]]:
    """(the estimators a replay of the run drives, one line per estimator it cannot); prior: the
    run's testbed.plugins.priors.priors; bag: for a bag export (unreproducible).

    The estimators: those a run of the scenario scores (testbed.plugins.defaults.estimator_specs:
    the default ones of its [pipeline] kind, then its [[estimators]]), in that order, keys kept (a
    key names its Context.rng stream); params resolved: an estimator whose Params is a pipeline
    config (testbed.plugins.params.pipeline_kind; today coop.*, phase.ekf, bandwidth.fusion,
    visnav.*) gets every key of that config with the value it ran with (testbed.plugins.settings,
    so a new built-in needs no edit here); the others (their
    defaults fixed in their code, not read from the scenario) keep the params given."""
    specs = estimator_specs(scenario)
    out, skipped = [], []
    for spec, p in zip(specs, resolve(specs)):
        why = unreproducible(p.cls, bag)
        if why:
            skipped.append(f"{p.key} is not exported: {why}")
            continue
        params = dict(p.params)
        Params = params_class(p.cls)
        if Params is not None and pipeline_kind(Params) is not None:  # a paper built-in: its [pipeline] config
            cfg = settings(Params, make_context(scenario, lever_arms(physics), p.key, p.params, prior), p.params, p.entry)
            params = {k: v for k, v in to_dict(cfg).items() if k not in NOT_PARAMS}
        out.append(EstimatorSpec(entry=spec.entry, name=spec.name, params=params))
    return out, skipped


def _vec(p) -> str:
    """A point as a one-line TOML array of exact floats."""
    return "[" + ", ".join(repr(float(x)) for x in p) + "]"


def spec_toml(scenario, run_dir: Path, arms: dict, n: int, estimators: list[EstimatorSpec] = (),
              prior: dict | None = None, skipped: list[str] = ()) -> str:
    """The spec.toml of an exported run (one line per site, anchor and prior row; the rest by
    tomli_w). estimators: exported_estimators; prior: testbed.plugins.priors.priors of the run;
    skipped: a comment line each."""
    lines = [f"# {line}" for line in skipped]
    lines += [tomli_w.dumps({
        "format": FORMAT,
        "description": f"exported from the run {run_dir.name}: scenario {scenario.name}, seed {scenario.seed}, "
                       f"{scenario.motion} motion, {scenario.duration:g} s",
        "seed": scenario.seed,
        "motion": scenario.motion,
        "estimators": [{"entry": s.entry, **({"name": s.name} if s.name else {}), "params": dict(s.params)} for s in estimators],
        "window": {"start": 0.0, "end": scenario.duration},
        **({"network": to_dict(scenario.network)} if scenario.network is not None else {}),
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
    for target, (mean, cov) in (prior or {}).items():
        lines.append(f"[prior.{target}]  # the built-ins' prior, in their own state")
        lines.append(f"mean = {_vec(mean)}")
        lines += ["cov = ["] + [f"    {_vec(row)}," for row in cov] + ["]", ""]
    return "\n".join(lines)


def _finite(x: np.ndarray) -> np.ndarray:
    """x with its non-finite entries NaN (an empty cell: the format refuses inf)."""
    return np.where(np.isfinite(x), x, np.nan)


def tables(scenario, log: dict, bag: bool = False) -> dict[str, dict[str, np.ndarray]]:
    """The dataset's tables of a run, {table: {column: (n,) array}} in the columns of docs/replay.md:
    links (always: without a row when the run has no link stream), poses (GNSS fixes), imu, phase
    and camera (when the run has them) and truth: what `export` writes as CSV. bag: those
    testbed.replay.bag_export writes as ROS 2 messages, which have no phase and no camera topic:
    the phase stream as links rows of its range (kind phase) and range rate (kind range-rate)."""
    out = {"links": _links(log, scenario, bag)}
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
    if "phase/value" in log and not bag:
        p = stream_arrays("phase", log)
        sig = _finite(declared_sigma("phase", p, scenario))
        pv = np.concatenate([p["master_pos"], p["master_vel"]], axis=1)
        out["phase"] = {"time": p["time"], "src": p["src"], "dst": p["dst"],
                        **{c: p["value"][:, k] for k, c in enumerate(("phase", "range", "rate"))},
                        **{c: pv[:, k] for k, c in enumerate(PHASE_MASTER_COLUMNS)}, "rate_periods": p["rate_periods"],
                        "wavelength": p["wavelength"], "slip": p["slip"],
                        **{f"sigma_{c}": sig[:, k] for k, c in enumerate(("phase", "range", "rate"))}, "arrival": p["arrival"]}
    if "camera/value" in log and not bag:
        c = stream_arrays("camera", log)
        out["camera"] = {"time": c["time"], "src": c["src"], "dst": c["dst"],
                         **{k: c["value"][:, j] for j, k in enumerate(CAMERA_COLUMNS)}, "arrival": c["arrival"]}
    return out


def left_out(log: dict, bag: bool = False, network: bool = False) -> list[str]:
    """One line per stream of the run that the export (bag: a bag export) leaves out or carries
    in part; network: the scenario has a [network]."""
    out = []
    if bag and network and "uwb/value" in log:
        out.append("the uwb rows' nlos flags are not exported: a bag's Link message has none; on replay the network "
                   "(Context.channel) counts every pair line of sight (export as csv to keep them)")
    undefined = int(np.sum(log["phase/rate_periods"] == 0)) if "phase/value" in log else 0
    if bag and "phase/value" in log:
        out.append("the phase stream is exported as links of its range (kind phase) and range rate (kind range-rate), "
                   "without its carrier phase, the masters' navigation solution, rate windows and slip flags: an "
                   "estimator that reads those is fed other measurements on replay (export as csv to keep them)")
    elif undefined:
        out.append(f"{undefined} phase rows without a range rate (no period averaged yet) have an infinite declared "
                   "rate sigma in the run; the format has no infinity: on replay they declare no sigma (None)")
    if bag and "camera/value" in log:
        out.append("the camera stream is not exported: a bag has no camera topic (export as csv to keep it)")
    return out


def run_spec(run_dir: Path, scenario, log: dict, bag: bool = False) -> str:
    """The spec.toml text of the run at run_dir (spec_toml with its estimators and prior), after
    a one-line note on stderr for each thing the export (bag: a bag export) leaves out (left_out,
    each estimator a replay cannot drive)."""
    physics, prior = world.build(scenario), priors(scenario, log)
    estimators, skipped = exported_estimators(scenario, physics, prior, bag)
    for line in left_out(log, bag, scenario.network is not None) + skipped:
        print(f"testbed: note: {run_dir}: {line}", file=sys.stderr)
    return spec_toml(scenario, Path(run_dir), lever_arms(physics), scenario.vehicles, estimators, prior, skipped)


def export(run_dir: Path, out: Path, *, force: bool = False) -> list[str]:
    """Write the run at run_dir as a dataset directory at out (testbed.outdir); returns the files written."""
    run = load_run(run_dir)
    sc, log = run.scenario, run.log
    spec = run_spec(Path(run_dir), sc, log)
    with Output(Path(out), kind="dataset", force=force) as o:
        (o.path / "spec.toml").write_text(spec)
        written = ["spec.toml"]
        for name, columns in tables(sc, log).items():
            write_csv(o.path / f"{name}.csv", columns)
            written.append(f"{name}.csv")
        o.commit()
    return written
