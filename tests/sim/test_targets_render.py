"""Rendered calibration targets: corner accuracy, cube faces identifiable, poses in view."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.geometry import Camera, RigidTransform
from scanrig.sim.calibration_shots import (
    calibration_sensor,
    default_target,
    random_pose,
    target_scene,
)
from scanrig.sim.render import CameraView
from scanrig.sim.rigs import look_at

from .conftest import STRONG_DIST, plane_scene, small_rig

#: Acceptance: findChessboardCornersSB (CALIB_CB_ACCURACY) within 0.08 px RMS of the truth.
CORNER_RMS_TOL_PX = 0.08


def _camera(width=640, height=512, fx=1100.0, dist=STRONG_DIST) -> Camera:
    params = np.array([fx, fx, (width - 1) / 2 + 3.2, (height - 1) / 2 - 2.1, *dist])
    return Camera("c", "opencv5", params, width, height, look_at((0.05, -0.45, 0.35), (0.0, 0.0, 0.0)))


def tilted_chessboard_corners(room) -> tuple[Camera, RigidTransform, np.ndarray]:
    """Render the default chessboard in ``room``, facing :func:`_camera` tilted ~20 degrees (its z,
    into the print, pointing away from the camera), and find its corners.

    Returns
    -------
    camera : Camera
    target_pose : RigidTransform
        World from target.
    corners_px : ndarray of shape (54, 2)
        ``findChessboardCornersSB`` (accuracy flag) corners, pixels.
    """
    import cv2
    from scipy.spatial.transform import Rotation

    cam = _camera()
    target = default_target("chessboard")
    w, h = target.boards[0].size_m
    view_dir = -cam.cam_from_world.inverse().R[:, 2]
    R = (Rotation.from_rotvec([0.35, 0.1, 0.0]) * Rotation.align_vectors([-view_dir], [[0, 0, 1.0]])[0]).as_matrix()
    pose = RigidTransform(R, -R @ [w / 2, h / 2, 0.0])
    sensor = calibration_sensor(room)
    img = sensor.expose(CameraView(cam, target_scene(target, pose, room), sensor).background_e,
                        np.random.default_rng(12))
    found, corners = cv2.findChessboardCornersSB(img, (9, 6), flags=cv2.CALIB_CB_ACCURACY)
    assert found
    return cam, pose, corners.reshape(-1, 2)


def corner_rms_px(corners_px: np.ndarray, truth_px: np.ndarray) -> float:
    """RMS distance of each true corner to its nearest found corner, every true corner found once."""
    nearest = np.linalg.norm(corners_px[:, None] - truth_px[None], axis=2).argmin(axis=1)
    assert len(set(nearest)) == len(truth_px)
    return float(np.sqrt(((corners_px - truth_px[nearest]) ** 2).sum(axis=1).mean()))


def test_chessboard_corners_are_found_at_their_true_projections():
    cam, pose, corners = tilted_chessboard_corners(plane_scene())
    rms = corner_rms_px(corners, cam.project(pose.apply(default_target("chessboard").boards[0].points_board)))
    print(f"chessboard corner RMS: {rms:.4f} px")
    assert rms < CORNER_RMS_TOL_PX


def test_cube_faces_are_distinguishable():
    """ArUco markers of the rendered cube decode to ids of at least two different faces."""
    from dataclasses import replace

    import cv2
    from scipy.spatial.transform import Rotation

    from scanrig.geometry import RigidTransform

    room = plane_scene()
    cube = default_target("cube")
    cam = _camera(dist=(-0.1, 0.05, 0.0, 0.0, 0.0))
    # a corner of the cube towards the camera: three faces in view
    R = Rotation.from_euler("zx", [40.0, -25.0], degrees=True).as_matrix()
    pose = RigidTransform(R, [0.0, 0.0, 0.0])
    sensor = replace(calibration_sensor(room), supersampling=2)     # decoding needs no sub-pixel accuracy
    img = sensor.expose(CameraView(cam, target_scene(cube, pose, room), sensor).background_e,
                        np.random.default_rng(4))
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_1000))
    _, ids, _ = detector.detectMarkers(img)
    assert ids is not None
    faces_seen = set((ids.ravel() // cube.boards[0].n_markers).tolist())
    assert len(faces_seen) >= 2, faces_seen


@pytest.mark.parametrize("kind", ["cube", "chessboard", "charuco"])
def test_random_poses_are_seen_by_two_cameras(kind):
    from scanrig.sim.calibration_shots import _n_cameras_seeing

    rig = small_rig(3, distance_m=1.0)
    target = default_target(kind)
    rng = np.random.default_rng(9)
    for _ in range(5):
        pose = random_pose(target, rig, (0.0, 0.0, 0.0), 0.1, rng)
        assert _n_cameras_seeing(target, pose, rig) >= 2
