"""Worker processes that stop with their parent.

`run_parallel(fn, jobs, workers)` yields `(index, fn(job))` as jobs complete, in worker processes
(spawned; one process per worker) or in this process when workers == 1. Within `backend("ray",
address)` the jobs run as Ray tasks instead (testbed.cluster), on this machine or a cluster; the
local process pool is the default. On any exception in the
parent (Ctrl-C, SIGTERM, an error) every worker is terminated at once: a worker turns SIGTERM into
SystemExit so that its own output writer removes its temporary directory. Workers ignore SIGINT and
SIGHUP (the terminal sends them to the whole process group; the parent decides) and die with their
parent even when it is killed outright: prctl(PR_SET_PDEATHSIG, SIGTERM) on Linux, else a thread
watching getppid().
"""
from __future__ import annotations

import contextvars
import ctypes
import functools
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterator, Sequence

from testbed.cluster import run_ray
from testbed.environment import apply_defaults
from testbed.errors import UsageError
from testbed.interrupt import signals_held

#: the backends of run_parallel
BACKENDS = ("local", "ray")
_backend: contextvars.ContextVar[tuple[str, str | None]] = contextvars.ContextVar("backend", default=("local", None))

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def _exit_on_sigterm(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(0.5)
    os.kill(os.getpid(), signal.SIGTERM)


def die_with_parent(parent: int) -> None:
    """Make this process receive SIGTERM when process `parent` (its parent) dies."""
    ok = False
    if sys.platform.startswith("linux"):
        try:
            ok = ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) == 0
        except (OSError, AttributeError):
            ok = False
    if not ok:
        threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    if os.getppid() != parent:  # it died before we asked
        os.kill(os.getpid(), signal.SIGTERM)


def worker_init(parent: int) -> None:
    """Pool initializer: the process defaults (testbed.environment) and the signal dispositions of a
    worker (see the module docstring)."""
    apply_defaults()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    die_with_parent(parent)


def _indexed(fn: Callable, item: tuple[int, object]) -> tuple[int, object]:
    return item[0], fn(item[1])


@contextmanager
def backend(name: str = "local", address: str | None = None) -> Iterator[None]:
    """Within the block run_parallel uses `name` ("local": process pool; "ray": Ray tasks, `address`
    as in testbed.cluster.connect). `address` needs the ray backend."""
    if name not in BACKENDS:
        raise UsageError(f"--backend {name!r}: choose one of {', '.join(BACKENDS)}")
    if address is not None and name != "ray":
        raise UsageError(f"--address {address!r} needs --backend ray")
    token = _backend.set((name, address))
    try:
        yield
    finally:
        _backend.reset(token)


def current_backend() -> str:
    """The backend run_parallel uses here: "local" or "ray"."""
    return _backend.get()[0]


def run_parallel(fn: Callable, jobs: Sequence, workers: int | None) -> Iterator[tuple[int, object]]:
    """Yield (i, fn(jobs[i])) in order of completion; `fn` must be importable (spawned workers, Ray
    tasks). workers: processes of the local pool; with Ray, the most tasks in flight (None: all)."""
    name, address = _backend.get()
    if name == "ray":
        yield from run_ray(fn, jobs, workers, address)
        return
    workers = workers or os.cpu_count() or 1
    if workers <= 1 or len(jobs) <= 1:
        for i, job in enumerate(jobs):
            yield i, fn(job)
        return
    pool = mp.get_context("spawn").Pool(min(workers, len(jobs)), initializer=worker_init, initargs=(os.getpid(),))
    try:
        yield from pool.imap_unordered(functools.partial(_indexed, fn), enumerate(jobs))
        pool.close()
    finally:
        with signals_held():
            pool.terminate()
            pool.join()
