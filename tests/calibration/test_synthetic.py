"""Synthetic calibration data: the optional detectable-size rule of the observer."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from scanrig.calibration.synthetic import (DETECTABLE_SQUARE_PX, _visible, covering_target_poses, observe,
                                           ring_cameras)
from scanrig.geometry.camera import Camera
from scanrig.geometry.transform import RigidTransform
from scanrig.targets import charuco, cube

#: Focal length of the test camera (px) and square of the test board (m): 35 px per square at 1 m.
FOCAL_PX = 1400.0
SQUARE_M = 0.025


def _camera() -> Camera:
    """A distortion-free camera at the origin looking along +z."""
    return Camera("c", "opencv5", np.array([FOCAL_PX, FOCAL_PX, 639.5, 511.5, 0, 0, 0, 0, 0]), 1280, 1024)


def _board_pose(board, depth_m: float, tilt_deg: float) -> RigidTransform:
    """The board centred on the optical axis at ``depth_m``, turned ``tilt_deg`` about its x axis."""
    R = Rotation.from_rotvec([np.deg2rad(tilt_deg), 0.0, 0.0]).as_matrix()
    centre = np.array([board.size_m[0] / 2, board.size_m[1] / 2, 0.0])
    return RigidTransform(R, np.array([0.0, 0.0, depth_m]) - R @ centre)


def test_size_rule_keeps_points_by_foreshortened_square_size():
    target = charuco((7, 5), SQUARE_M, 0.75 * SQUARE_M)
    cam = _camera()
    n = len(target.point_ids)
    # Face-on at 1 m: squares image 35 px (34.6-35 px over the board: ranges 1.0-1.01 m).
    face_on = _board_pose(target.boards[0], 1.0, 0.0)
    assert np.count_nonzero(_visible(cam, target, face_on)) == n
    assert np.count_nonzero(_visible(cam, target, face_on, 34.0)) == n
    assert np.count_nonzero(_visible(cam, target, face_on, 35.5)) == 0
    # Tilted 60 deg at 1 m: 35 px * cos 60 = 17.5 px at the centre (the view angle and range vary
    # by a few percent over the board, so a threshold between the extremes splits it).
    tilted = _board_pose(target.boards[0], 1.0, 60.0)
    assert np.count_nonzero(_visible(cam, target, tilted)) == n
    assert np.count_nonzero(_visible(cam, target, tilted, 15.0)) == n
    assert np.count_nonzero(_visible(cam, target, tilted, 20.0)) == 0
    split = np.count_nonzero(_visible(cam, target, tilted, 17.5))
    assert 0 < split < n


def test_size_rule_only_removes_observations():
    rng = np.random.default_rng(3)
    cams = ring_cameras(3, rng=rng)
    target = cube()
    poses = covering_target_poses(cams, target, 6, rng)
    seed = 17
    full = observe(cams, target, poses, 0.1, np.random.default_rng(seed))
    none = observe(cams, target, poses, 0.1, np.random.default_rng(seed), min_square_px=None)
    zero = observe(cams, target, poses, 0.1, np.random.default_rng(seed), min_square_px=0.0)
    limited = observe(cams, target, poses, 0.1, np.random.default_rng(seed), min_square_px=DETECTABLE_SQUARE_PX)
    assert len(none) == len(zero) == len(full)
    np.testing.assert_array_equal(none.uv, full.uv)
    assert 0 < len(limited) < len(full)
    key = lambda o: set(zip(o.camera.tolist(), o.shot.tolist(), o.point_id.tolist()))  # noqa: E731
    assert key(limited) <= key(full)


def test_covering_poses_honour_size_rule():
    rng = np.random.default_rng(8)
    cams = ring_cameras(3, rng=rng)
    target = cube(edge_m=0.4, squares=14, square_m=0.025, marker_m=0.01875)
    min_points = 12
    poses = covering_target_poses(cams, target, 8, rng, min_square_px=DETECTABLE_SQUARE_PX, min_points=min_points)
    for pose in poses[1:]:
        seen = [np.count_nonzero(_visible(c, target, pose, DETECTABLE_SQUARE_PX)) for c in cams]
        assert sum(k >= min_points for k in seen) >= 2, seen
