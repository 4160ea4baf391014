"""report.html opened in a real headless browser (Debian's `chromium`): the page renders (the
screenshot is not blank), every figure is on it, its script makes every figure interactive, and
no request leaves the file. CI installs chromium (.ci/run); without it the browser tests are
skipped. And the map from pixels to data each figure carries, which the hover readout uses."""
import json
import re
import shutil
import subprocess

import numpy as np
import pytest
from matplotlib.image import imread

from testbed.outputs.plots import figure, read_axes_map, save
from testbed.outputs.report import Claim, write_claims
from testbed.reproduce import document

CHROMIUM = shutil.which("chromium")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (apt-get install chromium)")
#: one colour per figure, found again in the screenshot (RGB in [0, 1])
COLOURS = {"magenta_curve": (1.0, 0.0, 1.0), "cyan_bars": (0.0, 0.8, 0.8)}
#: appended to a copy of the page: a mouse move and a wheel step at the centre of the second
#: figure's axes; the readout and the image's transform are left on <body> for --dump-dom
PROBE = """<script>
var box = document.querySelectorAll("div.plot")[1], img = box.querySelector("img");
var a = JSON.parse(box.dataset.axes)[0], r = img.getBoundingClientRect();
var at = {clientX: r.left + r.width * (a.box[0] + a.box[2]) / 2, clientY: r.top + r.height * (a.box[1] + a.box[3]) / 2,
          bubbles: true, cancelable: true};
box.dispatchEvent(new MouseEvent("mousemove", at));
document.body.dataset.tip = box.querySelector(".tip").textContent;
box.dispatchEvent(new WheelEvent("wheel", Object.assign({deltaY: -100}, at)));
document.body.dataset.zoom = img.style.transform;
</script>"""


def _chromium(tmp_path, page, *args):
    """Run headless chromium on `page` with its own empty profile and a network log; returns
    (stdout, the URLs the page itself asked for). Chromium's own background requests (updates,
    time) carry the initiator "not an origin"; the page's carry its origin ("null" for file://)."""
    profile, netlog = tmp_path / "profile", tmp_path / "net.json"
    shutil.rmtree(profile, ignore_errors=True)
    done = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                           "--disable-background-networking", "--disable-component-update", "--disable-sync",
                           f"--user-data-dir={profile}", '--host-resolver-rules=MAP * ~NOTFOUND',
                           f"--log-net-log={netlog}", *args, page.as_uri()],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    log = json.loads(netlog.read_text())
    start = log["constants"]["logEventTypes"]["URL_REQUEST_START_JOB"]
    asked = [e["params"]["url"] for e in log["events"] if e["type"] == start and "url" in e.get("params", {})
             and e["params"].get("initiator") != "not an origin"]
    return done.stdout, asked


def _reproduction(out):
    """A reproduction directory with two figures drawn in COLOURS and one claim."""
    fig = figure(figsize=(5, 3))
    fig.subplots().plot(np.linspace(0, 10, 50), np.sin(np.linspace(0, 10, 50)), lw=6, color=COLOURS["magenta_curve"])
    save(fig, out / "plots" / "magenta_curve.png")
    fig = figure(figsize=(4, 3))
    ax = fig.subplots()
    ax.bar(["gnss", "coop"], [87.0, 0.3], color=COLOURS["cyan_bars"])
    ax.set_yscale("log")
    save(fig, out / "plots" / "cyan_bars.png")
    write_claims(out / "claims.json", [Claim(id="c", text="a claim", criterion="p < 0.05", holds=True, numbers={})],
                 paper="denied", runs=1, seeds=[18])
    (out / "runs" / "truth").mkdir(parents=True)
    (out / "runs" / "truth" / "recording.rrd").write_bytes(b"")  # a `testbed view` recording: linked


@needs_chromium
def test_report_html_renders_every_figure_offline(tmp_path):
    out = tmp_path / "rep"
    _reproduction(out)
    _, page = document.write_report(out, paper="denied", command="testbed reproduce denied --out rep --runs 1")
    text = page.read_text()
    assert 'href="runs/truth/recording.rrd"' in text and "http://" not in text and "https://" not in text

    dom, asked = _chromium(tmp_path, page, "--dump-dom")
    assert asked == []
    assert 'data-plots="2"' in dom, "the page's script did not make both figures interactive"

    # the hover readout and the wheel zoom, driven by events at the centre of the curve's axes
    probe = tmp_path / "probe.html"
    probe.write_text(text.replace("</body>", PROBE + "</body>"))
    dom, asked = _chromium(tmp_path, probe, "--dump-dom")
    (curve,) = read_axes_map(out / "plots" / "magenta_curve.png")
    m = re.search(r'data-tip="x = ([-+.e\d]+), y = ([-+.e\d]+)"', dom)
    assert m, dom[-3000:]
    h, w = imread(out / "plots" / "magenta_curve.png").shape[:2]
    pixel = [np.ptp(curve["xlim"]) / (w * (curve["box"][2] - curve["box"][0])),
             np.ptp(curve["ylim"]) / (h * (curve["box"][3] - curve["box"][1]))]  # data units of one image pixel
    error = np.abs(np.array([float(m[1]), float(m[2])]) - [np.mean(curve["xlim"]), np.mean(curve["ylim"])])
    assert np.all(error < 1.5 * np.array(pixel)), (m[0], error, pixel)  # the centre rounds to a pixel
    assert 'data-zoom="translate(' in dom and "scale(1.25)" in dom and asked == []

    shot = tmp_path / "shot.png"
    _, asked = _chromium(tmp_path, page, f"--screenshot={shot}", "--window-size=1200,3000")
    assert asked == []
    rgb = imread(shot)[..., :3]
    assert rgb.std() > 0.05, "blank screenshot"
    for name, colour in COLOURS.items():
        near = np.all(np.abs(rgb - colour) < 0.08, axis=-1).sum()
        assert near > 2000, f"figure {name} is not on the page ({near} pixels of its colour)"


@needs_chromium
def test_the_request_check_sees_a_request_that_leaves_the_file(tmp_path):
    """The control of the test above: a page that asks for an image and a script on the web."""
    page = tmp_path / "leaky.html"
    page.write_text('<html><body><img src="http://example.invalid/x.png">'
                    '<script src="https://cdn.example.invalid/a.js"></script></body></html>')
    _, asked = _chromium(tmp_path, page, "--dump-dom")
    assert sorted(asked) == ["http://example.invalid/x.png", "https://cdn.example.invalid/a.js"]


def test_each_figure_carries_the_map_from_its_pixels_to_its_data(tmp_path):
    """The hover readout's arithmetic on the map a PNG carries: the pixel of a known data point."""
    _reproduction(tmp_path)
    (bars,) = read_axes_map(tmp_path / "plots" / "cyan_bars.png")
    assert bars["yscale"] == "log" and bars["xcat"] == ["gnss", "coop"]
    (curve,) = read_axes_map(tmp_path / "plots" / "magenta_curve.png")
    img = imread(tmp_path / "plots" / "magenta_curve.png")[..., :3]
    h, w = img.shape[:2]
    x0, y0, x1, y1 = curve["box"]
    for x in (2.0, 5.0, 8.0):  # the curve sin(x) at pixel columns, then its value read back
        u = (x - curve["xlim"][0]) / (curve["xlim"][1] - curve["xlim"][0])
        col = int(round((x0 + u * (x1 - x0)) * w))
        rows = np.flatnonzero(np.all(np.abs(img[:, col] - COLOURS["magenta_curve"]) < 0.08, axis=-1))
        v = (y1 - rows.mean() / h) / (y1 - y0)
        y = curve["ylim"][0] + v * (curve["ylim"][1] - curve["ylim"][0])
        assert abs(y - np.sin(x)) < 0.05, (x, y)  # a pixel is about 0.01 here
