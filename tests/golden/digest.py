"""Exact digests of every golden case's `metrics.json` and `log.npz`: the opt-in byte check.

On one machine, a refactoring that must not change any output should leave every byte equal. The
digests depend on the CPU's BLAS kernel (`tests/golden/values.py` says why), so the portable test
compares values (`tests/test_golden.py`); this check is for a refactor on the machine that stored
the digests (`tests/golden/digests.json`):

    .venv/bin/python -m tests.golden.digest --update   # before the refactor, on this machine
    .venv/bin/python -m tests.golden.digest --check    # after it: exit 1 and the files that differ
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

from testbed.environment import apply_defaults
from tests.golden.values import keys, scenario_of

DIGESTS = Path(__file__).with_name("digests.json")
FILES = ("metrics.json", "log.npz")


def compute() -> dict[str, dict[str, str]]:
    """{"NAME/MODE": {file: sha256}} for every golden case (tests.golden.values.keys)."""
    from testbed.runner import run

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for key in keys():
            run_dir = Path(tmp) / key.replace("/", "-")
            run(scenario_of(key), run_dir, plots=False)
            out[key] = {f: hashlib.sha256((run_dir / f).read_bytes()).hexdigest() for f in FILES}
    return out


def main() -> None:
    apply_defaults()  # single-threaded BLAS as in the CLI and the tests: digests depend on it
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--update", action="store_true", help="rewrite the stored digests")
    mode.add_argument("--check", action="store_true", help="compare with the stored digests; exit 1 on a difference")
    args = parser.parse_args()
    digests = compute()
    if args.update:
        DIGESTS.write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n")
    if args.check:
        stored = json.loads(DIGESTS.read_text())
        changed = sorted(f"{k}:{f}" for k in set(stored) | set(digests) for f in FILES
                         if stored.get(k, {}).get(f) != digests.get(k, {}).get(f))
        print("\n".join(changed) or "every digest equal")
        sys.exit(1 if changed else 0)
    if not args.update:
        print(json.dumps(digests, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()
