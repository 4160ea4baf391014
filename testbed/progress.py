"""Progress bars over the runs of long work (sweep, reproduce), on stderr.

A bar is shown only when stderr is a terminal and the user did not pass `--quiet` (`wanted`);
the command line decides once, around the whole command (`shown`), and the workflows draw their
bars with `bar`, which is off otherwise: a log file or a pipe never gets a bar's carriage
returns. tqdm gives the count, the rate and the time left (ETA).
"""
from __future__ import annotations

import sys
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Iterator

from tqdm import tqdm

_ON: ContextVar[bool] = ContextVar("testbed_progress", default=False)


def wanted(quiet: bool) -> bool:
    """Should a command show progress: stderr is a terminal and not --quiet."""
    return not quiet and sys.stderr.isatty()


@contextmanager
def shown(on: bool) -> Iterator[None]:
    """Within the block, bar() draws (on) or stays silent (not on)."""
    token = _ON.set(bool(on))
    try:
        yield
    finally:
        _ON.reset(token)


def enabled() -> bool:
    """Are bars drawn here (set by shown; off by default)?"""
    return _ON.get()


def bar(total: int, desc: str, *, initial: int = 0, on: bool | None = None) -> tqdm:
    """A bar over `total` runs on stderr, `initial` of them already done; drawn when `on` (None:
    as the enclosing shown() says)."""
    return tqdm(total=total, initial=initial, desc=desc, unit="run", file=sys.stderr,
                disable=not (enabled() if on is None else on))
