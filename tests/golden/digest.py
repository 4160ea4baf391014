"""Digests of every built-in scenario's `metrics.json` and `log.npz` on a short horizon.

The byte-identity contract: a refactoring must not change any output for the same seed. The
stored digests (`tests/golden/digests.json`) are regenerated only when a change of output is
intended, and the commit that regenerates them says why:

    .venv/bin/python -m tests.golden.digest --update
"""
from __future__ import annotations

import argparse
import hashlib
import json
import tempfile
from pathlib import Path

from testbed.environment import apply_defaults

DIGESTS = Path(__file__).with_name("digests.json")
DURATION_S = 4.0
FILES = ("metrics.json", "log.npz")


def compute() -> dict[str, dict[str, str]]:
    """{"NAME/MOTION": {file: sha256}} for every built-in scenario in both motion modes."""
    from testbed import scenario
    from testbed.runner import run

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in scenario.builtin_names():
            for motion in ("prescribed", "flown"):
                run_dir = Path(tmp) / f"{name}-{motion}"
                run(scenario.load(name, {}, motion=motion, duration=DURATION_S), run_dir, plots=False)
                out[f"{name}/{motion}"] = {f: hashlib.sha256((run_dir / f).read_bytes()).hexdigest() for f in FILES}
    return out


def main() -> None:
    apply_defaults()  # single-threaded BLAS as in the CLI and the tests: digests depend on it
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--update", action="store_true", help="rewrite the stored digests")
    args = parser.parse_args()
    digests = compute()
    if args.update:
        DIGESTS.write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n")
    print(json.dumps(digests, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()
