"""What the example scripts share: the short-horizon switch and the output directory.

TESTBED_EXAMPLE_SHORT=1 (set by the test suite) runs every example on a horizon of seconds;
the first command-line argument, if any, is the output directory (default: examples-out/NAME).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: the examples only write PNG files

SHORT = os.environ.get("TESTBED_EXAMPLE_SHORT", "") not in ("", "0")


def out_dir(name: str) -> Path:
    """The example's output directory (created)."""
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("examples-out") / name
    path.mkdir(parents=True, exist_ok=True)
    return path
