"""Stopping cleanly: SIGINT, SIGTERM and SIGHUP become an exception that unwinds the writers.

While `signals_raise()` is active (the command line), each of the three signals raises
`Interrupted` (a KeyboardInterrupt, so code that cleans up on Ctrl-C cleans up on all three) in the
main thread; every output writer removes its temporary directory on the way out, and `testbed.cli`
prints one line and exits with 128 + the signal number.
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
