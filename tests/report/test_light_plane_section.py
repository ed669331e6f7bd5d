"""The report's light-plane section: the plane's figures from light_plane.toml and the turntable's motion."""

import numpy as np
from scipy.spatial.transform import Rotation

from scanrig.geometry import RigidTransform
from scanrig.io.object_poses import object_poses_path, write_object_poses
from scanrig.io.session import Session
from scanrig.reconstruct.light_plane import fit_plane, save_light_plane
from scanrig.report.light_plane_section import light_plane_sections

#: Turntable step of the synthetic motion, degrees.
STEP_DEG = 7.5


def _turntable(tmp_path, n_frames: int) -> None:
    (tmp_path / "scan").mkdir()
    axis_point = np.array([0.01, -0.02, 0.0])
    poses = {}
    for k in range(n_frames):
        R = Rotation.from_rotvec([0.0, 0.0, np.radians(STEP_DEG * k)]).as_matrix()
        poses[f"{k:05d}"] = RigidTransform(R, axis_point - R @ axis_point)
    write_object_poses(object_poses_path(tmp_path), poses)


def test_no_plane_and_no_poses_gives_no_section(tmp_path):
    assert light_plane_sections(Session(tmp_path), []) == []


def test_plane_figures_and_motion(tmp_path):
    rng = np.random.default_rng(8)
    p = np.c_[np.full(200, 0.05) + rng.normal(0.0, 2e-5, 200), rng.uniform(-0.1, 0.1, (200, 2))]
    plane = fit_plane(p)
    save_light_plane(tmp_path / "light_plane.toml", plane, "cam0")
    _turntable(tmp_path, 9)
    facts = []
    (sec,) = light_plane_sections(Session(tmp_path), facts)
    html = "".join(sec.parts)
    assert facts == [("light plane of cam0", f"RMS {1e3 * plane.residual_m:.4f} mm, 200 inliers")]
    assert "light_plane.toml" in html and f"{STEP_DEG:.4f}, {STEP_DEG:.4f}, {STEP_DEG:.4f}" in html
    assert f"{8 * STEP_DEG:.3f}" in html   # 8 steps between 9 frames
    assert "calibration_report/light_plane_&lt;camera&gt;.png not found" in html


def test_poses_without_plane_say_the_plane_is_missing(tmp_path):
    _turntable(tmp_path, 3)
    (sec,) = light_plane_sections(Session(tmp_path), [])
    html = "".join(sec.parts)
    assert "light_plane.toml not found" in html and "points.ply is in the object frame" in html
