"""Target-point detections as CSV, to compare tools on identical input.

Columns (header required; ``weight`` optional, default 1)::

    image,camera,point_id,x,y,weight
    000,cam0,17,512.25,400.75,1.0

``image`` is the shot stem (same stem = same instant in every camera), ``point_id`` the target
point id (``Target.point_ids``), ``x, y`` the pixel (u, v) with (0, 0) the centre of the
top-left pixel.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from scanrig.calibration.observations import Observations
from scanrig.errors import FileFormatError
from scanrig.io.atomic import atomic_write
from scanrig.io.csv_rows import read_csv_rows
from scanrig.io.session import natural_key

COLUMNS = ("image", "camera", "point_id", "x", "y", "weight")
_REQUIRED = ("image", "camera", "point_id", "x", "y")


def read_corners_csv(path: str | Path, image_sizes: dict[str, tuple[int, int]],
                     camera_names: list[str] | None = None) -> Observations:
    """Read detections.

    Parameters
    ----------
    path : str or Path
    image_sizes : dict
        ``camera -> (width, height)``, pixels (a CSV does not carry image sizes).
    camera_names : list of str, optional
        Rig order; default: cameras of the file in natural order.

    Raises
    ------
    FileFormatError
        Missing file or column, a row whose cells do not match the header, a non-numeric or
        non-finite value, a weight that is not positive, or a camera without an image size.
    """
    path = Path(path)
    rows = read_csv_rows(path, _REQUIRED, "corners file", COLUMNS)
    if not rows:
        raise FileFormatError(path, "no detections in file")
    images = [r["image"] for _, r in rows]
    cams = [r["camera"] for _, r in rows]
    ids, x, y, weight = zip(*(_numbers(path, line, r) for line, r in rows))
    names = camera_names or sorted(set(cams), key=natural_key)
    unknown = sorted(set(cams) - set(names))
    if unknown:
        raise FileFormatError(path, f"cameras {unknown} are not in the rig {names}")
    missing_sizes = [c for c in names if c not in image_sizes]
    if missing_sizes:
        raise FileFormatError(path, f"no image size known for cameras {missing_sizes}")
    shots = sorted(set(images), key=natural_key)
    cam_index = {c: i for i, c in enumerate(names)}
    shot_index = {s: i for i, s in enumerate(shots)}
    return Observations(np.array([cam_index[c] for c in cams]), np.array([shot_index[s] for s in images]),
                        np.array(ids, dtype=np.int64), np.column_stack([x, y]), np.array(weight), names, shots,
                        {c: tuple(image_sizes[c]) for c in names})


def _numbers(path: Path, line: int, row: dict) -> tuple[int, float, float, float]:
    """``point_id, x, y, weight`` of one row: numbers, finite pixel, positive finite weight."""
    try:
        point_id, x, y = int(row["point_id"]), float(row["x"]), float(row["y"])
        weight = float(row.get("weight") or 1.0)
    except ValueError as exc:
        raise FileFormatError(path, f"line {line}: non-numeric value: {exc}") from None
    if not np.isfinite(x) or not np.isfinite(y):
        raise FileFormatError(path, f"line {line}: x, y must be finite pixel coordinates, got {x}, {y} "
                                    "(leave undetected points out instead of writing NaN)")
    if not 0.0 < weight < np.inf:
        raise FileFormatError(path, f"line {line}: weight must be a positive finite number, got {weight}")
    return point_id, x, y, weight


def write_corners_csv(obs: Observations, path: str | Path) -> None:
    """Write detections atomically (full float precision)."""
    with atomic_write(path, "w") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(COLUMNS)
        for c, s, i, (x, y), w in zip(obs.camera, obs.shot, obs.point_id, obs.uv, obs.weight):
            writer.writerow([obs.shot_names[s], obs.camera_names[c], int(i), repr(float(x)), repr(float(y)),
                             repr(float(w))])
