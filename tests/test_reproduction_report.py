"""Issue 15, "a report per reproduction": report.md and a self-contained report.html with the claims
(tests, paper's number beside ours), the figures, the command, the seeds and the versions."""
import base64
import re

import numpy as np

from testbed.outputs.plots import figure, save
from testbed.outputs.report import Claim, write_claims, write_markdown
from testbed.reproduce import document
from testbed.scoring.stats import clopper_pearson


def _fake_reproduction(out):
    (out / "plots").mkdir(parents=True)
    fig = figure(figsize=(2, 2))
    fig.subplots().plot([0, 1], [0, 1])
    save(fig, out / "plots" / "error_envelope.png")
    cp = clopper_pearson(0, 20)
    claims = [Claim(id="bound", text="errors within +/-0.01 m | always", criterion="CP upper < 0.15", holds=True,
                    numbers={"violations": 0}, summary="0/20 runs violate", paper_value="±0.01 m",
                    **cp.claim_fields()),
              Claim(id="order", text="A better than B", criterion="Wilcoxon p < 0.05", holds=False,
                    numbers={"p": float("nan")}, test="Wilcoxon signed-rank (less)", statistic=float("nan"), n=1)]
    write_claims(out / "claims.json", claims, paper="003", runs=20, seeds=list(range(1, 21)))
    write_markdown(out / "table.md", ["# Table", "", "| a | b |", "|---|---|", "| 1 | 2 |"])


def test_report_markdown_and_self_contained_html(tmp_path):
    _fake_reproduction(tmp_path)
    cmd = "testbed reproduce phase --out D --runs 20 --motion prescribed"
    md_path, html_path = document.write_report(tmp_path, paper="phase", command=cmd)
    md = md_path.read_text()
    assert cmd in md and "seeds: 1..20 (20 runs)" in md
    for name in ("python", "testbed", "numpy", "scipy", "mujoco", "gtsam"):
        assert re.search(rf"\b{name} \S+", md), name
    row = next(ln for ln in md.splitlines() if ln.startswith("| bound"))
    assert "±0.01 m" in row and "0/20 runs violate" in row and "Clopper-Pearson (upper)" in row
    assert f"interval [0, {0.1391:.4g}]" in row and "n = 20" in row and "**holds**" in row
    assert "\\|" in row  # a '|' inside a cell is escaped
    assert "1 of 2 claims hold" in md and "![error envelope](plots/error_envelope.png)" in md
    assert "## Tables" in md and "| 1 | 2 |" in md
    page = html_path.read_text()
    srcs = re.findall(r'src="([^"]+)"', page)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert base64.b64decode(srcs[0].split(",", 1)[1]) == (tmp_path / "plots" / "error_envelope.png").read_bytes()
    assert "http" not in page.replace("http-equiv", "") and "<table>" in page and "<b>holds</b>" in page


def test_bars_spanning_decades_are_drawn_on_a_log_axis(tmp_path, monkeypatch):
    """The denied reproduction's RMSE bars: GNSS only 87 m beside 0.27-0.63 m would flatten the
    cooperative bars on a linear axis; within a factor 30 the axis stays linear."""
    from testbed.outputs import plots

    drawn = []
    monkeypatch.setattr(plots, "save", lambda fig, path: drawn.append(fig) or path)
    for means in ([0.3, 87.0, 0.27, 0.63], [0.3, 0.5, 0.27, 0.63]):
        m = np.array(means)
        plots.compare_bars(["truth", "gnss_ekf", "coop", "window"], m, 0.9 * m, 1.1 * m, tmp_path / "b.png",
                           title="t", ylabel="position RMSE [m]")
    assert [f.axes[0].get_yscale() for f in drawn] == ["log", "linear"]
    assert drawn[0].axes[0].get_ylabel() == "position RMSE [m] (log scale)"
    assert not plots.spans_decades([0.0, 87.0]) and not plots.spans_decades([np.nan, 1.0, 100.0])
