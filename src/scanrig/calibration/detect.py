"""Detection of target points in calibration images, per target kind.

- Chessboard: the classic ``cv2.findChessboardCorners`` (adaptive threshold, fast) with a
  ``cornerSubPix`` window sized to the squares, falling back to ``findChessboardCornersSB``
  with ``CALIB_CB_ACCURACY`` (no normalisation, which degrades it;
  reference/calibration-anchors.md §3b) when the classic detector fails. The corner order is then fixed by the
  colour of the corner squares (the top-left square of the print is black), so two cameras
  seeing one board agree on point ids whenever the board is not symmetric under a half turn
  (inner corner counts of different parity, e.g. 9 x 6). Then every corner is refined by
  :func:`scanrig.calibration.corners.refine_corners` (blurred-saddle model fit; more accurate than
  both OpenCV refiners once the optics blur by >= 0.8 px, see benchmarks/bench_calibration.py).
- ChArUco and the cube: ``cv2.aruco`` marker detection once per image, then
  ``CharucoDetector.detectBoard`` per board with those markers, so a board cut by the image
  border or partly occluded still gives its visible corners. Then every corner is refined by
  :func:`scanrig.calibration.corners.refine_charuco_corners` (the saddle fit with the markers
  masked out, geometry from the board's homography). OpenCV's own ChArUco corners are good on
  faces seen head-on (0.04 px RMS on rendered cube sessions) but err by 0.3-0.5 px RMS on faces
  seen at 65-90 degrees, where its window reaches markers and neighbouring corners; refined,
  0.01 px and 0.015-0.05 px. A corner whose fit fails (mostly on faces seen nearly edge-on,
  where OpenCV's corner can be pixels off) is left out. An image in which no board is found is
  searched again with its grey levels inverted: boards printed white on black (caliscope's
  default, "inverted") have the same corners, and OpenCV finds their markers only so. Boards of
  OpenCV < 4.6's layout (``legacy = true``) and AprilTag dictionaries are detected the same way.
  A board with an even row count whose markers fit the other layout (legacy or current) than the
  declared one raises :class:`BoardLayoutError` (:func:`check_layout`): OpenCV then finds no
  corners, or corners shifted by a square.
- Circle grids: ``cv2.findCirclesGrid`` (symmetric or asymmetric).

Every detection has weight 1 (the common pixel noise is estimated by the bundle adjustment).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError
from scanrig.targets import Target
from scanrig.targets.boards import CharucoBoard, ChessBoard, CircleGridBoard, cv_dictionary

#: Markers of a board needed in a view to judge its layout (:func:`check_layout`).
LAYOUT_MIN_MARKERS = 4
#: The view shows the other layout when the markers' homography residual in the declared layout
#: exceeds this fraction of a marker side ...
LAYOUT_MIN_RESIDUAL = 0.05
#: ... and this many times their residual in the other layout. Measured on 335 random views
#: (perspective, barrel distortion k1 down to -0.4, blur, noise) of 6x4, 5x4, 7x6 and 8x6 boards:
#: the true layout never fits worse than the other (ratio <= 1.00002); the wrong one fits worse by
#: more than 4 times in every view but those whose markers are all shifted by one square alike.
LAYOUT_RESIDUAL_RATIO = 3.0


class BoardLayoutError(InputError):
    """The image shows a ChArUco board of the other layout (legacy or current) than declared."""


@dataclass
class Detection:
    """Target points found in one image.

    Attributes
    ----------
    point_ids : ndarray of shape (n,), int64
    uv : ndarray of shape (n, 2)
        Pixels, (0, 0) = centre of the top-left pixel.
    weight : ndarray of shape (n,)
    method : str
        Which detector produced them.
    """

    point_ids: np.ndarray
    uv: np.ndarray
    weight: np.ndarray
    method: str

    @classmethod
    def empty(cls, method: str = "none") -> Detection:
        return cls(np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros(0), method)


def to_grey8(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey image from 8/16-bit grey or RGB (16-bit scaled by its own maximum)."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = img.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    if img.dtype == np.uint8:
        return img
    img = img.astype(np.float64)
    top = img.max() if img.max() > 0 else 1.0
    top = max(255.0, top)
    return np.clip(np.round(img * (255.0 / top)), 0, 255).astype(np.uint8)


def detect_target(image: np.ndarray, target: Target, refine: bool = True) -> Detection:
    """Find the target's points in one image.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        8- or 16-bit image.
    target : Target
    refine : bool
        Chessboards: refine corners with the saddle-model fit (True) or keep OpenCV's positions.

    Returns
    -------
    Detection
        Empty when the target is not found.
    """
    grey = to_grey8(image)
    boards = target.boards
    if all(isinstance(b, CharucoBoard) for b in boards):
        return _detect_charuco(grey, boards, refine)
    if isinstance(boards[0], ChessBoard):
        return _detect_chessboard(grey, boards[0], refine)
    if isinstance(boards[0], CircleGridBoard):
        return _detect_circles(grey, boards[0])
    raise TypeError(f"no detector for boards of kind {boards[0].kind!r}")


def _detect_chessboard(grey: np.ndarray, board: ChessBoard, refine: bool) -> Detection:
    import cv2

    size = tuple(int(n) for n in board.inner_corners)
    found, corners = cv2.findChessboardCorners(grey, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH)
    if found:
        half = subpix_half_window(corners.reshape(-1, 2), size)
        corners = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4))
        method = "findChessboardCorners+cornerSubPix"
    else:
        found, corners = cv2.findChessboardCornersSB(grey, size, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        method = "findChessboardCornersSB"
        if not found:
            return Detection.empty(method)
    uv = orient_chessboard(grey, corners.reshape(-1, 2).astype(np.float64), size)
    if refine:
        from scanrig.calibration.corners import refine_corners

        uv, _ = refine_corners(grey, uv, size)
        method += "+saddle"
    return Detection(board.point_ids.copy(), uv, np.ones(len(uv)), method)


def subpix_half_window(uv: np.ndarray, size: tuple[int, int]) -> int:
    """Half-width (pixels) of a ``cornerSubPix`` window: 40 % of the smallest square side, 2..15.

    A window reaching a neighbouring corner biases the result; a tiny one is noise-limited.
    """
    grid = uv.reshape(size[1], size[0], 2)
    d = np.concatenate([np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel(),
                        np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel()])
    return int(np.clip(np.floor(0.4 * d.min()), 2, 15))


def orient_chessboard(grey: np.ndarray, uv: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Reorder corners so that point 0 is next to the print's black top-left square.

    A board with ``cols + rows`` odd has different colours at its two ends under a half turn; the
    square diagonally outside corner 0 must be black. Boards symmetric under a half turn are
    returned in OpenCV's order.
    """
    cols, rows = size
    if (cols + rows) % 2 == 0:
        return uv
    grid = uv.reshape(rows, cols, 2)
    step_col = grid[0, 1] - grid[0, 0]
    step_row = grid[1, 0] - grid[0, 0]
    outside = grid[0, 0] - 0.5 * (step_col + step_row)     # centre of square (0, 0)
    beside = grid[0, 0] + 0.5 * (step_col - step_row)      # centre of square (1, 0): white
    if _sample(grey, outside) > _sample(grey, beside):
        return uv[::-1].copy()
    return uv


def _sample(grey: np.ndarray, uv: np.ndarray) -> float:
    u = int(np.clip(np.round(uv[0]), 0, grey.shape[1] - 1))
    v = int(np.clip(np.round(uv[1]), 0, grey.shape[0] - 1))
    return float(grey[v, u])


def _detect_charuco(grey: np.ndarray, boards, refine: bool = True) -> Detection:
    """ChArUco corners of every board, from the image as it is or, when that finds none, inverted."""
    for image, print_kind in ((grey, ""), (255 - grey, " (inverted print)")):
        found = _detect_charuco_print(image, boards, refine)
        if len(found.point_ids):
            found.method += print_kind
            return found
    return found


def _detect_charuco_print(grey: np.ndarray, boards, refine: bool) -> Detection:
    """ChArUco corners of every board in a grey image of a black-on-white print."""
    import cv2

    dictionary = cv_dictionary(boards[0].dictionary)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    marker_corners, marker_ids, _ = cv2.aruco.ArucoDetector(dictionary, params).detectMarkers(grey)
    if marker_ids is None or len(marker_ids) == 0:
        return Detection.empty("charuco")
    ids, uvs = [], []
    flat_ids = marker_ids.ravel()
    for board in boards:
        mine = np.isin(flat_ids, board.marker_ids)
        if np.count_nonzero(mine) < 2:
            continue
        detector = cv2.aruco.CharucoDetector(board.cv_board())
        corners = [marker_corners[i] for i in np.flatnonzero(mine)]
        check_layout(board, np.concatenate(corners).astype(np.float64), flat_ids[mine])
        ch_corners, ch_ids, _, _ = detector.detectBoard(grey, markerCorners=corners,
                                                        markerIds=marker_ids[mine].reshape(-1, 1))
        if ch_ids is None or len(ch_ids) == 0:
            continue
        uv = ch_corners.reshape(-1, 2).astype(np.float64)
        local = ch_ids.ravel()
        if refine:
            from scanrig.calibration.corners import refine_charuco_corners

            # The refinement knows the current layout's square colours: a legacy board is fitted
            # in coordinates reflected to it (CharucoBoard.as_top_left_black).
            xy_board = board.as_top_left_black(board.points_board[local, :2])
            uv, ok = refine_charuco_corners(grey, uv, xy_board, board.square_m, board.marker_m, board.margin_m)
            # OpenCV's position of a corner the fit cannot refine is off by up to a few pixels
            # (a face seen edge-on): leave the corner out.
            uv, local = uv[ok], local[ok]
        ids.append(board.point_ids[local])
        uvs.append(uv)
    if not ids:
        return Detection.empty("charuco")
    point_ids = np.concatenate(ids)
    return Detection(point_ids, np.concatenate(uvs), np.ones(len(point_ids)),
                     "CharucoDetector+saddle" if refine else "CharucoDetector")


def check_layout(board: CharucoBoard, marker_uv: np.ndarray, marker_ids: np.ndarray) -> None:
    """Raise :class:`BoardLayoutError` when a board's markers fit its other layout clearly better.

    The legacy and current layouts of a board with an even row count put the same marker ids on
    different squares. Each layout's board positions of the seen markers' corners are fitted by
    one homography to their image positions; the true layout fits to lens distortion and noise,
    the other misplaces markers by a square (see :data:`LAYOUT_RESIDUAL_RATIO`). Two small
    least-squares fits per view; nothing when the layouts are the same print (odd row count).

    Parameters
    ----------
    board : CharucoBoard
    marker_uv : ndarray of shape (n, 4, 2)
        Corners of the board's detected markers, pixels, OpenCV's corner order.
    marker_ids : ndarray of shape (n,), int
        Their ids (all among ``board.marker_ids``).
    """
    if not board.layouts_differ or len(marker_ids) < LAYOUT_MIN_MARKERS:
        return
    declared = _marker_fit_residual(board, marker_uv, marker_ids)
    other = _marker_fit_residual(board.other_layout, marker_uv, marker_ids)
    if declared > LAYOUT_MIN_RESIDUAL and declared > LAYOUT_RESIDUAL_RATIO * other:
        shown, setting = (("OpenCV < 4.6's legacy layout (top-left square white)", "legacy = true")
                          if board.top_left_black else
                          ("OpenCV's current layout (top-left square black)", "legacy = false"))
        raise BoardLayoutError(
            f"the ChArUco board's markers follow {shown}, not the declared one (they fit it to "
            f"{other:.3f} marker sides, the declared one to {declared:.3f}): set {setting} in target.toml")


def _marker_fit_residual(board: CharucoBoard, marker_uv: np.ndarray, marker_ids: np.ndarray) -> float:
    """RMS residual of the homography from the markers' board corners to ``marker_uv``, in marker
    sides (the median side in the image); see :func:`check_layout` for the arguments."""
    import cv2

    xy = board.marker_corners_board[np.asarray(marker_ids) - board.first_marker_id].reshape(-1, 2)
    uv = marker_uv.reshape(-1, 2)
    H, _ = cv2.findHomography(xy.astype(np.float64), uv, 0)
    if H is None:
        return np.inf
    fitted = cv2.perspectiveTransform(xy.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
    side_px = np.median(np.linalg.norm(marker_uv - np.roll(marker_uv, 1, axis=1), axis=2))
    return float(np.sqrt(np.mean(np.sum((fitted - uv) ** 2, axis=1))) / side_px)


def _detect_circles(grey: np.ndarray, board: CircleGridBoard) -> Detection:
    import cv2

    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if board.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    # Dark discs on white: the default blob detector looks for dark blobs.
    found, centres = cv2.findCirclesGrid(grey, tuple(int(n) for n in board.grid), flags=flags)
    if not found:
        return Detection.empty("findCirclesGrid")
    uv = centres.reshape(-1, 2).astype(np.float64)
    return Detection(board.point_ids.copy(), uv, np.ones(len(uv)), "findCirclesGrid")
