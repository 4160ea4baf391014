"""The golden numbers: every built-in scenario's outputs on a short horizon, compared by value.

A refactoring must not change any output for the same seed. Bytes cannot carry that contract
across machines: OpenBLAS picks its kernels by CPU, and the last bits of a matrix product depend on
the kernel (`OPENBLAS_CORETYPE=Haswell` and `SkylakeX` give different digests of the same run).
So the stored record (`tests/golden/values.json`) is the numbers themselves, compared with the
tolerances of `TOLERANCES`, measured across kernels (`docs/testing.md`, "Golden values"):

* every number of each run's `metrics.json` (flattened to `a.b[3].c` paths);
* the key arrays of `log.npz` (truth, reference, controls and every stream's values): each
  array's shape exactly, its column sums and sums of magnitudes, and up to `SAMPLE_ROWS` rows
  evenly spaced over the run (first and last included); wide arrays (a swarm's truth) by sums
  over groups of columns. A log array is compared normwise: each part against its largest
  magnitude, since its entries near zero carry no relative precision.

Regenerate only for an intended change of output, in a commit that says why:

    .venv/bin/python -m tests.golden.values --update

The exact bytes, for a refactor checked on one machine: `python -m tests.golden.digest --check`.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

from testbed.environment import apply_defaults

apply_defaults()  # before numpy loads (python -m tests.golden.values): single-threaded BLAS, as the tests run

import numpy as np  # noqa: E402

VALUES = Path(__file__).with_name("values.json")
DURATION_S = 4.0
MOTIONS = ("prescribed", "flown")
SAMPLE_ROWS = 12
COLUMN_GROUPS = 24
# log.npz arrays compared: the truth, the reference, the controls and each sensor stream's value
# (suffixes of "stream/field" keys). Bookkeeping arrays (indices, names, flags) are covered by
# the shapes and by the metrics.
LOG_KEYS = ("time", "ctrl", "qpos", "qvel")
LOG_PREFIXES = ("truth/", "reference/")
LOG_SUFFIXES = ("/value", "/clean", "/time", "/sigma", "/bias")

# The tolerance: |a - b| <= RTOL * max(|a|, |b|) + ATOL for a metric; a log array's part within
# RTOL of its largest magnitude (+ ATOL). Measured across OpenBLAS kernels (SkylakeX, Haswell,
# Haswell with numpy's AVX-512 loops off, Katmai) over DURATION_S, docs/testing.md ("Golden
# values"): open loop (the physics reads no BLAS; an estimator's numbers carry its rounding)
# at most 2.5e-10, closed loop (an estimate flown, so rounding reaches the physics) 2.1e-12.
RTOL = 1e-9
# A closed loop's rounding reaches the physics and grows with the flight: since rotor commands past
# their limits are allocated by priority (testbed/sim/control.py), uav2 and uav9 saturate during
# coop-denied's take-off and the 4-s flight moves by up to 1.13e-9 under Haswell (8.3e-10 in the
# log arrays; it was 2.1e-12 before). Closed-loop cases pass within CLOSED_LOOP_RTOL, about 9x
# the measured difference (docs/testing.md, "The tolerance, measured").
CLOSED_LOOP_RTOL = 1e-8
ATOL = 1e-12  # a metric that is zero up to rounding (an RMSE of a vehicle on its reference)

# A metric that counts the samples past a limit (the attitude samples whose own sd exceeds 0.1 rad:
# testbed.plugins.score's "unobserved", phase's "attitude_unobserved_fraction") moves by whole
# samples when a sample lies within rounding of the limit. Measured under Haswell against the
# SkylakeX values: one sample of 381 (0.0026) on coop-denied's closed loop and prescribed runs.
# Such a fraction passes within FRACTION_ATOL, four samples of the 4-s horizon's 381.
THRESHOLD_FRACTIONS = ("unobserved", "attitude_unobserved_fraction")
FRACTION_ATOL = 0.01

# closed-loop cases: reproduce denied's variants flown on an estimate ("coop-denied/VARIANT")
CLOSED_LOOP = ("coop", "coop_distributed")


def keys() -> list[str]:
    """Every golden case: each built-in in both motions, then the closed-loop variants."""
    from testbed.config import scenario

    return [f"{n}/{m}" for n in scenario.builtin_names() for m in MOTIONS] + [f"coop-denied/{v}" for v in CLOSED_LOOP]


def scenario_of(key: str):
    """The scenario of a golden case "NAME/MOTION" or "coop-denied/VARIANT"."""
    from testbed.config import scenario
    from testbed.reproduce.denied import variant

    name, mode = key.split("/")
    if mode in MOTIONS:
        return scenario.load(name, {}, motion=mode, duration=DURATION_S)
    return variant(scenario.load(name, {}, motion="flown", duration=DURATION_S), mode)


def loop_kind(sc) -> str:
    """'closed' where the flight feeds an estimate back into the controller, else 'open'."""
    return "closed" if sc.motion == "flown" and sc.control.feedback != "truth" else "open"


def flatten(value: object, path: str = "") -> dict[str, object]:
    """{"a.b[2]": leaf} for every leaf of nested dicts and lists (JSON's own types)."""
    if isinstance(value, dict):
        out: dict[str, object] = {}
        for k, v in value.items():
            out.update(flatten(v, f"{path}.{k}" if path else str(k)))
        return out
    if isinstance(value, list):
        out = {}
        for i, v in enumerate(value):
            out.update(flatten(v, f"{path}[{i}]"))
        return out
    return {path: value}


def _groups(flat: np.ndarray) -> np.ndarray:
    """(rows, cols) -> (rows, <= COLUMN_GROUPS): sums over contiguous groups of columns."""
    if flat.shape[1] <= COLUMN_GROUPS:
        return flat
    return np.add.reduceat(flat, np.linspace(0, flat.shape[1], COLUMN_GROUPS, endpoint=False).astype(int), axis=1)


def _log_summary(npz: Path) -> dict[str, dict[str, list]]:
    """{array: {"shape", "sum", "abs_sum", "rows"}} for the compared float arrays of a log: the
    shape; the sums and sums of magnitudes over rows (by column, or by group of columns where there
    are more than COLUMN_GROUPS); up to SAMPLE_ROWS rows evenly spaced over the run (likewise)."""
    out = {}
    with np.load(npz) as log:
        for k in sorted(log.files):
            if not (k in LOG_KEYS or k.startswith(LOG_PREFIXES) or k.endswith(LOG_SUFFIXES)):
                continue
            a = log[k]
            if a.dtype.kind != "f":
                continue
            flat = a.reshape(len(a), -1) if a.ndim else a.reshape(1, 1)
            rows = np.unique(np.linspace(0, len(flat) - 1, min(SAMPLE_ROWS, len(flat))).round().astype(int))
            out[k] = {
                "shape": list(a.shape),
                "sum": _groups(flat).sum(axis=0).tolist(),
                "abs_sum": _groups(np.abs(flat)).sum(axis=0).tolist(),
                "rows": _groups(flat[rows]).tolist() if len(flat) else [],
            }
    return out


def compute(names: list[str] | None = None) -> dict[str, dict]:
    """{"NAME/MODE": {"kind", "metrics": {path: leaf}, "log": {array: summary}}}."""
    from testbed.runner import run

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for key in names or keys():
            run_dir = Path(tmp) / key.replace("/", "-")
            sc = scenario_of(key)
            run(sc, run_dir, plots=False)
            out[key] = {
                "kind": loop_kind(sc),
                "metrics": flatten(json.loads((run_dir / "metrics.json").read_text())),
                "log": _log_summary(run_dir / "log.npz"),
            }
    return out


def _close(a: object, b: object, rtol: float, fraction: bool = False) -> bool:
    """Numbers within the tolerance rtol (fraction: a count of samples past a limit,
    FRACTION_ATOL); anything else (strings, flags, null) equal."""
    if isinstance(a, bool) or isinstance(b, bool) or not isinstance(a, (int, float)) or not isinstance(b, (int, float)):
        return a == b
    return abs(a - b) <= (FRACTION_ATOL if fraction else rtol * max(abs(a), abs(b)) + ATOL)


def _scale(values: list) -> float:
    return float(np.max(np.abs(np.asarray(values, float)), initial=0.0))


def _normwise(stored: list, now: list) -> float:
    """max |stored - now| / max |stored| (inf where the shapes differ; 0 for two zero arrays)."""
    a, b = np.asarray(stored, float), np.asarray(now, float)
    if a.shape != b.shape:
        return math.inf
    diff = float(np.max(np.abs(a - b), initial=0.0))
    return 0.0 if diff == 0 else diff / max(_scale(stored), _scale(now))


def differences(stored: dict, now: dict) -> list[str]:
    """Every leaf of `now` that is not within its tolerance of `stored`, one line each."""
    out = []
    if sorted(stored) != sorted(now):
        out.append(f"runs: stored {sorted(stored)} != now {sorted(now)}")
    for key in sorted(set(stored) & set(now)):
        rtol = CLOSED_LOOP_RTOL if stored[key]["kind"] == "closed" else RTOL
        sm, nm = stored[key]["metrics"], now[key]["metrics"]
        for path in sorted(set(sm) | set(nm)):
            if path not in sm or path not in nm:
                out.append(f"{key} metrics.json {path}: {'missing now' if path in sm else 'new'}")
            elif not _close(sm[path], nm[path], rtol, path.rsplit(".", 1)[-1] in THRESHOLD_FRACTIONS):
                out.append(f"{key} metrics.json {path}: stored {sm[path]!r}, now {nm[path]!r}")
        sl, nl = stored[key]["log"], now[key]["log"]
        for arr in sorted(set(sl) | set(nl)):
            if arr not in sl or arr not in nl:
                out.append(f"{key} log.npz {arr}: {'missing now' if arr in sl else 'new'}")
                continue
            if sl[arr]["shape"] != nl[arr]["shape"]:
                out.append(f"{key} log.npz {arr}: shape {sl[arr]['shape']} -> {nl[arr]['shape']}")
                continue
            for part in ("sum", "abs_sum", "rows"):
                worst = _normwise(sl[arr][part], nl[arr][part])
                if worst > rtol + ATOL / max(_scale(sl[arr][part]), 1e-300):
                    out.append(f"{key} log.npz {arr} {part}: largest difference {worst:.3g} of its largest magnitude")
    return out


def largest_relative(stored: dict, now: dict) -> dict[str, float]:
    """{"NAME/MOTION": the largest relative difference of any compared number} (measurement aid)."""
    out = {}
    for key in sorted(set(stored) & set(now)):
        worst = 0.0
        for path, a in stored[key]["metrics"].items():
            b = now[key]["metrics"].get(path)
            if isinstance(a, (int, float)) and not isinstance(a, bool) and isinstance(b, (int, float)) and abs(a - b) > ATOL:
                worst = max(worst, abs(a - b) / max(abs(a), abs(b)))
        for arr, s in stored[key]["log"].items():
            n = now[key]["log"].get(arr)
            if n is None or n["shape"] != s["shape"]:
                worst = math.inf
                continue
            for part in ("sum", "abs_sum", "rows"):
                worst = max(worst, _normwise(s[part], n[part]))
        out[key] = worst
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--update", action="store_true", help="rewrite the stored values")
    parser.add_argument("--save", metavar="FILE", help="write the values computed here to FILE")
    parser.add_argument("--against", metavar="FILE", help="print the largest relative difference per run to FILE's values")
    args = parser.parse_args()
    if args.against:
        other = json.loads(Path(args.against).read_text())
        now = compute(sorted(other))
        for key, worst in largest_relative(other, now).items():
            print(f"{key:32s} {other[key]['kind']:6s} {worst:.3g}")
        return
    now = compute()
    if args.save:
        Path(args.save).write_text(json.dumps(now, sort_keys=True) + "\n")
    if args.update:
        VALUES.write_text("{\n" + ",\n".join(f"{json.dumps(k)}: {json.dumps(now[k], sort_keys=True)}" for k in sorted(now)) + "\n}\n")
    if not (args.save or args.update):
        bad = differences(json.loads(VALUES.read_text()), now)
        print("\n".join(bad) or "all golden values within tolerance")
        sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
