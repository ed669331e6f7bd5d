"""Read and write PLY files: vertices with any per-vertex fields, optional triangle faces.

Reading accepts ASCII and binary PLY whose ``vertex`` element has ``x, y, z`` of any numeric
type; writing produces binary little-endian (or ASCII) PLY atomically, with header comments
(units, frame, seed, command line).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plyfile

from scanrig.errors import FileFormatError, InputError
from scanrig.io.atomic import atomic_write

XYZ = ("x", "y", "z")


def read_ply(path: str | Path) -> tuple[dict[str, np.ndarray], np.ndarray | None, list[str]]:
    """Read the vertices (and faces, if any) of a PLY file.

    Parameters
    ----------
    path : str or Path
        A PLY file whose ``vertex`` element has at least ``x, y, z``.

    Returns
    -------
    vertices : dict of str -> (N,) array
        Every scalar vertex property, in file order, with its stored dtype.
    faces : (F, k) int64 array or None
        Vertex indices of each face (all faces must have the same count), or None without faces.
    comments : list of str
        Header comments.

    Raises
    ------
    FileFormatError
        Missing or unreadable file, no ``vertex`` element, or missing ``x, y, z``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "no such file")
    try:
        ply = plyfile.PlyData.read(str(path))
    except Exception as exc:  # plyfile raises several types for malformed files
        raise FileFormatError(path, f"not a readable PLY file ({exc})") from None
    names = [el.name for el in ply.elements]
    if "vertex" not in names:
        raise FileFormatError(path, f"has no 'vertex' element (elements: {names})")
    data = ply["vertex"].data
    fields = data.dtype.names or ()
    missing = [f for f in XYZ if f not in fields]
    if missing:
        raise FileFormatError(path, f"vertex element lacks field(s) {', '.join(missing)}; "
                                    f"it has {', '.join(fields) or 'none'}")
    vertices = {name: np.asarray(data[name]) for name in fields if data.dtype[name].shape == ()}
    faces = None
    if "face" in names and len(ply["face"].data):
        face_data = ply["face"].data
        key = "vertex_indices" if "vertex_indices" in face_data.dtype.names else face_data.dtype.names[0]
        try:
            faces = np.stack([np.asarray(f, dtype=np.int64) for f in face_data[key]])
        except ValueError:
            raise FileFormatError(path, "faces have different vertex counts") from None
    return vertices, faces, list(ply.comments)


def read_points(path: str | Path) -> np.ndarray:
    """The ``(N, 3)`` float64 ``x, y, z`` of a PLY file's vertices (see :func:`read_ply`)."""
    return read_points_with_sigma(path)[0]


def read_points_with_sigma(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Points and, when the file has a usable ``sigma`` field, each point's predicted sigma.

    Returns
    -------
    xyz : ndarray of shape (N, 3)
        World metres, float64.
    sigma : ndarray of shape (N,) or None
        ``sigma`` (metres) of ``points.ply``; None when the field is absent or not finite and
        positive everywhere (a cloud from another tool), so callers fall back to fitted scales.
    """
    vertices, _, _ = read_ply(path)
    xyz = np.column_stack([vertices[f].astype(np.float64) for f in XYZ])
    sigma = vertices.get("sigma")
    if sigma is None:
        return xyz, None
    sigma = sigma.astype(np.float64)
    return xyz, (sigma if np.all(np.isfinite(sigma) & (sigma > 0)) else None)


def write_ply(path: str | Path, vertices: dict[str, np.ndarray], faces: np.ndarray | None = None,
              comments=(), binary: bool = True) -> None:
    """Write a PLY file atomically.

    Parameters
    ----------
    path : str or Path
        Output file; its folder must exist. Written through a temporary file and renamed.
    vertices : dict of str -> (N,) array
        Per-vertex properties in the order given; numeric dtypes (bool is stored as uint8).
    faces : (F, k) int array, optional
        Vertex indices per face (stored as a uchar-counted int32 list ``vertex_indices``).
    comments : iterable of str
        Header comment lines (no newlines).
    binary : bool
        Binary little-endian (default) or ASCII.

    Raises
    ------
    InputError
        Empty ``vertices``, fields of different lengths or non-numeric, or bad faces.
    """
    if not vertices:
        raise InputError("vertices must hold at least one field")
    arrays = {name: np.asarray(v) for name, v in vertices.items()}
    lengths = {name: a.shape for name, a in arrays.items()}
    n = next(iter(arrays.values())).shape[0] if next(iter(arrays.values())).ndim else -1
    if any(a.ndim != 1 or a.shape[0] != n for a in arrays.values()):
        raise InputError(f"vertex fields must be 1-D arrays of one length, got shapes {lengths}")
    dtype = []
    for name, a in arrays.items():
        if a.dtype == bool:
            arrays[name] = a = a.astype(np.uint8)
        if a.dtype.kind not in "uif":
            raise InputError(f"vertex field {name!r} must be numeric, got dtype {a.dtype}")
        dtype.append((name, a.dtype.newbyteorder("<")))
    table = np.empty(n, dtype=dtype)
    for name, a in arrays.items():
        table[name] = a
    elements = [plyfile.PlyElement.describe(table, "vertex")]
    if faces is not None:
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] < 3 or faces.dtype.kind not in "ui":
            raise InputError(f"faces must be an integer array of shape (F, k >= 3), got {faces.shape} {faces.dtype}")
        if faces.size and (faces.min() < 0 or faces.max() >= n):
            raise InputError(f"faces index vertices outside [0, {n})")
        face_table = np.empty(len(faces), dtype=[("vertex_indices", "<i4", (faces.shape[1],))])
        face_table["vertex_indices"] = faces
        elements.append(plyfile.PlyElement.describe(face_table, "face",
                                                    len_types={"vertex_indices": "u1"}))
    comments = [str(c) for c in comments]
    if any("\n" in c or "\r" in c for c in comments):
        raise InputError("PLY header comments must be single lines")
    ply = plyfile.PlyData(elements, text=not binary, byte_order="<", comments=comments)
    with atomic_write(path) as f:
        ply.write(f)
