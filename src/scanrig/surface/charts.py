"""Split a point cloud into charts: pieces that are height fields in their own frames.

A chart has an origin, an orthonormal frame ``(u, v, n)`` (rows of ``rotation``), a radius and
a *reach*: the bounding box of its core in the ``(u, v)`` plane widened by an overlap margin on
every side, and a height window. Its *core* points partition the cloud; its *members* are the
core plus the neighbouring points in the reach whose normals face the same way and whose heights
lie in the window (the core's height range widened by the margin; this keeps the far side of a
thin or closed object out), so fits overlap at chart borders and can be blended with a smooth
partition of unity (:func:`blend_weights`).

The reach is a box in the chart plane, not a ball in 3D (our choice): a gross error far above the
surface set the ball's radius, and a ball around an elongated core holds several times its
area; the members of such charts grew to 4-8x their cores (26 000 members for 3000 core points on
a cloud with 10 % uniform outliers), and the members are what the networks are trained on.

Splitting is recursive (our choice): a set of points becomes a chart when it has at most
``max_points`` points and the normals of all but a fraction ``q`` of them lie within
``max_angle`` of the chart normal; otherwise it is cut at the median of its longest axis.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

#: Point sets this small are never split further (by :func:`split_charts` or the filter's refinement).
MIN_CHART_POINTS = 64
#: Sheet points that vote on which sheet owns a place (:class:`Claim`).
CLAIM_NEIGHBOURS = 8


@dataclass(frozen=True)
class Claim:
    """Where one sheet of a height field split at a step holds (see :mod:`scanrig.surface.sheets`).

    A place in the height field's plane belongs to the sheet that holds most of the
    ``CLAIM_NEIGHBOURS`` sheet points nearest to it in the plane (ties: the nearest point's
    sheet), so a few stray points of one sheet inside another's place do not carve out an island.

    Attributes
    ----------
    points : (n, 3) float array
        The points of all sibling sheets, metres.
    label : (n,) int array
        Their sheets, ``0 .. n_sheets - 1``.
    own : int
        This sheet's label.
    normal : (3,) float array
        Unit normal of the height field that was split; places are positions across it.
    """

    points: np.ndarray
    label: np.ndarray
    own: int
    normal: np.ndarray

    def owner(self, points: np.ndarray) -> np.ndarray:
        """``(m,)`` int: the sheet that owns the place of each of the ``(m, 3)`` points."""
        def flat(p):
            return p - np.outer(p @ self.normal, self.normal)

        k = min(CLAIM_NEIGHBOURS, len(self.points))
        nearest = cKDTree(flat(self.points)).query(flat(points), k=k)[1].reshape(len(points), k)
        sheets = np.arange(self.label.max() + 1)
        votes = ((self.label[nearest][..., None] == sheets).sum(axis=1)
                 + 0.5 * (self.label[nearest[:, 0], None] == sheets))  # ties: the nearest point's sheet
        return np.argmax(votes, axis=1)

    def holds(self, points: np.ndarray) -> np.ndarray:
        """``(m,)`` bool: whether this sheet owns the place of each of the ``(m, 3)`` points."""
        return self.owner(points) == self.own


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
        Largest distance from the origin to a core point in the ``(u, v)`` plane, metres (the
        unit of the chart's normalised coordinates).
    reach : (2, 2) float array
        ``[[u_low, u_high], [v_low, v_high]]``: the box of the members in the chart plane,
        metres.
    height_window : (2,) float array
        Lowest and highest height of a member (the core's ``q/2`` and ``1 - q/2`` height
        quantiles widened by the overlap margin), metres.
    core : (n_core,) int array
        Indices of the points this chart owns.
    members : (n_members,) int array
        Core plus overlap points, the points the chart's network is fitted on.
    claim : Claim or None
        For one sheet of a height field split at a discontinuity: where it holds (None: all
        of its reach).
    trained : (n_members,) bool array or None
        Which members train the network (None: all); every member is judged by it.
    """

    origin: np.ndarray
    rotation: np.ndarray
    radius: float
    reach: np.ndarray
    height_window: np.ndarray
    core: np.ndarray
    members: np.ndarray
    claim: Claim | None = None
    trained: np.ndarray | None = None

    def to_chart(self, points: np.ndarray) -> np.ndarray:
        """``(N, 3)`` points in the cloud frame -> ``(N, 3)`` ``(u, v, height)`` in metres."""
        return (points - self.origin) @ self.rotation.T

    def from_chart(self, uvh: np.ndarray) -> np.ndarray:
        """``(..., 3)`` ``(u, v, height)`` in metres -> points in the cloud frame."""
        return uvh @ self.rotation + self.origin

    def in_window(self, points: np.ndarray) -> np.ndarray:
        """``(N,)`` bool: which points' heights lie in the chart's height window."""
        height = (points - self.origin) @ self.rotation[2]
        return (height >= self.height_window[0]) & (height <= self.height_window[1])

    def holds(self, points: np.ndarray) -> np.ndarray:
        """``(N,)`` bool: where the chart's surface holds (everywhere but its siblings' side, see
        :class:`Claim`)."""
        return np.ones(len(points), bool) if self.claim is None else self.claim.holds(points)


#: A neighbourhood whose middle covariance eigenvalue is below this fraction of its largest is
#: a curve, not a surface (:func:`estimate_normals`): its width is under 10 % of its length.
LINE_RATIO = 0.01
#: Factor by which :func:`estimate_normals` enlarges such a neighbourhood.
GROW = 4
#: Largest neighbourhood :func:`estimate_normals` grows to: a cloud that is one line throughout
#: (a single stripe) would otherwise grow every point's neighbourhood to the whole cloud, an
#: (N, N, 3) array. Stripes 14 mm apart with 1.7 mm between points need 64.
MAX_NEIGHBOURS = 256


def estimate_normals(points: np.ndarray, k: int = 16, *, workers: int = 1) -> np.ndarray:
    """Unoriented unit normals from the covariance of the nearest neighbours.

    A neighbourhood along a curve (the ``k`` nearest points of a laser stripe all lie on it)
    fixes one tangent only, and its smallest eigenvector may lie anywhere across the curve;
    such points, whose middle eigenvalue is below ``LINE_RATIO`` times the largest, get
    ``GROW`` times more neighbours (reaching the next stripes), repeatedly, until their
    neighbourhood spans a surface or holds ``MAX_NEIGHBOURS`` points or the whole cloud.

    Parameters
    ----------
    points : (N, 3) float array
        Metres.
    k : int
        Neighbours per point (including itself), clipped to N.
    workers : int
        Threads of the neighbour queries (the same normals whatever their number).

    Returns
    -------
    (N, 3) float array
        Eigenvector of the smallest eigenvalue of each neighbourhood covariance.
    """
    normals = np.empty_like(points, dtype=float)
    tree = cKDTree(points)
    todo = np.arange(len(points))
    while len(todo):
        k = min(k, len(points))
        _, idx = tree.query(points[todo], k=k, workers=workers)
        nb = points[idx.reshape(len(todo), k)]
        centred = nb - nb.mean(axis=1, keepdims=True)
        value, vector = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
        normals[todo] = vector[:, :, 0]
        if k >= min(MAX_NEIGHBOURS, len(points)):
            break
        todo = todo[value[:, 1] < LINE_RATIO * value[:, 2]]
        k = min(k * GROW, MAX_NEIGHBOURS)
    return normals


def split_charts(points: np.ndarray, normals: np.ndarray, *, max_points: int, q: float,
                 max_angle: float = np.deg2rad(60.0), overlap: float = 0.25,
                 min_points: int = MIN_CHART_POINTS) -> list[Chart]:
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
        The reach is the core's box in the chart plane widened by ``overlap`` times its half
        extent on every side; heights by ``overlap`` times the larger half extent.
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
        halves = _halves(points, idx, origin, rotation)
        if len(idx) <= min_points or (len(idx) <= max_points and flat_enough) or halves is None:
            cores.append(idx)
        else:
            pending += halves
    return _charts_from_cores(points, normals, cores, q=q, cos_max=cos_max, overlap=overlap)


def halve_charts(points: np.ndarray, normals: np.ndarray, charts: list[Chart], *, q: float,
                 max_angle: float = np.deg2rad(60.0), overlap: float = 0.25) -> list[Chart]:
    """Split each chart's core in two at the median of its longest axis (new members).

    For charts that cannot follow their surface (a step or a gap between two objects inside
    one height field). A core that cannot be halved (all points at one position along the
    axis) is returned as it was.

    Parameters
    ----------
    points, normals : (N, 3) float arrays
        The cloud the charts were split from.
    charts : list of Chart
    q, max_angle, overlap
        As in :func:`split_charts`.

    Returns
    -------
    list of Chart
        Two charts per input chart (one where it could not be halved).
    """
    cores = []
    for chart in charts:
        cores += _halves(points, chart.core, chart.origin, chart.rotation) or [chart.core]
    return _charts_from_cores(points, normals, cores, q=q, cos_max=np.cos(max_angle), overlap=overlap)


def _halves(points: np.ndarray, idx: np.ndarray, origin: np.ndarray,
            rotation: np.ndarray) -> list[np.ndarray] | None:
    """``idx`` cut at the median of the first axis of ``rotation``; None if one side is empty."""
    along = (points[idx] - origin) @ rotation[0]
    below = along <= np.median(along)
    if below.all() or not below.any():
        return None
    return [idx[below], idx[~below]]


def _charts_from_cores(points: np.ndarray, normals: np.ndarray, cores: list[np.ndarray], *, q: float,
                       cos_max: float, overlap: float) -> list[Chart]:
    """Frame, radius, reach, height window and members of each core (see :func:`split_charts`)."""
    tree = cKDTree(points)
    charts = []
    for core in cores:
        chart = _bare_chart(points, core, q=q, overlap=overlap)
        corner = np.abs(chart.reach).max(axis=1)
        radius = np.linalg.norm([*corner, np.abs(chart.height_window).max()])
        near = np.asarray(tree.query_ball_point(chart.origin, radius), dtype=int)
        charts.append(_with_members(chart, points, normals, near, cos_max))
    return charts


def chart_from_core(points: np.ndarray, normals: np.ndarray, core: np.ndarray, candidates: np.ndarray, *,
                    q: float, cos_max: float, overlap: float, claim: Claim | None = None) -> Chart:
    """The chart that owns ``core``: frame, radius, reach and height window from the core (see
    :func:`split_charts`); members the core and the ``candidates`` in the reach and the window
    whose normals agree.

    Parameters
    ----------
    points, normals : (N, 3) float arrays
    core : (n,) int array
        Indices of the points the chart owns.
    candidates : (m,) int array
        Indices of the points that may become members.
    q, overlap
        As in :func:`split_charts`.
    cos_max : float
        Cosine of ``max_angle``.
    claim : Claim, optional
        Where the chart's surface holds (sheets of one height field, :mod:`scanrig.surface.sheets`).

    Returns
    -------
    Chart
    """
    return _with_members(_bare_chart(points, core, q=q, overlap=overlap, claim=claim), points, normals,
                         candidates, cos_max)


def _bare_chart(points: np.ndarray, core: np.ndarray, *, q: float, overlap: float,
                claim: Claim | None = None) -> Chart:
    """Frame, radius, reach and height window of ``core``; its members only the core."""
    origin, rotation = _frame(points[core])
    local = (points[core] - origin) @ rotation.T
    radius = float(np.max(np.linalg.norm(local[:, :2], axis=1)))
    low, high = local[:, :2].min(axis=0), local[:, :2].max(axis=0)
    widen = overlap * (high - low) / 2 + 1e-9 * max(radius, 1e-300)
    reach = np.column_stack([low - widen, high + widen])
    h_low, h_high = np.quantile(local[:, 2], [q / 2, 1 - q / 2])
    window = np.array([h_low, h_high]) + np.array([-1.0, 1.0]) * widen.max()
    return Chart(origin, rotation, radius, reach, window, core, core, claim)


def _with_members(chart: Chart, points: np.ndarray, normals: np.ndarray, candidates: np.ndarray,
                  cos_max: float) -> Chart:
    """``chart`` with the core and the ``candidates`` in its reach and window whose normals agree as members."""
    local = chart.to_chart(points[candidates])
    keep = (np.all((local[:, :2] >= chart.reach[:, 0]) & (local[:, :2] <= chart.reach[:, 1]), axis=1)
            & (np.abs(normals[candidates] @ chart.rotation[2]) >= cos_max)
            & (local[:, 2] >= chart.height_window[0]) & (local[:, 2] <= chart.height_window[1]))
    return replace(chart, members=np.union1d(chart.core, candidates[keep]))


def blend_weights(chart: Chart, points: np.ndarray) -> np.ndarray:
    """Partition-of-unity weights of a chart at its member points (before normalisation).

    The product over the chart plane's two axes of ``(1 - (d / R)^2)^2``, with ``d`` the
    distance from the middle of the chart's reach along the axis and ``R`` its half width:
    positive inside the reach (so at every core point), zero on and beyond its rim. Heights
    are not looked at (see :meth:`Chart.in_window`).

    Parameters
    ----------
    chart : Chart
    points : (m, 3) float array
        Metres.

    Returns
    -------
    (m,) float array
    """
    uv = (points - chart.origin) @ chart.rotation[:2].T
    middle = chart.reach.mean(axis=1)
    half = np.diff(chart.reach, axis=1)[:, 0] / 2
    d = (uv - middle) / half
    return np.prod(np.clip(1.0 - d**2, 0.0, None) ** 2, axis=1)


def frames_from_normals(normal: np.ndarray) -> np.ndarray:
    """Right-handed frames (m, 3, 3) whose columns are two tangents and the unit ``normal`` (m, 3)."""
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return np.stack([t1, np.cross(normal, t1), normal], axis=-1)


def _frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median origin and principal axes (largest first, normal last) of a point set."""
    origin = np.median(points, axis=0)
    centred = points - origin
    _, vecs = np.linalg.eigh(centred.T @ centred)
    rotation = vecs[:, ::-1].T.copy()
    if np.linalg.det(rotation) < 0:
        rotation[2] *= -1.0
    return origin, rotation
