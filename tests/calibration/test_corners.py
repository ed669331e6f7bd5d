"""Corner refiners against the analytic truth of rendered boards (sharp edges, grazing ChArUco views)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from scanrig.calibration.corners import refine_charuco_corners, refine_corners
from scanrig.calibration.detect import detect_target
from scanrig.calibration.synthetic import render_board
from scanrig.geometry.camera import Camera
from scanrig.geometry.transform import RigidTransform
from scanrig.targets import charuco, chessboard

CAM = Camera("c", "opencv5", np.array([900.0, 900.0, 320.0, 240.0, -0.05, 0.02, 0.0, 0.0, 0.0]), 640, 480)


def _pose(board, rotvec_deg, distance):
    centre = np.array([board.size_m[0] / 2, board.size_m[1] / 2, 0.0])
    R = Rotation.from_rotvec(np.deg2rad(rotvec_deg)).as_matrix()
    return RigidTransform(R, np.array([0.0, 0.0, distance]) - R @ centre)


def _rms(err):
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))


def test_sharp_fronto_parallel_chessboard():
    """Edges along the pixel grid, no blur: the pixel-integrated model has no phase bias."""
    board = chessboard((5, 4), 0.02).boards[0]
    pose = _pose(board, [0.5, 0.3, 0.4], 0.45)
    img = render_board(board, CAM, pose, 0.0, 1.0, np.random.default_rng(1))
    truth = CAM.project_cam(pose.apply(board.points_board))
    start = truth + np.random.default_rng(2).uniform(-0.5, 0.5, truth.shape)
    uv, ok = refine_corners(img, start, (5, 4))
    assert ok.all()
    assert _rms(uv - truth) < 0.04


def test_charuco_grazing_view_refined():
    """A ChArUco board at 70 degrees: refined corners within a few hundredths of a pixel."""
    target = charuco((6, 5), 0.03, 0.0225)
    board = target.boards[0]
    pose = _pose(board, [70.0, 0.0, 3.0], 0.5)
    img = render_board(board, CAM, pose, 0.6, 1.0, np.random.default_rng(3))
    raw = detect_target(img, target, refine=False)
    det = detect_target(img, target)
    assert len(det.point_ids) >= 10 and det.method.endswith("+saddle")
    truth = CAM.project_cam(pose.apply(board.points_board[det.point_ids]))
    assert _rms(det.uv - truth) < 0.05
    assert _rms(det.uv - truth) < 0.5 * _rms(raw.uv - truth)
    # Too few corners for a homography: returned unchanged, not refined.
    uv, ok = refine_charuco_corners(img, det.uv[:3], board.points_board[det.point_ids[:3], :2],
                                    board.square_m, board.marker_m, board.margin_m)
    assert not ok.any() and np.array_equal(uv, det.uv[:3])
