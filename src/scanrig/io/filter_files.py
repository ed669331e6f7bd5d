"""The files of the surface filter: ``surface.ply`` (one vertex per input point) and ``mesh.ply``.

Written by ``scanrig filter`` and by ``scanrig demo``; read by the report and the exports.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.io.ply import write_ply

SURFACE_NAME = "surface.ply"
MESH_NAME = "mesh.ply"
#: Header comment that documents the vertex fields of ``surface.ply``.
SURFACE_FIELDS = "fields: x y z denoised (m); inlier 0/1; score |r|/sigma; residual (m)"


def write_filter_files(folder: str | Path, result, vertices: np.ndarray, faces: np.ndarray,
                       comments=()) -> tuple[Path, Path]:
    """Write ``surface.ply`` and ``mesh.ply`` of a filter run into ``folder``.

    Parameters
    ----------
    folder : str or Path
        Existing output folder.
    result : FilterResult
        Output of :func:`scanrig.surface.filter_points` (``denoised``, ``inlier``, ``score`` and
        ``residual`` are used).
    vertices : (V, 3) float array
        Mesh vertices, metres (from :func:`scanrig.surface.mesh_from_result`).
    faces : (F, 3) int array
        Vertex indices of each triangle.
    comments : iterable of str
        Header comments of both files (command line, seed, units).

    Returns
    -------
    surface_path, mesh_path : Path
        ``surface.ply`` holds, per input point in input order, ``x y z`` (denoised position,
        metres), ``inlier`` (uint8 0/1), ``score`` (float32, ``|r| / sigma``) and ``residual``
        (metres).
    """
    folder = Path(folder)
    comments = [str(c) for c in comments]
    denoised = result.denoised
    surface_path, mesh_path = folder / SURFACE_NAME, folder / MESH_NAME
    write_ply(surface_path,
              {"x": denoised[:, 0], "y": denoised[:, 1], "z": denoised[:, 2],
               "inlier": result.inlier.astype(np.uint8), "score": result.score.astype(np.float32),
               "residual": result.residual},
              comments=comments + [SURFACE_FIELDS])
    write_ply(mesh_path, {"x": vertices[:, 0], "y": vertices[:, 1], "z": vertices[:, 2]},
              faces=faces, comments=comments)
    return surface_path, mesh_path
