"""The Ray backend of `testbed.workers.run_parallel`: every job is one Ray task.

`run_ray(fn, jobs, workers, address)` connects to Ray (`address`: None starts a local instance on
this machine, "auto" joins the cluster this machine belongs to, "HOST:PORT" a given head node; an
already initialized Ray in this process is used as it is), submits one task per job (1 CPU each, at
most `workers` in flight when given, else all) and yields `(index, fn(job))` as tasks finish.

The tasks write their outputs themselves: a sweep's run directory is written by the task on the node
that runs it, into the sweep's temporary directory, so the output path must be on a file system
shared by every node (NFS, a cluster file system) under the same path; the driver checks each run
directory after its task and stops with one line if it cannot see it (testbed.sweep). Each task
runs with testbed.environment's defaults (single-threaded BLAS) in its environment, so a run gives
the same bytes on a Ray worker as in a local worker process.

A task whose worker process or node dies is rerun by Ray (SYSTEM_RETRIES times, on any node); after
that the failure is a TaskLost, which a sweep handles like an interrupt (finished runs kept).
Stopping (Ctrl-C, SIGTERM, SIGHUP, an error in the driver): every unfinished task is cancelled. A
running task gets a KeyboardInterrupt (its output writer removes its temporary directory); tasks
still running after CANCEL_GRACE_S are killed (force), which may leave a temporary directory named
after the dead worker's pid, removed by the next command writing there (testbed.outdir).

Joining a cluster (`address` given) takes at most CONNECT_TIMEOUT_S: a TCP connection to the
address first, then a driver's handshake made by a child process that is stopped when the time is
up (Ray's own client, in this process, retries an unreachable head for minutes and cannot be
given a deadline). A failure is one line; one that Ray's messages show to be the cluster's token
authentication says what to set (RAY_AUTH_MODE=token, docs/cluster.md). What Ray's C++ core
writes to stderr while connecting goes to a temporary file, never to the terminal.
"""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
from typing import Callable, Iterator, Sequence

from testbed.environment import DEFAULTS, apply_defaults, last_line, stderr_to, written
from testbed.errors import RunError, TestbedError
from testbed.interrupt import signals_held

__all__ = ["CANCEL_GRACE_S", "CONNECT_TIMEOUT_S", "SYSTEM_RETRIES", "TaskLost", "connect", "run_ray"]

#: seconds a cancelled task gets to unwind (remove its temporary directory) before it is killed
CANCEL_GRACE_S = 3.0
#: times Ray reruns a task whose worker or node died (system failures only; an error of the run
#: itself is never retried)
SYSTEM_RETRIES = 3
#: seconds of one wait for finished tasks
WAIT_S = 0.2
#: seconds joining a cluster at --address may take (TCP connection, then a driver's handshake)
CONNECT_TIMEOUT_S = 30.0
# the handshake, run by a child process: `python -c _HANDSHAKE ADDRESS`
_HANDSHAKE = ("import sys, ray; ray.init(address=sys.argv[1], log_to_driver=False, configure_logging=False, "
              "include_dashboard=False); ray.shutdown()")


class TaskLost(RunError):
    """A Ray task failed for a reason outside the run (its node died more than SYSTEM_RETRIES times,
    the cluster went away): the sweep keeps its finished runs, as on an interrupt."""


def _task(fn: Callable, job: object) -> object:
    """Body of one Ray task: the process defaults, then fn(job)."""
    apply_defaults()
    return fn(job)


def _import_ray():
    """The ray module; imported here, not at module top, because ray is an optional dependency
    (`pip install 'uav-swarm-testbed[cluster]'`) and slow to import."""
    try:
        import ray
    except ImportError:
        raise RunError("--backend ray needs the ray package: pip install 'ray[default]' "
                       "(or the testbed's extra: pip install '.[cluster]')") from None
    return ray


def failure(address: str | None, ray_stderr: str, reason: str) -> str:
    """The one line for a failed connection: what Ray wrote to stderr (`ray_stderr`) tells an
    authentication failure (Ray's InvalidAuthToken: docs/cluster.md), else `reason`."""
    where = "a local Ray instance" if address is None else f"the Ray cluster at --address {address}"
    if "InvalidAuthToken" in ray_stderr or "RAY_AUTH_MODE" in ray_stderr:
        return (f"{where} refused this driver's authentication (Ray: InvalidAuthToken): set RAY_AUTH_MODE=token "
                "in the environment, with the head's ~/.ray/auth_token on this machine (docs/cluster.md)")
    return f"cannot connect to {where}: {reason}"


def _reach(address: str) -> None:
    """Within CONNECT_TIMEOUT_S: a TCP connection to HOST:PORT, then a driver's handshake in a child
    process (module docstring); RunError (one line) if either fails."""
    deadline = time.monotonic() + CONNECT_TIMEOUT_S
    host, _, port = address.rpartition("://")[2].rpartition(":")
    if host and port.isdigit():
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
        except OSError as e:
            raise RunError(failure(address, "", e.strerror or str(e) or type(e).__name__)) from None
    try:
        p = subprocess.run([sys.executable, "-c", _HANDSHAKE, address], capture_output=True, text=True,
                           timeout=max(1.0, deadline - time.monotonic()), stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired as e:
        text = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else e.stderr or ""
        raise RunError(failure(address, text, f"no answer within {CONNECT_TIMEOUT_S:g} s "
                                              "(testbed.cluster.CONNECT_TIMEOUT_S)")) from None
    if p.returncode != 0:
        raise RunError(failure(address, p.stderr, last_line(p.stderr) or f"exit code {p.returncode}"))


def connect(address: str | None) -> tuple[object, bool]:
    """(ray module, whether this call started the connection). address: see the module docstring."""
    ray = _import_ray()
    if ray.is_initialized():
        return ray, False
    if address is not None:
        _reach(address)
    with tempfile.TemporaryFile() as log:
        try:
            with stderr_to(log):  # Ray's C++ core writes there while connecting
                ray.init(address=address, log_to_driver=False, configure_logging=False, include_dashboard=False)
        except (ConnectionError, ValueError, RuntimeError) as e:
            reason = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise RunError(failure(address, written(log), reason)) from None
    return ray, True


def _task_env() -> dict[str, str]:
    """Environment variables of every task: testbed.environment's defaults, the driver's values kept."""
    return {name: os.environ.get(name, value) for name, value in DEFAULTS.items()}


def _cancel(ray, refs: list) -> None:
    """Cancel unfinished tasks: KeyboardInterrupt first, a kill after CANCEL_GRACE_S. A task that
    has finished is not cancelled: Ray (2.x) can abort the driver on a cancel that crosses its
    completion ("Tried to complete task that was not pending"), seen once in a clean-clone CI run."""
    _, refs = ray.wait(list(refs), num_returns=len(refs), timeout=0)
    for ref in refs:
        ray.cancel(ref, force=False)
    deadline = time.monotonic() + CANCEL_GRACE_S
    left = list(refs)
    while left and time.monotonic() < deadline:
        _, left = ray.wait(left, num_returns=len(left), timeout=0.1)
    for ref in left:
        try:
            ray.cancel(ref, force=True)
        except ValueError:  # finished in between
            pass


def run_ray(fn: Callable, jobs: Sequence, workers: int | None, address: str | None) -> Iterator[tuple[int, object]]:
    """Yield (i, fn(jobs[i])) in order of completion, each call a Ray task; `fn` must be importable
    on every node (the testbed installed there)."""
    if not jobs:
        return
    ray, started = connect(address)
    remote = ray.remote(num_cpus=1, max_retries=SYSTEM_RETRIES)(_task).options(runtime_env={"env_vars": _task_env()})
    cap = len(jobs) if not workers else max(1, workers)
    index: dict = {}
    queue = list(range(len(jobs)))
    try:
        while queue or index:
            while queue and len(index) < cap:
                i = queue.pop(0)
                index[remote.remote(fn, jobs[i])] = i
            # with a timeout, so that a signal handler (Ctrl-C) runs between waits
            ready, _ = ray.wait(list(index), num_returns=1, timeout=WAIT_S)
            for ref in ready:
                i = index.pop(ref)
                try:
                    value = ray.get(ref)
                except ray.exceptions.RayTaskError as e:
                    # a user-facing error of the run stays one line; anything else keeps Ray's traceback
                    raise (e.cause if isinstance(e.cause, TestbedError) else e.as_instanceof_cause()) from None
                except ray.exceptions.RayError as e:  # worker, node or cluster lost
                    raise TaskLost(f"Ray lost job {i}: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}") from None
                yield i, value
    finally:
        with signals_held():
            if index:
                _cancel(ray, list(index))
            if started:
                ray.shutdown()
