"""testbed.outputs.report: claims, strict JSON, tables and the one number format."""
import csv
import json

import numpy as np
import pytest

from testbed.outputs.report import (
    NULL_SUFFIX, Claim, Undefined, claims_section, fmt, fmt_ci, fmt_pm, markdown_table, tally, write_claims,
    write_csv, write_json,
)


def _strict_load(path):
    """json.loads that fails on NaN / Infinity (which Python's json accepts by default)."""
    def refuse(token):
        raise ValueError(f"non-standard JSON constant {token}")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_json_is_strict_and_says_why_a_value_is_null(tmp_path):
    doc = {"mean": np.float64(1.5), "n": np.int64(3), "ok": np.bool_(True), "p": float("nan"),
           "worst": [0.1, float("inf"), np.nan], "t": Undefined("1 run: no paired test"),
           "nested": {"se": np.nan, "arr": np.array([1.0, 2.0])}}
    back = _strict_load(write_json(tmp_path / "x.json", doc))
    assert back["mean"] == 1.5 and back["n"] == 3 and back["ok"] is True
    assert back["p"] is None and "undefined" in back["p" + NULL_SUFFIX]
    assert back["worst"] == [0.1, None, None]
    assert "[1]" in back["worst" + NULL_SUFFIX] and "[2]" in back["worst" + NULL_SUFFIX]
    assert back["t"] is None and back["t" + NULL_SUFFIX] == "1 run: no paired test"
    assert back["nested"]["se"] is None and "se" + NULL_SUFFIX in back["nested"]
    assert back["nested"]["arr"] == [1.0, 2.0]
    assert "mean" + NULL_SUFFIX not in back


def test_json_refuses_what_it_cannot_represent(tmp_path):
    with pytest.raises(TypeError, match="not JSON-able"):
        write_json(tmp_path / "x.json", {"a": object()})


def test_claim_needs_a_bool_verdict_and_round_trips(tmp_path):
    with pytest.raises(TypeError, match="bool"):
        Claim(id="c", text="t", criterion="k", holds=np.bool_(True), numbers={})
    c = Claim(id="c", text="it holds", criterion="x < 1", holds=True, numbers={"x": np.float64(0.5)},
              summary="x = 0.5", context={"mode": "paper"})
    doc = write_claims(tmp_path / "claims.json", [c], paper="000", runs=2)
    assert _strict_load(tmp_path / "claims.json") == doc
    assert doc["paper"] == "000" and doc["runs"] == 2
    assert doc["claims"] == [{"id": "c", "mode": "paper", "claim": "it holds", "criterion": "x < 1", "holds": True,
                              "numbers": {"x": 0.5}, "summary": "x = 0.5"}]


def test_verdict_table_counts_and_labels_claims():
    claims = [Claim(id="a", text="A", criterion="ka", holds=True, numbers={}),
              Claim(id="b", text="B", criterion="kb", holds=False, numbers={}, context={"reading": "r1"})]
    lines = claims_section(claims)
    assert "1 of 2 claims hold." in lines
    assert any(ln.startswith("| a | A |") and "**holds**" in ln for ln in lines)
    assert any(ln.startswith("| b [r1] | B |") and "**does not hold**" in ln for ln in lines)


def test_a_claim_whose_condition_did_not_occur_is_counted_apart(tmp_path):
    claims = [Claim(id="a", text="A", criterion="ka", holds=True, numbers={}),
              Claim(id="b", text="B", criterion="kb", holds=False, numbers={}, not_decidable="no link was dropped"),
              Claim(id="c", text="C", criterion="kc", holds=False, numbers={})]
    lines = claims_section(claims)
    assert "1 of 2 claims hold, 1 not decidable." in lines
    assert any(ln.startswith("| b | B |") and "**not decidable: no link was dropped**" in ln for ln in lines)
    doc = write_claims(tmp_path / "claims.json", claims)
    assert [c["holds"] for c in doc["claims"]] == [True, None, False]
    assert doc["claims"][1]["not_decidable"] == "no link was dropped" and "not_decidable" not in doc["claims"][0]
    assert tally(c["holds"] for c in doc["claims"]) == "1 of 2 claims hold, 1 not decidable"
    assert tally([True, False]) == "1 of 2 claims hold"


def test_numbers_for_people_are_formatted_in_one_way():
    assert fmt(0.0123456) == "0.01235" and fmt(np.float32(2.0)) == "2" and fmt(12345678.0) == "1.235e+07"
    assert fmt(float("nan")) == "n/a" and fmt(None) == "n/a" and fmt(Undefined("x")) == "n/a"
    assert fmt(np.int64(7)) == "7" and fmt(True) == "True"
    assert fmt([1.0, 2.5]) == "[1, 2.5]" and fmt([1.0] * 10) == "[10 values, mean 1]"
    assert fmt_pm(1.23456, 0.012345) == "1.235 ± 0.012"
    assert fmt_ci(1.0, 0.5, 1.5) == "1 [0.5, 1.5]"
    md = markdown_table(["a", "b"], [["x|y", 3.14159265], [1, None]])
    assert md == ["| a | b |", "|---|---|", "| x\\|y | 3.142 |", "| 1 | n/a |"]


def test_csv_keeps_full_precision(tmp_path):
    x = 0.1 + 0.2
    write_csv(tmp_path / "t.csv", ["name", "x", "flag", "missing"], [["r", np.float64(x), np.bool_(True), None]])
    rows = list(csv.reader(open(tmp_path / "t.csv")))
    assert rows[0] == ["name", "x", "flag", "missing"]
    assert float(rows[1][1]) == x and rows[1][2:] == ["1", ""]
