"""Property-based fuzz test: bad input never crashes the command line.

Each example takes a built-in scenario (every default written out), mutates it (values replaced by
NaN, +-inf, 0, negatives, huge numbers, wrong types, strings; keys deleted, renamed or added;
lists emptied or lengthened), writes it as a TOML file and runs `testbed run FILE --out OUT
--duration 0.3` in-process. The outcome must be one of
- exit 0 with a complete run directory whose metrics.json is strict JSON (no NaN or Infinity);
- exit 2 with exactly one stderr line `testbed: error: ...` and nothing written;
never a traceback, a hang (SIGALRM after TIME_LIMIT_S) or a file outside OUT (the working
directory, a fresh temporary one, must hold only the scenario and OUT; no MUJOCO_LOG.TXT).

Seeded (derandomize) with a fixed number of examples that fits CI; TESTBED_FUZZ=slow selects the
`slow` profile with many more. A few fixed cases follow: two as subprocesses of `python -m testbed`
(an exit 0 and an exit 2), the others through main() in-process.
"""
from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from testbed.config import scenario
from testbed.cli import main
from testbed.config import to_dict

DURATION = "0.3"  # s of simulated time per example
TIME_LIMIT_S = 120  # per example (wall clock, on a shared machine): a hang fails the test
RUN_FILES = ("scenario.toml", "scene.xml", "log.npz", "metrics.json")

settings.register_profile("ci", max_examples=80, derandomize=True, database=None, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.register_profile("slow", max_examples=600, derandomize=True, database=None, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
PROFILE = settings.get_profile("slow" if os.environ.get("TESTBED_FUZZ") == "slow" else "ci")

NAMES = scenario.builtin_names()
TABLES = {name: to_dict(scenario.load(name)) for name in NAMES}
BAD_VALUES = [math.nan, math.inf, -math.inf, 0, 0.0, -1, -1.0, -1e300, 1e300, 10**30, 5e-324, 1e6, -1e6,
              "x", "", True, [], [1.0], {}, {"a": 1}, [[0.0, 0.0, 0.0]]]


def _paths(node: object, prefix: tuple = ()) -> list[tuple]:
    """Every key path of a TOML table (tables, lists and leaves), as tuples of keys and indices."""
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, prefix + (i,))
    return out


def _parent(table: dict, path: tuple) -> object:
    node: object = table
    for k in path[:-1]:
        node = node[k]  # type: ignore[index]
    return node


def _mutate(table: dict, data: st.DataObject) -> None:
    """One mutation of `table` in place, drawn from `data`."""
    path = data.draw(st.sampled_from(_paths(table)), label="path")
    parent, key = _parent(table, path), path[-1]
    value = parent[key]  # type: ignore[index]
    actions = ["replace", "replace", "replace"]
    actions += ["delete", "rename", "add"] if isinstance(parent, dict) else ["delete", "duplicate"]
    actions += ["empty", "lengthen"] if isinstance(value, list) else []
    action = data.draw(st.sampled_from(actions), label="action")
    if action == "replace":
        parent[key] = copy.deepcopy(data.draw(st.sampled_from(BAD_VALUES), label="value"))  # type: ignore[index]
    elif action == "delete":
        del parent[key]  # type: ignore[arg-type]
    elif action == "rename":
        parent[f"{key}_x"] = parent.pop(key)  # type: ignore[union-attr]
    elif action == "add":
        parent["bogus_key"] = 1  # type: ignore[index]
    elif action == "duplicate":
        parent.insert(key, value)  # type: ignore[union-attr]
    elif action == "empty":
        value.clear()
    else:  # lengthen
        value.extend([value[-1] if value else 0.0] * data.draw(st.sampled_from([1, 5]), label="extra"))


class _Timeout(Exception):
    pass


def _alarm(signum, frame):  # noqa: ARG001 - signal handler signature
    raise _Timeout(f"example exceeded {TIME_LIMIT_S} s")


def run_cli(argv: list[str], cwd: Path) -> tuple[int, str]:
    """testbed.cli.main(argv) in `cwd` under a time limit: (exit code, stderr)."""
    err = io.StringIO()
    here = os.getcwd()
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(TIME_LIMIT_S)
    try:
        os.chdir(cwd)
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
        os.chdir(here)
    return code, err.getvalue()


def _strict(text: str) -> object:
    def refuse(c: str) -> None:
        raise ValueError(f"metrics.json is not strict JSON: {c}")
    return json.loads(text, parse_constant=refuse)


def check_outcome(code: int, err: str, cwd: Path, inputs: set[str], out: Path) -> None:
    """The contract: exit 0 and a complete run, or exit 2, one line and nothing written."""
    assert "Traceback" not in err, err
    assert code in (0, 2), f"exit {code}: {err}"
    left = set(os.listdir(cwd)) - inputs
    if code == 0:
        assert left == {out.name}, f"files outside --out: {sorted(left - {out.name})}"
        assert all((out / f).is_file() for f in RUN_FILES), sorted(os.listdir(out))
        _strict((out / "metrics.json").read_text())
    else:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("testbed: error: "), err
        assert not left, f"left behind after exit 2: {sorted(left)}"


@settings(PROFILE)
@given(name=st.sampled_from(NAMES), flown=st.booleans(), data=st.data())
def test_mutated_builtin_scenarios_exit_0_complete_or_2_in_one_line(name, flown, data):
    table = copy.deepcopy(TABLES[name])
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        _mutate(table, data)
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp)
        try:
            (cwd / "fuzz.toml").write_text(tomli_w.dumps(table))
        except (TypeError, ValueError):  # not representable in TOML (e.g. a table in a mixed list)
            return
        argv = ["run", "./fuzz.toml", "--out", "out", "--duration", DURATION] + (["--motion", "flown"] if flown else [])
        code, err = run_cli(argv, cwd)
        check_outcome(code, err, cwd, {"fuzz.toml"}, cwd / "out")


# A handful of fixed cases: the exit code and stderr a user sees. One success and one refusal go
# through a real process (`python -m testbed`); the other refusals through the same main() in this
# process (a new interpreter per case: 0.2-3.4 s wall each under load, most of it start-up and imports).
SUBPROCESS_CASES = [
    (["run", "bandwidth", "--out", "out", "--duration", "0.2"], 0),  # ~3 s of CPU (visnav, 15 figures: ~7 s)
    (["run", "./bad.toml", "--out", "out"], 2),
]
IN_PROCESS_CASES = [
    ["run", "visnav", "--out", "out", "--set", "control.kv=nan", "--motion", "flown"],
    ["run", "visnav", "--out", "out", "--duration", "inf"],
    ["render", "nowhere", "--fps", "0"],
]


@pytest.mark.parametrize("argv, expected", SUBPROCESS_CASES, ids=[" ".join(c[0][:4]) for c in SUBPROCESS_CASES])
def test_subprocess_exit_codes_and_one_line(argv, expected, tmp_path):
    (tmp_path / "bad.toml").write_bytes(b'name = "caf\xe9"\n')
    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": str(root)}
    p = subprocess.run([sys.executable, "-m", "testbed", *argv], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == expected, p.stderr
    check_outcome(p.returncode, p.stderr if expected == 2 else "", tmp_path, {"bad.toml"}, tmp_path / "out")


@pytest.mark.parametrize("argv", IN_PROCESS_CASES, ids=[" ".join(c[:4]) for c in IN_PROCESS_CASES])
def test_fixed_bad_cases_exit_2_in_one_line(argv, tmp_path):
    code, err = run_cli(argv, tmp_path)
    assert code == 2, err
    check_outcome(code, err, tmp_path, set(), tmp_path / "out")
