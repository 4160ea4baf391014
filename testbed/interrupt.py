"""Stopping cleanly: SIGINT, SIGTERM and SIGHUP become an exception that unwinds the writers.

While `signals_raise()` is active (the command line), each of the three signals raises
`Interrupted` (a KeyboardInterrupt, so code that cleans up on Ctrl-C cleans up on all three) in the
main thread; every output writer removes its temporary directory on the way out, and `testbed.cli`
prints one line and exits with 128 + the signal number.

Worker processes (testbed.workers) stop cooperatively instead: a stop request (their parent's, or a
SIGTERM of their own) is only recorded, and the long loops call `poll()` between units of work
(a chunk of simulation ticks, a stage of a run), which raises Interrupted there, in ordinary code,
so the worker unwinds its writers and returns to its pool.
"""
from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Interrupted(KeyboardInterrupt):
    """A stop signal arrived. signum: the signal; detail: what was kept (set by the code it stopped)."""

    def __init__(self, signum: int, detail: str = ""):
        super().__init__(signal.Signals(signum).name)
        self.signum, self.detail = signum, detail

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


#: a stop requested in this process (a signal number, 0: none) and the parent's shared request
_requested = 0
_shared = None


def watch(shared) -> None:
    """Also stop when `shared.value` (a multiprocessing RawValue the parent sets to a signal number)
    is non-zero."""
    global _shared
    _shared = shared


def request(signum: int) -> None:
    """Record a stop request; the next `poll()` raises it."""
    global _requested
    _requested = _requested or signum


def requested() -> int:
    """The signal number of a pending stop request (this process's or its parent's), else 0."""
    return _requested or (_shared.value if _shared is not None else 0)


def poll() -> None:
    """Raise Interrupted if a stop was requested (see the module docstring); cheap, call it often."""
    signum = requested()
    if signum:
        raise Interrupted(signum)


def _raise(signum: int, frame: object) -> None:
    raise Interrupted(signum)


@contextmanager
def signals_raise() -> Iterator[None]:
    """Within the block, SIGINT/SIGTERM/SIGHUP raise Interrupted (main thread only; else a no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _raise) for s in SIGNALS}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


@contextmanager
def signals_held() -> Iterator[None]:
    """Defer SIGINT/SIGTERM/SIGHUP (delivered on exit) so that a few steps are not torn apart."""
    old = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def exit_code(e: KeyboardInterrupt) -> int:
    """128 + the signal number (SIGINT for a plain KeyboardInterrupt)."""
    return 128 + getattr(e, "signum", signal.SIGINT)
