"""Checks shared by the tests of the reproductions' tables (tests only)."""
from __future__ import annotations

import re

ANEES_CELL = re.compile(r"^\S+ \[(\S+, \S+|not decidable from one run)\] \(n_eff \S+\)$")  # report.fmt_anees
#: a list of ANEES means, each with its interval ("1e-12: 4.1 [2.3, 9.7], 1e-9: ..."; testbed.reproduce.phase's q
#: table), or "[n/a: fewer than 2 seeds]" where the seeds' spread cannot give one
_ENTRY = r"\S+: \S+ \[(\S+, \S+|n/a: fewer than 2 seeds)\]"
ANEES_LIST = re.compile(rf"^{_ENTRY}(, {_ENTRY})*$")
INTERVAL = re.compile(r"\[\S+, \S+\]")


def assert_every_anees_has_its_interval(markdown: str) -> int:
    """Every non-empty cell of a column whose header names an ANEES, in the markdown tables of
    `markdown`, reads "mean [lo, hi] (n_eff N)" or "mean [not decidable from one run] (n_eff N)"
    (docs/consistency.md), or is a list "value: mean [lo, hi], ...", unless the header gives the one
    interval of the whole column ("[lo, hi]"); returns how many cells were checked."""
    checked, head = 0, None
    for line in markdown.splitlines():
        if not line.startswith("|"):
            head = None
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if head is None:
            head = cells
        elif not set("".join(cells)) <= set("-: "):
            for h, c in zip(head, cells):
                if "ANEES" in h and c and not INTERVAL.search(h):
                    assert ANEES_CELL.match(c) or ANEES_LIST.match(c), f"ANEES without its interval: {h!r} = {c!r}"
                    checked += 1
    return checked
