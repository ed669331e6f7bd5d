"""report.html in headless Chromium: no console message, no network request, 3-D view and plots drawn,
and at 1280 x 800 the first screen shows the verdict and the mesh, with no horizontal overflow.

With logging on, every console message (script errors, CSP violations) appears on stderr as a
``:CONSOLE`` line. Every request the page starts is in Chromium's NetLog (``--log-net-log``) as a
``URL_REQUEST_START_JOB`` event with the page as initiator; Chromium's own background requests
(update checks) carry the initiator "not an origin" and are set aside. A proxy on a closed port
keeps anything from leaving the machine. Install with ``apt-get install -y chromium``; the tests
skip without it.
"""

import html as html_text
import json
import re
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from scanrig.report import write_report
from tests.report.synth import make_session

CHROMIUM = Path("/usr/bin/chromium")
#: Tall enough for the synthetic session's whole page, so one screenshot shows every section.
WINDOW = (1400, 5000)
#: The first screen of a laptop: the verdict and the 3-D view must be on it.
FIRST_SCREEN = (1280, 800)
#: The 3-D view's canvas on the first screen (report.cloud_sections.FIRST_VIEW_PX).
FIRST_VIEW = (800, 520)
#: The mesh is drawn flat grey, shaded 70-220 by the angle to the line of sight: a pixel of it has
#: equal channels (within MESH_GREY_DN) and is lighter than the background by MESH_MIN_DN.
MESH_GREY_DN = 3
MESH_MIN_DN = 40
#: The synthetic sphere's mesh (radius 50 mm in a view of the 50 mm cloud) covers ~ a third of the
#: canvas and the points cover part of it; a tenth of the canvas in mesh pixels is a drawn mesh.
MIN_MESH_PIXELS = FIRST_VIEW[0] * FIRST_VIEW[1] // 10
#: Seconds Chromium may take to render the page on a loaded 2-core machine.
TIMEOUT_S = 120
#: The viewer canvas's background, #202020.
CANVAS_BG = 0x20
#: A drawn 3-D view: many colours and at least a point's splat per few hundred canvas pixels.
MIN_COLOURS = 50
MIN_POINT_PIXELS = 2000
#: Plots are colour PNGs (viridis maps, blue and green histograms); text is grey. A pixel is
#: "colour" when its channels differ by this much.
SATURATION_DN = 60
MIN_PLOT_COLOURS = 50

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed (apt-get install -y chromium)")


def _screenshot(html: Path, tmp: Path, window=WINDOW) -> tuple[np.ndarray, list[str], list[str]]:
    """Screenshot of the page in a window of ``window`` pixels; its console lines and the URLs it requested."""
    png, netlog = tmp / "page.png", tmp / "netlog.json"
    args = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            "--proxy-server=127.0.0.1:9", "--enable-logging=stderr", "--v=0", f"--log-net-log={netlog}",
            f"--user-data-dir={tmp / 'profile'}", f"--screenshot={png}", f"--window-size={window[0]},{window[1]}",
            html.as_uri()]
    run = subprocess.run(args, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert png.is_file(), f"chromium wrote no screenshot: {run.stderr[-2000:]}"
    console = [line for line in run.stderr.splitlines() if ":CONSOLE" in line]
    return cv2.imread(str(png)), console, _page_requests(netlog)


#: Measures the laid-out page: its scrolling width against the window's, and the boxes of the
#: verdict and of the 3-D view's canvas (left, top, right, bottom in CSS pixels).
_PROBE = """<script>(function () {
  const box = (q) => { const b = document.querySelector(q).getBoundingClientRect(); return [b.left, b.top, b.right, b.bottom]; };
  document.body.setAttribute("data-layout", JSON.stringify({scroll: document.documentElement.scrollWidth,
    client: document.documentElement.clientWidth, verdict: box(".verdict"), view: box("#cloud")}));
})();</script>"""


def _layout(page: Path, tmp: Path) -> dict:
    """The probe's measurements of ``page`` in a FIRST_SCREEN window (Chromium's --dump-dom)."""
    probe = tmp / f"probe-{page.stem}.html"
    probe.write_text(page.read_text().replace("</body>", _PROBE + "</body>"))
    args = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
            "--proxy-server=127.0.0.1:9", f"--user-data-dir={tmp / 'profile-dom'}",
            f"--window-size={FIRST_SCREEN[0]},{FIRST_SCREEN[1]}", "--dump-dom", probe.as_uri()]
    run = subprocess.run(args, check=False, capture_output=True, text=True, timeout=TIMEOUT_S)
    found = re.search(r'data-layout="([^"]*)"', run.stdout)
    assert found, f"the probe did not run: {run.stderr[-2000:]}"
    return json.loads(html_text.unescape(found.group(1)))


def _page_requests(netlog: Path) -> list[str]:
    log = json.loads(netlog.read_text())
    start = log["constants"]["logEventTypes"]["URL_REQUEST_START_JOB"]
    params = [e.get("params", {}) for e in log["events"] if e["type"] == start]
    return [p["url"] for p in params if "url" in p and p.get("initiator") != "not an origin"]


def _canvas_box(shot: np.ndarray) -> tuple[int, int, int, int]:
    """Rows and columns (start, stop) of the viewer canvas: the large #202020 block."""
    dark = np.all(np.abs(shot.astype(int) - CANVAS_BG) <= 2, axis=2)
    rows = np.flatnonzero(dark.sum(axis=1) > 300)
    cols = np.flatnonzero(dark.sum(axis=0) > 200)
    assert rows.size and cols.size, "no viewer canvas (#202020 block) on the page"
    return rows.min(), rows.max() + 1, cols.min(), cols.max() + 1


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("browser")
    root = make_session(tmp / "s", np.random.default_rng(21))
    return _screenshot(write_report(root, rng=np.random.default_rng(22)), tmp)


def test_no_console_message_and_no_request(rendered):
    _, console, requests = rendered
    assert console == [] and requests == []


def test_viewer_draws_the_cloud(rendered):
    shot = rendered[0]
    r0, r1, c0, c1 = _canvas_box(shot)
    assert (r1 - r0, c1 - c0) == FIRST_VIEW[::-1]   # the canvas, at its size: the script did not break the layout
    canvas = shot[r0:r1, c0:c1].reshape(-1, 3)
    drawn = canvas[np.any(np.abs(canvas.astype(int) - CANVAS_BG) > 2, axis=1)]
    assert len(drawn) >= MIN_POINT_PIXELS, "the 3-D view is blank"
    assert len(np.unique(drawn, axis=0)) >= MIN_COLOURS, "the 3-D view is not coloured by a field"


def test_plots_render_below_the_viewer(rendered):
    shot = rendered[0]
    below = shot[_canvas_box(shot)[1]:].reshape(-1, 3).astype(int)
    colour = below[np.ptp(below, axis=1) > SATURATION_DN]
    assert len(np.unique(colour, axis=0)) >= MIN_PLOT_COLOURS, "the density and error plots are blank"


@pytest.fixture(scope="module")
def first_screen(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("first")
    root = make_session(tmp / "s", np.random.default_rng(23))
    page = write_report(root, rng=np.random.default_rng(24))
    return _screenshot(page, tmp, FIRST_SCREEN)[0], _layout(page, tmp)


def test_first_screen_shows_the_verdict_and_the_mesh(first_screen):
    shot, layout = first_screen
    width, height = FIRST_SCREEN
    for name in ("verdict", "view"):
        left, top, right, bottom = layout[name]
        assert left >= 0 and top >= 0 and right <= width and bottom <= height, f"the {name} is not on the first screen"
    r0, r1, c0, c1 = _canvas_box(shot)
    assert r1 <= height and (r1 - r0, c1 - c0) == FIRST_VIEW[::-1]
    canvas = shot[r0:r1, c0:c1].reshape(-1, 3).astype(int)
    grey = (np.ptp(canvas, axis=1) <= MESH_GREY_DN) & (canvas.min(axis=1) >= CANVAS_BG + MESH_MIN_DN)
    assert grey.sum() >= MIN_MESH_PIXELS, "no mesh in the 3-D view"
    coloured = canvas[np.ptp(canvas, axis=1) > SATURATION_DN]
    assert len(coloured) >= MIN_POINT_PIXELS, "no points coloured by deviation over the mesh"


def test_page_is_no_wider_than_the_window(first_screen):
    _, layout = first_screen
    assert layout["scroll"] <= layout["client"], f"page {layout['scroll']} px wide in a {layout['client']} px window"


def test_an_overflow_would_be_caught(tmp_path):
    """The probe itself: a page wider than the window is measured wider."""
    page = tmp_path / "wide.html"
    page.write_text('<!DOCTYPE html><html><body><div class="verdict">v</div><canvas id="cloud" width="10" '
                    'height="10"></canvas><pre>' + "x" * 400 + "</pre></body></html>")
    layout = _layout(page, tmp_path)
    assert layout["scroll"] > layout["client"]


def test_a_network_request_would_be_caught(tmp_path):
    """The detectors themselves: a remote image is seen in the NetLog, a script error on the console."""
    page = tmp_path / "leak.html"
    page.write_text('<!DOCTYPE html><html><body><img src="https://example.invalid/x.png">'
                    '<script>undefinedFunction();</script></body></html>')
    _, console, requests = _screenshot(page, tmp_path)
    assert requests == ["https://example.invalid/x.png"]
    assert any("undefinedFunction is not defined" in line for line in console)
