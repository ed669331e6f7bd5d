"""A ChArUco board printed inverted (white markers on black squares), on a real webcam frame."""

from __future__ import annotations

import csv

import numpy as np

from scanrig.calibration.detect import detect_target
from scanrig.io.session import read_image
from scanrig.targets import charuco
from tests.data_paths import real_data

FRAME = real_data("caliscope-charuco-inverted-frame") / "cam_0_sync_089.jpg"
#: The rig's board (tests/data/caliscope-4cam-charuco/PROVENANCE.md): 4 x 5 squares of 54 mm.
BOARD = charuco((4, 5), 0.054, 0.0405, "DICT_4X4_1000")
#: scanrig's corners against caliscope's (OpenCV's, unrefined) on this frame, px
#: (measured: mean 0.13, max 0.32).
MEAN_PX, MAX_PX = 0.2, 0.5


def caliscope_corners(sync_index: int, cam_id: int) -> dict:
    """``keypoint_id -> (x, y)`` of caliscope's own detections in one frame."""
    path = real_data("caliscope-4cam-charuco") / "post_optimization" / "CHARUCO" / "xy_CHARUCO.csv"
    with path.open() as f:
        return {int(r["keypoint_id"]): (float(r["img_loc_x"]), float(r["img_loc_y"])) for r in csv.DictReader(f)
                if int(r["sync_index"]) == sync_index and int(r["cam_id"]) == cam_id}


def test_an_inverted_print_gives_caliscopes_corners_with_their_ids():
    found = detect_target(read_image(FRAME), BOARD)
    reference = caliscope_corners(89, 0)
    assert found.method.endswith("(inverted print)")
    assert sorted(found.point_ids.tolist()) == sorted(reference) == list(range(12))
    error = np.linalg.norm(found.uv - np.array([reference[i] for i in found.point_ids]), axis=1)
    assert error.mean() < MEAN_PX and error.max() < MAX_PX


def test_the_inverted_search_finds_the_corners_of_the_same_board_printed_black_on_white():
    image = read_image(FRAME)
    inverted = detect_target(image, BOARD)
    normal = detect_target(255 - image, BOARD)
    assert normal.method == "CharucoDetector+saddle"
    np.testing.assert_array_equal(normal.point_ids, inverted.point_ids)
    np.testing.assert_array_equal(normal.uv, inverted.uv)
