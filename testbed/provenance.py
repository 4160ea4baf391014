"""Provenance: how, where and with what an output was made (`provenance.json`).

Every output directory (run, sweep, reproduction, replay, exported dataset, demo) holds
`provenance.json`, written by testbed.outdir.Output just before the directory is put in place;
`testbed bench --json F` puts the same record under the key "provenance" of F. It is kept out of
metrics.json on purpose: metrics stay byte-comparable across machines, provenance never is.

`record(started, output=KIND)` builds the record, a dict of strict-JSON values:

- testbed: {"version", "source" (the directory the package was imported from), "git": {"commit",
  "dirty"} or null, "git_note" (why git is null: not a checkout, git missing, timed out)};
  dirty: a tracked file differs from the commit (untracked files are not counted);
- command: {"interface": "command line", "argv": ["testbed", ...], "line": the same as one string}
  for the `testbed` command (and every run its workers write), or {"interface": "python API",
  "function": the outermost testbed function called ("testbed.api.run"), "argv": the host
  program's sys.argv};
- output: the kind of output ("run", "sweep", "reproduce-coop", "replay", "dataset", "demo",
  "bench-physics");
- python: {"version", "implementation", "executable"}; packages: {name: version} of the testbed's
  distribution and of every package it requires, dependencies and extras (null: not installed);
- blas: the BLAS libraries loaded in the process, as threadpoolctl reports them (library, version,
  kernel "architecture" such as "SkylakeX" or "Haswell" for OpenBLAS, threads, threading layer,
  file; null without threadpoolctl);
- cpu: {"model" (/proc/cpuinfo "model name", else the platform's name), "machine", "cores"
  (os.cpu_count()), "cores_usable" (this process's CPU affinity)}; platform: the OS string;
- environment: the variables that change results or speed (OPENBLAS_CORETYPE, the thread counts,
  MUJOCO_GL), null when unset;
- time: {"started_utc", "finished_utc" (ISO 8601), "wall_s", "cpu_s" (this process, user +
  system), "children_cpu_s" (child processes that ended and were waited for in that span: a local
  sweep's worker pool; Ray tasks run elsewhere and are not counted)} over the making of the output:
  from the moment its writer started (`start()`) to the record; the command's start-up before that
  (imports, argument checks) is not included; a resumed sweep or reproduction records the command
  that finished it.

Cheap: git, the package versions and the CPU model are read once per process (git with a short
timeout; about 0.1 s in all on a loaded 2-core machine); a record then costs about a millisecond.
"""
from __future__ import annotations

import functools
import os
import platform
import re
import resource
import shlex
import subprocess
import sys
import time
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterator, NamedTuple

from testbed import __version__

PROVENANCE = "provenance.json"
#: environment variables recorded: they choose the BLAS kernel, its threads, the renderer
ENVIRONMENT = ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "MUJOCO_GL")
GIT_TIMEOUT_S = 2.0
DISTRIBUTION = "uav-swarm-testbed"  # the testbed's name in pyproject.toml
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")  # the package name at the start of a requirement
SOURCE = Path(__file__).resolve().parent.parent  # the directory holding the testbed package

#: the command of this process when it is the `testbed` command line (or one of its workers)
_command: dict | None = None


class Started(NamedTuple):
    """When the making of an output started: epoch s (UTC), a monotonic s, CPU s of this process
    and of its waited-for children."""
    epoch: float
    monotonic: float
    cpu: float
    children_cpu: float


def _cpu() -> tuple[float, float]:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, children.ru_utime + children.ru_stime


def start() -> Started:
    """Now, for the `time` of a later record."""
    return Started(time.time(), time.monotonic(), *_cpu())


@contextmanager
def command_line(argv: list[str]) -> Iterator[None]:
    """Within the block this process is the command `testbed ARGV...` (testbed.cli.main)."""
    global _command
    full = ["testbed", *argv]
    before, _command = _command, {"interface": "command line", "argv": full, "line": shlex.join(full)}
    try:
        yield
    finally:
        _command = before


def _as_command(command: dict, fn: Callable, job: object) -> object:
    global _command
    before, _command = _command, command
    try:
        return fn(job)
    finally:
        _command = before


def carried(fn: Callable) -> Callable:
    """fn, calling which in a worker process records this process's command (picklable when fn is)."""
    return functools.partial(_as_command, command(), fn)


def command() -> dict:
    """The command making the outputs of this process (see the module docstring)."""
    if _command is not None:
        return _command
    frame, outermost = sys._getframe(1), None
    while frame is not None:
        module = frame.f_globals.get("__name__", "")
        if module.startswith("testbed.") and module not in (__name__, "testbed.outdir"):
            outermost = f"{module}.{frame.f_code.co_qualname}"
        frame = frame.f_back
    return {"interface": "python API", "function": outermost, "argv": list(sys.argv)}


def _git(*args: str) -> str:
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}  # `git status` must not take the index lock
    return subprocess.run(["git", "-C", str(SOURCE), *args], capture_output=True, text=True, check=True,
                          timeout=GIT_TIMEOUT_S, env=env).stdout.strip()


@functools.cache
def git() -> tuple[dict | None, str | None]:
    """({"commit", "dirty"}, None) when the testbed runs from a git checkout, else (None, why)."""
    try:
        top, commit = _git("rev-parse", "--show-toplevel", "HEAD").splitlines()
        if Path(top).resolve() != SOURCE:
            return None, f"not a git checkout (the testbed is installed in {SOURCE})"
        dirty = _git("status", "--porcelain", "--untracked-files=no") != ""
    except FileNotFoundError:
        return None, "git is not installed"
    except OSError as e:
        return None, f"git could not be run: {e.strerror or e}"
    except subprocess.TimeoutExpired:
        return None, f"git did not answer within {GIT_TIMEOUT_S:g} s"
    except subprocess.CalledProcessError:
        return None, f"not a git checkout (the testbed is installed in {SOURCE})"
    return {"commit": commit, "dirty": dirty}, None


@functools.cache
def packages() -> dict[str, str | None]:
    """{name: version} of the testbed's distribution and of every package it requires (dependencies
    and extras; None: not installed), by name. Run from a checkout without being installed: every
    installed distribution instead. (Listing every distribution always would cost 0.1-0.3 s.)"""
    # lazy: importlib.metadata takes 50-120 ms to import, which `testbed --help` must not pay
    from importlib import metadata

    def version(name: str) -> str | None:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    try:
        required = metadata.requires(DISTRIBUTION) or []
    except metadata.PackageNotFoundError:
        found = {d.metadata["Name"]: d.version for d in metadata.distributions() if d.metadata["Name"]}
    else:
        found = {name: version(name) for name in {DISTRIBUTION, *(_NAME.match(r).group(0) for r in required)}}
    return dict(sorted(found.items(), key=lambda kv: kv[0].lower()))


def blas() -> list[dict] | None:
    """The BLAS (and OpenMP) libraries loaded in this process, as threadpoolctl reports them; None
    without threadpoolctl (a dependency: a broken installation must still not lose the output)."""
    try:
        # lazy: threadpoolctl is only needed when a record is made, not for `testbed --help`
        from threadpoolctl import threadpool_info
    except ImportError:
        return None

    keep = ("user_api", "internal_api", "version", "architecture", "threading_layer", "num_threads", "filepath")
    return [{k: lib.get(k) for k in keep} for lib in threadpool_info()]


@functools.cache
def cpu() -> dict:
    """The CPU model, machine type and core counts."""
    model = None
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() in ("model name", "Model", "Hardware", "cpu model") and value.strip():
                    model = value.strip()
                    break
    except OSError:
        pass
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {"model": model or platform.processor() or None, "machine": platform.machine(), "cores": os.cpu_count(),
            "cores_usable": usable}


def _utc(epoch: float) -> str:
    return datetime.fromtimestamp(epoch, timezone.utc).isoformat(timespec="milliseconds")


def record(started: Started, *, output: str) -> dict:
    """The provenance of an output of kind `output` whose making began at `started` (module docstring)."""
    now, wall, (cpu_s, children_s) = time.time(), time.monotonic(), _cpu()
    git_info, git_note = git()
    return {
        "testbed": {"version": __version__, "source": str(SOURCE), "git": git_info, "git_note": git_note},
        "command": command(),
        "output": output,
        "python": {"version": platform.python_version(), "implementation": platform.python_implementation(),
                   "executable": sys.executable},
        "packages": packages(),
        "blas": blas(),
        "cpu": cpu(),
        "platform": platform.platform(),
        "environment": {name: os.environ.get(name) for name in ENVIRONMENT},
        "time": {"started_utc": _utc(started.epoch), "finished_utc": _utc(now),
                 "wall_s": round(wall - started.monotonic, 3),
                 "cpu_s": round(cpu_s - started.cpu, 3), "children_cpu_s": round(children_s - started.children_cpu, 3)},
    }
