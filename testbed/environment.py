"""Process environment the testbed wants before numpy and mujoco load.

`import testbed` changes nothing; the command line (testbed.cli.main) and the sweep's worker
processes call `apply_defaults()` first. Variables the user set are kept. `stderr_to` keeps what
C/C++ libraries and child processes write to the terminal (ffmpeg, Ray's core) off it.
"""
from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from typing import BinaryIO, Iterator

DEFAULTS = {
    # headless rendering; mujoco reads it when first imported
    "MUJOCO_GL": "egl",
    # small dense linear algebra (90 x 90 filter solves) is 10x slower with threaded BLAS on a
    # busy machine; parallelism comes from worker processes (testbed sweep) instead. BLAS reads
    # these when numpy loads.
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}


def apply_defaults() -> None:
    """Set every DEFAULTS variable the environment does not set yet (call before numpy loads)."""
    for name, value in DEFAULTS.items():
        os.environ.setdefault(name, value)


@contextmanager
def stderr_to(file: BinaryIO) -> Iterator[None]:
    """Point the process's file descriptor 2 at `file` (open, binary) while inside: what C/C++
    libraries write there, and the stderr of child processes started inside (they keep it), goes
    to `file` instead of the terminal. Restored on exit."""
    sys.stderr.flush()
    saved = os.dup(2)
    os.dup2(file.fileno(), 2)
    try:
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


def written(file: BinaryIO) -> str:
    """Everything written to `file` (a stderr_to target) so far, as text."""
    file.seek(0)
    return file.read().decode(errors="replace")


def last_line(text: str) -> str:
    """The last non-empty line of `text` (stripped), else ''."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else ""
