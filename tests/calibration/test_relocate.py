"""Re-localisation of a moved camera from known world points."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scanrig.calibration.relocate import read_known_points, relocate_camera
from scanrig.calibration.synthetic import ring_cameras
from scanrig.errors import FileFormatError, InputError
from scanrig.geometry.transform import RigidTransform

#: Pixel noise on the known points' image positions.
SIGMA_PX = 0.1


def _moved(cam, rng):
    delta = RigidTransform(Rotation.from_rotvec(rng.normal(scale=0.01, size=3)).as_matrix(),
                           rng.normal(scale=0.003, size=3))
    return cam.with_pose(delta @ cam.cam_from_world)


def points_in_view(cam, n, rng, depth_m=(0.5, 1.1)):
    """``n`` world points seen by ``cam`` spread over its image, at depths in ``depth_m``."""
    q = rng.uniform([0.05 * cam.width, 0.05 * cam.height], [0.95 * cam.width, 0.95 * cam.height], size=(n, 2))
    origins, dirs = cam.rays(q)
    z_axis = cam.cam_from_world.R[2]
    depth = rng.uniform(*depth_m, size=n)
    return origins + dirs * (depth / (dirs @ z_axis))[:, None]


def test_relocate_from_six_points_meets_acceptance():
    """Camera 0.8 m from the rig centre, f = 1400 px, six points in view at 0.5-1.1 m, 0.1 px noise.

    Acceptance: within 0.5 mm / 0.05 deg. The error is random (reported centre sigma ~0.1-0.3 mm
    for six points), so it is checked over 20 seeds: at least 90 % within both limits, and every
    error within 5 reported sigmas.
    """
    within, errors = 0, []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        cam = ring_cameras(1)[0]
        moved = _moved(cam, rng)
        pts = points_in_view(moved, 6, rng)
        uv = moved.project(pts) + rng.normal(scale=SIGMA_PX, size=(6, 2))
        result = relocate_camera(cam, pts, uv, sigma_px=SIGMA_PX)
        err_m = np.linalg.norm(result.camera.center_world - moved.center_world)
        err_deg = np.degrees(np.linalg.norm((result.camera.cam_from_world @ moved.cam_from_world.inverse()).rvec))
        within += err_m < 5e-4 and err_deg < 0.05
        errors.append(err_m)
        assert err_m < 5 * np.linalg.norm(result.center_std_m)
        assert result.moved
        np.testing.assert_array_equal(result.camera.params, cam.params)
    assert within >= 18, (within, np.round(np.array(errors) * 1000, 3))


def test_relocate_unmoved_camera_is_not_flagged():
    rng = np.random.default_rng(9)
    cam = ring_cameras(1)[0]
    pts = rng.uniform(-0.3, 0.3, size=(8, 3))
    uv = cam.project(pts) + rng.normal(scale=SIGMA_PX, size=(8, 2))
    assert not relocate_camera(cam, pts, uv, sigma_px=SIGMA_PX).moved


def test_relocate_bad_input(tmp_path):
    cam = ring_cameras(1)[0]
    with pytest.raises(InputError, match="4 known points; at least 5 are needed"):
        relocate_camera(cam, np.zeros((4, 3)), np.zeros((4, 2)))
    path = tmp_path / "known_points.csv"
    path.write_text("point,x,y,z,u\np,0,0,0,1\n")
    with pytest.raises(FileFormatError, match=r"missing column\(s\) \['v'\]"):
        read_known_points(path)
