"""Calibration targets: planar chessboard, ChArUco and circle grids, and the ChArUco cube.

A :class:`Target` is a rigid set of flat :class:`Board` objects, each posed in the target frame,
with target points (inner corners or circle centres) whose ids are unique over the target.
Both the simulator (to render targets) and calibration (to detect and solve) use this package.

>>> from scanrig.targets import cube
>>> target = cube(edge_m=0.2)
>>> target.points_target.shape
(216, 3)
"""

from scanrig.targets.boards import Board, CharucoBoard, ChessBoard, CircleGridBoard
from scanrig.targets.target import CUBE_FACES, TARGET_KINDS, Target, charuco, chessboard, circle_grid, cube
from scanrig.targets.target_file import load_target, save_target, target_to_toml

__all__ = [
    "CUBE_FACES", "TARGET_KINDS", "Board", "CharucoBoard", "ChessBoard", "CircleGridBoard", "Target",
    "charuco", "chessboard", "circle_grid", "cube", "load_target", "save_target", "target_to_toml",
]
