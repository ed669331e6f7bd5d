"""Split a point cloud into charts: pieces that are height fields in their own frames.

A chart has an origin, an orthonormal frame ``(u, v, n)`` (rows of ``rotation``) and a radius.
Its *core* points partition the cloud; its *members* are the core plus the neighbouring points
within an overlap margin whose normals face the same way and whose heights lie in the core's
height range (widened by the margin; this keeps the far side of a thin or closed object out),
so fits overlap at chart borders and
can be blended with a smooth partition of unity (:func:`blend_weights`).

Splitting is recursive (our choice): a set of points becomes a chart when it has at most
``max_points`` points and the normals of all but a fraction ``q`` of them lie within
``max_angle`` of the chart normal; otherwise it is cut at the median of its longest axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class Chart:
    """One height-field chart.

    Attributes
    ----------
    origin : (3,) float array
        Chart origin in the cloud's frame, metres.
    rotation : (3, 3) float array
        Rows are the chart axes ``u, v, n`` in the cloud's frame: ``p_chart = (p - origin) @ rotation.T``.
    radius : float
        Largest distance from the origin to a core point, metres.
    core : (n_core,) int array
        Indices of the points this chart owns.
    members : (n_members,) int array
        Core plus overlap points, the points the chart's network is fitted on.
    """

    origin: np.ndarray
    rotation: np.ndarray
    radius: float
    core: np.ndarray
    members: np.ndarray

    def to_chart(self, points: np.ndarray) -> np.ndarray:
        """``(N, 3)`` points in the cloud frame -> ``(N, 3)`` ``(u, v, height)`` in metres."""
        return (points - self.origin) @ self.rotation.T

    def from_chart(self, uvh: np.ndarray) -> np.ndarray:
        """``(..., 3)`` ``(u, v, height)`` in metres -> points in the cloud frame."""
        return uvh @ self.rotation + self.origin


def estimate_normals(points: np.ndarray, k: int = 16) -> np.ndarray:
    """Unoriented unit normals from the covariance of the ``k`` nearest neighbours.

    Parameters
    ----------
    points : (N, 3) float array
        Metres.
    k : int
        Neighbours per point (including itself), clipped to N.

    Returns
    -------
    (N, 3) float array
        Eigenvector of the smallest eigenvalue of each neighbourhood covariance.
    """
    k = min(k, len(points))
    _, idx = cKDTree(points).query(points, k=k)
    nb = points[idx.reshape(len(points), k)]
    centred = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred)
    return np.linalg.eigh(cov)[1][:, :, 0]


def split_charts(points: np.ndarray, normals: np.ndarray, *, max_points: int, q: float,
                 max_angle: float = np.deg2rad(60.0), overlap: float = 0.25,
                 min_points: int = 64) -> list[Chart]:
    """Partition a cloud into height-field charts with overlapping members.

    Parameters
    ----------
    points : (N, 3) float array
        Metres.
    normals : (N, 3) float array
        Unit normals, any orientation (:func:`estimate_normals`).
    max_points : int
        Largest core size.
    q : float
        Fraction of points whose normals may disagree with the chart normal (bad data).
    max_angle : float
        Largest angle between a point normal and its chart normal, radians.
    overlap : float
        Members reach ``(1 + overlap) * radius`` from the chart origin.
    min_points : int
        Sets this small are never split further.

    Returns
    -------
    list of Chart
    """
    cos_max = np.cos(max_angle)
    pending = [np.arange(len(points))]
    cores = []
    while pending:
        idx = pending.pop()
        origin, rotation = _frame(points[idx])
        facing = np.abs(normals[idx] @ rotation[2])
        flat_enough = np.quantile(facing, q) >= cos_max
        if len(idx) <= min_points or (len(idx) <= max_points and flat_enough):
            cores.append((idx, origin, rotation))
            continue
        along = (points[idx] - origin) @ rotation[0]
        below = along <= np.median(along)
        if below.all() or not below.any():
            cores.append((idx, origin, rotation))
            continue
        pending += [idx[below], idx[~below]]

    tree = cKDTree(points)
    charts = []
    for core, origin, rotation in cores:
        radius = float(np.max(np.linalg.norm(points[core] - origin, axis=1)))
        near = np.asarray(tree.query_ball_point(origin, (1.0 + overlap) * radius), dtype=int)
        height = (points[near] - origin) @ rotation[2]
        low, high = np.quantile((points[core] - origin) @ rotation[2], [q / 2, 1 - q / 2])
        margin = overlap * radius
        near = near[(np.abs(normals[near] @ rotation[2]) >= cos_max)
                    & (height >= low - margin) & (height <= high + margin)]
        members = np.union1d(core, near)
        charts.append(Chart(origin, rotation, radius, core, members))
    return charts


def blend_weights(chart: Chart, points: np.ndarray, overlap: float = 0.25) -> np.ndarray:
    """Partition-of-unity weights of a chart at its member points (before normalisation).

    ``w = (1 - (d / R)^2)^2`` with ``d`` the distance to the chart origin and
    ``R = (1 + overlap) * radius + tiny``: positive at every core point, zero at the rim.

    Parameters
    ----------
    chart : Chart
    points : (m, 3) float array
        Metres.

    Returns
    -------
    (m,) float array
    """
    reach = (1.0 + overlap) * chart.radius * (1.0 + 1e-9) + 1e-300
    d = np.linalg.norm(points - chart.origin, axis=1) / reach
    return np.clip(1.0 - d**2, 0.0, None) ** 2


def _frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median origin and principal axes (largest first, normal last) of a point set."""
    origin = np.median(points, axis=0)
    centred = points - origin
    _, vecs = np.linalg.eigh(centred.T @ centred)
    rotation = vecs[:, ::-1].T.copy()
    if np.linalg.det(rotation) < 0:
        rotation[2] *= -1.0
    return origin, rotation
