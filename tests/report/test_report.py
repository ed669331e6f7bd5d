"""report.html from a synthetic session: figures computed from the files, self-contained, honest about gaps."""

import base64
import json
import re

import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.errors import FileFormatError
from scanrig.report import write_report
from scanrig.report.viewer import subsample
from tests.report.synth import (
    N_OUTLIERS,
    N_POINTS,
    NOISE_M,
    OUTLIER_OFFSET_M,
    make_session,
)

OUTLIER_SHARE = N_OUTLIERS / N_POINTS
#: The viewer ships float32 coordinates of a unit-radius cloud: half an ulp per axis, at most
#: sqrt(3)/2 eps in 3-D; 2 eps (relative to the radius) leaves a margin of two.
FLOAT32_EPS_RELATIVE = 2 * float(np.finfo(np.float32).eps)
#: The RMS with outliers is nearly deterministic (fixed count and offset); what moves it is the
#: noise on the outliers' offset (0.1 mm of 10 mm, averaged over 20: ~0.2 %) and the truth mesh's
#: ~0.01 mm tessellation error (~0.1 %): 1 % leaves a margin of 3 over their sum.
RMS_WITH_OUTLIERS_TOLERANCE = 0.01
#: The inliers' RMS: 3-sigma sampling error of an RMS of ~2000 Gaussian residuals (3 / sqrt(2 N)
#: ~ 5 %) plus the mesh's tessellation error (~1 % of the noise in quadrature, up to 10 % as a bias).
RMS_INLIERS_TOLERANCE = 0.15


def _figure(html: str, label: str) -> str:
    match = re.search(re.escape(label) + r'</td><td[^>]*>([^<]+)</td>', html)
    assert match, f"summary row {label!r} missing"
    return match.group(1)


def _viewer_data(html: str) -> dict:
    return json.loads(re.search(r"const DATA = (\{.*?\});\n", html).group(1))


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return make_session(tmp_path_factory.mktemp("report") / "s", np.random.default_rng(11))


def test_report_figures_come_from_the_files(session):
    path = write_report(session, rng=np.random.default_rng(1), summary=[("caller row", "42")])
    html = path.read_text()
    assert path == session / "report.html"
    assert _figure(html, "caller row") == "42"
    assert _figure(html, "points") == str(N_POINTS)
    # Outliers dominate the RMS: sqrt(share * offset^2 + noise^2) up to the mesh's own error.
    expected_mm = np.sqrt(OUTLIER_SHARE * OUTLIER_OFFSET_M**2 + NOISE_M**2) * 1e3
    rms_mm = float(_figure(html, "RMS distance to the truth, all points").split()[0])
    assert rms_mm == pytest.approx(expected_mm, rel=RMS_WITH_OUTLIERS_TOLERANCE)
    surface_mm = float(_figure(html, "RMS distance to the truth, points the filter kept").split()[0])
    assert surface_mm == pytest.approx(NOISE_M * 1e3, rel=RMS_INLIERS_TOLERANCE)   # inliers only
    assert _figure(html, "points the filter removed") == str(N_OUTLIERS)
    anchors = ["verdict", "summary", "calibration", "laser-detection", "point-cloud", "sampling-density",
               "accuracy-against-truth", "run-parameters-versions-seed"]
    positions = [html.index(f'<section id="{anchor}">') for anchor in anchors]
    assert positions == sorted(positions)                  # the verdict opens the page


def test_verdict_quotes_the_figures_of_scanrig_evaluate(session, capsys):
    """One definition: the verdict's RMS before and after the filter are the ones `scanrig evaluate` prints."""
    html = write_report(session, rng=np.random.default_rng(7)).read_text()
    verdict = html[html.index('<section id="verdict">'):html.index('<section id="summary">')]
    assert main(["evaluate", str(session)]) == 0
    printed = capsys.readouterr().out
    before = re.search(r"(\d+) points: RMS ([0-9.]+) mm", printed)
    after = re.search(r"after the filter: (\d+) kept, (\d+) removed: RMS ([0-9.]+) mm", printed)
    assert before.group(1) == str(N_POINTS) and after.group(2) == str(N_OUTLIERS)
    assert f"RMS {before.group(2)} mm: the RMS of the distances of all {N_POINTS} points" in verdict
    assert f"RMS {after.group(3)} mm over the {after.group(1)} points it kept; it removed {N_OUTLIERS}" in verdict
    coverage = re.search(r"coverage: ([0-9.]+) %", printed).group(1)
    assert f"{coverage} % of the true surface" in verdict


def test_report_is_self_contained(session):
    html = write_report(session, rng=np.random.default_rng(2)).read_text()
    assert "http://" not in html and "https://" not in html   # ':' is not a base64 character
    assert "default-src 'none'" in html
    sources = re.findall(r'src="([^"]*)"', html)
    assert sources and all(s.startswith("data:image/png;base64,") for s in sources)
    assert "<link" not in html and "fetch(" not in html and "XMLHttpRequest" not in html


def test_viewer_ships_a_subsample_of_the_cloud(session):
    from scanrig.reconstruct.points import read_points

    html = write_report(session, rng=np.random.default_rng(3), max_points=500).read_text()
    data = _viewer_data(html)
    assert data["n"] == 500
    xyz = np.frombuffer(base64.b64decode(data["xyz"]), "<f4").reshape(-1, 3)
    cloud, _ = read_points(session / "points.ply")
    shipped_m = xyz * data["radius_m"] + np.array(data["centre_m"])
    # Every shipped point is one of the cloud's, to the float32 precision of a unit-radius cloud.
    d = np.min(np.linalg.norm(cloud.p_world[None, :, :] - shipped_m[:, None, :], axis=2), axis=1)
    assert np.max(d) < FLOAT32_EPS_RELATIVE * data["radius_m"]
    labels = [f["label"] for f in data["fields"]]
    assert labels[:2] == ["distance to true surface", "uncertainty (1-sigma, largest axis)"]
    faces = np.frombuffer(base64.b64decode(data["mesh_faces"]), "<u4").reshape(-1, 3)
    mesh_xyz = np.frombuffer(base64.b64decode(data["mesh_xyz"]), "<f4").reshape(-1, 3)
    from scanrig.io.ply import read_ply

    vertices, mesh_faces, _ = read_ply(session / "mesh.ply")
    assert len(faces) == len(mesh_faces) and len(mesh_xyz) == len(vertices["x"])   # the whole mesh.ply


def test_subsample_is_sorted_unique_and_bounded():
    rng = np.random.default_rng(4)
    for n, cap in [(10, 20), (1000, 100), (5, 5)]:
        idx = subsample(n, cap, rng)
        assert len(idx) == min(n, cap) and np.all(np.diff(idx) > 0) and idx.max() < n


def test_empty_session_report_says_what_is_missing(tmp_path):
    html = write_report(tmp_path, rng=np.random.default_rng(5)).read_text()
    assert "rig.toml not found: the session is not calibrated yet" in html
    assert "traces.parquet not found" in html
    assert "points.ply not found: nothing reconstructed yet" in html


def test_cli_report(session, tmp_path, capsys):
    out = tmp_path / "r.html"
    assert main(["report", str(session), "--out", str(out), "--max-points", "300", "--seed", "3"]) == 0
    assert _viewer_data(out.read_text())["n"] == 300
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert "missing: session folder not found" in capsys.readouterr().err


def test_missing_session_raises(tmp_path):
    with pytest.raises(FileFormatError, match="nowhere: session folder not found"):
        write_report(tmp_path / "nowhere", rng=np.random.default_rng(6))


def test_histogram_axis_is_fitted_to_the_data():
    """A 0.05 mm distribution with one 1 mm outlier gets an axis near 0.06 mm, not 1 mm."""
    from scanrig.report.plots import AXIS_MARGIN, fitted_top

    d_mm = np.r_[np.linspace(0.0, 0.05, 2000), 1.0]
    assert fitted_top(d_mm) == pytest.approx(np.percentile(d_mm, 99.9) * AXIS_MARGIN)
    assert fitted_top(d_mm) < 0.1
