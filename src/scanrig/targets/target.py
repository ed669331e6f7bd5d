"""A calibration target: a rigid set of boards, and constructors for every supported kind.

The target frame is the frame the calibration's world is anchored to (world = the target frame
at its first shot). Planar targets have one board whose frame is the target frame; the cube
has one ChArUco board per face and its target frame at the cube's centre, axes along its edges.

A planar target may be declared flexible (``flex=True``): its board then bends out of its plane
by two parabolic terms that the calibration estimates (:func:`flex_shape`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry.transform import RigidTransform
from scanrig.targets.boards import Board, CharucoBoard, ChessBoard, CircleGridBoard, check_length

#: Kinds of target, as written in ``target.toml``.
TARGET_KINDS = ("chessboard", "charuco", "circles", "circles_asym", "cube")

#: Cube faces in their canonical order (board ``face<k>`` is on ``CUBE_FACES[k]``): the outward normal.
CUBE_FACES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0),
              "+z": (0, 0, 1), "-z": (0, 0, -1)}


@dataclass(frozen=True)
class Target:
    """A rigid set of boards.

    Attributes
    ----------
    kind : str
        One of :data:`TARGET_KINDS`.
    boards : tuple of Board
        Boards with disjoint point ids, each posed in the target frame.
    spec : dict
        The ``target.toml`` fields this target was built from (written back by ``save_target``).
    flex : bool
        The board bends (:func:`flex_shape`); calibration then estimates two flex terms. Only
        for a planar target: the boards of a multi-board target are rigidly joined.
    """

    kind: str
    boards: tuple[Board, ...]
    spec: dict = field(default_factory=dict, compare=False)
    flex: bool = False

    def __post_init__(self):
        if self.kind not in TARGET_KINDS:
            raise InputError(f"target kind must be one of {list(TARGET_KINDS)}, got {self.kind!r}")
        if not isinstance(self.flex, bool):
            raise InputError(f"flex must be true or false, got {self.flex!r}")
        if self.flex and len(self.boards) != 1:
            raise InputError(f"flex = true needs a planar target (one board); a {self.kind} target has "
                             f"{len(self.boards)} rigidly joined boards, whose bending is not modelled")
        ids = np.concatenate([b.point_ids for b in self.boards])
        if len(np.unique(ids)) != len(ids):
            raise InputError("target boards must have disjoint point ids (set id_offset)")

    @functools.cached_property
    def points_target(self) -> np.ndarray:
        """(M, 3) every target point in the target frame, metres, in :attr:`point_ids` order."""
        return np.concatenate([b.points_target for b in self.boards])

    @functools.cached_property
    def point_ids(self) -> np.ndarray:
        """(M,) int64 ids of :attr:`points_target`."""
        return np.concatenate([b.point_ids for b in self.boards])

    @functools.cached_property
    def point_board_index(self) -> np.ndarray:
        """(M,) index into :attr:`boards` of the board carrying each point."""
        return np.concatenate([np.full(len(b.point_ids), k) for k, b in enumerate(self.boards)])

    def _positions(self, point_ids) -> tuple[np.ndarray, np.ndarray]:
        """Index into :attr:`point_ids` of each id, and whether the id is known."""
        ids = np.asarray(point_ids, dtype=np.int64).ravel()
        order = np.argsort(self.point_ids)
        sorted_ids = self.point_ids[order]
        pos = np.clip(np.searchsorted(sorted_ids, ids), 0, len(sorted_ids) - 1)
        known = sorted_ids[pos] == ids
        return order[pos], known

    def lookup(self, point_ids) -> tuple[np.ndarray, np.ndarray]:
        """Target-frame coordinates of points given by id.

        Parameters
        ----------
        point_ids : array_like of int, shape (N,)

        Returns
        -------
        points : ndarray of shape (N, 3)
            Target frame, metres; NaN for ids the target does not have.
        known : ndarray of shape (N,), bool
        """
        index, known = self._positions(point_ids)
        points = np.full((len(index), 3), np.nan)
        points[known] = self.points_target[index[known]]
        return points, known

    def board_of(self, point_ids) -> np.ndarray:
        """(N,) index into :attr:`boards` of the board carrying each id; -1 for unknown ids."""
        index, known = self._positions(point_ids)
        return np.where(known, self.point_board_index[index], -1)

    def points_on_board(self, point_ids) -> np.ndarray:
        """(N, 3) coordinates of points (ids must be known) in their own board's frame, metres."""
        index, known = self._positions(point_ids)
        if not np.all(known):
            raise InputError(f"unknown target point ids {np.asarray(point_ids)[~known][:5].tolist()}")
        local = np.concatenate([b.points_board for b in self.boards])
        return local[index]

    def flex_directions(self, point_ids) -> np.ndarray:
        """(N, 3, 2) displacement of each point (ids must be known) in the target frame per metre
        of the two flex terms ``(c_x, c_y)`` of :func:`flex_shape`: along its board's z axis."""
        index, _ = self._positions(point_ids)
        local = self.points_on_board(point_ids)
        board = self.point_board_index[index]
        shape = np.empty((len(local), 2))
        normal = np.empty((len(local), 3))
        for k, b in enumerate(self.boards):
            rows = board == k
            shape[rows] = flex_shape(b, local[rows, :2])
            normal[rows] = b.target_from_board.R[:, 2]
        return normal[:, :, None] * shape[:, None, :]

    @property
    def is_planar(self) -> bool:
        """True when every point lies in one plane (a single board)."""
        return len(self.boards) == 1


def flex_shape(board: Board, xy_board) -> np.ndarray:
    """Out-of-plane height of a bent board per metre of each of its two flex terms.

    The bent board's surface is ``z = c_x (1 - u²) + c_y (1 - v²)`` in the board frame (z into
    the board, away from a viewer reading the print), with ``u = (x - x0) / wx`` and
    ``v = (y - y0) / wy``: ``(x0, y0)`` the centre and ``(wx, wy)`` the half-widths of the
    board's grid of target points. ``c_x`` is the sag along x: the height of the grid's centre
    above the line joining the midpoints of its left and right edges (``c_y`` likewise along y);
    the grid's centre is at ``c_x + c_y`` and its four outer corners at 0. Points keep their
    printed (x, y): a 1 mm bend over 0.3 m shortens the board by 9 µm, which is left out.

    Parameters
    ----------
    board : Board
    xy_board : array_like of shape (N, 2)
        Board coordinates (x, y), metres.

    Returns
    -------
    ndarray of shape (N, 2)
        ``(1 - u², 1 - v²)``, dimensionless: the height is this times ``(c_x, c_y)``.
    """
    grid = board.points_local
    lo, hi = grid.min(axis=0), grid.max(axis=0)
    uv = (np.asarray(xy_board, dtype=np.float64) - 0.5 * (lo + hi)) / (0.5 * (hi - lo))
    return 1.0 - uv ** 2


def _flex_spec(spec: dict, flex: bool) -> dict:
    """``spec`` with ``flex = true`` added when set (a rigid target's file stays as it was)."""
    return {**spec, "flex": True} if flex else spec


def chessboard(inner_corners=(9, 6), square_m=0.025, margin_m=None, flex=False) -> Target:
    """A planar chessboard target; ``margin_m`` defaults to one square; ``flex`` see :class:`Target`."""
    check_length(square_m, "square_m")
    margin = square_m if margin_m is None else margin_m
    inner_corners = _pair(inner_corners, "inner_corners")
    board = ChessBoard("board", inner_corners=inner_corners, square_m=square_m, margin_m=margin)
    spec = {"kind": "chessboard", "inner_corners": list(inner_corners), "square_m": square_m, "margin_m": margin}
    return Target("chessboard", (board,), _flex_spec(spec, flex), flex)


def charuco(squares=(7, 5), square_m=0.04, marker_m=0.03, dictionary="DICT_5X5_1000",
            first_marker_id=0, margin_m=None, flex=False, legacy=False) -> Target:
    """A planar ChArUco target (OpenCV layout); ``margin_m`` defaults to half a square; ``flex``
    see :class:`Target`; ``legacy`` a board of OpenCV < 4.6's layout (:class:`CharucoBoard`)."""
    check_length(square_m, "square_m")
    margin = 0.5 * square_m if margin_m is None else margin_m
    squares = _pair(squares, "squares")
    board = CharucoBoard("board", squares=squares, square_m=square_m, marker_m=marker_m,
                         dictionary=dictionary, first_marker_id=first_marker_id, margin_m=margin, legacy=legacy)
    spec = {"kind": "charuco", "squares": list(squares), "square_m": square_m, "marker_m": marker_m,
            "dictionary": dictionary, "first_marker_id": first_marker_id, "margin_m": margin}
    if legacy:
        spec["legacy"] = True               # a current-layout board's file stays as it was
    return Target("charuco", (board,), _flex_spec(spec, flex), flex)


def circle_grid(grid=(4, 11), spacing_m=0.02, diameter_m=None, asymmetric=False, margin_m=None,
                flex=False) -> Target:
    """A planar circle-grid target (OpenCV layout); diameter defaults to half the neighbour
    distance; ``flex`` see :class:`Target`."""
    check_length(spacing_m, "spacing_m")
    diameter = 0.5 * spacing_m if diameter_m is None else diameter_m
    margin = spacing_m if margin_m is None else margin_m
    grid = _pair(grid, "grid")
    board = CircleGridBoard("board", grid=grid, spacing_m=spacing_m, diameter_m=diameter,
                            asymmetric=asymmetric, margin_m=margin)
    kind = board.kind
    spec = {"kind": kind, "grid": list(grid), "spacing_m": spacing_m, "diameter_m": diameter, "margin_m": margin}
    return Target(kind, (board,), _flex_spec(spec, flex), flex)


def cube(edge_m=0.2, squares=7, square_m=0.025, marker_m=0.01875, dictionary="DICT_5X5_1000",
         faces=tuple(CUBE_FACES), flex=False) -> Target:
    """A cube with a ChArUco board on each chosen face; target frame at the cube centre.

    Parameters
    ----------
    edge_m : float
        Cube edge, metres; each face board is ``edge_m`` square, its squares centred on the face.
    squares : int
        Squares per face side.
    square_m, marker_m : float
        ChArUco square and marker side, metres (``squares * square_m <= edge_m``).
    dictionary : str
        ArUco dictionary; face ``k`` uses marker ids from ``k * n_markers`` so ids are disjoint.
    faces : sequence of str
        Faces carrying a board, among ``"+x" "-x" "+y" "-y" "+z" "-z"`` (outward normal in the
        target frame); e.g. leave out ``"-z"`` for a cube standing on its bottom face.
    flex : bool
        Refused when true (:class:`InputError`): the faces are rigidly joined.

    Notes
    -----
    Each face board's frame has its origin at the face's printed top-left corner and its z axis
    pointing into the cube. On the four side faces the print's "up" is +z of the target; on the
    top face (+z) it is -x and on the bottom face (-z) +x. Board ``face<k>`` is on face
    ``list(CUBE_FACES)[k]`` whatever subset is chosen, so ids do not depend on ``faces``.
    """
    names = list(CUBE_FACES)
    if isinstance(faces, str) or not isinstance(faces, (list, tuple)):
        raise InputError(f"faces must be a list of face names among {names}, got {faces!r}")
    unknown = [f for f in faces if not isinstance(f, str) or f not in CUBE_FACES]
    if unknown or not faces or len(set(faces)) != len(faces):
        raise InputError(f"faces must be distinct names among {names}, got {list(faces)!r}")
    if not (isinstance(squares, (int, np.integer)) and not isinstance(squares, bool) and squares >= 2):
        raise InputError(f"squares must be an integer >= 2, got {squares!r}")
    check_length(edge_m, "edge_m")
    check_length(square_m, "square_m")
    margin = 0.5 * (edge_m - squares * square_m)
    if margin < 0:
        raise InputError(f"squares * square_m ({squares * square_m:.6g} m) exceeds edge_m ({edge_m} m)")
    n_markers = (squares * squares) // 2
    n_corners = (squares - 1) ** 2
    boards = []
    for k, face in enumerate(names):
        if face not in faces:
            continue
        boards.append(CharucoBoard(
            f"face{k}", squares=(squares, squares), square_m=square_m, marker_m=marker_m,
            dictionary=dictionary, first_marker_id=k * n_markers, margin_m=margin,
            target_from_board=_cube_face_pose(np.array(CUBE_FACES[face], dtype=np.float64), edge_m),
            id_offset=k * n_corners,
        ))
    spec = {"kind": "cube", "edge_m": edge_m, "squares": squares, "square_m": square_m, "marker_m": marker_m,
            "dictionary": dictionary, "faces": list(faces)}
    return Target("cube", tuple(boards), spec, flex)


def _cube_face_pose(normal: np.ndarray, edge_m: float) -> RigidTransform:
    """``target_from_board`` of the board on the face with outward ``normal`` (see :func:`cube`)."""
    up = np.array([0.0, 0.0, 1.0]) if normal[2] == 0 else np.array([-normal[2], 0.0, 0.0])
    y = -up                      # rows of the print run downwards
    z = -normal                  # into the cube
    x = np.cross(y, z)
    R = np.column_stack([x, y, z])
    origin = 0.5 * edge_m * (normal - x - y)
    return RigidTransform(R, origin)


def _pair(value, name: str) -> tuple:
    """``value`` as a 2-tuple, or :class:`InputError` naming ``name``."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise InputError(f"{name} must be two integers (columns, rows), got {value!r}")
    return tuple(value)
