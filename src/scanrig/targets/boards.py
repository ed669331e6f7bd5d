"""Planar boards: chessboard, ChArUco and circle grids, each posed in its target's frame.

Board frame (all kinds): origin at the top-left corner of the printed area (margin included),
x along the printed rows to the right, y down the printed columns, **z into the board** (away
from a viewer who reads the print), so a camera looking at the printed side sees the board's z
axis pointing forward, like its own optical axis. All board points lie in z = 0.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry.transform import RigidTransform
from scanrig.targets import patterns

#: Marker dictionaries accepted by name (OpenCV's ``cv2.aruco.DICT_*`` constants): ArUco and AprilTag.
ARUCO_DICTIONARIES = tuple(
    f"DICT_{bits}X{bits}_{n}" for bits in (4, 5, 6, 7) for n in (50, 100, 250, 1000)
) + ("DICT_ARUCO_ORIGINAL",) + tuple(f"DICT_APRILTAG_{family}" for family in ("16h5", "25h9", "36h10", "36h11"))


@dataclass(frozen=True)
class Board:
    """A flat printed board; subclasses define the points and the look.

    Attributes
    ----------
    name : str
        Unique within the target (``"board"`` for planar targets, ``"face0"``.. for the cube).
    target_from_board : RigidTransform
        Pose of the board in the target frame.
    id_offset : int
        Added to the board's local point indices to give ids unique over the whole target.
    """

    name: str
    target_from_board: RigidTransform = field(default_factory=RigidTransform.identity, kw_only=True)
    id_offset: int = field(default=0, kw_only=True)

    kind = "board"

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the printed area, metres."""
        raise NotImplementedError

    @property
    def points_local(self) -> np.ndarray:
        """(N, 2) target points in board coordinates (x, y), metres, in local-index order."""
        raise NotImplementedError

    @property
    def points_board(self) -> np.ndarray:
        """(N, 3) target points in the board frame, metres; z = 0."""
        xy = self.points_local
        return np.column_stack([xy, np.zeros(len(xy))])

    @property
    def point_ids(self) -> np.ndarray:
        """(N,) int64 ids of :attr:`points_board`, unique over the whole target."""
        return np.arange(len(self.points_local), dtype=np.int64) + self.id_offset

    @property
    def points_target(self) -> np.ndarray:
        """(N, 3) target points in the target frame, metres."""
        return self.target_from_board.apply(self.points_board)

    def reflectance(self, xy_board) -> np.ndarray:
        """Printed reflectance at board coordinates.

        Parameters
        ----------
        xy_board : array_like of shape (N, 2)
            Board coordinates (x, y), metres; outside the printed area counts as white paper.

        Returns
        -------
        ndarray of shape (N,)
            0.0 for black ink, 1.0 for white paper.
        """
        raise NotImplementedError

    def pattern(self, px_per_m: float, supersample: int = 1) -> np.ndarray:
        """The printed pattern as an (H, W) uint8 image (0 black, 255 white).

        Pixel (0, 0) has its centre at board coordinates ``(0.5, 0.5) / px_per_m``; x runs along
        columns, y along rows. ``supersample > 1`` averages that many samples per pixel side.
        """
        return patterns.rasterise(self.reflectance, self.size_m, px_per_m, supersample)


@dataclass(frozen=True)
class ChessBoard(Board):
    """A chessboard with a white margin; the top-left square is black.

    Parameters
    ----------
    inner_corners : (int, int)
        Inner corners along x (columns) and y (rows); there is one square more each way.
    square_m : float
        Square side, metres.
    margin_m : float
        White border around the squares, metres.

    Notes
    -----
    Point ``k`` is the inner corner in column ``k % cols`` and row ``k // cols``, at
    ``margin + ((k % cols) + 1, (k // cols) + 1) * square`` (OpenCV's row-major order).
    """

    inner_corners: tuple[int, int] = (9, 6)
    square_m: float = 0.025
    margin_m: float = 0.025

    kind = "chessboard"
    #: As :attr:`CharucoBoard.top_left_black`: a chessboard has no other layout.
    top_left_black = True

    def __post_init__(self):
        _check_grid(self.inner_corners, "inner_corners", minimum=2)
        check_length(self.square_m, "square_m")
        check_length(self.margin_m, "margin_m", allow_zero=True)

    @property
    def squares(self) -> tuple[int, int]:
        """Squares along x and y."""
        return (self.inner_corners[0] + 1, self.inner_corners[1] + 1)

    @property
    def size_m(self):
        return tuple(n * self.square_m + 2 * self.margin_m for n in self.squares)

    @property
    def points_local(self):
        return _grid_points(self.inner_corners, self.square_m, self.margin_m + self.square_m)

    def reflectance(self, xy_board):
        xy = np.asarray(xy_board, dtype=np.float64)
        return patterns.chessboard_reflectance(xy, self.squares, self.square_m, self.margin_m)


@dataclass(frozen=True)
class CharucoBoard(Board):
    """A ChArUco board (OpenCV's layout): chessboard with ArUco markers in the white squares.

    Parameters
    ----------
    squares : (int, int)
        Squares along x (columns) and y (rows).
    square_m, marker_m : float
        Square and marker side, metres (marker < square).
    dictionary : str
        Marker dictionary name (:data:`ARUCO_DICTIONARIES`), e.g. ``"DICT_5X5_1000"`` or
        ``"DICT_APRILTAG_36h11"``.
    first_marker_id : int
        Marker ids are ``first_marker_id, first_marker_id + 1, ...`` in OpenCV's order, so several
        boards of one target use disjoint ids.
    margin_m : float
        White border, metres.
    legacy : bool
        The board follows OpenCV < 4.6's layout (``CharucoBoard.setLegacyPattern(True)``).

    Notes
    -----
    The top-left square is black (OpenCV ≥ 4.6 layout, legacy pattern off). The legacy layout
    differs only with an even number of rows: its top-left square is white and carries marker 0,
    every square has the other colour, and the markers sit in the other half of the squares (so
    at other places); with an odd number of rows both layouts are the same print. Point ``k`` is
    the inner ChArUco corner in column ``k % (cols - 1)`` and row ``k // (cols - 1)``, OpenCV's
    ChArUco corner id, in both layouts.
    """

    squares: tuple[int, int] = (7, 7)
    square_m: float = 0.025
    marker_m: float = 0.01875
    dictionary: str = "DICT_5X5_1000"
    first_marker_id: int = 0
    margin_m: float = 0.0
    legacy: bool = False

    kind = "charuco"

    def __post_init__(self):
        _check_grid(self.squares, "squares", minimum=2)
        check_length(self.square_m, "square_m")
        check_length(self.marker_m, "marker_m")
        check_length(self.margin_m, "margin_m", allow_zero=True)
        if self.marker_m >= self.square_m:
            raise InputError(f"marker_m ({self.marker_m}) must be smaller than square_m ({self.square_m})")
        if self.dictionary not in ARUCO_DICTIONARIES:
            raise InputError(f"dictionary must be one of {list(ARUCO_DICTIONARIES)}, got {self.dictionary!r}")
        if isinstance(self.first_marker_id, bool) or not isinstance(self.first_marker_id, (int, np.integer)) \
                or self.first_marker_id < 0:
            raise InputError(f"first_marker_id must be a non-negative integer, got {self.first_marker_id!r}")
        if not isinstance(self.legacy, bool):
            raise InputError(f"legacy must be true or false, got {self.legacy!r}")
        capacity = _dictionary_size(self.dictionary)
        if self.first_marker_id + self.n_markers > capacity:
            raise InputError(
                f"{self.dictionary} has {capacity} markers; this board needs ids "
                f"{self.first_marker_id}..{self.first_marker_id + self.n_markers - 1}: use a larger dictionary"
            )

    @property
    def n_markers(self) -> int:
        """Number of ArUco markers (one per white square; the same in both layouts)."""
        return (self.squares[0] * self.squares[1]) // 2

    @property
    def marker_ids(self) -> np.ndarray:
        """(n_markers,) ArUco ids in OpenCV's board order."""
        return np.arange(self.n_markers) + self.first_marker_id

    @property
    def layouts_differ(self) -> bool:
        """Whether OpenCV's legacy and current layouts are different prints at this size (even rows)."""
        return self.squares[1] % 2 == 0

    @property
    def top_left_black(self) -> bool:
        """Whether the top-left square is black: false only for the legacy layout with even rows."""
        return not (self.legacy and self.layouts_differ)

    @functools.cached_property
    def other_layout(self) -> CharucoBoard:
        """The same board with ``legacy`` flipped (to tell the user which layout the images show)."""
        return replace(self, legacy=not self.legacy)

    @property
    def size_m(self):
        return tuple(n * self.square_m + 2 * self.margin_m for n in self.squares)

    @property
    def points_local(self):
        inner = (self.squares[0] - 1, self.squares[1] - 1)
        return _grid_points(inner, self.square_m, self.margin_m + self.square_m)

    def cv_board(self):
        """The equivalent ``cv2.aruco.CharucoBoard`` (board units metres, no margin)."""
        import cv2

        board = cv2.aruco.CharucoBoard(tuple(int(n) for n in self.squares), float(self.square_m),
                                       float(self.marker_m), cv_dictionary(self.dictionary),
                                       self.marker_ids.astype(np.int32))
        board.setLegacyPattern(self.legacy)
        return board

    @functools.cached_property
    def marker_corners_board(self) -> np.ndarray:
        """(n_markers, 4, 2) float32 corners of every marker in board coordinates (margin included),
        metres, in :attr:`marker_ids` order and OpenCV's corner order (top-left first, clockwise);
        float32 as OpenCV gives them."""
        return np.array(self.cv_board().getObjPoints())[:, :, :2] + self.margin_m

    @functools.cached_property
    def marker_layout(self):
        """(top-left corners (n, 2) in board coordinates, bit images (n, c, c) with 1 = white)."""
        import cv2

        dictionary = cv_dictionary(self.dictionary)
        n_cells = dictionary.markerSize + 2
        bits = np.stack([cv2.aruco.generateImageMarker(dictionary, int(i), n_cells, borderBits=1) // 255
                         for i in self.marker_ids])
        return self.marker_corners_board[:, 0], bits.astype(np.float64)

    def as_top_left_black(self, xy_board) -> np.ndarray:
        """Board coordinates in which this print's chessboard has its top-left square black.

        A legacy-layout board (even rows) reflected top to bottom (y -> height - y) has the
        current layout's square colours, so the code written for that layout (the reflectance of
        :mod:`scanrig.targets.patterns`, the ChArUco corner refinement) serves it unchanged when
        given these coordinates; its markers are reflected with them (:meth:`reflectance`).

        Parameters
        ----------
        xy_board : array_like of shape (N, 2)
            Board coordinates, metres.

        Returns
        -------
        ndarray of shape (N, 2)
            Metres; ``xy_board`` itself (as float array) when the top-left square is black.
        """
        xy = np.asarray(xy_board, dtype=np.float64)
        if self.top_left_black:
            return xy
        return np.column_stack([xy[:, 0], self.size_m[1] - xy[:, 1]])

    @functools.cached_property
    def _markers_top_left_black(self):
        """:attr:`marker_layout` in the coordinates of :meth:`as_top_left_black`."""
        corners, bits = self.marker_layout
        if self.top_left_black:
            return corners, bits
        bottom_left = self.marker_corners_board[:, 3]
        return self.as_top_left_black(bottom_left), bits[:, ::-1, :]

    def reflectance(self, xy_board):
        corners, bits = self._markers_top_left_black
        return patterns.charuco_reflectance(self.as_top_left_black(xy_board), self.squares, self.square_m,
                                            self.margin_m, self.marker_m, corners, bits)


@dataclass(frozen=True)
class CircleGridBoard(Board):
    """Black discs on white paper, in OpenCV's symmetric or asymmetric grid.

    Parameters
    ----------
    grid : (int, int)
        OpenCV's ``patternSize``: discs per row and number of rows.
    spacing_m : float
        Symmetric: distance between neighbouring centres. Asymmetric: OpenCV's ``squareSize``,
        half the distance between neighbours of one row.
    diameter_m : float
        Disc diameter, metres.
    asymmetric : bool
        OpenCV's ``CALIB_CB_ASYMMETRIC_GRID`` layout: odd rows shifted by ``spacing_m``.
    margin_m : float
        White border around the outermost discs' bounding squares, metres.

    Notes
    -----
    Point ``k`` (row ``i = k // cols``, column ``j = k % cols``) is at
    ``margin + (j, i) * spacing + spacing / 2`` (symmetric) or
    ``margin + ((2 j + i % 2), i) * spacing + spacing / 2`` (asymmetric), OpenCV's order.
    """

    grid: tuple[int, int] = (4, 11)
    spacing_m: float = 0.02
    diameter_m: float = 0.01
    asymmetric: bool = False
    margin_m: float = 0.02

    def __post_init__(self):
        _check_grid(self.grid, "grid", minimum=2)
        check_length(self.spacing_m, "spacing_m")
        check_length(self.diameter_m, "diameter_m")
        check_length(self.margin_m, "margin_m", allow_zero=True)
        neighbour_m = self.spacing_m * (np.sqrt(2.0) if self.asymmetric else 1.0)
        if self.diameter_m >= neighbour_m:
            raise InputError(
                f"diameter_m ({self.diameter_m}) must be smaller than the distance between neighbouring "
                f"centres ({neighbour_m:.6g} m)"
            )

    @property
    def kind(self):
        return "circles_asym" if self.asymmetric else "circles"

    @property
    def size_m(self):
        cols, rows = self.grid
        width_cells = 2 * cols if self.asymmetric else cols
        return (width_cells * self.spacing_m + 2 * self.margin_m, rows * self.spacing_m + 2 * self.margin_m)

    @property
    def points_local(self):
        cols, rows = self.grid
        i, j = np.divmod(np.arange(cols * rows), cols)
        x = (2 * j + i % 2) if self.asymmetric else j
        return np.column_stack([x, i]).astype(np.float64) * self.spacing_m + self.margin_m + 0.5 * self.spacing_m

    def reflectance(self, xy_board):
        xy = np.asarray(xy_board, dtype=np.float64)
        return patterns.circles_reflectance(xy, self.points_local, self.spacing_m, self.diameter_m)


def _grid_points(counts: tuple[int, int], step_m: float, start_m: float) -> np.ndarray:
    """Row-major grid ``(cols * rows, 2)``: point k at ``start + (k % cols, k // cols) * step``."""
    cols, rows = counts
    i, j = np.divmod(np.arange(cols * rows), cols)
    return np.column_stack([j, i]).astype(np.float64) * step_m + start_m


def cv_dictionary(name: str):
    """OpenCV's predefined marker dictionary ``name`` (one of :data:`ARUCO_DICTIONARIES`)."""
    import cv2

    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def _dictionary_size(name: str) -> int:
    return int(cv_dictionary(name).bytesList.shape[0])


def _check_grid(value, name: str, minimum: int) -> None:
    ok = (isinstance(value, (tuple, list)) and len(value) == 2
          and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= minimum for v in value))
    if not ok:
        raise InputError(f"{name} must be two integers >= {minimum} (columns, rows), got {value!r}")


#: No printed target is a kilometre across; larger values are typing errors (and overflow later).
MAX_LENGTH_M = 1000.0


def _finite(value) -> bool:
    """Whether a number is finite as a float (a TOML integer beyond float range is not)."""
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def check_length(value, name: str, allow_zero: bool = False) -> None:
    """Raise :class:`InputError` naming ``name`` unless ``value`` is a positive (or zero) length
    in metres below :data:`MAX_LENGTH_M`."""
    ok = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool) \
        and _finite(value) and (value >= 0 if allow_zero else value > 0) and value < MAX_LENGTH_M
    if not ok:
        kind = "non-negative" if allow_zero else "positive"
        raise InputError(f"{name} must be a {kind} length in metres below {MAX_LENGTH_M:g}, got {value!r}")
