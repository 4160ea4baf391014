"""The `testbed` command line (also `python -m testbed`).

    testbed list
    testbed estimators [NAME] [--markdown]
    testbed run SCENARIO --out DIR [--seed N] [--motion prescribed|flown] [--duration S]
                [--set key=value ...] [--estimator ENTRY [--param key=value ...] ...] [--video] [--fail-on-crash] [--force]
    testbed render DIR [--out FILE] [--force] [--width W --height H --fps F --speed X --max-seconds S
                       --shadow-size N --samples N --links nearest|epoch|none --nearest K --error-scale X]
    testbed sweep SCENARIO --runs N [--workers K] --out DIR [--force | --resume] [--backend local|ray
                [--address ADDR]] [--quiet] [run options]
    testbed bench physics|sensors|estimators|replay|loop|denied|swarm-loop [--json FILE] [--vehicles N,N,...]
    testbed reproduce phase|visnav|bandwidth|coop|denied --out DIR [--force | --resume] [--runs N] [--motion M]
                [--estimator ENTRY [--param key=value ...] ...]
                [--backend local|ray [--address ADDR]] [--quiet]
    testbed demo [--out DIR] [--force]
    testbed schema
    testbed replay SPEC.toml --out DIR [--calibration FILE] [--estimator ENTRY [--param key=value ...] ...] [--force]
    testbed calibrate SPEC.toml --window T0,T1 --out FILE.toml [--force]
    testbed export RUN_DIR --out DIR [--format csv|mcap] [--force]
    testbed view RUN_OR_REPLAY_DIR [--out FILE.rrd] [--force] [--spawn]

Long commands show a progress bar on stderr when it is a terminal (sweep and reproduce: over the
runs, with the time left; off with --quiet) and end with one line on stdout naming what they wrote
and where.

A user mistake (unknown scenario, bad TOML, unknown key, bad value, bad argument, existing output,
an output location that is not the testbed's, an OS error such as a full disk) prints one line
`testbed: error: ...` and exits with code 2, leaving no run directory behind. Output directories
follow testbed.outdir: only a directory the testbed wrote (its `.testbed` marker) is ever replaced.
SIGINT, SIGTERM and SIGHUP stop the command cleanly (temporary files removed, workers stopped, one
line) with exit code 128 + the signal number; a closed stdout (`testbed list | head -1`) ends it
quietly. A flown run prints its safety in one line (testbed.scoring.safety) and, if a vehicle crashed,
a warning naming it as the last line on stderr; it still exits 0 (its run directory is complete
and scored) unless --fail-on-crash is given, then 1.

Imports: this module loads only the standard library and light testbed modules at the top; each
command imports what it needs inside `_dispatch` (numpy, mujoco, scipy, matplotlib come with
testbed.config.scenario, testbed.runner and the rest), so `testbed --help` answers at once and the
environment (testbed.environment) is set before numpy or mujoco load.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
from pathlib import Path

from testbed import provenance
from testbed.environment import apply_defaults
from testbed.errors import TestbedError, UsageError
from testbed.interrupt import exit_code, signals_raise
from testbed.outdir import apart, check_new_file, out_arg


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, no usage dump
        raise UsageError(f"{self.prog}: {message}")


# ------------------------------------------------------------------ argument types (checked once)
# Each returns the converted value or raises ArgumentTypeError; argparse then reports one line
# naming the flag and the value (`testbed run: argument --duration: must be ... got 'nan'`).


def _number(parse, ok, want: str, kind: str):
    """argparse type: parse(text), which must satisfy ok(value); want, kind: for the message."""
    def convert(text: str):
        try:
            value = parse(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}")
        return value
    return convert


def _int_in(lo: int, hi: int, *, even: bool = False):
    """argparse type: an integer in [lo, hi] (even if asked)."""
    return _number(int, lambda v: lo <= v <= hi and not (even and v % 2),
                   f"{'an even integer' if even else 'an integer'} in [{lo}, {hi}]", "an integer")


def _float_in(lo: float, hi: float):
    """argparse type: a finite number in (lo, hi]."""
    return _number(float, lambda v: math.isfinite(v) and lo < v <= hi, f"a finite number in ({lo:g}, {hi:g}]", "a number")


def _window(text: str) -> tuple[float, float]:
    """argparse type: "T0,T1", two finite numbers (s), T0 < T1."""
    parts = text.split(",")
    try:
        t0, t1 = (float(x) for x in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected T0,T1 (two numbers, s), got {text!r}") from None
    if not (math.isfinite(t0) and math.isfinite(t1) and t0 < t1):
        raise argparse.ArgumentTypeError(f"must be two finite numbers T0 < T1 (s), got {text!r}")
    return t0, t1


def _writable_file(text: str) -> Path:
    """argparse type: a file path that can be written (its directory exists and is writable)."""
    path = Path(text)
    parent = path.parent
    if not text:
        raise argparse.ArgumentTypeError("an empty path")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a directory, not a file")
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: the directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise argparse.ArgumentTypeError(f"{text}: not writable")
    return path


SEED = _int_in(0, 10**9)  # the scenario's `seed` range (testbed.config.MAX_MAGNITUDE)
DURATION = _float_in(0, 1e9)  # s; the physics step count is bounded by the scenario (scenario.MAX_STEPS)
RUNS = _int_in(1, 100_000)
WORKERS = _int_in(1, 1024)


def _add_backend_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--backend", choices=["local", "ray"], default="local",
                   help="where the runs execute: local worker processes (default) or Ray tasks (docs/cluster.md)")
    p.add_argument("--address", help="Ray cluster to join (HOST:PORT of the head, or 'auto' on a cluster node; "
                   "default: start Ray on this machine); needs --backend ray")


def _add_quiet_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quiet", action="store_true", help="no progress bar (there is none when stderr is not a terminal)")


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="built-in scenario name (see `testbed list`), or a TOML file named by a path "
                                    "with a '/' or a .toml suffix (./bandwidth names a local file, bandwidth the built-in)")
    p.add_argument("--seed", type=SEED, help="scenario seed, 0..1e9 (default: the scenario's)")
    p.add_argument("--motion", choices=["prescribed", "flown"], help="motion mode (default: the scenario's)")
    p.add_argument("--duration", type=DURATION, help="run length in seconds (default: the scenario's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scenario key, e.g. --set world.truth_rate=20")
    _add_estimator_option(p)


class _Param(argparse.Action):
    """--param KEY=VALUE: a parameter of the --estimator before it (args.params, one dict per
    --estimator), the value parsed like a --set value (a TOML value, else a string)."""

    def __call__(self, parser, namespace, value, option_string=None):
        from testbed.config import parse_value

        key, sep, raw = value.partition("=")
        if not namespace.estimator:
            raise UsageError(f"--param {value!r}: give it after the --estimator it sets")
        if not sep or not key.strip():
            raise UsageError(f"--param {value!r}: expected KEY=VALUE")
        params = list(namespace.params) + [{}] * (len(namespace.estimator) - len(namespace.params))
        params[-1] = {**params[-1], key.strip(): parse_value(raw.strip())}
        namespace.params = params


def _add_estimator_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--estimator", action="append", default=[], metavar="ENTRY",
                   help="also run and score this estimator (a name from `testbed estimators`, package.module:Name or file.py:Name); repeatable")
    p.add_argument("--param", action=_Param, default=[], dest="params", metavar="KEY=VALUE",
                   help="a parameter of the --estimator before it (`testbed estimators NAME` lists them), "
                        "the value as for --set; repeatable")


def _overrides(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UsageError(f"--set {item!r}: expected KEY=VALUE")
        out[key.strip()] = value.strip()
    return out


def _inputs(args: argparse.Namespace, *paths: Path) -> list[Path]:
    """What the command reads besides `paths`: its scenario file (not a built-in) and its plugin files."""
    from testbed.config import scenario  # lazy: see the module docstring
    from testbed.plugins.loading import entry_file

    name = getattr(args, "scenario", None)
    files = [Path(name)] if name is not None and not scenario.resolve(name)[0] else []
    return [*paths, *files, *filter(None, map(entry_file, args.estimator))]


def _load(args: argparse.Namespace):
    """The scenario of a run or sweep, checked whole before anything is simulated: its values
    (testbed.config.scenario.load) and its reference paths' clearance (testbed.reference.clearance)."""
    from testbed.config import scenario  # lazy: see the module docstring
    from testbed import reference  # lazy: see the module docstring

    builtin, label = scenario.resolve(args.scenario)
    sc = scenario.load(args.scenario, _overrides(args.set), seed=args.seed, motion=args.motion, duration=args.duration)
    if builtin and Path(args.scenario).exists():
        print(f"testbed: note: {args.scenario!r} is the built-in scenario, not the local {args.scenario!r} "
              f"(a file is named by a path: ./{args.scenario})", file=sys.stderr)
    warning = reference.check_clearance(sc, label)
    if warning is not None:
        print(f"testbed: warning: {warning}", file=sys.stderr)
    return _with_estimators(sc, args)


def _estimator_specs(args: argparse.Namespace) -> tuple:
    """One [[estimators]] table (EstimatorSpec) per --estimator ENTRY, with its --param values."""
    from testbed.config.estimators import EstimatorSpec

    params = args.params + [{}] * (len(args.estimator) - len(args.params))
    return tuple(EstimatorSpec(entry=e, params=p) for e, p in zip(args.estimator, params))


def _with_estimators(sc, args: argparse.Namespace):
    """The scenario plus one [[estimators]] table per --estimator, every entry loaded (checked) now."""
    import dataclasses

    from testbed.plugins.defaults import estimator_specs
    from testbed.plugins.loading import resolve

    sc = dataclasses.replace(sc, estimators=sc.estimators + _estimator_specs(args))
    resolve(estimator_specs(sc))  # exit 2 on a bad entry (or a name clash) before anything is simulated
    return sc


def _vehicle_counts(text: str) -> tuple[int, ...]:
    """--vehicles: comma-separated positive vehicle counts, e.g. 18,100,300,1000."""
    try:
        counts = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated vehicle counts such as 18,100, got {text!r}") from None
    if not counts or min(counts) < 1:
        raise argparse.ArgumentTypeError(f"vehicle counts must be >= 1, got {text!r}")
    return counts


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="testbed", description="MuJoCo physics-in-the-loop testbed for cooperative navigation of UAV swarms")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    sub.add_parser("list", help="list the built-in scenarios")
    p = sub.add_parser("estimators", help="list the registered estimators with one-line descriptions, or one's parameters")
    p.add_argument("name", nargs="?", help="print this estimator's parameters (name, type, unit, default, range, doc)")
    p.add_argument("--markdown", action="store_true", help="print every estimator's parameter tables (docs/estimators.md)")

    p = sub.add_parser("run", help="simulate a scenario and write its run directory")
    _add_run_options(p)
    p.add_argument("--out", type=out_arg, required=True, help="run directory to write")
    p.add_argument("--video", action="store_true", help="also render video.mp4")
    p.add_argument("--no-plots", dest="plots", action="store_false",
                   help="write no figures (plots/ stays empty): a short run's figures cost more CPU than its simulation")
    p.add_argument("--fail-on-crash", action="store_true", help="exit with code 1 when a flown vehicle crashed")
    p.add_argument("--force", action="store_true", help="replace an earlier output of the testbed")

    p = sub.add_parser("render", help="render a run directory to video.mp4 (headless)")
    p.add_argument("run_dir", type=Path)
    p.add_argument("--out", type=out_arg, help="output MP4 (default RUN_DIR/video.mp4)")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.add_argument("--width", type=_int_in(16, 7680, even=True), default=960, help="pixels, even, 16..7680")
    p.add_argument("--height", type=_int_in(16, 4320, even=True), default=540, help="pixels, even, 16..4320")
    p.add_argument("--fps", type=_int_in(1, 240), default=30, help="frames per second, 1..240")
    p.add_argument("--speed", type=_float_in(0, 1e4), default=1.0, help="playback speed, x real time, in (0, 1e4]")
    p.add_argument("--max-seconds", type=_float_in(0, 1e9), help="cap on the video length (s of video, > 0; simulated time = this x --speed)")
    p.add_argument("--shadow-size", type=_int_in(0, 16384), default=1024, help="shadow map size, 0..16384 (smaller is faster on llvmpipe)")
    p.add_argument("--samples", type=_int_in(0, 16), default=0, help="multisampling, 0..16 (0 is fastest on llvmpipe)")
    p.add_argument("--links", choices=("nearest", "epoch", "none"), default="nearest",
                   help="UWB links drawn: each vehicle's --nearest shortest of the latest sample (default), all of it, or none")
    p.add_argument("--nearest", type=_int_in(1, 1000), default=2, help="links kept per vehicle with --links nearest, 1..1000 (default 2)")
    p.add_argument("--error-scale", type=_float_in(0, 1e6),
                   help="draw the estimate's error segment and 3-sigma ellipse this many times their size (1: to scale; "
                        "default: 1, or the round factor that makes them visible, which the legend states)")

    p = sub.add_parser("sweep", help="Monte Carlo: run N seeds in parallel and aggregate metrics")
    _add_run_options(p)
    p.add_argument("--runs", type=RUNS, required=True)
    p.add_argument("--workers", type=WORKERS, help="worker processes, >= 1 (default: all cores)")
    p.add_argument("--out", type=out_arg, required=True)
    p.add_argument("--force", action="store_true", help="replace an earlier output of the testbed")
    p.add_argument("--resume", action="store_true", help="finish an interrupted sweep at --out, skipping its finished runs")
    p.add_argument("--no-plots", dest="plots", action="store_false",
                   help="the runs write no figures (run-XXX/plots/ stays empty): they cost more CPU than a short run's simulation")
    _add_backend_options(p)
    _add_quiet_option(p)

    p = sub.add_parser("bench", help="benchmarks, printed and saved as JSON")
    p.add_argument("what", choices=["physics", "sensors", "estimators", "replay", "loop", "denied", "swarm-loop"])
    p.add_argument("--json", type=_writable_file, help="write the figures to this JSON file (checked before the benchmark runs)")
    p.add_argument("--vehicles", type=_vehicle_counts, metavar="N[,N...]",
                   help="swarm sizes (physics: default 1,6,18,50; sensors: default 18; loop: default 1,10,30)")

    p = sub.add_parser("reproduce", help="reproduce a paper's results (tables, figures, claims)")
    p.add_argument("paper", choices=["phase", "visnav", "bandwidth", "coop", "denied"])
    p.add_argument("--out", type=out_arg, required=True)
    p.add_argument("--force", action="store_true", help="replace an earlier output of the testbed")
    p.add_argument("--resume", action="store_true",
                   help="finish an interrupted reproduction at --out (same options), skipping its finished runs")
    p.add_argument("--runs", type=RUNS, help="Monte Carlo runs (default: the paper's reproduction default)")
    p.add_argument("--motion", choices=["prescribed", "flown"], help="default prescribed (denied: flown, the only choice)")
    p.add_argument("--duration", type=DURATION, help="shorten every run (seconds)")
    p.add_argument("--workers", type=WORKERS, help="worker processes, >= 1")
    p.add_argument("--no-run-plots", dest="run_plots", action="store_false",
                   help="the Monte Carlo run directories get no figures (the reproduction's own plots/ are drawn, without run 0's)")
    _add_estimator_option(p)
    _add_backend_options(p)
    _add_quiet_option(p)

    p = sub.add_parser("demo", help="run the paper scenarios briefly, write results and a video")
    p.add_argument("--out", type=out_arg, default=Path("runs/demo"), help="an earlier demo here is replaced")
    p.add_argument("--force", action="store_true", help="replace another earlier output of the testbed")

    sub.add_parser("schema", help="print every scenario key with type, unit, default and range (docs/scenario.md)")

    p = sub.add_parser("replay", help="run estimators on a recorded dataset and score them (docs/replay.md)")
    p.add_argument("spec", type=Path, help="the dataset's spec.toml (its tables lie beside it)")
    p.add_argument("--out", type=out_arg, required=True, help="replay directory to write")
    p.add_argument("--force", action="store_true", help="replace an earlier output of the testbed")
    p.add_argument("--calibration", type=Path, metavar="FILE",
                   help="a calibration file (testbed calibrate): ranges corrected, its noise the defaults, its window not scored")
    p.add_argument("--no-plots", dest="plots", action="store_false", help="write no figures (plots/ stays empty)")
    _add_estimator_option(p)

    p = sub.add_parser("calibrate", help="estimate range bias, scale and noise and the process noise on a segment with truth (docs/calibration.md)")
    p.add_argument("spec", type=Path, help="the dataset's spec.toml (its tables lie beside it)")
    p.add_argument("--window", type=_window, required=True, metavar="T0,T1",
                   help="the calibration segment, s in the files' clock (as the spec's window)")
    p.add_argument("--out", type=out_arg, required=True, help="calibration file to write (TOML)")
    p.add_argument("--force", action="store_true", help="replace an existing file")

    p = sub.add_parser("export", help="write a run directory as a recorded dataset (docs/replay.md)")
    p.add_argument("run_dir", type=Path)
    p.add_argument("--out", type=out_arg, required=True, help="dataset directory to write")
    p.add_argument("--format", choices=["csv", "mcap"], default="csv",
                   help="csv: spec.toml and CSV tables; mcap: a ROS 2 bag (MCAP) and its spec.toml (the bags extra)")
    p.add_argument("--force", action="store_true", help="replace an earlier output of the testbed")

    p = sub.add_parser("view", help="write an interactive 3-D recording of a run or a replay (Rerun .rrd; the viz extra)")
    p.add_argument("run_dir", type=Path, help="a run directory or a replay directory")
    p.add_argument("--out", type=out_arg, help="output .rrd (default RUN_DIR/recording.rrd)")
    p.add_argument("--force", action="store_true", help="replace an existing recording")
    p.add_argument("--spawn", action="store_true", help="then open it in the Rerun viewer")
    return parser


def _dispatch(args: argparse.Namespace) -> int:
    # the imports below are lazy on purpose: see the module docstring
    if args.command == "list":
        from testbed.config import scenario

        names = scenario.builtin_names()
        width = max(map(len, names), default=0)
        for name in names:
            print(f"{name:{width}s}  {scenario.load(name).description}")
        return 0
    if args.command == "estimators":
        from testbed.plugins import params
        from testbed.plugins.loading import description, load_class, registered

        entries = registered()
        if args.markdown:
            print(params.markdown({name: load_class(name) for name in entries}), end="")
            return 0
        if args.name is not None:
            print(params.text(args.name, load_class(args.name)))
            return 0
        width = max(map(len, entries), default=0)
        for name, target in entries.items():
            print(f"{name:{width}s}  {description(load_class(name))}  ({target})")
        return 0
    if args.command == "run":
        from testbed.outputs.report import fmt
        from testbed.runner import run

        apart(args.out, _inputs(args))
        sc = _load(args)
        metrics = run(sc, args.out, force=args.force, progress=sys.stderr.isatty(), plots=args.plots, video=args.video)
        rmse = ", ".join(f"{x:.3g}" for x in metrics["tracking_rmse_m"])
        print(f"{sc.name} ({sc.motion}, seed {sc.seed}): tracking RMSE [m]: {rmse}")
        for name, est in metrics["estimators"].items():
            keys = [k for k in est if k.startswith("rmse_")]
            print(f"  {name}: " + ", ".join(f"{k} {fmt(est[k])}" for k in keys))
        crash = None
        if "flight" in metrics:
            from testbed.scoring.safety import crash_warning, summary_line

            print(summary_line(metrics["flight"], metrics["estimators"], sc.control.feedback_estimator))
            crash = crash_warning(metrics["flight"])
        print(f"run directory -> {args.out}")
        if crash:
            sys.stdout.flush()
            print(f"testbed: warning: {crash}", file=sys.stderr)
        return 1 if crash and args.fail_on_crash else 0
    if args.command == "render":
        from testbed.outputs.render import check_run_dir, render_run

        if not (args.run_dir / "scene.xml").is_file() or not (args.run_dir / "log.npz").is_file():
            raise UsageError(f"{args.run_dir}: not a run directory (needs scene.xml and log.npz)")
        check_new_file(args.out or args.run_dir / "video.mp4", force=args.force)  # the user's file first
        apart(args.out or args.run_dir / "video.mp4", [args.run_dir / "scene.xml", args.run_dir / "log.npz"])
        check_run_dir(args.run_dir)
        out = render_run(
            args.run_dir, args.out, width=args.width, height=args.height, fps=args.fps, speed=args.speed,
            max_seconds=args.max_seconds, shadow_size=args.shadow_size, samples=args.samples, progress=sys.stderr.isatty(),
            links=args.links, nearest=args.nearest, error_scale=args.error_scale, force=args.force,
        )
        print(f"video of {args.run_dir} -> {out}")
        return 0
    if args.command == "sweep":
        from testbed.progress import wanted
        from testbed.sweep import sweep

        apart(args.out, _inputs(args))
        summary = sweep(_load(args), args.runs, args.out, workers=args.workers, force=args.force, resume=args.resume,
                        progress=wanted(args.quiet), backend=args.backend, address=args.address, plots=args.plots)
        print(f"{args.runs} runs -> {args.out}/summary.csv ({len(summary)} scores)")
        return 0
    if args.command == "bench":
        from testbed.bench.run import bench

        bench(args.what, args.json, vehicles=args.vehicles)
        print(f"bench {args.what} -> {args.json}" if args.json else f"bench {args.what}: figures above (--json FILE saves them)")
        return 0
    if args.command == "reproduce":
        from testbed.plugins.loading import resolve
        from testbed.progress import shown, wanted
        from testbed.outputs.report import tally
        from testbed.reproduce import reproduce

        apart(args.out, _inputs(args))
        specs = _estimator_specs(args)
        resolve(specs)  # exit 2 on a bad entry before anything is simulated
        with shown(wanted(args.quiet)):
            reproduce(args.paper, args.out, runs=args.runs, motion=args.motion, duration=args.duration, workers=args.workers,
                      force=args.force, estimators=specs, backend=args.backend, address=args.address, resume=args.resume,
                      run_plots=args.run_plots)
        claims = json.loads((args.out / "claims.json").read_text()).get("claims", [])
        print(f"reproduce {args.paper}: {tally(c.get('holds') for c in claims)} -> {args.out}/report.html")
        return 0
    if args.command == "demo":
        from testbed.demo import demo

        demo(args.out, force=args.force)
        return 0
    if args.command == "replay":
        from testbed.replay.recording import dataset_files
        from testbed.replay.run import replay
        from testbed.outputs.report import fmt, fmt_anees

        apart(args.out, _inputs(args, *dataset_files(args.spec), *filter(None, [args.calibration])))
        metrics = replay(args.spec, args.out, estimators=_estimator_specs(args), force=args.force,
                         calibration=args.calibration, plots=args.plots)
        print(f"{args.spec}: {sum(metrics['measurements'].values())} measurements, truth {'yes' if metrics['truth'] else 'no'}")
        if "calibration" in metrics:
            c = metrics["calibration"]
            print(f"  calibration {c['file']}: window {c['window_s'][0]:g}-{c['window_s'][1]:g} s not scored; "
                  f"noise defaults {', '.join(f'{k} {v:.4g}' for k, v in c['noise'].items())}")
        for name, est in metrics["estimators"].items():
            # every ANEES with its interval and effective samples (docs/consistency.md)
            scores = [f"{k} {fmt_anees(est, k) if k.startswith('anees_') else fmt(est[k])}" for k in est
                      if k.startswith(("rmse_", "anees_", "coverage_")) and "_interval_" not in k
                      and not k.endswith(("_dof", "_null_reason"))]
            print(f"  {name}: " + (", ".join(scores) or f"{est.get('estimates', 0)} estimates"))
            if est.get("attitude_unobserved"):
                print(f"  {name}: attitude not observed (its own covariance) of {', '.join(est['attitude_unobserved'])}")
        print(f"replay directory -> {args.out}")
        return 0
    if args.command == "calibrate":
        from testbed.replay.calibrate import calibrate
        from testbed.replay.recording import dataset_files

        apart(args.out, dataset_files(args.spec))
        c = calibrate(args.spec, args.window, args.out, force=args.force)
        print(f"{args.spec}: {len(c['links'])} links, {c['fit']['range_rows']} ranges on {args.window[0]:g}-{args.window[1]:g} s; "
              + ", ".join(f"{k} {v:.4g}" for k, v in c["noise"].items()))
        print(f"calibration -> {args.out}")
        return 0
    if args.command == "export":
        from testbed.replay.bag_export import export_bag
        from testbed.replay.export import export

        if not (args.run_dir / "log.npz").is_file() or not (args.run_dir / "scenario.toml").is_file():
            raise UsageError(f"{args.run_dir}: not a run directory (needs scenario.toml and log.npz)")
        apart(args.out, [args.run_dir])
        files = (export_bag if args.format == "mcap" else export)(args.run_dir, args.out, force=args.force)
        print(f"{args.run_dir} -> {args.out}: {', '.join(files)}")
        return 0
    if args.command == "view":
        from testbed.viewer import view

        out = view(args.run_dir, args.out, force=args.force, spawn=args.spawn)
        print(f"Rerun recording of {args.run_dir} -> {out}  (open it: rerun {out})")
        return 0
    if args.command == "schema":
        from testbed.config.schema import markdown

        print(markdown(), end="")
        return 0
    raise UsageError(f"unknown command {args.command!r}")


def main(argv: list[str] | None = None) -> int:
    apply_defaults()  # before any command imports numpy or mujoco
    argv = sys.argv[1:] if argv is None else argv
    try:
        with signals_raise(), provenance.command_line(argv):
            code = _dispatch(build_parser().parse_args(argv))
            sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
            return code
    except TestbedError as e:
        print(f"testbed: error: {e}", file=sys.stderr)
        return e.exit_code  # 2, or 1 for a plugin that failed during the run
    except KeyboardInterrupt as e:
        what = " ".join(a for a in argv[:2] if not a.startswith("-")) or "testbed"
        detail = getattr(e, "detail", "") or "temporary files removed"
        print(f"testbed: {what} interrupted by {getattr(e, 'name', 'SIGINT')}: {detail}", file=sys.stderr)
        return exit_code(e)
    except BrokenPipeError:  # the reader went away (`testbed list | head -1`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    except OSError as e:  # disk full, read-only, permission denied, ...: the path and the OS's reason
        where = f"{e.filename}: " if e.filename else ""
        print(f"testbed: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
