"""The report of one reproduction: DIR/report.md and a self-contained DIR/report.html.

Written by `testbed reproduce X --out DIR` after the reproduction's own files (claims.json,
table.md, plots/), from those files only:
1. how it was made: the exact command, the Monte Carlo seeds, the versions of the testbed and of its
   dependencies (python, numpy, scipy, mujoco, gtsam, matplotlib);
2. the claims: the paper's words and number beside ours, the criterion, the test that decided it
   (statistic, p-value or interval, n) and the verdict (from claims.json);
3. the figures (every PNG of DIR/plots: error curves with 3-sigma envelopes, RMSE against the PCRB
   where there is one, ...): linked in report.md, embedded as base64 PNG in report.html;
4. the reproduction's tables (table.md);
5. the 3-D recordings (`testbed view`) found under DIR, linked.
The HTML needs nothing but itself: styles and script inline, figures as data: URIs, no request
leaves the file. Its figures are interactive: the wheel zooms about the cursor, a drag pans, a
double click resets, and the data values under the cursor are shown (each PNG's own map from
pixels to data, testbed.outputs.plots.axes_map). Hand-written script, no library: the page opens offline.
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
from testbed.outputs.plots import read_axes_map
from testbed.outputs.report import format_test, markdown_table, tally, verdict, write_markdown

DEPENDENCIES = ("numpy", "scipy", "mujoco", "gtsam", "matplotlib")
TITLES = {"phase": "Seed 003 (Pan, Yin, Xu 2023): carrier-phase relative navigation of formations",
          "visnav": "Seed 004 (Jin et al. 2017): vision-aided relative navigation with glint noise",
          "bandwidth": "Seed 000 (Zhao et al. 2020): bandwidth-limited distributed fusion",
          "coop": "Seed 001 (Chen et al. 2020): factor-graph cooperative navigation",
          "denied": "GNSS-denied cooperative flight (coop-denied, 18 UAVs through streets where GNSS fades)"}
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
                     f"**{verdict(c['holds'], c.get('not_decidable', ''))}**"])
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
    lines += ["## Claims", "", f"{tally(c['holds'] for c in claims)}. Each is decided by the test named beside it "
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
    recordings = sorted(out.rglob("*.rrd"))
    if recordings:
        lines += ["", "## 3-D recordings", "", "Open one in the Rerun viewer: `rerun FILE`.", ""]
        lines += [f"- [{f.relative_to(out).as_posix()}]({f.relative_to(out).as_posix()})" for f in recordings]
    return lines


# ------------------------------------------------------------------------------------ HTML

_STYLE = ("body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;line-height:1.4}"
          "table{border-collapse:collapse;font-size:0.85em;margin:1em 0}td,th{border:1px solid #bbb;"
          "padding:3px 6px;vertical-align:top}th{background:#eee}img{max-width:100%}"
          "pre{background:#f4f4f4;padding:0.6em;overflow-x:auto}figure{margin:1em 0}"
          ".plot{position:relative;overflow:hidden;display:inline-block;max-width:100%;cursor:crosshair}"
          ".plot img{display:block;transform-origin:0 0}.tip{position:absolute;display:none;pointer-events:none;"
          "background:#fffe;border:1px solid #888;padding:1px 4px;font-size:0.8em;white-space:nowrap}")
# Zoom, pan and the values under the cursor for every div.plot (its data-axes: plots.axes_map);
# body's data-plots counts the figures it made interactive (tests read it).
_SCRIPT = """
(function () {
  function value(lim, scale, t) {
    return scale === "log" ? lim[0] * Math.pow(lim[1] / lim[0], t) : lim[0] + t * (lim[1] - lim[0]);
  }
  function fmt(v) { return Math.abs(v) >= 1e4 || (v !== 0 && Math.abs(v) < 1e-3) ? v.toExponential(3) : v.toPrecision(4); }
  var boxes = document.querySelectorAll("div.plot");
  boxes.forEach(function (box) {
    var img = box.querySelector("img"), tip = box.querySelector(".tip");
    var axes = JSON.parse(box.dataset.axes), s = 1, x = 0, y = 0, drag = null;
    function show() {
      var w = box.clientWidth, h = box.clientHeight;
      x = Math.min(0, Math.max(w - s * w, x)); y = Math.min(0, Math.max(h - s * h, y));
      img.style.transform = "translate(" + x + "px," + y + "px) scale(" + s + ")";
    }
    function readout(e) {
      var r = img.getBoundingClientRect(), fx = (e.clientX - r.left) / r.width, fy = (e.clientY - r.top) / r.height;
      var a = axes.filter(function (a) { return fx >= a.box[0] && fx <= a.box[2] && fy >= a.box[1] && fy <= a.box[3]; })[0];
      if (!a) { tip.style.display = "none"; return; }
      var xv = value(a.xlim, a.xscale, (fx - a.box[0]) / (a.box[2] - a.box[0]));
      var yv = value(a.ylim, a.yscale, (a.box[3] - fy) / (a.box[3] - a.box[1]));
      var xs = a.xcat ? (a.xcat[Math.round(xv)] || "") : (a.xlabel || "x") + " = " + fmt(xv);
      tip.textContent = (a.title ? a.title + ": " : "") + xs + ", " + (a.ylabel || "y") + " = " + fmt(yv);
      var b = box.getBoundingClientRect();
      tip.style.left = Math.min(e.clientX - b.left + 12, b.width - tip.offsetWidth) + "px";
      tip.style.top = (e.clientY - b.top + 12) + "px";
      tip.style.display = "block";
    }
    box.addEventListener("wheel", function (e) {
      e.preventDefault();
      var b = box.getBoundingClientRect(), cx = e.clientX - b.left, cy = e.clientY - b.top;
      var k = Math.min(Math.max(s * (e.deltaY < 0 ? 1.25 : 0.8), 1), 20) / s;
      x = cx - k * (cx - x); y = cy - k * (cy - y); s *= k; show(); readout(e);
    }, {passive: false});
    box.addEventListener("mousedown", function (e) { e.preventDefault(); drag = [e.clientX - x, e.clientY - y]; });
    box.addEventListener("mousemove", function (e) {
      if (drag) { x = e.clientX - drag[0]; y = e.clientY - drag[1]; show(); }
      readout(e);
    });
    box.addEventListener("mouseup", function () { drag = null; });
    box.addEventListener("mouseleave", function () { drag = null; tip.style.display = "none"; });
    box.addEventListener("dblclick", function () { s = 1; x = 0; y = 0; show(); });
  });
  document.body.dataset.plots = String(boxes.length);
})();
"""


def _inline(text: str) -> str:
    """Escaped text with **bold**, `code` and [links](relative/path)."""
    t = html.escape(text, quote=False)
    t = re.sub(r"\[([^\]]+)\]\(([^)\s\"]+)\)", r'<a href="\2">\1</a>', t)
    t = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", t)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", t)


def _cells(line: str) -> list[str]:
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]


def to_html(lines: Sequence[str], base: Path, title: str) -> str:
    """HTML of the Markdown subset report.md uses (headings, tables, lists, links, code blocks,
    images relative to `base`, embedded as base64 PNG in an interactive figure, and paragraphs)."""
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
            axes = html.escape(json.dumps(read_axes_map(base / m["src"])))
            body.append(f'<figure><div class="plot" data-axes="{axes}"><img alt="{html.escape(m["alt"])}" '
                        f'src="data:image/png;base64,{data}"><div class="tip"></div></div>'
                        f"<figcaption>{_inline(m['alt'])}</figcaption></figure>")
        elif ln.startswith("#"):
            level = min(len(ln) - len(ln.lstrip("#")), 6)
            body.append(f"<h{level}>{_inline(ln[level:].strip())}</h{level}>")
        elif ln.strip():
            body.append(f"<p>{_inline(ln)}</p>")
        i += 1
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + f"\n<script>{_SCRIPT}</script>\n</body></html>\n")


def write_report(out: Path, *, paper: str, command: str) -> tuple[Path, Path]:
    """Write out/report.md and out/report.html; returns their paths."""
    out = Path(out)
    lines = markdown(out, paper=paper, command=command)
    md = write_markdown(out / "report.md", lines)
    page = out / "report.html"
    page.write_text(to_html(lines, out, TITLES.get(paper, paper)))
    return md, page
