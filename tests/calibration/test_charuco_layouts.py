"""Detection of ChArUco boards of OpenCV's legacy layout and of AprilTag dictionaries."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scanrig.calibration.detect import BoardLayoutError, detect_target
from scanrig.calibration.synthetic import render_board
from scanrig.geometry.camera import Camera
from scanrig.geometry.transform import RigidTransform
from scanrig.targets import charuco, load_target, save_target

#: Board image to camera image: perspective, the board filling most of a 900 x 700 image.
HOMOGRAPHY = np.array([[0.95, 0.12, 60.0], [-0.06, 0.9, 50.0], [1.5e-4, 1e-4, 1.0]])
SQUARE_PX = 60


def _opencv_view(target, seed: int):
    """The board drawn by OpenCV itself, warped by :data:`HOMOGRAPHY`, blurred and noised; with the
    true image position of every corner, (N, 2) pixels in point-id order."""
    board = target.boards[0]
    px_per_m = SQUARE_PX / board.square_m
    size = tuple(int(round(v * px_per_m)) for v in board.size_m)
    drawn = board.cv_board().generateImage(size, marginSize=int(round(board.margin_m * px_per_m)), borderBits=1)
    warped = cv2.warpPerspective(drawn, HOMOGRAPHY, (900, 700), flags=cv2.INTER_AREA, borderValue=255)
    noisy = cv2.GaussianBlur(warped.astype(np.float64), (0, 0), 1.0) \
        + np.random.default_rng(seed).normal(0.0, 2.0, warped.shape)
    # Pixel (0, 0) of OpenCV's image has its centre at board coordinates (0.5, 0.5) / px_per_m.
    drawn_uv = board.points_board[:, :2] * px_per_m - 0.5
    truth = cv2.perspectiveTransform(drawn_uv.reshape(-1, 1, 2), HOMOGRAPHY).reshape(-1, 2)
    return np.clip(np.round(noisy), 0, 255).astype(np.uint8), truth


def _rms(err):
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))


@pytest.mark.parametrize("squares", [(7, 6), (8, 6)])
def test_legacy_board_found_when_declared_and_named_when_not(squares):
    legacy = charuco(squares, 0.04, 0.03, legacy=True)
    image, truth = _opencv_view(legacy, seed=squares[0])
    det = detect_target(image, legacy)
    assert len(det.point_ids) == len(truth) and det.method == "CharucoDetector+saddle"
    assert _rms(det.uv - truth[det.point_ids]) < 0.03
    with pytest.raises(BoardLayoutError, match=r"^the ChArUco board's markers follow OpenCV < 4.6's legacy layout "
                                               r"\(top-left square white\), not the declared one \(they fit it to "
                                               r"0\.0\d\d marker sides, the declared one to \d\.\d\d\d\): set legacy "
                                               r"= true in target.toml$"):
        detect_target(image, charuco(squares, 0.04, 0.03))


def test_current_board_declared_legacy_is_named():
    image, _ = _opencv_view(charuco((6, 4), 0.04, 0.03, "DICT_4X4_50"), seed=1)
    with pytest.raises(BoardLayoutError, match=r"follow OpenCV's current layout \(top-left square black\).*: "
                                               r"set legacy = false in target.toml$"):
        detect_target(image, charuco((6, 4), 0.04, 0.03, "DICT_4X4_50", legacy=True))


def test_odd_rows_either_declaration():
    """With an odd row count both layouts are one print: the same corners, no complaint."""
    image, truth = _opencv_view(charuco((7, 5), 0.04, 0.03, legacy=True), seed=2)
    found = [detect_target(image, charuco((7, 5), 0.04, 0.03, legacy=legacy)) for legacy in (False, True)]
    assert len(found[0].point_ids) == len(truth)
    np.testing.assert_array_equal(found[0].point_ids, found[1].point_ids)
    np.testing.assert_array_equal(found[0].uv, found[1].uv)


def test_apriltag_board_round_trip(tmp_path):
    """An AprilTag 36h11 legacy board: target.toml written and read back, rendered by the simulator
    (its reflectance) at 70 degrees, found at the right places. The refinement must mask the
    markers of the legacy layout's white squares: fitted with the current layout's squares it
    errs by 0.0145 px RMS here, instead of 0.0055 px."""
    path = tmp_path / "target.toml"
    save_target(charuco((8, 6), 0.03, 0.0225, "DICT_APRILTAG_36h11", legacy=True), path)
    target = load_target(path)
    board = target.boards[0]
    camera = Camera("c", "opencv5", np.array([900.0, 900.0, 320.0, 240.0, -0.05, 0.02, 0.0, 0.0, 0.0]), 640, 480)
    R = Rotation.from_rotvec(np.deg2rad([70.0, 0.0, 3.0])).as_matrix()
    pose = RigidTransform(R, np.array([0.0, 0.0, 0.45]) - R @ np.array([*board.size_m, 0.0]) / 2)
    image = render_board(board, camera, pose, 0.6, 1.0, np.random.default_rng(4))
    det = detect_target(image, target)
    assert len(det.point_ids) >= 25            # of 35; some corners seen too steeply fail the fit
    truth = camera.project_cam(pose.apply(board.points_board[det.point_ids]))
    assert _rms(det.uv - truth) < 0.01


def test_session_detection_names_the_image_of_the_other_layout(tmp_path):
    """In a session the wrong-layout message names the image (``scanrig calibrate`` exits 2 with it)."""
    from scanrig.calibration.pipeline import detect_session
    from scanrig.errors import FileFormatError
    from scanrig.io.session import Session, write_image

    image, _ = _opencv_view(charuco((8, 6), 0.04, 0.03, legacy=True), seed=3)
    path = tmp_path / "calibration" / "cam0" / "000.png"
    path.parent.mkdir(parents=True)
    write_image(path, image)
    with pytest.raises(FileFormatError, match=r"000\.png: the ChArUco board's markers follow OpenCV < 4.6's legacy "
                                              r"layout .*: set legacy = true in target.toml$"):
        detect_session(Session(tmp_path), charuco((8, 6), 0.04, 0.03))
