"""Exports to the tools people already use: clouds and meshes, calibrations, Open3D objects.

========================  =====================================================================
format                    writes
========================  =====================================================================
``ply``                   binary little-endian PLY, every vertex field kept (:mod:`scanrig.io.ply`)
``ply-ascii``             the same as text
``stl``                   binary STL (meshes only: STL has no bare points)
``obj``                   Wavefront OBJ (``v`` lines to 1e-10 m; ``f`` lines for meshes)
``opencv-yaml``           the rig as OpenCV FileStorage YAML (:mod:`scanrig.io.opencv_yaml`)
``mrcal``                 one mrcal ``.cameramodel`` per camera (:mod:`scanrig.io.mrcal_model`)
``colmap``                COLMAP ``cameras.txt`` and ``images.txt`` (:mod:`scanrig.io.colmap_text`)
========================  =====================================================================

Coordinates are written as stored: metres, world frame of ``rig.toml``. Every file is written
atomically (temporary file, then rename).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError, ScanrigError, ShapeError
from scanrig.io.atomic import write_bytes_atomic, write_text_atomic

GEOMETRY_FORMATS = ("ply", "ply-ascii", "stl", "obj")
CALIBRATION_FORMATS = ("opencv-yaml", "mrcal", "colmap")
FORMATS = GEOMETRY_FORMATS + CALIBRATION_FORMATS
#: File suffix of each geometry format.
SUFFIXES = {"ply": ".ply", "ply-ascii": ".ply", "stl": ".stl", "obj": ".obj"}
#: Session geometry files, exported in this order when present.
SESSION_GEOMETRY = ("points.ply", "surface.ply", "mesh.ply")
#: Decimal places of OBJ coordinates (metres): 1e-10 m, far below any measurement.
OBJ_DIGITS = 10


class MissingDependencyError(ScanrigError, ImportError):
    """An optional dependency is not installed; the message names the pip extra."""


def check_format(fmt: str, allowed: tuple[str, ...] = FORMATS) -> str:
    """Return ``fmt`` or raise :class:`InputError` listing the allowed formats."""
    if fmt not in allowed:
        raise InputError(f"format must be one of {', '.join(allowed)}; got {fmt!r}")
    return fmt


def export_geometry(path: str | Path, vertices: dict[str, np.ndarray], faces: np.ndarray | None = None,
                    fmt: str = "ply", comments=()) -> Path:
    """Write a point cloud or a triangle mesh in one of :data:`GEOMETRY_FORMATS`.

    Parameters
    ----------
    path : str or Path
        Output file; its folder must exist.
    vertices : dict of str to (N,) arrays
        Vertex fields; must hold ``x, y, z`` (metres, world frame). PLY keeps every field; STL
        and OBJ keep the coordinates only.
    faces : (M, 3) int array, optional
        Triangles as vertex indices; ``None`` for a point cloud.
    fmt : {"ply", "ply-ascii", "stl", "obj"}
    comments : iterable of str
        PLY header comments (units, frame, provenance).

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    InputError
        Unknown format, STL without faces, missing ``x, y, z``.
    ShapeError
        ``faces`` not ``(M, 3)``.
    """
    check_format(fmt, GEOMETRY_FORMATS)
    path = Path(path)
    missing = [name for name in ("x", "y", "z") if name not in vertices]
    if missing:
        raise InputError(f"vertices for {path} lack the fields {missing}")
    if faces is not None:
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ShapeError(f"faces must be (M, 3) vertex indices, got shape {faces.shape}")
    if fmt in ("ply", "ply-ascii"):
        from scanrig.io.ply import write_ply

        write_ply(path, vertices, faces=faces, comments=tuple(comments), binary=fmt == "ply")
        return path
    import trimesh

    xyz = np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=1).astype(np.float64)
    if fmt == "stl":
        if faces is None:
            raise InputError(f"{path}: STL stores triangles only; export a point cloud as ply, ply-ascii or obj")
        write_bytes_atomic(path, trimesh.Trimesh(xyz, faces, process=False).export(file_type="stl"))
        return path
    shape = trimesh.PointCloud(xyz) if faces is None else trimesh.Trimesh(xyz, faces, process=False)
    write_text_atomic(path, shape.export(file_type="obj", digits=OBJ_DIGITS, include_normals=False,
                                         include_texture=False))
    return path


def export_calibration(rig, out_dir: str | Path, fmt: str) -> list[Path]:
    """Write a rig in one of :data:`CALIBRATION_FORMATS` into ``out_dir`` (created if missing).

    Parameters
    ----------
    rig : Rig
    out_dir : str or Path
    fmt : {"opencv-yaml", "mrcal", "colmap"}

    Returns
    -------
    list of Path
        ``rig.yml``; one ``<camera>.cameramodel`` per camera; ``cameras.txt`` and ``images.txt``.
    """
    check_format(fmt, CALIBRATION_FORMATS)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if fmt == "opencv-yaml":
        from scanrig.io.opencv_yaml import export_opencv_yaml

        export_opencv_yaml(rig, out_dir / "rig.yml")
        return [out_dir / "rig.yml"]
    if fmt == "mrcal":
        from scanrig.io.mrcal_model import export_cameramodels

        return export_cameramodels(rig.cameras, out_dir)
    from scanrig.io.colmap_text import export_colmap_text

    return list(export_colmap_text(rig, out_dir))


def export_session(session_root: str | Path, fmt: str, out_dir: str | Path) -> list[Path]:
    """Export a session's results: geometry (``points.ply``, ``surface.ply``, ``mesh.ply``) or calibration.

    Geometry formats convert each of the session's PLY files that exists (STL: only those with
    faces; OBJ of ``surface.ply``: only the points the filter kept, as OBJ cannot carry its
    ``inlier`` flag); calibration formats convert ``rig.toml``.

    Parameters
    ----------
    session_root : str or Path
        Session folder.
    fmt : str
        One of :data:`FORMATS`.
    out_dir : str or Path
        Output folder (created if missing); files keep the session file's stem.

    Returns
    -------
    list of Path
        Files written.

    Raises
    ------
    FileFormatError
        When the session has nothing to export in that format.
    """
    from scanrig.io.session import Session

    check_format(fmt)
    session = Session(session_root)
    out_dir = Path(out_dir)
    if fmt in CALIBRATION_FORMATS:
        from scanrig.io.rig_file import load_rig

        if not session.rig_path.is_file():
            raise FileFormatError(session.rig_path, "rig file not found (run `scanrig calibrate` first)")
        return export_calibration(load_rig(session.rig_path), out_dir, fmt)
    from scanrig.io.ply import read_ply

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name in SESSION_GEOMETRY:
        source = session.root / name
        if not source.is_file():
            continue
        vertices, faces, comments = read_ply(source)
        if fmt == "stl" and faces is None:
            continue
        if fmt == "obj" and "inlier" in vertices:   # OBJ cannot carry the filter's flag: keep the inliers
            keep = vertices["inlier"] != 0
            vertices = {name: values[keep] for name, values in vertices.items()}
        target = out_dir / (source.stem + SUFFIXES[fmt])
        written.append(export_geometry(target, vertices, faces, fmt, comments=(*comments, f"exported from {source}")))
    if not written:
        what = "no mesh (mesh.ply)" if fmt == "stl" else f"none of {', '.join(SESSION_GEOMETRY)}"
        raise FileFormatError(session.root, f"has {what} to export as {fmt}")
    return written


def to_open3d(data, faces: np.ndarray | None = None):
    """Convert points, a mesh or a PLY file to an Open3D geometry.

    Parameters
    ----------
    data : (N, 3) float array, PointCloud, str or Path
        Points (metres, world frame), a :class:`scanrig.reconstruct.points.PointCloud`, or a
        PLY file (``points.ply``, ``surface.ply``, ``mesh.ply``).
    faces : (M, 3) int array, optional
        Triangles for array input.

    Returns
    -------
    open3d.geometry.PointCloud or open3d.geometry.TriangleMesh
        A mesh when there are faces, else a point cloud.

    Raises
    ------
    MissingDependencyError
        When Open3D is not installed (``pip install "scanrig[open3d]"``).
    """
    try:
        import open3d as o3d
    except ImportError as exc:
        raise MissingDependencyError(
            'to_open3d needs Open3D: pip install "scanrig[open3d]" (the open3d extra)') from exc
    if isinstance(data, (str, Path)):
        from scanrig.io.ply import read_ply

        vertices, faces, _ = read_ply(data)
        xyz = np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=1)
    else:
        xyz = np.asarray(getattr(data, "p_world", data), dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ShapeError(f"points must be (N, 3), got shape {xyz.shape}")
    xyz = o3d.utility.Vector3dVector(np.ascontiguousarray(xyz, dtype=np.float64))
    if faces is None:
        return o3d.geometry.PointCloud(xyz)
    triangles = o3d.utility.Vector3iVector(np.ascontiguousarray(faces, dtype=np.int32))
    return o3d.geometry.TriangleMesh(xyz, triangles)
