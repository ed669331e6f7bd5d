"""Distance to the true surface: exact point–triangle distances, statistics, ``scanrig evaluate``."""

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from scanrig.cli.main import main
from scanrig.errors import FileFormatError, InputError
from scanrig.reconstruct.evaluate import (
    SurfaceDistance,
    distance_statistics,
    load_truth_surface,
    point_triangle_distance,
)
from scanrig.reconstruct.points import PointCloud, write_points

#: Distances are computed in float64 from coordinates of order 1: round-off ~1e-15.
DIST_TOL_M = 1e-12


def _reference_distance(p, a, b, c):
    """Independent reference: projection onto the plane if inside, else the nearest edge point."""
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    proj = p - np.dot(p - a, n) * n
    T = np.column_stack([b - a, c - a])
    uv = np.linalg.lstsq(T, proj - a, rcond=None)[0]
    if uv.min() >= 0 and uv.sum() <= 1:
        return abs(np.dot(p - a, n))

    def seg(x, y):
        t = np.clip(np.dot(p - x, y - x) / np.dot(y - x, y - x), 0.0, 1.0)
        return np.linalg.norm(p - (x + t * (y - x)))

    return min(seg(a, b), seg(b, c), seg(c, a))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_point_triangle_distance_matches_reference(seed):
    rng = np.random.default_rng(seed)
    p, a, b, c = rng.normal(size=(4, 50, 3))
    d = point_triangle_distance(p, a, b, c)
    ref = [_reference_distance(p[i], a[i], b[i], c[i]) for i in range(50)]
    np.testing.assert_allclose(d, ref, rtol=1e-9, atol=DIST_TOL_M)


def test_distance_to_a_large_plane_is_the_height():
    """Two 1.2 m triangles (the simulator's floor): subdivision keeps the search exact."""
    v = np.array([[-0.6, -0.6, 0.0], [0.6, -0.6, 0.0], [0.6, 0.6, 0.0], [-0.6, 0.6, 0.0]])
    surface = SurfaceDistance(v, np.array([[0, 1, 2], [0, 2, 3]]))
    rng = np.random.default_rng(51)
    p = np.c_[rng.uniform(-0.5, 0.5, (2000, 2)), rng.normal(0.0, 0.002, 2000)]
    np.testing.assert_allclose(surface(p), np.abs(p[:, 2]), atol=DIST_TOL_M)


def test_distance_to_a_sphere_mesh_equals_brute_force():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    surface = SurfaceDistance(mesh.vertices, mesh.faces)
    rng = np.random.default_rng(52)
    p = rng.normal(size=(100, 3))
    p *= (0.1 + rng.normal(0.0, 0.003, 100))[:, None] / np.linalg.norm(p, axis=1, keepdims=True)
    tri = mesh.vertices[mesh.faces]
    brute = [point_triangle_distance(np.repeat(x[None], len(tri), 0), *tri.transpose(1, 0, 2)).min() for x in p]
    np.testing.assert_allclose(surface(p), brute, atol=DIST_TOL_M)


def test_statistics():
    d = np.r_[np.full(990, 1e-4), np.full(10, 2e-3)]
    stats = distance_statistics(d)
    assert stats["fraction_beyond"] == pytest.approx(0.01)
    assert stats["rms_m"] == pytest.approx(np.sqrt((990 * 1e-8 + 10 * 4e-6) / 1000))
    assert stats["p95_m"] == pytest.approx(1e-4) and stats["max_m"] == pytest.approx(2e-3)
    with pytest.raises(InputError, match="no points to evaluate"):
        distance_statistics(np.zeros(0))


def test_cli_evaluate(tmp_path, capsys):
    (tmp_path / "truth" / "meshes").mkdir(parents=True)
    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(tmp_path / "truth" / "meshes" / "box.ply")
    p = np.array([[0.0, 0.0, 0.1005], [0.0, 0.0, -0.1002], [0.1, 0.0, 0.0], [0.0, 0.0, 0.103]])
    write_points(tmp_path / "points.ply", PointCloud(p, np.full(4, 1e-4), [2] * 4, [0.1] * 4, range(4), [0] * 4))
    assert main(["evaluate", str(tmp_path / "points.ply"), "--truth", str(tmp_path / "truth")]) == 0
    out = capsys.readouterr().out
    expected_rms_mm = np.sqrt((0.5**2 + 0.2**2 + 0.0**2 + 3.0**2) / 4)  # distances to the box faces
    assert f"4 points: RMS {expected_rms_mm:.4f} mm" in out and "25.000 % beyond 1 mm" in out
    assert (tmp_path / "points_distances.png").stat().st_size > 0
    assert main(["evaluate", str(tmp_path / "points.ply"), "--truth", str(tmp_path)]) == 2
    assert "no true meshes (*.ply) found" in capsys.readouterr().err


def test_missing_truth_is_named(tmp_path):
    with pytest.raises(FileFormatError, match=r"meshes: no true meshes \(\*.ply\) found; --truth must be"):
        load_truth_surface(tmp_path)


def test_rig_alignment_recovers_a_change_of_world_frame():
    from scanrig.geometry import Rig, RigidTransform
    from scanrig.reconstruct.evaluate import rig_alignment
    from tests.reconstruct.synth import ring_rig

    rig_true = ring_rig()
    est_from_true = RigidTransform.from_rvec_tvec([0.3, -0.2, 1.0], [0.1, 0.5, -0.2])
    rig_est = Rig([c.with_pose(c.cam_from_world @ est_from_true.inverse()) for c in rig_true.cameras])
    true_from_est = rig_alignment(rig_est, rig_true)
    np.testing.assert_allclose((true_from_est @ est_from_true).as_matrix(), np.eye(4), atol=1e-12)
    with pytest.raises(InputError, match=r"rig alignment needs 2 or more cameras in common, got \['cam0'\]"):
        rig_alignment(Rig(rig_est.cameras[:1]), rig_true)
