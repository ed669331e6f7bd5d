"""Rendered calibration targets: corner accuracy, cube faces identifiable, poses in view."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.geometry import Camera
from scanrig.sim.calibration_shots import (calibration_sensor, default_target, random_pose, target_scene)
from scanrig.sim.render import CameraView
from scanrig.sim.rigs import look_at

from .conftest import STRONG_DIST, plane_scene, small_rig

#: Acceptance: findChessboardCornersSB (CALIB_CB_ACCURACY) within 0.08 px RMS of the truth.
CORNER_RMS_TOL_PX = 0.08


def _camera(width=640, height=512, fx=1100.0, dist=STRONG_DIST) -> Camera:
    params = np.array([fx, fx, (width - 1) / 2 + 3.2, (height - 1) / 2 - 2.1, *dist])
    return Camera("c", "opencv5", params, width, height, look_at((0.05, -0.45, 0.35), (0.0, 0.0, 0.0)))


def test_chessboard_corners_are_found_at_their_true_projections():
    import cv2
    from scipy.spatial.transform import Rotation

    from scanrig.geometry import RigidTransform

    cam = _camera()
    room = plane_scene()
    target = default_target("chessboard")
    board = target.boards[0]
    # board facing the camera (its z, into the print, pointing away from it), tilted 20 degrees
    w, h = board.size_m
    view_dir = -cam.cam_from_world.inverse().R[:, 2]
    R = (Rotation.from_rotvec([0.35, 0.1, 0.0]) * Rotation.align_vectors([-view_dir], [[0, 0, 1.0]])[0]).as_matrix()
    pose = RigidTransform(R, -R @ [w / 2, h / 2, 0.0])
    sensor = calibration_sensor(room)
    img = sensor.expose(CameraView(cam, target_scene(target, pose, room), sensor).background_e,
                        np.random.default_rng(12))
    found, corners = cv2.findChessboardCornersSB(img, (9, 6), flags=cv2.CALIB_CB_ACCURACY)
    assert found
    corners = corners.reshape(-1, 2)
    truth = cam.project(pose.apply(board.points_board))
    nearest = np.linalg.norm(corners[:, None] - truth[None], axis=2).argmin(axis=1)
    assert len(set(nearest)) == len(truth)
    rms = np.sqrt(((corners - truth[nearest]) ** 2).sum(axis=1).mean())
    print(f"chessboard corner RMS: {rms:.4f} px")
    assert rms < CORNER_RMS_TOL_PX


def test_cube_faces_are_distinguishable():
    """ArUco markers of the rendered cube decode to ids of at least two different faces."""
    import cv2

    from dataclasses import replace

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
