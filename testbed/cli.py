"""The `testbed` command line (also `python -m testbed`).

    testbed list
    testbed run SCENARIO --out DIR [--seed N] [--motion prescribed|flown] [--duration S]
                [--set key=value ...] [--video] [--force]
    testbed render DIR [--out FILE] [--force] [--width W --height H --fps F --speed X --max-seconds S
                       --shadow-size N --samples N]
    testbed sweep SCENARIO --runs N [--workers K] --out DIR [--force | --resume] [--backend local|ray
                [--address ADDR]] [run options]
    testbed bench physics|sensors|estimators [--json FILE]
    testbed reproduce phase|visnav|bandwidth|coop --out DIR [--force] [--runs N] [--motion M]
                [--backend local|ray [--address ADDR]]
    testbed demo [--out DIR] [--force]

A user mistake (unknown scenario, bad TOML, unknown key, bad value, bad argument, existing output,
an output location that is not the testbed's, an OS error such as a full disk) prints one line
`testbed: error: ...` and exits with code 2, leaving no run directory behind. Output directories
follow testbed.outdir: only a directory the testbed wrote (its `.testbed` marker) is ever replaced.
SIGINT, SIGTERM and SIGHUP stop the command cleanly (temporary files removed, workers stopped, one
line) with exit code 128 + the signal number; a closed stdout (`testbed list | head -1`) ends it
quietly.

Imports: this module loads only the standard library and light testbed modules at the top; each
command imports what it needs inside `_dispatch` (numpy, mujoco, scipy, matplotlib come with
testbed.scenario, testbed.runner and the rest), so `testbed --help` answers at once and the
environment (testbed.environment) is set before numpy or mujoco load.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path

from testbed.environment import apply_defaults
from testbed.errors import TestbedError, UsageError
from testbed.interrupt import exit_code, signals_raise
from testbed.outdir import out_arg


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, no usage dump
        raise UsageError(f"{self.prog}: {message}")


def _add_backend_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--backend", choices=["local", "ray"], default="local",
                   help="where the runs execute: local worker processes (default) or Ray tasks (docs/cluster.md)")
    p.add_argument("--address", help="Ray cluster to join (HOST:PORT of the head, or 'auto' on a cluster node; "
                   "default: start Ray on this machine); needs --backend ray")


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="built-in scenario name (see `testbed list`) or path to a TOML file")
    p.add_argument("--seed", type=int, help="scenario seed (default: the scenario's)")
    p.add_argument("--motion", choices=["prescribed", "flown"], help="motion mode (default: the scenario's)")
    p.add_argument("--duration", type=float, help="run length in seconds (default: the scenario's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scenario key, e.g. --set world.truth_rate=20")


def _overrides(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UsageError(f"--set {item!r}: expected KEY=VALUE")
        out[key.strip()] = value.strip()
    return out


def _load(args: argparse.Namespace):
    from testbed import scenario  # lazy: see the module docstring

    return scenario.load(args.scenario, _overrides(args.set), seed=args.seed, motion=args.motion, duration=args.duration)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="testbed", description="MuJoCo physics-in-the-loop testbed for cooperative navigation of UAV swarms")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    sub.add_parser("list", help="list the built-in scenarios")

    p = sub.add_parser("run", help="simulate a scenario and write its run directory")
    _add_run_options(p)
    p.add_argument("--out", type=out_arg, required=True, help="run directory to write")
    p.add_argument("--video", action="store_true", help="also render video.mp4")
    p.add_argument("--force", action="store_true", help="replace an earlier output of the testbed")

    p = sub.add_parser("render", help="render a run directory to video.mp4 (headless)")
    p.add_argument("run_dir", type=Path)
    p.add_argument("--out", type=out_arg, help="output MP4 (default RUN_DIR/video.mp4)")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.add_argument("--width", type=int, default=960)
    p.add_argument("--height", type=int, default=540)
    p.add_argument("--fps", type=int, default=30)
    p.add_argument("--speed", type=float, default=1.0, help="playback speed, x real time")
    p.add_argument("--max-seconds", type=float, help="render at most this much simulated time")
    p.add_argument("--shadow-size", type=int, default=1024, help="shadow map size (smaller is faster on llvmpipe)")
    p.add_argument("--samples", type=int, default=0, help="multisampling (0 is fastest on llvmpipe)")

    p = sub.add_parser("sweep", help="Monte Carlo: run N seeds in parallel and aggregate metrics")
    _add_run_options(p)
    p.add_argument("--runs", type=int, required=True)
    p.add_argument("--workers", type=int, help="worker processes (default: all cores)")
    p.add_argument("--out", type=out_arg, required=True)
    p.add_argument("--force", action="store_true", help="replace an earlier output of the testbed")
    p.add_argument("--resume", action="store_true", help="finish an interrupted sweep at --out, skipping its finished runs")
    _add_backend_options(p)

    p = sub.add_parser("bench", help="benchmarks, printed and saved as JSON")
    p.add_argument("what", choices=["physics", "sensors", "estimators"])
    p.add_argument("--json", type=Path, help="write the figures to this JSON file")

    p = sub.add_parser("reproduce", help="reproduce a paper's results (tables, figures, claims)")
    p.add_argument("paper", choices=["phase", "visnav", "bandwidth", "coop"])
    p.add_argument("--out", type=out_arg, required=True)
    p.add_argument("--force", action="store_true", help="replace an earlier output of the testbed")
    p.add_argument("--runs", type=int, help="Monte Carlo runs (default: the paper's reproduction default)")
    p.add_argument("--motion", choices=["prescribed", "flown"], default="prescribed")
    p.add_argument("--duration", type=float, help="shorten every run (seconds)")
    p.add_argument("--workers", type=int)
    _add_backend_options(p)

    p = sub.add_parser("demo", help="run the paper scenarios briefly, write results and a video")
    p.add_argument("--out", type=out_arg, default=Path("runs/demo"), help="an earlier demo here is replaced")
    p.add_argument("--force", action="store_true", help="replace another earlier output of the testbed")
    return parser


def _dispatch(args: argparse.Namespace) -> int:
    # the imports below are lazy on purpose: see the module docstring
    if args.command == "list":
        from testbed import scenario

        for name in scenario.builtin_names():
            print(f"{name:22s} {scenario.load(name).description}")
        return 0
    if args.command == "run":
        from testbed.report import fmt
        from testbed.runner import run

        sc = _load(args)
        metrics = run(sc, args.out, force=args.force, progress=sys.stderr.isatty(), video=args.video)
        rmse = ", ".join(f"{x:.3g}" for x in metrics["tracking_rmse_m"])
        print(f"{sc.name} ({sc.motion}, seed {sc.seed}) -> {args.out}  tracking RMSE [m]: {rmse}")
        for name, est in metrics["estimators"].items():
            keys = [k for k in est if k.startswith("rmse_")]
            print(f"  {name}: " + ", ".join(f"{k} {fmt(est[k])}" for k in keys))
        return 0
    if args.command == "render":
        from testbed.render import render_run

        if not (args.run_dir / "scene.xml").is_file() or not (args.run_dir / "log.npz").is_file():
            raise UsageError(f"{args.run_dir}: not a run directory (needs scene.xml and log.npz)")
        out = render_run(
            args.run_dir, args.out, width=args.width, height=args.height, fps=args.fps, speed=args.speed,
            max_seconds=args.max_seconds, shadow_size=args.shadow_size, samples=args.samples, progress=sys.stderr.isatty(),
            force=args.force,
        )
        print(out)
        return 0
    if args.command == "sweep":
        from testbed.sweep import sweep

        summary = sweep(_load(args), args.runs, args.out, workers=args.workers, force=args.force, resume=args.resume,
                        progress=sys.stderr.isatty(), backend=args.backend, address=args.address)
        print(f"{args.runs} runs -> {args.out}/summary.csv ({len(summary)} scores)")
        return 0
    if args.command == "bench":
        from testbed.bench.run import bench

        bench(args.what, args.json)
        return 0
    if args.command == "reproduce":
        from testbed.reproduce import reproduce

        reproduce(args.paper, args.out, runs=args.runs, motion=args.motion, duration=args.duration, workers=args.workers,
                  force=args.force, backend=args.backend, address=args.address)
        return 0
    if args.command == "demo":
        from testbed.demo import demo

        demo(args.out, force=args.force)
        return 0
    raise UsageError(f"unknown command {args.command!r}")


def main(argv: list[str] | None = None) -> int:
    apply_defaults()  # before any command imports numpy or mujoco
    argv = sys.argv[1:] if argv is None else argv
    try:
        with signals_raise():
            code = _dispatch(build_parser().parse_args(argv))
            sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
            return code
    except TestbedError as e:
        print(f"testbed: error: {e}", file=sys.stderr)
        return 2
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
