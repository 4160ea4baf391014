"""Issue 15, "a report per reproduction": report.md and a self-contained report.html with the claims
(tests, paper's number beside ours), the figures, the command, the seeds and the versions."""
import base64
import json
import re

import numpy as np
import pytest

from testbed.outputs.plots import figure, save
from testbed.outputs.report import Claim, write_claims, write_markdown
from testbed.reproduce import document
from testbed.scoring.stats import clopper_pearson

from table_checks import assert_every_anees_has_its_interval  # tests/ helper


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


@pytest.mark.slow  # a short phase reproduction, ~12 s
def test_phase_reproduction_writes_its_report(tmp_path):
    """A short `testbed reproduce phase` (2 runs of 4 s): report.md and report.html exist, the window
    is the run's last half and says so, every claim shows its test and n, RMSE vs PCRB is a figure."""
    from testbed.reproduce import reproduce

    out = tmp_path / "rep"
    reproduce("phase", out, runs=2, duration=4.0, workers=1)
    md = (out / "report.md").read_text()
    doc = json.loads((out / "claims.json").read_text())
    table = (out / "table.md").read_text()
    assert doc["window_s"] == 2.0 and "uses the last 2 s instead" in table and "RMSE pos last 2 s" in table
    # eight formations, three ANEES each, and the attitude's where a run observed it (line H000: none)
    observed = {d.parent.name for d in (out / "runs").glob("phase-*/run-*")
                if "anees_attitude6" in json.loads((d / "metrics.json").read_text())["estimators"]["ekf"]}
    assert "phase-line-h000" not in observed
    assert assert_every_anees_has_its_interval(table) == 8 * 3 + len(observed)
    assert "last_100s" not in (out / "table.csv").read_text()
    assert "testbed reproduce phase --out" in md and "--runs 2" in md and "--duration 4" in md
    for c in doc["claims"]:
        assert c["test"]["name"] and c["test"]["n"] == 2, c["id"]
    assert (out / "plots" / "rmse_vs_pcrb.png").is_file()
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == len(list((out / "plots").glob("*.png")))
    m = json.loads((out / "runs" / "phase-cross-h000" / "run-000" / "metrics.json").read_text())["estimators"]["ekf"]
    assert m["last_window_s"] == 2.0 and np.isfinite(m["rmse_position_last_2s_m"])
    made = json.loads((out / "provenance.json").read_text())  # and each of its runs (testbed.provenance)
    assert made["output"] == "reproduce-phase" and made["command"]["function"] == "testbed.reproduce.reproduce"
    assert json.loads((out / "runs" / "phase-cross-h000" / "run-000" / "provenance.json").read_text())["output"] == "run"


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
