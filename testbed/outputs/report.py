"""Reports for people and programs: claims and verdicts, tables, strict JSON; numbers formatted once.

Every reproduction (`testbed.reproduce.<paper>`) states the paper's claims as `Claim`s and writes
its files through this module:
- `table.md`: Markdown, tables built by `markdown_table` and the verdicts by `claims_section`;
- `table.csv`: every number at full precision (`write_csv`);
- `claims.json`: strict JSON (`write_claims` / `write_json`): no bare NaN or Infinity; a value
  that cannot exist is `null`, with the reason beside it under `<key>_null_reason`.

Numbers for people are formatted here and only here: `fmt` (4 significant digits), `fmt_pm`
(mean ± spread), `fmt_ci` (mean [lo, hi]). CSV and JSON keep full precision (shortest repr that
reads back to the same float).
"""
from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from testbed import outdir

SIG = 4  # significant digits of a value shown to a person
SIG_SPREAD = 2  # significant digits of a spread (std, interval half-width)
NULL_SUFFIX = "_null_reason"
NAN_REASON = "undefined for these data (e.g. a statistic of fewer than 2 runs)"


# ------------------------------------------------------------------------------- formatting


def fmt(v: object, sig: int = SIG) -> str:
    """A number (or a short list of them) for a person: `sig` significant digits; long numeric
    lists summarized by their mean; None and undefined values as "n/a"."""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.{sig}g}" if math.isfinite(v) else ("n/a" if math.isnan(v) else str(float(v)))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if v is None or isinstance(v, Undefined):
        return "n/a"
    if isinstance(v, (list, tuple)) and len(v) <= 4:
        return "[" + ", ".join(fmt(x, sig) for x in v) + "]"
    if isinstance(v, (list, tuple)) and v and all(isinstance(x, (int, float)) for x in v):
        return f"[{len(v)} values, mean {fmt(sum(v) / len(v), sig)}]"
    return str(v)


def fmt_pm(mean: float, spread: float) -> str:
    """"mean ± spread" (spread: a standard deviation or an interval half-width)."""
    return f"{fmt(mean)} ± {fmt(spread, SIG_SPREAD)}"


def fmt_ci(mean: float, lo: float, hi: float) -> str:
    """"mean [lo, hi]" of a confidence interval."""
    return f"{fmt(mean)} [{fmt(lo)}, {fmt(hi)}]"


def fmt_anees(keys: dict, key: str = "anees") -> str:
    """"ANEES [lo, hi] (n_eff N)" from the keys testbed.scoring.metrics.anees_keys writes ("" without KEY);
    "ANEES [not decidable from one run] (n_eff N)" where the interval is null."""
    if keys.get(key) is None:
        return ""
    interval = next(v for k, v in keys.items() if k.startswith(f"{key}_interval_") and k[-1].isdigit())
    n_eff = keys.get(key.replace("anees", "n_eff"))
    tail = f" (n_eff {fmt(n_eff, 3)})" if n_eff is not None else ""
    if interval is None:
        return f"{fmt(keys[key])} [not decidable from one run]{tail}"
    return f"{fmt_ci(keys[key], *interval)}{tail}"


def fmt_list(values: Iterable[float], sep: str = ", ") -> str:
    """Every value of a sequence, formatted and joined (no summarizing)."""
    return sep.join(fmt(v) for v in values)


def verdict(holds: bool | None, not_decidable: str = "") -> str:
    """A claim's verdict in words; not_decidable: why the runs cannot decide it (then holds is None
    or ignored)."""
    if not_decidable:
        return f"not decidable: {not_decidable}"
    return "holds" if holds else "does not hold"


def tally(verdicts: Iterable[bool | None]) -> str:
    """"H of D claims hold" over the decided claims (True / False), the undecidable ones (None)
    counted apart: "H of D claims hold, U not decidable"."""
    v = list(verdicts)
    undecided = sum(x is None for x in v)
    line = f"{sum(x is True for x in v)} of {len(v) - undecided} claims hold"
    return line + (f", {undecided} not decidable" if undecided else "")


# ------------------------------------------------------------------------------- claims


@dataclass(frozen=True, slots=True)
class Undefined:
    """A number that cannot exist for these data (a t statistic of one run, a ratio over zero):
    written as JSON null with `reason` beside it, shown to people as "n/a"."""

    reason: str


@dataclass(frozen=True, kw_only=True, slots=True)
class Claim:
    """One claim of a paper, decided.

    id: stable key (unique within a reproduction, with `context`); text: the claim as the paper
    states it; criterion: how it is decided (test, threshold, sample), fixed before the runs;
    holds: the verdict; numbers: what it was judged on (JSON-able; numpy values, `Undefined` and
    non-finite floats are converted by `write_json`); not_decidable: when set, the reason the runs
    cannot decide the claim (its condition never occurred in them: no vehicle lost its fix, no link
    was dropped, ...): the claim neither holds nor fails, is written with "holds": null and
    "not_decidable": the reason, and counted apart (`tally`); holds is then False and means
    nothing; summary: the decisive numbers in one line,
    for the verdict table; note: a remark for the reader; context: keys that locate the claim
    (e.g. {"mode": "paper", "reading": "a_dt1"}).

    Verdict fields (every claim decided by a stated test, testbed.scoring.stats), shown on the verdict line:
    test: the test's name (e.g. "Wilcoxon signed-rank (less)", "Clopper-Pearson (upper)", or
    "deterministic comparison" when nothing is sampled); statistic; p_value (None when the test
    gives an interval only); interval: (lo, hi) at `level`; n: the sample size (Monte Carlo runs);
    level: confidence level of the interval or 1 - alpha of the decision; paper_value: the paper's
    own number or words for the quantity, shown beside ours (`summary`).
    """

    id: str
    text: str
    criterion: str
    holds: bool
    numbers: Mapping[str, object]
    summary: str = ""
    note: str = ""
    context: Mapping[str, str] = field(default_factory=dict)
    test: str = ""
    statistic: float | None = None
    p_value: float | None = None
    interval: tuple[float, float] | None = None
    n: int | None = None
    level: float | None = None
    paper_value: str = ""
    not_decidable: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.holds, bool):
            raise TypeError(f"Claim {self.id!r}: holds must be a bool, got {type(self.holds).__name__}")

    def to_json(self) -> dict:
        """{"id", <context keys>, "claim", "criterion", "holds"[, "not_decidable"], "numbers"[, "summary"][, "note"]}."""
        out = {"id": self.id, **self.context, "claim": self.text, "criterion": self.criterion,
               "holds": None if self.not_decidable else self.holds, "numbers": dict(self.numbers)}
        if self.not_decidable:
            out["not_decidable"] = self.not_decidable
        if self.summary:
            out["summary"] = self.summary
        if self.note:
            out["note"] = self.note
        if self.test:
            out["test"] = {"name": self.test, "statistic": self.statistic, "p_value": self.p_value,
                           "interval": list(self.interval) if self.interval is not None else None,
                           "n": self.n, "level": self.level}
        if self.paper_value:
            out["paper_value"] = self.paper_value
        return out

    def test_line(self) -> str:
        """The verdict's test in one line (`format_test`)."""
        return format_test(self.test, self.statistic, self.p_value, self.interval, self.n, self.level)

    def label(self) -> str:
        """The claim's name in a table: id, then its context in brackets."""
        ctx = ", ".join(str(v) for v in self.context.values())
        return f"{self.id} [{ctx}]" if ctx else self.id


def format_test(name: str, statistic: float | None = None, p_value: float | None = None,
                interval: Sequence[float] | None = None, n: int | None = None, level: float | None = None) -> str:
    """A claim's test in one line: name; statistic; p-value; interval at its level; n ("" if no test)."""
    if not name:
        return ""
    parts = [name]
    if statistic is not None:
        parts.append(f"statistic {fmt(statistic)}")
    if p_value is not None:
        parts.append(f"p = {fmt(p_value, 3)}")
    if interval is not None:
        lvl = f"{fmt(100 * level, 3)} % " if level is not None else ""
        lo, hi = (fmt(x) if x is not None else e for x, e in zip(interval, ("-inf", "inf")))  # JSON: inf read back as null
        parts.append(f"{lvl}interval [{lo}, {hi}]")
    if n is not None:
        parts.append(f"n = {n}")
    return "; ".join(parts)


def claims_section(claims: Sequence[Claim], heading: str = "## Claims") -> list[str]:
    """Markdown lines: the verdict table (claim, the paper's words and number, ours, criterion,
    test with statistic, p-value or interval and n, verdict)."""
    rows = [[c.label(), c.text, c.paper_value, c.summary, c.criterion, c.test_line(),
             f"**{verdict(c.holds, c.not_decidable)}**"] for c in claims]
    return [heading, "", tally(None if c.not_decidable else c.holds for c in claims) + ".", "",
            *markdown_table(["claim", "paper", "paper's number", "ours", "criterion", "test", "verdict"], rows)]


# ------------------------------------------------------------------------------- tables


def markdown_table(columns: Sequence[str], rows: Iterable[Sequence[object]]) -> list[str]:
    """Markdown lines of a table; cells that are not strings are formatted with `fmt`."""

    def cell(v: object) -> str:
        return (v if isinstance(v, str) else fmt(v)).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(v) for v in r) + " |" for r in rows]
    return lines


def csv_cell(v: object) -> object:
    """A CSV cell at full precision: floats as their shortest exact repr, bools as 0/1, None empty."""
    if v is None or isinstance(v, Undefined):
        return ""
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, np.integer):
        return int(v)
    return v


def interval_cells(v: Sequence[float] | None) -> list:
    """The two CSV cells [lo, hi] of an interval; [None, None] (empty cells) for a null one (an
    interval not decidable, docs/consistency.md)."""
    return list(v) if v is not None else [None, None]


def write_csv(path: Path, columns: Sequence[str], rows: Iterable[Sequence[object]]) -> Path:
    """Write a table as CSV (header row, then one row per entry, cells by `csv_cell`)."""
    path = Path(path)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(columns)
        w.writerows([csv_cell(v) for v in r] for r in rows)
    return path


def write_markdown(path: Path, lines: Iterable[str]) -> Path:
    path = Path(path)
    path.write_text("\n".join(lines).rstrip("\n") + "\n")
    return path


# ------------------------------------------------------------------------------- strict JSON


def _bad(x: float) -> str | None:
    return None if math.isfinite(x) else (NAN_REASON if math.isnan(x) else f"{x} (no finite value: the open end of a one-sided interval, or a quantity that diverged)")


def _plain(v: object) -> tuple[object, str | None]:
    """(JSON-able value, reason if v or anything inside a list of it cannot exist)."""
    if isinstance(v, Claim):
        return jsonable(v.to_json()), None
    if isinstance(v, Mapping):
        return jsonable(v), None
    if isinstance(v, Undefined):
        return None, v.reason
    if isinstance(v, (bool, np.bool_)):
        return bool(v), None
    if isinstance(v, (int, np.integer)):
        return int(v), None
    if isinstance(v, (float, np.floating)):
        reason = _bad(float(v))
        return (None, reason) if reason else (float(v), None)
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, (list, tuple)):
        items = [_plain(x) for x in v]
        bad = [f"[{i}]: {r}" for i, (_, r) in enumerate(items) if r]
        return [x for x, _ in items], ("; ".join(bad) if bad else None)
    if isinstance(v, Path):
        return str(v), None
    if v is None or isinstance(v, str):
        return v, None
    raise TypeError(f"not JSON-able: {type(v).__name__}")


def jsonable(obj: Mapping) -> dict:
    """A plain dict for strict JSON: numpy to Python, Claims to dicts, and every value that cannot
    exist (Undefined, NaN, +-inf, also inside lists) to null with `<key>_null_reason` beside it."""
    out: dict = {}
    for k, v in obj.items():
        out[str(k)], reason = _plain(v)
        if reason:
            out[f"{k}{NULL_SUFFIX}"] = reason
    return out


def write_json(path: Path, obj: Mapping) -> Path:
    """Strict JSON of `jsonable(obj)` through the one JSON writer (outdir.write_json)."""
    path = Path(path)
    outdir.write_json(path, jsonable(obj))
    return path


def write_claims(path: Path, claims: Sequence[Claim], **context: object) -> dict:
    """claims.json: {<context: paper, runs, seeds, ...>, "claims": [...]}; returns what was written
    (as it reads back)."""
    doc = jsonable({**context, "claims": list(claims)})
    write_json(path, doc)
    return doc
