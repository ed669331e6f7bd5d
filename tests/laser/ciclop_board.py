"""The two red lasers on the Ciclop chessboard (tests/data/ciclop-laser-stripes, CC BY-SA 4.0, the
``-x`` pair): the detector's points on each, undistorted, and how straight they are."""

from __future__ import annotations

import cv2
import numpy as np

from scanrig.io.session import read_image
from tests.data_paths import real_data

FOLDER = real_data("ciclop-laser-stripes") / "laser_on_pattern"
#: Undistorted columns of the two lasers on the board, px.
BOARD_LINES = ((250, 400), (560, 720))
#: Rows of the specular glint beside the left laser (the laser-on frame), where the webcam turns the
#: saturated beam white.
GLINT_ROWS = (569, 638)
#: The intrinsics of the data set's PROVENANCE.md (OpenCV on its 16 calibration views, 0.24 px RMS).
CAMERA = np.array([[1429.665, 0, 478.030], [0, 1430.394, 642.597], [0, 0, 1]])
DISTORTION = np.array([0.02719, -0.23098, -0.00087, -0.00007, 0.50889])


def frames() -> tuple[np.ndarray, np.ndarray]:
    """The ``-x`` laser-on frame and its laser-off frame, RGB uint8."""
    return read_image(FOLDER / "laser-0-255-255-8-x.png"), read_image(FOLDER / "laser-background-0-255-255-8-x.png")


def board_outline() -> np.ndarray:
    """The board's outline in the ``-x`` frames (``pattern.png`` shares their pose): the convex hull of
    the 11 × 6 inner corners extended by one square, ``(k, 1, 2)`` float32 px."""
    found, corners = cv2.findChessboardCorners(cv2.cvtColor(read_image(FOLDER / "pattern.png"), cv2.COLOR_RGB2GRAY),
                                               (11, 6))
    assert found
    grid = corners.reshape(6, 11, 2)
    return cv2.convexHull(np.concatenate([2 * grid[0] - grid[1], 2 * grid[-1] - grid[-2],
                                          2 * grid[:, 0] - grid[:, 1], 2 * grid[:, -1] - grid[:, -2]]))


def board_lines(table, outline: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per laser: the undistorted rank <= 1 row-scanned centres inside ``outline`` ``(n, 2)`` px,
    their σ ``(n,)`` px and their rows in the frame ``(n,)``.

    Two lasers: the two most prominent peaks of a row are the two lines."""
    u, v, line, rank, sigma = (table[k].to_numpy() for k in ("u", "v", "line", "rank", "sigma_px"))
    two = (rank <= 1) & (v == line)
    q = np.c_[u, v][two]
    inside = np.array([cv2.pointPolygonTest(outline, (float(a), float(b)), False) >= 0 for a, b in q], bool)
    q, sigma = q[inside], sigma[two][inside]
    flat = cv2.undistortPoints(q[:, None], CAMERA, DISTORTION, P=CAMERA)[:, 0]
    near = [(flat[:, 0] > lo) & (flat[:, 0] < hi) for lo, hi in BOARD_LINES]
    return [(flat[m], sigma[m], q[m, 1]) for m in near]


def line_residuals(points: np.ndarray, fit: np.ndarray | None = None) -> np.ndarray:
    """Column residuals ``(n,)`` px of ``points (n, 2)`` from the least-squares line ``u = a + b v``
    through ``points[fit]`` (all by default)."""
    a = np.c_[np.ones(len(points)), points[:, 1]]
    take = slice(None) if fit is None else fit
    return points[:, 0] - a @ np.linalg.lstsq(a[take], points[take, 0], rcond=None)[0]
