"""Triangle mesh of the fitted surface from the denoised inliers of every chart."""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay, QhullError


def mesh_from_result(result, *, max_edge_factor: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Mesh the denoised inliers, chart by chart, by Delaunay triangulation in chart coordinates.

    Each chart triangulates the inliers it owns (its core) in its ``(u, v)`` plane; triangles with
    an edge longer than ``max_edge_factor`` times the chart's median edge are dropped, so holes
    and concave borders stay open. Seams between charts are not stitched.

    Parameters
    ----------
    result : FilterResult
        Output of :func:`~scanrig.surface.filter.filter_points`.
    max_edge_factor : float
        Longest edge kept, in median edges of the chart.

    Returns
    -------
    vertices : (V, 3) float array
        Denoised inlier positions, metres, in input order.
    faces : (F, 3) int64 array
        Vertex indices of each triangle.
    """
    keep = np.flatnonzero(result.inlier)
    new_index = np.full(len(result.inlier), -1)
    new_index[keep] = np.arange(len(keep))
    faces = []
    for chart in result.charts:
        own = chart.core[result.inlier[chart.core]]
        if len(own) < 3:
            continue
        uv = chart.to_chart(result.denoised[own])[:, :2]
        try:
            tri = Delaunay(uv).simplices
        except QhullError:  # degenerate (collinear) point sets have no triangulation
            continue
        corners = result.denoised[own][tri]
        edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
        tri = tri[edges <= max_edge_factor * np.median(edges)]
        faces.append(new_index[own[tri]])
    faces = np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64)
    return result.denoised[keep], faces.astype(np.int64)
