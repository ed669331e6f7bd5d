"""``scanrig filter`` end to end on a small PLY."""

import json

import numpy as np
import plyfile
import pytest

from scanrig.cli.main import main
from scanrig.io.ply import read_ply, write_ply

from .conftest import tilted_plane_with_outliers


def test_filter_writes_surface_and_mesh_beside_the_input(tmp_path, capsys):
    points, _, bad, _ = tilted_plane_with_outliers(np.random.default_rng(5), n_side=16)
    src = tmp_path / "points.ply"
    write_ply(src, {"x": points[:, 0].astype(np.float32), "y": points[:, 1].astype(np.float32),
                    "z": points[:, 2].astype(np.float32), "intensity": np.ones(len(points), np.float32)})
    assert main(["filter", str(src), "--seed", "11", "--q", "0.3"]) == 0
    surface, faces, comments = read_ply(tmp_path / "surface.ply")
    assert list(surface) == ["x", "y", "z", "inlier", "score", "residual"]
    assert len(surface["x"]) == len(points)
    # input order is kept: denoised inliers stay at their (x, y); they move along the chart
    # normal (tilted ~20 deg from z) by about their noise, well under 0.05 m
    np.testing.assert_allclose(surface["x"][~bad], points[~bad, 0], atol=0.05)
    assert faces is None and any("seed 11" in c for c in comments)
    assert set(np.unique(surface["inlier"])) <= {0, 1}
    _, mesh_faces, _ = read_ply(tmp_path / "mesh.ply")
    assert mesh_faces is not None and mesh_faces.shape[1] == 3
    # the summary: how many points were removed and the RMS over all points beside the kept ones
    summary = json.loads((tmp_path / "filter_summary.json").read_text())
    removed = int(np.count_nonzero(surface["inlier"] == 0))
    assert summary["n_points"] == len(points) and summary["n_removed"] == removed and summary["seed"] == 11
    residual = np.asarray(surface["residual"], float)
    assert summary["rms_residual_all_m"] == pytest.approx(np.sqrt(np.mean(residual ** 2)))
    assert summary["rms_residual_inliers_m"] == pytest.approx(
        np.sqrt(np.mean(residual[surface["inlier"] == 1] ** 2)))
    out = capsys.readouterr().out
    assert f"{len(points) - removed} of {len(points)} points kept, {removed} removed" in out
    assert "over all" in out and "filter_summary.json" in out


def test_filter_bad_input_exits_2(tmp_path, capsys):
    path = tmp_path / "flat.ply"
    table = np.zeros(20, dtype=[("x", "f4"), ("y", "f4")])
    plyfile.PlyData([plyfile.PlyElement.describe(table, "vertex")]).write(str(path))
    assert main(["filter", str(path)]) == 2
    assert "flat.ply" in capsys.readouterr().err
    assert main(["filter", str(path), "--q", "0.9"]) == 2
    assert main(["filter", str(tmp_path / "missing.ply")]) == 2
