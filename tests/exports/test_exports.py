"""Exports: clouds and meshes load in trimesh (and Open3D) with the same counts; calibrations parse."""

import ast

import cv2
import numpy as np
import pytest
import trimesh

from scanrig.cli.main import main
from scanrig.errors import FileFormatError, InputError, ShapeError
from scanrig.exports import (FORMATS, MissingDependencyError, OBJ_DIGITS, export_calibration, export_geometry,
                             export_session, to_open3d)
from scanrig.io.ply import read_ply
from tests.report.synth import make_rig, make_session

#: OBJ stores OBJ_DIGITS decimals of a metre: half a unit of the last one is the rounding error.
OBJ_ROUNDING_M = 0.5 * 10.0 ** -OBJ_DIGITS


def _cloud(rng, n=500):
    p = rng.normal(0.0, 0.1, (n, 3))
    return {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "sigma": rng.uniform(1e-5, 1e-4, n),
            "n_views": rng.integers(2, 5, n).astype(np.uint8)}


def _mesh():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    v = np.asarray(sphere.vertices)
    return {"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}, np.asarray(sphere.faces)


@pytest.mark.parametrize("fmt", ["ply", "ply-ascii"])
def test_ply_keeps_every_field_exactly(tmp_path, fmt):
    vertices = _cloud(np.random.default_rng(1))
    path = export_geometry(tmp_path / "c.ply", vertices, fmt=fmt, comments=("units: metres",))
    back, faces, comments = read_ply(path)
    assert faces is None and "units: metres" in comments
    for name, values in vertices.items():
        np.testing.assert_array_equal(back[name], values)
    assert (path.read_bytes()[:200].find(b"format ascii") >= 0) == (fmt == "ply-ascii")


@pytest.mark.parametrize("fmt", ["ply", "ply-ascii", "obj"])
def test_cloud_loads_in_trimesh_with_same_points(tmp_path, fmt):
    vertices = _cloud(np.random.default_rng(2))
    path = export_geometry(tmp_path / f"c.{fmt[:3]}", vertices, fmt=fmt)
    loaded = trimesh.load(path, process=False)
    xyz = np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=1)
    assert isinstance(loaded, trimesh.PointCloud)
    np.testing.assert_allclose(loaded.vertices, xyz, rtol=0, atol=OBJ_ROUNDING_M)


@pytest.mark.parametrize("fmt", ["ply", "ply-ascii", "stl", "obj"])
def test_mesh_loads_in_trimesh_with_same_counts(tmp_path, fmt):
    vertices, faces = _mesh()
    path = export_geometry(tmp_path / f"m.{fmt[:3]}", vertices, faces, fmt=fmt)
    loaded = trimesh.load(path)   # processing merges STL's per-face vertex copies
    assert len(loaded.faces) == len(faces)
    assert len(loaded.vertices) == len(vertices["x"])
    assert loaded.is_watertight


@pytest.mark.parametrize("fmt", ["ply", "ply-ascii", "stl", "obj"])
def test_mesh_loads_in_open3d_with_same_counts(tmp_path, fmt):
    o3d = pytest.importorskip("open3d")
    vertices, faces = _mesh()
    path = export_geometry(tmp_path / f"m.{fmt[:3]}", vertices, faces, fmt=fmt)
    mesh = o3d.io.read_triangle_mesh(str(path))
    if fmt == "stl":
        mesh = mesh.merge_close_vertices(1e-12)
    assert len(mesh.triangles) == len(faces)
    assert len(mesh.vertices) == len(vertices["x"])


@pytest.mark.parametrize("fmt", ["ply", "ply-ascii"])   # Open3D reads OBJ meshes only, not bare points
def test_cloud_loads_in_open3d_with_same_points(tmp_path, fmt):
    o3d = pytest.importorskip("open3d")
    vertices = _cloud(np.random.default_rng(3))
    path = export_geometry(tmp_path / f"c.{fmt[:3]}", vertices, fmt=fmt)
    cloud = o3d.io.read_point_cloud(str(path))
    assert len(cloud.points) == len(vertices["x"])


def test_to_open3d_counts_or_names_the_extra(tmp_path):
    vertices, faces = _mesh()
    xyz = np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=1)
    try:
        import open3d  # noqa: F401
    except ImportError:
        with pytest.raises(MissingDependencyError, match=r'pip install "scanrig\[open3d\]"'):
            to_open3d(xyz)
        return
    assert len(to_open3d(xyz).points) == len(xyz)
    mesh = to_open3d(xyz, faces)
    assert (len(mesh.vertices), len(mesh.triangles)) == (len(xyz), len(faces))
    path = export_geometry(tmp_path / "m.ply", vertices, faces)
    assert len(to_open3d(path).triangles) == len(faces)


def test_calibration_formats_parse(tmp_path):
    rig = make_rig()
    (yml,) = export_calibration(rig, tmp_path / "cv", "opencv-yaml")
    fs = cv2.FileStorage(str(yml), cv2.FILE_STORAGE_READ)
    assert fs.getNode("camera_count").real() == len(rig)
    np.testing.assert_array_equal(fs.getNode("camera_2").getNode("camera_matrix").mat(), rig["cam2"].K)
    models = export_calibration(rig, tmp_path / "mrcal", "mrcal")
    assert [p.name for p in models] == [f"{n}.cameramodel" for n in rig.names]
    model = ast.literal_eval(models[0].read_text())
    assert model["lensmodel"] == "LENSMODEL_OPENCV5" and model["imagersize"] == [1280, 1024]
    cameras, images = export_calibration(rig, tmp_path / "colmap", "colmap")
    assert len([l for l in cameras.read_text().splitlines() if not l.startswith("#")]) == len(rig)


def test_session_export_converts_each_result_file(tmp_path):
    session = make_session(tmp_path / "s", np.random.default_rng(4))
    written = export_session(session, "obj", tmp_path / "out")
    assert [p.name for p in written] == ["points.obj", "surface.obj", "mesh.obj"]
    (stl,) = export_session(session, "stl", tmp_path / "stl")
    assert stl.name == "mesh.stl"
    points, _, _ = read_ply(session / "points.ply")
    assert len(trimesh.load(written[0], process=False).vertices) == len(points["x"])
    surface, _, _ = read_ply(session / "surface.ply")
    assert len(trimesh.load(written[1], process=False).vertices) == np.count_nonzero(surface["inlier"])


def test_cli_export_writes_files_and_rejects_bad_format(tmp_path, capsys):
    session = make_session(tmp_path / "s", np.random.default_rng(5))
    assert main(["export", str(session), "--format", "mrcal", "--out", str(tmp_path / "m")]) == 0
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["cam0.cameramodel", "cam1.cameramodel",
                                                                  "cam2.cameramodel"]
    assert main(["export", str(session), "--format", "vrml"]) == 2
    assert f"format must be one of {', '.join(FORMATS)}; got 'vrml'" in capsys.readouterr().err


def test_bad_inputs_name_the_problem(tmp_path):
    vertices, faces = _mesh()
    with pytest.raises(InputError, match="STL stores triangles only"):
        export_geometry(tmp_path / "c.stl", vertices, fmt="stl")
    with pytest.raises(ShapeError, match=r"faces must be \(M, 3\) vertex indices, got shape \(4,\)"):
        export_geometry(tmp_path / "m.obj", vertices, np.arange(4), fmt="obj")
    with pytest.raises(InputError, match=r"lack the fields \['z'\]"):
        export_geometry(tmp_path / "c.obj", {"x": vertices["x"], "y": vertices["y"]}, fmt="obj")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileFormatError, match=r"empty: has none of points.ply, surface.ply, mesh.ply to export as ply"):
        export_session(tmp_path / "empty", "ply", tmp_path / "o")
    with pytest.raises(FileFormatError, match=r"rig.toml: rig file not found"):
        export_session(tmp_path / "empty", "colmap", tmp_path / "o")
