"""Process environment the testbed wants before numpy and mujoco load.

`import testbed` changes nothing; the command line (testbed.cli.main) and the sweep's worker
processes call `apply_defaults()` first. Variables the user set are kept.
"""
from __future__ import annotations

import os

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
