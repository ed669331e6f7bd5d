"""``scan/object_poses.csv``: where a moving object (turntable, linear stage) was at each scan frame.

A fixed laser plane lights one profile of the object per frame; the object moves between frames by
a known motion. The file gives that motion as ``world_from_object`` per frame stem (world frame of
``rig.toml``, metres), so the profiles can be mapped into the object's own frame and accumulate
into one cloud::

    frame,r00,r01,r02,r10,r11,r12,r20,r21,r22,tx_m,ty_m,tz_m
    00000,1.0,0.0,0.0,0.0,1.0,0.0,0.0,0.0,1.0,0.0,0.0,0.0

``r<i><j>`` is row ``i``, column ``j`` of the rotation; ``p_world = R @ p_object + t``. A turntable
turning by ``θ`` about an axis through ``a`` with unit direction ``u`` gives ``R = rot(u, θ)`` and
``t = a − R a``. The rotation may carry the round-off of a few printed digits (up to
:data:`ORTHONORMAL_TOL_FILE`); it is projected onto the nearest rotation on reading.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError
from scanrig.geometry.transform import RigidTransform
from scanrig.io.atomic import write_text_atomic
from scanrig.io.csv_rows import read_csv_rows

#: Path of the file inside a session folder.
OBJECT_POSES_FILE = Path("scan") / "object_poses.csv"
#: Words that ``points.ply`` headers (the ``mode:`` line) carry when the points are in the object frame.
OBJECT_FRAME_NOTE = f"object frame of {OBJECT_POSES_FILE.as_posix()}"
#: Columns, in file order.
COLUMNS = ("frame", *(f"r{i}{j}" for i in range(3) for j in range(3)), "tx_m", "ty_m", "tz_m")
#: Largest deviation of ``R Rᵀ`` from the identity accepted in a file (7 printed digits suffice).
ORTHONORMAL_TOL_FILE = 1e-6


def object_poses_path(session_root: str | Path) -> Path:
    """``SESSION/scan/object_poses.csv`` (whether or not it exists)."""
    return Path(session_root) / OBJECT_POSES_FILE


def read_object_poses(path: str | Path) -> dict[str, RigidTransform]:
    """Read ``world_from_object`` of every frame.

    Parameters
    ----------
    path : str or Path
        An ``object_poses.csv`` file.

    Returns
    -------
    dict of str to RigidTransform
        Frame stem -> ``world_from_object``, in file order.

    Raises
    ------
    FileFormatError
        Naming the file and the line: missing file or column, a cell that is not a finite number,
        a frame listed twice, a matrix that is not a proper rotation.
    """
    path = Path(path)
    rows = read_csv_rows(path, COLUMNS, "object poses file")
    poses: dict[str, RigidTransform] = {}
    for line, row in rows:
        frame = row["frame"].strip()
        if not frame:
            raise FileFormatError(path, f"line {line}: empty frame stem")
        if frame in poses:
            raise FileFormatError(path, f"line {line}: frame {frame!r} is listed twice")
        try:
            values = np.array([float(row[c]) for c in COLUMNS[1:]])
        except ValueError:
            raise FileFormatError(path, f"line {line}: every cell but 'frame' must be a number") from None
        if not np.all(np.isfinite(values)):
            raise FileFormatError(path, f"line {line}: cells must be finite numbers")
        R = values[:9].reshape(3, 3)
        if np.abs(R @ R.T - np.eye(3)).max() > ORTHONORMAL_TOL_FILE or np.linalg.det(R) < 0:
            raise FileFormatError(path, f"line {line}: r00..r22 of frame {frame!r} are not a proper rotation "
                                        f"(orthonormal to {ORTHONORMAL_TOL_FILE:g}, determinant +1)")
        U, _, Vt = np.linalg.svd(R)
        poses[frame] = RigidTransform(U @ Vt, values[9:])
    if not poses:
        raise FileFormatError(path, "holds no poses")
    return poses


def write_object_poses(path: str | Path, poses: dict[str, RigidTransform]) -> None:
    """Write ``world_from_object`` per frame stem (atomically, full float precision).

    Raises
    ------
    InputError
        If ``poses`` is empty.
    """
    if not poses:
        raise InputError("write_object_poses needs at least one pose")
    lines = [",".join(COLUMNS)]
    for frame, pose in poses.items():
        lines.append(",".join([frame, *(repr(float(v)) for v in (*pose.R.ravel(), *pose.t))]))
    write_text_atomic(path, "\n".join(lines) + "\n")
