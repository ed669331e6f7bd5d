"""Tests of scanrig.targets: geometry, patterns (checked with OpenCV's detectors), files."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanrig.cli.main import main
from scanrig.errors import FileFormatError, InputError
from scanrig.targets import (CUBE_FACES, charuco, chessboard, circle_grid, cube, load_target, save_target)
from scanrig.targets.print_files import write_print_files

#: Pattern images are sampled exactly at pixel centres; OpenCV's detectors on such ideal images
#: are accurate to a few hundredths of a pixel, so the board geometry must agree within this.
DETECTOR_TOL_PX = 0.1


def _pixels(board, px_per_m):
    """Board points to pattern pixels (pixel centre (0, 0) at board (0.5, 0.5) / px_per_m)."""
    return board.points_local * px_per_m - 0.5


def test_cube_geometry_faces_on_cube_surface_with_z_into_cube():
    edge = 0.2
    target = cube(edge_m=edge)
    assert target.points_target.shape == (6 * 36, 3)
    assert len(np.unique(target.point_ids)) == 216
    for board, normal in zip(target.boards, CUBE_FACES.values()):
        pose = board.target_from_board
        n = np.array(normal, dtype=float)
        np.testing.assert_allclose(pose.R[:, 2], -n, atol=1e-15)
        # every point lies on the face plane and inside the face
        p = board.points_target
        np.testing.assert_allclose(p @ n, edge / 2, atol=1e-12)
        assert np.all(np.abs(p) <= edge / 2 + 1e-12)
        # the printed area's corners are the face's corners
        w, h = board.size_m
        corners = pose.apply(np.array([[0, 0, 0], [w, h, 0]]))
        np.testing.assert_allclose(np.abs(corners), edge / 2, atol=1e-12)


def test_cube_faces_subset_keeps_ids():
    full = cube()
    five = cube(faces=["+x", "-x", "+y", "-y", "+z"])
    assert [b.name for b in five.boards] == ["face0", "face1", "face2", "face3", "face4"]
    np.testing.assert_array_equal(five.point_ids, full.point_ids[:180])
    marker_sets = [set(b.marker_ids) for b in full.boards]
    assert sum(len(s) for s in marker_sets) == len(set().union(*marker_sets))


def test_charuco_pattern_detected_by_opencv_at_the_documented_points():
    target = cube()
    for board in target.boards[:2]:
        px_per_m = 4000.0
        img = board.pattern(px_per_m)
        corners, ids, _, marker_ids = cv2.aruco.CharucoDetector(board.cv_board()).detectBoard(img)
        assert len(ids) == len(board.points_local)
        np.testing.assert_array_equal(np.sort(marker_ids.ravel()), board.marker_ids)
        err = corners.reshape(-1, 2) - _pixels(board, px_per_m)[ids.ravel()]
        assert np.abs(err).max() < DETECTOR_TOL_PX


def test_chessboard_pattern_matches_points():
    board = chessboard((9, 6), 0.025).boards[0]
    px_per_m = 2000.0
    img = board.pattern(px_per_m, supersample=4)
    assert img.shape == (round(0.225 * px_per_m), round(0.3 * px_per_m))  # (H, W): 7 and 10 squares + margins
    found, corners = cv2.findChessboardCorners(img, (9, 6))
    assert found
    corners = cv2.cornerSubPix(img, corners, (11, 11), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4))
    err = corners.reshape(-1, 2) - _pixels(board, px_per_m)
    assert np.abs(err).max() < DETECTOR_TOL_PX
    assert img[0, 0] == 255 and img[int(0.03 * px_per_m), int(0.03 * px_per_m)] == 0  # margin, black square


@pytest.mark.parametrize("asymmetric", [False, True])
def test_circle_grid_pattern_matches_points(asymmetric):
    board = circle_grid((4, 11), 0.02, asymmetric=asymmetric).boards[0]
    px_per_m = 3000.0
    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    found, centres = cv2.findCirclesGrid(board.pattern(px_per_m, 2), (4, 11), flags=flags)
    assert found
    assert np.abs(centres.reshape(-1, 2) - _pixels(board, px_per_m)).max() < DETECTOR_TOL_PX


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 12), st.integers(2, 12), st.floats(0.005, 0.1), st.integers(0, 3))
def test_chessboard_reflectance_alternates_around_every_corner(cols, rows, square_m, margin_squares):
    board = chessboard((cols, rows), square_m, margin_m=margin_squares * square_m).boards[0]
    eps = 1e-3 * square_m
    p = board.points_local
    offsets = np.array([[-eps, -eps], [eps, -eps], [eps, eps], [-eps, eps]])
    values = np.stack([board.reflectance(p + o) for o in offsets], axis=1)
    # around an inner corner the four quadrants alternate black/white
    assert np.all(values[:, 0] == values[:, 2]) and np.all(values[:, 1] == values[:, 3])
    assert np.all(values[:, 0] != values[:, 1])


def test_lookup_returns_points_and_unknown_mask():
    target = cube()
    pts, known = target.lookup([0, 215, 999])
    np.testing.assert_array_equal(known, [True, True, False])
    np.testing.assert_allclose(pts[:2], target.points_target[[0, 215]])
    assert np.all(np.isnan(pts[2]))


@pytest.mark.parametrize("target", [chessboard((8, 5), 0.03), charuco((5, 4), 0.04, 0.03),
                                    circle_grid((4, 11), 0.02, asymmetric=True), cube(edge_m=0.15, squares=5)])
def test_target_file_round_trip(tmp_path, target):
    path = tmp_path / "target.toml"
    save_target(target, path)
    again = load_target(path)
    assert again.kind == target.kind
    np.testing.assert_array_equal(again.point_ids, target.point_ids)
    np.testing.assert_allclose(again.points_target, target.points_target, rtol=0, atol=0)


def test_target_file_missing_field(tmp_path):
    path = tmp_path / "target.toml"
    path.write_text('kind = "chessboard"\ninner_corners = [9, 6]\n')
    with pytest.raises(FileFormatError, match=r"target.toml: target \(kind = 'chessboard'\): missing field 'square_m'"):
        load_target(path)


def test_target_file_unknown_field_and_kind(tmp_path):
    path = tmp_path / "target.toml"
    path.write_text('kind = "chessboard"\ninner_corners = [9, 6]\nsquare_m = 0.02\nsquare_mm = 20\n')
    with pytest.raises(FileFormatError, match=r"unknown field 'square_mm' \(did you mean 'square_m'\?\)"):
        load_target(path)
    path.write_text('kind = "sphere"\n')
    with pytest.raises(FileFormatError, match=r"kind must be one of .*got 'sphere'"):
        load_target(path)


def test_target_file_bad_values(tmp_path):
    path = tmp_path / "target.toml"
    path.write_text('kind = "charuco"\nsquares = [5, 4]\nsquare_m = 0.03\nmarker_m = 0.04\ndictionary = "DICT_4X4_50"\n')
    with pytest.raises(FileFormatError, match=r"marker_m \(0.04\) must be smaller than square_m \(0.03\)"):
        load_target(path)
    path.write_text('kind = "chessboard"\ninner_corners = 9\nsquare_m = 0.02\n')
    with pytest.raises(FileFormatError, match=r"inner_corners must be two integers \(columns, rows\), got 9"):
        load_target(path)


def test_constructor_errors():
    with pytest.raises(InputError, match=r"squares \* square_m \(0.21 m\) exceeds edge_m \(0.2 m\)"):
        cube(edge_m=0.2, squares=7, square_m=0.03)
    with pytest.raises(InputError, match=r"DICT_4X4_50 has 50 markers"):
        charuco((12, 12), 0.02, 0.015, dictionary="DICT_4X4_50")
    with pytest.raises(InputError, match=r"square_m must be a positive length in metres below 1000, got 1000000000"):
        cube(square_m=10 ** 400)                     # TOML integers are unbounded; no OverflowError
    with pytest.raises(InputError, match=r"faces must be distinct names among .*, got \[\[1\]\]"):
        cube(faces=[[1]])                            # an unhashable face: no TypeError


def test_print_files_true_scale(tmp_path):
    files = write_print_files(cube(edge_m=0.2), tmp_path)
    assert [f.name for f in files] == [f"face{k}.svg" for k in range(6)] + ["cube_net.svg"]
    root = ET.parse(files[0]).getroot()
    assert root.get("width").endswith("mm")
    # board area 200 mm, plus footer; the black squares of a 7x7 board: 25 of 49 at 25 mm
    ns = "{http://www.w3.org/2000/svg}"
    squares = [r for r in root.iter(f"{ns}rect") if float(r.get("width")) == pytest.approx(25.0)]
    assert len(squares) == 25


def test_cli_target_print(tmp_path, capsys):
    path = tmp_path / "target.toml"
    save_target(chessboard(), path)
    assert main(["target", "print", str(path), "--out", str(tmp_path / "p")]) == 0
    assert (tmp_path / "p" / "board.svg").exists()
    assert main(["target", "draw", str(path)]) == 2
    assert "action must be 'print', got 'draw'" in capsys.readouterr().err
