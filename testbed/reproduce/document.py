"""The report of one reproduction: DIR/report.md and a self-contained DIR/report.html.

Written by `testbed reproduce X --out DIR` after the reproduction's own files (claims.json,
table.md, plots/), from those files only:
1. how it was made: the exact command, the Monte Carlo seeds, the versions of the testbed and of its
   dependencies (python, numpy, scipy, mujoco, gtsam, matplotlib);
2. the claims: the paper's words and number beside ours, the criterion, the test that decided it
   (statistic, p-value or interval, n) and the verdict (from claims.json);
3. the figures (every PNG of DIR/plots: error curves with 3-sigma envelopes, RMSE against the PCRB
   where there is one, ...): linked in report.md, embedded as base64 PNG in report.html;
4. the reproduction's tables (table.md).
The HTML needs nothing but itself: styles inline, figures as data: URIs.
"""
from __future__ import annotations

import base64
import html
import json
import platform
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import testbed
from testbed import provenance
from testbed.report import format_test, markdown_table, verdict, write_markdown

DEPENDENCIES = ("numpy", "scipy", "mujoco", "gtsam", "matplotlib")
TITLES = {"phase": "Seed 003 (Pan, Yin, Xu 2023): carrier-phase relative navigation of formations",
          "visnav": "Seed 004 (Jin et al. 2017): vision-aided relative navigation with glint noise",
          "bandwidth": "Seed 000 (Zhao et al. 2020): bandwidth-limited distributed fusion",
          "coop": "Seed 001 (Chen et al. 2020): factor-graph cooperative navigation",
          "denied": "GNSS-denied cooperative flight (coop-denied): 18 UAVs through streets where GNSS fades"}
_IMAGE = re.compile(r"^!\[(?P<alt>[^\]]*)\]\((?P<src>[^)]+)\)$")


def versions() -> dict[str, str]:
    """{name: version} of python, the testbed and DEPENDENCIES ("not installed" when absent); every
    package is in the reproduction's provenance.json (testbed.provenance)."""
    installed = {name.lower(): v for name, v in provenance.packages().items()}
    return {"python": platform.python_version(), "testbed": testbed.__version__,
            **{name: installed.get(name) or "not installed" for name in DEPENDENCIES}}


def _seeds(doc: Mapping) -> list[str]:
    """Every seed entry of claims.json's context, as "key: value" lines."""
    return [f"{k}: {v[0]}..{v[-1]} ({len(v)} runs)" if isinstance(v, list) and len(v) > 2 else f"{k}: {v}"
            for k, v in doc.items() if "seed" in k]


def _claim_rows(claims: Sequence[Mapping]) -> list[list[str]]:
    rows = []
    for c in claims:
        ctx = ", ".join(str(v) for k, v in c.items() if k in ("mode", "reading"))
        t = c.get("test") or {}
        rows.append([f"{c['id']} [{ctx}]" if ctx else c["id"], c["claim"], c.get("paper_value", ""), c.get("summary", ""),
                     c["criterion"], format_test(t.get("name", ""), t.get("statistic"), t.get("p_value"),
                                                 t.get("interval"), t.get("n"), t.get("level")),
                     f"**{verdict(c['holds'])}**"])
    return rows


def markdown(out: Path, *, paper: str, command: str) -> list[str]:
    """The lines of report.md for the reproduction in `out` (module docstring)."""
    out = Path(out)
    doc = json.loads((out / "claims.json").read_text())
    claims = doc["claims"]
    lines = [f"# {TITLES.get(paper, paper)}: reproduction report", "",
             "## How this was made", "", "```", command, "```", ""]
    lines += [f"- {s}" for s in _seeds(doc)]
    lines += ["- versions: " + ", ".join(f"{k} {v}" for k, v in versions().items()), ""]
    held = sum(bool(c["holds"]) for c in claims)
    lines += ["## Claims", "", f"{held} of {len(claims)} claims hold. Each is decided by the test named beside it "
              "(statistic; p-value or confidence interval; n = Monte Carlo runs unless stated).", ""]
    lines += markdown_table(["claim", "paper", "paper's number", "ours", "criterion", "test", "verdict"],
                            _claim_rows(claims))
    figures = sorted((out / "plots").glob("*.png")) if (out / "plots").is_dir() else []
    lines += ["", "## Figures", ""]
    for f in figures:
        lines += [f"![{f.stem.replace('_', ' ')}]({f.relative_to(out).as_posix()})", ""]
    if not figures:
        lines += ["(no figures)", ""]
    if (out / "table.md").exists():
        lines += ["## Tables", ""]
        lines += ["#" + ln if ln.startswith("#") else ln for ln in (out / "table.md").read_text().splitlines()]
    return lines


# ------------------------------------------------------------------------------------ HTML

_STYLE = ("body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;line-height:1.4}"
          "table{border-collapse:collapse;font-size:0.85em;margin:1em 0}td,th{border:1px solid #bbb;"
          "padding:3px 6px;vertical-align:top}th{background:#eee}img{max-width:100%}"
          "pre{background:#f4f4f4;padding:0.6em;overflow-x:auto}figure{margin:1em 0}")


def _inline(text: str) -> str:
    """Escaped text with **bold** and `code`."""
    t = html.escape(text, quote=False)
    t = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", t)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", t)


def _cells(line: str) -> list[str]:
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]


def to_html(lines: Sequence[str], base: Path, title: str) -> str:
    """HTML of the Markdown subset report.md uses (headings, tables, lists, code blocks, images
    relative to `base`, embedded as base64 PNG, and paragraphs)."""
    body: list[str] = []
    i = 0
    while i < len(lines):
        ln = lines[i]
        if ln.startswith("```"):
            j = i + 1
            while j < len(lines) and not lines[j].startswith("```"):
                j += 1
            body.append("<pre>" + html.escape("\n".join(lines[i + 1:j])) + "</pre>")
            i = j + 1
            continue
        if ln.startswith("|"):
            j = i
            while j < len(lines) and lines[j].startswith("|"):
                j += 1
            head, rows = _cells(lines[i]), [_cells(r) for r in lines[i + 2:j]]
            body.append("<table><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr>"
                        + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in rows)
                        + "</table>")
            i = j
            continue
        if ln.startswith("- "):
            j = i
            while j < len(lines) and lines[j].startswith("- "):
                j += 1
            body.append("<ul>" + "".join(f"<li>{_inline(r[2:])}</li>" for r in lines[i:j]) + "</ul>")
            i = j
            continue
        m = _IMAGE.match(ln)
        if m:
            data = base64.b64encode((base / m["src"]).read_bytes()).decode("ascii")
            body.append(f'<figure><img alt="{html.escape(m["alt"])}" src="data:image/png;base64,{data}">'
                        f"<figcaption>{_inline(m['alt'])}</figcaption></figure>")
        elif ln.startswith("#"):
            level = min(len(ln) - len(ln.lstrip("#")), 6)
            body.append(f"<h{level}>{_inline(ln[level:].strip())}</h{level}>")
        elif ln.strip():
            body.append(f"<p>{_inline(ln)}</p>")
        i += 1
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def write_report(out: Path, *, paper: str, command: str) -> tuple[Path, Path]:
    """Write out/report.md and out/report.html; returns their paths."""
    out = Path(out)
    lines = markdown(out, paper=paper, command=command)
    md = write_markdown(out / "report.md", lines)
    page = out / "report.html"
    page.write_text(to_html(lines, out, TITLES.get(paper, paper)))
    return md, page
