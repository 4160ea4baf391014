"""The worker side of testbed.workers: what a worker process does with signals, its parent and its
jobs (testbed.workers has the module docstring that says how stopping works).

`worker_init(parent, stop)` is a pool's initializer, and what a process delegated to by its
parent calls first (testbed.outputs.render); `run_job(fn, (i, job))` runs one job in a worker. Kept apart
from the pools (testbed.workers, which imports the Ray backend) so that a process of the outputs
layer can be a well-behaved worker without importing a workflow.
"""
from __future__ import annotations

import atexit
import ctypes
import os
import signal
import sys
import threading
import time
from typing import Callable

from testbed import interrupt
from testbed.environment import apply_defaults
from testbed.interrupt import Interrupted

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>

#: in a worker: its parent's pid, whether it is inside a job, and its exit code
_parent = 0
_busy = False
_exit_code = 0


class Stopped:
    """The result of a job that a stop request ended (signum: the request's signal)."""

    def __init__(self, signum: int):
        self.signum = signum


def _on_sigterm(signum: int, frame: object) -> None:
    """A worker's SIGTERM (see the module docstring)."""
    if not _busy:
        os._exit(128 + signum)  # between jobs or shutting down: nothing of ours to clean
    if interrupt.requested() or os.getppid() != _parent:
        _exit_as(128 + signum)  # asked before, or orphaned: unwind now
    interrupt.request(signum)


def _exit_as(code: int) -> None:
    global _exit_code
    _exit_code = code
    raise SystemExit(code)


def _exit_now() -> None:
    """A worker's last atexit callback: flush and exit without the interpreter's teardown."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(_exit_code)


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


def worker_init(parent: int, stop=None) -> None:
    """Pool initializer: the process defaults (testbed.environment), the signal dispositions of a
    worker and the parent's stop request `stop` (a RawValue; see the module docstring)."""
    global _parent
    _parent = parent
    atexit.register(_exit_now)  # registered first, so it runs last
    apply_defaults()
    if stop is not None:
        interrupt.watch(stop)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _on_sigterm)
    die_with_parent(parent)


def run_job(fn: Callable, item: tuple[int, object]) -> tuple[int, object]:
    """(i, fn(job)) in a worker, or (i, Stopped) when a stop request ended or skipped the job."""
    global _busy
    i, job = item
    _busy = True
    try:
        interrupt.poll()
        return i, fn(job)
    except Interrupted as e:
        if os.getppid() != _parent:  # nobody to report to
            os._exit(128 + e.signum)
        return i, Stopped(e.signum)
    finally:
        _busy = False
