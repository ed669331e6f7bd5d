"""ChArUco boards as users print them: OpenCV's legacy layout and AprilTag dictionaries."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from scanrig.errors import FileFormatError, InputError
from scanrig.targets import charuco, load_target, save_target
from scanrig.targets.print_files import write_print_files

#: Board sizes of whole pixels in OpenCV's image: 100 px squares, 50 px margin, and a marker side
#: that is a whole number of pixels per marker cell (10 px for 5x5, 4 px for 36h11, 10 px for 16h5).
SQUARE_PX, MARGIN_PX = 100, 50
MARKER_PX = {"DICT_5X5_1000": 70, "DICT_APRILTAG_36h11": 32, "DICT_APRILTAG_16h5": 60}


def _board(squares, dictionary, legacy):
    scale = 0.04 / SQUARE_PX
    return charuco(squares, 0.04, MARKER_PX[dictionary] * scale, dictionary, margin_m=MARGIN_PX * scale,
                   legacy=legacy).boards[0]


@pytest.mark.parametrize("squares, dictionary, legacy", [
    ((7, 6), "DICT_5X5_1000", True), ((6, 4), "DICT_5X5_1000", True), ((7, 5), "DICT_5X5_1000", True),
    ((7, 6), "DICT_5X5_1000", False), ((8, 6), "DICT_APRILTAG_36h11", True),
    ((7, 5), "DICT_APRILTAG_36h11", False), ((6, 4), "DICT_APRILTAG_16h5", True)])
def test_pattern_is_opencvs_image(squares, dictionary, legacy):
    """The printed look (what the simulator renders) is OpenCV's own board image, pixel for pixel."""
    board = _board(squares, dictionary, legacy)
    size_px = tuple(n * SQUARE_PX + 2 * MARGIN_PX for n in squares)
    expected = board.cv_board().generateImage(size_px, marginSize=MARGIN_PX, borderBits=1)
    np.testing.assert_array_equal(board.pattern(SQUARE_PX / board.square_m), expected)


def test_legacy_layout_differs_only_with_even_rows():
    odd = [_board((7, 5), "DICT_5X5_1000", legacy) for legacy in (False, True)]
    even = [_board((7, 6), "DICT_5X5_1000", legacy) for legacy in (False, True)]
    assert odd[1].top_left_black and not even[1].top_left_black
    np.testing.assert_array_equal(odd[0].pattern(2500.0), odd[1].pattern(2500.0))
    # Legacy with even rows: the top-left square is white and carries marker 0; corners unchanged.
    centre = np.array([[MARGIN_PX + 3, MARGIN_PX + 3]]) * 0.04 / SQUARE_PX       # inside square (0, 0)
    assert even[0].reflectance(centre)[0] == 0.0 and even[1].reflectance(centre)[0] == 1.0
    assert np.all(np.floor((even[1].marker_corners_board[0, 0] - even[1].margin_m) / 0.04) == 0)
    np.testing.assert_array_equal(even[0].points_board, even[1].points_board)


def _svg_black(path, px_per_mm: int, shape) -> np.ndarray:
    """Rasterise the black rectangles of a board SVG at pixel centres, (H, W) bool."""
    ns = "{http://www.w3.org/2000/svg}"
    black = np.zeros(shape, dtype=bool)
    v, u = np.mgrid[0:shape[0], 0:shape[1]]
    x_mm, y_mm = (u + 0.5) / px_per_mm, (v + 0.5) / px_per_mm
    group = next(g for g in ET.parse(path).getroot().iter(f"{ns}g") if g.get("fill") == "black")
    for rect in group.iter(f"{ns}rect"):
        x, y, w, h = (float(rect.get(k)) for k in ("x", "y", "width", "height"))
        black |= (x_mm >= x) & (x_mm < x + w) & (y_mm >= y) & (y_mm < y + h)
    return black


@pytest.mark.parametrize("legacy", [False, True])
def test_print_file_draws_the_declared_layout_true_to_scale(tmp_path, legacy):
    target = charuco((6, 4), 0.04, 0.024, "DICT_APRILTAG_16h5", margin_m=0.02, legacy=legacy)
    (svg,) = write_print_files(target, tmp_path)
    pattern = target.boards[0].pattern(2000.0)                  # 2 px per mm
    np.testing.assert_array_equal(_svg_black(svg, 2, pattern.shape), pattern == 0)


def test_target_file_round_trip_legacy_apriltag(tmp_path):
    path = tmp_path / "target.toml"
    target = charuco((8, 6), 0.04, 0.03, "DICT_APRILTAG_36h11", legacy=True)
    save_target(target, path)
    assert "legacy = true" in path.read_text()
    again = load_target(path)
    board = again.boards[0]
    assert board.legacy and board.dictionary == "DICT_APRILTAG_36h11"
    np.testing.assert_array_equal(board.pattern(1000.0), target.boards[0].pattern(1000.0))
    save_target(charuco((8, 6), 0.04, 0.03), path)               # current layout: no new key
    assert "legacy" not in path.read_text()


def test_bad_dictionary_and_legacy_fields(tmp_path):
    path = tmp_path / "target.toml"
    charuco_head = 'kind = "charuco"\nsquares = [6, 4]\nsquare_m = 0.04\nmarker_m = 0.03\n'
    path.write_text(charuco_head + 'dictionary = "DICT_APRILTAG_36h12"\n')
    with pytest.raises(FileFormatError, match=r"target.toml: target: dictionary must be one of \[.*"
                                              r"'DICT_APRILTAG_36h11'\], got 'DICT_APRILTAG_36h12'"):
        load_target(path)
    path.write_text(charuco_head + 'dictionary = "DICT_4X4_50"\nlegacy = "yes"\n')
    with pytest.raises(FileFormatError, match=r"target.toml: target: legacy must be true or false, got 'yes'"):
        load_target(path)
    path.write_text('kind = "chessboard"\ninner_corners = [9, 6]\nsquare_m = 0.02\nlegacy = true\n')
    with pytest.raises(FileFormatError, match=r"target.toml: target \(kind = 'chessboard'\): legacy applies only "
                                              r"to kind = 'charuco' \(a ChArUco board printed with OpenCV < 4.6's "
                                              r"layout\)$"):
        load_target(path)
    with pytest.raises(InputError, match=r"DICT_APRILTAG_16h5 has 30 markers; this board needs ids 0..34"):
        charuco((10, 7), 0.04, 0.03, "DICT_APRILTAG_16h5")
