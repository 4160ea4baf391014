"""Worker processes that stop with their parent.

`run_parallel(fn, jobs, workers)` yields `(index, fn(job))` as jobs complete, in worker processes
(spawned; one process per worker) or in this process when workers == 1. Within `backend("ray",
address)` the jobs run as Ray tasks instead (testbed.cluster), on this machine or a cluster; the
local process pool is the default. A job records its parent's command in the provenance of what it
writes (testbed.provenance.carried).

Stopping is cooperative: on any exception in the parent (Ctrl-C, SIGTERM, an error) the parent
sets a shared stop request and closes the pool; each worker's current unit of work raises
Interrupted at its next `testbed.interrupt.poll()` (in ordinary code, so its output writer removes
its temporary directory), the queued jobs return at once, and the workers exit as a pool does
when it is done. A worker that has not stopped within GRACE_S is terminated (SIGTERM, then it
unwinds where it stands). A worker's own SIGTERM is likewise a stop request while it works on a
job (a second one, or one after its parent asked or died, unwinds at once) and a quiet exit
between jobs, where it has nothing to clean. Workers ignore SIGINT and SIGHUP (the terminal sends
them to the whole process group; the parent decides) and die with their parent even when it is
killed outright: prctl(PR_SET_PDEATHSIG, SIGTERM) on Linux, else a thread watching getppid().
A worker skips the interpreter's teardown when it exits (after multiprocessing's own cleanup, from
its last atexit callback): freeing every module of a simulation takes seconds of CPU for nothing.
"""
from __future__ import annotations

import contextvars
import ctypes
import functools
import multiprocessing as mp
import os
import signal
import threading
from contextlib import contextmanager
from typing import Callable, Iterator, Sequence

from testbed import provenance
from testbed.cluster import run_ray
from testbed.errors import UsageError
from testbed.interrupt import Interrupted, signals_held
from testbed.worker_process import Stopped, run_job, worker_init

#: the backends of run_parallel
BACKENDS = ("local", "ray")
_backend: contextvars.ContextVar[tuple[str, str | None]] = contextvars.ContextVar("backend", default=("local", None))

#: seconds a stopping worker may take before it is terminated
GRACE_S = 3.0


def _stop(pool, stop, signum: int) -> None:
    """Ask the workers to stop, let them finish as a closed pool does, terminate them after GRACE_S."""
    stop.value = signum
    pool.close()
    waiter = threading.Thread(target=pool.join, daemon=True)
    waiter.start()
    waiter.join(GRACE_S)
    if waiter.is_alive():
        pool.terminate()
        waiter.join()


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
        yield from run_ray(provenance.carried(fn), jobs, workers, address)
        return
    workers = workers or os.cpu_count() or 1
    if workers <= 1 or len(jobs) <= 1:
        for i, job in enumerate(jobs):
            yield i, fn(job)
        return
    ctx = mp.get_context("spawn")
    stop = ctx.RawValue(ctypes.c_int, 0)  # lock-free: a worker's signal handler reads it
    pool = ctx.Pool(min(workers, len(jobs)), initializer=worker_init, initargs=(os.getpid(), stop))
    finished = False
    try:
        for i, result in pool.imap_unordered(functools.partial(run_job, provenance.carried(fn)), enumerate(jobs)):
            if isinstance(result, Stopped):  # a worker was sent SIGTERM by someone else
                raise Interrupted(result.signum)
            yield i, result
        finished = True
    finally:
        with signals_held():
            if finished:
                pool.close()
                pool.join()
            else:
                _stop(pool, stop, signal.SIGTERM)
