"""A refactoring must not change any output: every golden case's numbers match the stored values
within the tolerance measured across BLAS kernels (tests/golden/values.py, docs/testing.md)."""
import copy
import json

import pytest

from tests.golden.values import CLOSED_LOOP_RTOL, RTOL, THRESHOLD_FRACTIONS, VALUES, compute, differences, keys

STORED = json.loads(VALUES.read_text())


def test_the_stored_cases_are_the_golden_cases():
    assert sorted(STORED) == sorted(keys()), "the set of golden cases changed: regenerate tests/golden/values.json"


@pytest.mark.parametrize("key", sorted(STORED))
def test_outputs_match_the_stored_values(key):
    bad = differences({key: STORED[key]}, compute([key]))
    assert not bad, "outputs changed (regenerate only for an intended change):\n" + "\n".join(bad[:20])


def _some_number(case: dict) -> str:
    return next(p for p, v in sorted(case["metrics"].items())
                if isinstance(v, float) and abs(v) > 1e-3 and p.rsplit(".", 1)[-1] not in THRESHOLD_FRACTIONS)


@pytest.mark.parametrize("key, rtol", [("coop-fg/prescribed", RTOL), ("coop-denied/coop", CLOSED_LOOP_RTOL)])
def test_the_comparison_fails_beyond_the_tolerance_and_holds_within_it(key, rtol):
    path = _some_number(STORED[key])
    for factor, flagged in ((10 * rtol, True), (0.1 * rtol, False)):
        now = copy.deepcopy({key: STORED[key]})
        now[key]["metrics"][path] *= 1 + factor
        assert bool(differences({key: STORED[key]}, now)) is flagged, (factor, path)
        now = copy.deepcopy({key: STORED[key]})
        rows = now[key]["log"]["truth/pos"]["rows"]
        rows[-1][0] += factor * max(abs(x) for r in rows for x in r)
        assert bool(differences({key: STORED[key]}, now)) is flagged, (factor, "truth/pos")
    now = copy.deepcopy({key: STORED[key]})
    now[key]["metrics"]["scenario"] = "other"
    name = STORED[key]["metrics"]["scenario"]
    assert differences({key: STORED[key]}, now) == [f"{key} metrics.json scenario: stored {name!r}, now 'other'"]
