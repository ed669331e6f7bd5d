"""Split height-field charts at steps into sheets that are fitted separately.

A network is a smooth function: across a step it drew a ramp 3-5 sample spacings wide (the
oracle, trained on the true points only, about two), the true points next to the step lie beyond
its rejection point and are flagged, and edge ghosts between the two levels lie on the ramp and
are kept. A chart holding a step is therefore cut into *sheets* (our choice):

1. every member gets a least-trimmed-squares plane through its ``k`` nearest neighbours in the
   chart plane (itself left out), as in the robust start (:mod:`scanrig.surface.local_start`);
   it is *on a surface* if its height lies within ``cut`` noise scales of that plane and the
   plane's trimmed scale is at most ``SURFACE_SCALE_FACTOR`` noise scales (the noise scale is
   the ``q``-trimmed scale of those held-out residuals, refined inside ``SURFACE_SCALE_FACTOR``
   scales: with fewer bad points than ``q`` the trimmed scale alone over-estimates the noise,
   1.9x on the protocol's step at 40 % outliers, where it let chains of outliers link the levels);
2. two such points, one among the other's ``LINK_NEIGHBOURS`` nearest neighbours, are linked
   when each lies within ``cut * sigma`` of the other's plane; a step far above the noise breaks
   every link across it, a crease (a change of slope only) none, and points between the two
   levels (edge ghosts) cannot bridge them: each lies near the plane of one level only. A few
   ghosts can: their trimmed planes run up the step (slopes 1-2 on the protocol's step, the
   levels' 0-0.4) through the foot of the step or its top, and a chain of them, low level to
   ghost to ghost to high level, joined the levels into one sheet, fitted by one network (2 of
   600 draws of the step at 20 and 40 % outliers, ``bench_filter.py --ghost-chains 300``: ramps
   6.2 and 6.8 spacings wide, 4.3 and 2.4 % of the true points flagged). Where these links find
   one sheet they are taken again with the planes of linked points agreeing in slope as well
   (see :func:`_labels_and_scale`; only where the points' neighbours spread over an area, and
   only the sheets that do, ``SLOPE_SPREAD``), which cuts such chains (none of the 600 draws;
   those two: widths 0.86 and 0.02 spacings, 0 and 0.2 % flagged, 1.04 and 0.92 times the
   oracle's error). Only there: such a rule on every chart (slopes within 1) cost accuracy
   elsewhere (the step at 40 %, held-out seeds 110-119: 1.065 the oracle's error in the median,
   1.088 with it); as this fallback it changed one of the 960 draws of the benchmark's cells at
   data seeds 0-9 and 100-119, the chained step at 20 %, seed 116 (width 7.73 -> 0.06
   spacings, 2.6 -> 0.03 % flagged, 0.99 -> 1.04 times the oracle's error);
3. connected components with at least ``MIN_CHART_POINTS`` of the chart's core points are the
   sheets (components that continue each other's surface across a gap, such as a blob of
   reflections, are joined first); with two or more, every member but the sheets' inner
   points (those whose nearest sheet points are all of their own sheet) joins the sheet that
   owns its place in the chart plane (:class:`~scanrig.surface.charts.Claim`: most of its
   nearest inner points are that sheet's). A height field has one surface over each place: an edge ghost on the low
   side of a step joins the low sheet and is judged by its fit, even when its height is near
   the high level (joining the sheet whose plane is nearest in height kept such ghosts: recall
   of the outliers 0.93-0.98 instead of 0.95-0.99 on the step at 10-40 %, two seeds). Each
   sheet becomes a chart of its own, with its own frame, reach and window and members from its
   own place only; its :class:`~scanrig.surface.charts.Claim` keeps its extrapolation across the
   step out of :func:`~scanrig.surface.filter.project_on_surface`.
4. a point that is on no surface (item 1), or on one of the sheets without being one of its
   inner points, and lies between ``TRAIN_CUT`` and ``TRAIN_FAR`` noise scales from the
   trimmed plane through its sheet's 16 inner points nearest to it does not train the sheet's
   network (:attr:`~scanrig.surface.charts.Chart.trained`); it is still judged by the fit. At
   a sheet's front no point beyond holds the network, and edge ghosts a few noise scales off
   the level pulled it to them (protocol step at 20 % outliers, data seeds 120-129:
   transition widths of 1.6-2.6 spacings on four draws). A column of such ghosts tilts their
   own local planes, and those linked into the sheet through them trained it (a 48 x 48 step
   with a ghost 3-8 noise scales below the high level at every site of its first column: the
   fit there 1.5-2 noise scales low on 7 of 40 draws; left out, on 1). Points farther off,
   and points on a surface that is none of the sheets, are left to the robust loss, which
   gives them no weight unless the network reaches them: a sampled side of an object, which
   the chart has to hold (on the stripe demo, leaving out every point beyond ``TRAIN_CUT``
   flagged 146-191 true points instead of 83-92).

Outliers are rarely on a surface (uniform gross errors are isolated, a patch of reflections
spreads the kept half of its neighbourhood over its height range), so they seldom form
components; a component needs ``MIN_CHART_POINTS`` core points to count.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from scanrig.surface.charts import MIN_CHART_POINTS, Chart, Claim, chart_from_core, frames_from_normals
from scanrig.surface.hampel import refined_scale
from scanrig.surface.local_start import SURFACE_SCALE_FACTOR, neighbour_planes, trimmed_planes

#: Neighbours of each point that it may be linked to.
LINK_NEIGHBOURS = 8
#: A point off any surface, or on a sheet but none of its inner points, whose distance from its
#: sheet's inner plane lies between these (in noise scales) does not train the sheet's network
#: (see the module's item 4).
TRAIN_CUT, TRAIN_FAR = 2.5, 12.0
#: Planes are compared in slope (:func:`_labels_and_scale`) only where both points' neighbours
#: spread over an area, and the sheets this comparison cuts count only where they do: the
#: smaller standard deviation of the points in the chart plane at least this fraction of the
#: larger. Along a laser stripe the slope across it is not measured: on a simulated turntable
#: scan (57,523 points, 0.25 mm apart along the stripes) the comparison alone cut two of its 32
#: charts into a sheet and three or four strips each (8 x 1.1 mm, 1.6-2 mm apart in height).
SLOPE_SPREAD = 0.3


def split_sheets(points: np.ndarray, normals: np.ndarray, charts: list[Chart], *, q: float, cut: float,
                 k: int = 16, max_angle: float = np.deg2rad(60.0), overlap: float = 0.25,
                 point_sigma: np.ndarray | None = None, workers: int = 1) -> list[Chart]:
    """Replace each chart that holds two or more sheets (a step) by one chart per sheet.

    Parameters
    ----------
    points, normals : (N, 3) float arrays
        The cloud the charts were split from (metres; unit normals).
    charts : list of Chart
    q : float
        Tolerated fraction of bad data (breakdown point of the noise scale).
    cut : float
        Rejection point in noise scales (Hampel ``r``).
    k : int
        Neighbours of the local planes.
    max_angle, overlap
        As in :func:`~scanrig.surface.charts.split_charts`.
    point_sigma : (N,) float array, optional
        The points' own predicted noise, metres: a chart's noise scale is never taken below the
        median of its members' (see :func:`sheet_labels`).
    workers : int
        Threads that split charts side by side (the charts are independent and their
        arithmetic releases the GIL; the sheets are the same whatever their number).

    Returns
    -------
    list of Chart
        The charts without a step unchanged, then the sheets.
    """
    def split(chart: Chart) -> list[Chart] | None:
        floor = 0.0 if point_sigma is None else float(np.median(point_sigma[chart.members]))
        return _sheets_of(points, normals, chart, q=q, cut=cut, k=k, cos_max=np.cos(max_angle),
                          overlap=overlap, sigma_floor=floor)

    with ThreadPoolExecutor(max(1, workers)) as pool:
        splits = list(pool.map(split, charts))
    kept = [chart for chart, parts in zip(charts, splits) if parts is None]
    return kept + [sheet for parts in splits if parts is not None for sheet in parts]


def sheet_labels(uv: np.ndarray, h: np.ndarray, *, q: float, cut: float, k: int = 16,
                 sigma_floor: float = 0.0) -> np.ndarray:
    """Connected pieces of surface in a height field (steps cut them apart).

    Parameters
    ----------
    uv : (m, 2) float array
        Positions in the chart plane.
    h : (m,) float array
        Heights.
    q, cut, k
        As in :func:`split_sheets`.
    sigma_floor : float
        Lower bound of the noise scale, in the units of ``h``. Neighbours along one laser
        stripe share most of their error, so their planes predict each point far closer than
        the noise: without it, 15 stripes across a plane fell into 11-12 sheets (2-3 with it).

    Returns
    -------
    (m,) int array
        Component of each point on a surface; -1 for points not on a surface.
    """
    return _labels_and_scale(uv, h, q=q, cut=cut, k=k, sigma_floor=sigma_floor)[0]


def _labels_and_scale(uv: np.ndarray, h: np.ndarray, *, q: float, cut: float, k: int,
                      sigma_floor: float) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`sheet_labels`, the labels of the links whose planes also agree in slope (see
    :func:`_sheets_of`), each (m,), and the noise scale they linked with (units of ``h``).

    Two linked points' planes agree in slope when they lie within ``cut`` noise scales of each
    other one typical spacing (the median distance to the nearest neighbour) away from the
    point, in every direction, or when either point's neighbours lie along a line rather than
    over an area (``SLOPE_SPREAD``): on the protocol's crease (0.8 change of slope) a spacing away
    they part by 2.5 noise scales and stay linked; the two chains of edge ghosts of the module's
    item 2 each held a link between planes 2 apart in slope, 5.3-5.5 noise scales a spacing away.
    """
    m = len(h)
    nb, planes, scale = neighbour_planes(uv, h, k=k)
    residual = h - planes[:, 0]
    sigma = max(refined_scale(residual, q, cut=SURFACE_SCALE_FACTOR)[0], sigma_floor)
    on_surface = (np.abs(residual) <= cut * sigma) & (scale <= SURFACE_SCALE_FACTOR * sigma)
    candidates = nb[:, :LINK_NEIGHBOURS]
    i, j = np.repeat(np.arange(m), candidates.shape[1]), candidates.ravel()
    link = (on_surface[i] & on_surface[j] & (np.abs(_plane_gap(planes[i], uv[i], uv[j], h[j])) <= cut * sigma)
            & (np.abs(_plane_gap(planes[j], uv[j], uv[i], h[i])) <= cut * sigma))
    spacing = np.median(np.linalg.norm(uv[nb[:, 0]] - uv, axis=1))
    areal = _areal(uv[nb] - uv[:, None, :])  # neighbours over an area, not along a line
    agree = ((np.linalg.norm(planes[i, 1:] - planes[j, 1:], axis=1) * spacing <= cut * sigma)
             | ~(areal[i] & areal[j]))

    def components(linked):
        graph = coo_matrix((np.ones(int(linked.sum())), (i[linked], j[linked])), shape=(m, m))
        label = np.where(on_surface, connected_components(graph, directed=False)[1], -1)
        return _join_continuations(uv, h, label, cut * sigma)

    return components(link), components(link & agree), sigma


def _areal(offsets: np.ndarray) -> np.ndarray:
    """``(...)`` bool: whether each set of ``offsets`` (..., n, 2) spreads over an area, its smaller
    standard deviation at least ``SLOPE_SPREAD`` times its larger."""
    centred = offsets - offsets.mean(axis=-2, keepdims=True)
    spread = np.linalg.eigvalsh(np.einsum("...ki,...kj->...ij", centred, centred))  # ascending
    return spread[..., 0] >= SLOPE_SPREAD**2 * spread[..., 1]


def _join_continuations(uv: np.ndarray, h: np.ndarray, label: np.ndarray, tol: float,
                        n_front: int = 16) -> np.ndarray:
    """``label`` (m,) with the components of ``MIN_CHART_POINTS`` or more that continue each other joined.

    A blob of reflections across a surface breaks the links through it, and a corner cut off
    by it became a sheet of its own (the protocol's crease at 40 %, data seed 7: 102 true points
    in the corner; their chart, halved around the blob, flagged 2.4 % of the inliers). Two
    components continue each other when each one's ``n_front`` points nearest to the other lie,
    in the median, within ``tol`` of a least-squares plane through the other's ``4 * n_front``
    points nearest to them (uv (m, 2), h (m,)); across a step they lie a step away. (The
    points' own local planes at the front are fitted through one side only and half of their
    neighbours are in the blob: extrapolated across it, they missed by 7-18 noise scales.)
    """
    counts = np.bincount(label[label >= 0]) if np.any(label >= 0) else np.zeros(0, int)
    big = np.flatnonzero(counts >= MIN_CHART_POINTS)
    members = {c: np.flatnonzero(label == c) for c in big}
    trees = {c: cKDTree(uv[members[c]]) for c in big}

    def continues(a, b):  # b's front against a plane through a's points beside it
        ia, ib = members[a], members[b]
        front = ib[np.argsort(trees[a].query(uv[ib])[0])[:n_front]]
        centre = uv[front].mean(axis=0)
        patch = ia[trees[a].query(centre, k=min(4 * n_front, len(ia)))[1]]
        design = np.column_stack([np.ones(len(patch)), uv[patch] - centre])
        plane = np.linalg.lstsq(design, h[patch], rcond=None)[0]
        gap = h[front] - plane[0] - (uv[front] - centre) @ plane[1:]
        return np.median(np.abs(gap)) <= tol

    pairs = np.array([(n, k) for n in range(len(big)) for k in range(n + 1, len(big))
                      if continues(big[n], big[k]) and continues(big[k], big[n])], dtype=int).reshape(-1, 2)
    group = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                            shape=(len(big), len(big))), directed=False)[1]
    joined = label.copy()
    for n, c in enumerate(big):
        joined[label == c] = big[np.argmax(group == group[n])]  # the group's first component
    return joined


def _plane_gap(plane: np.ndarray, uv_plane: np.ndarray, uv: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``(n,)`` heights ``h`` at ``uv`` (n, 2) minus the local planes ``(n, 3)`` made at ``uv_plane`` (n, 2)."""
    return h - plane[:, 0] - np.einsum("nd,nd->n", plane[:, 1:], uv - uv_plane)


def _sheets_of(points: np.ndarray, normals: np.ndarray, chart: Chart, *, q: float, cut: float, k: int,
               cos_max: float, overlap: float, sigma_floor: float) -> list[Chart] | None:
    """One chart per sheet of ``chart``, or None if it holds fewer than two."""
    members = chart.members
    levels = _levels_frame(normals[members], chart.rotation)
    local = (points[members] - chart.origin) @ levels.T
    is_core = np.isin(members, chart.core)
    *labels, sigma = _labels_and_scale(local[:, :2], local[:, 2], q=q, cut=cut, k=k, sigma_floor=sigma_floor)
    for slopes, label in enumerate(labels):  # the slope agreement only where the plain links find one sheet
        counts = np.bincount(label[is_core & (label >= 0)], minlength=label.max() + 1)
        sheet_ids = np.flatnonzero(counts >= MIN_CHART_POINTS)
        if slopes:  # and only its sheets that spread over an area (see SLOPE_SPREAD)
            sheet_ids = np.array([c for c in sheet_ids if _areal(local[is_core & (label == c), :2])], dtype=int)
        if len(sheet_ids) >= 2:
            break
    else:
        return None
    # every point joins the sheet that owns its place in the chart plane (a height field has one
    # surface over each place); the places are claimed by the sheets' inner points, which keep
    # their sheet
    labelled = np.flatnonzero(np.isin(label, sheet_ids))
    sheet = np.searchsorted(sheet_ids, label[labelled])
    inner = _inner(local[labelled, :2], sheet)
    if len(np.unique(sheet[inner])) < len(sheet_ids):  # a sheet too thin to have inner points
        inner[:] = True
    owner = Claim(points[members[labelled[inner]]], sheet[inner], 0, chart.rotation[2]).owner(points[members])
    owner[labelled[inner]] = sheet[inner]
    claim = Claim(points[members], owner, 0, chart.rotation[2])
    gap = _inner_plane_gap(local, owner, labelled[inner], sheet[inner])
    untrained = ((label < 0) | np.isin(label, sheet_ids)) & (gap > TRAIN_CUT * sigma) & (gap <= TRAIN_FAR * sigma)
    sheets = [chart_from_core(points, normals, members[(owner == s) & is_core], members[owner == s], q=q,
                              cos_max=cos_max, overlap=overlap, claim=replace(claim, own=s))
              for s in range(len(sheet_ids))]
    return [replace(c, trained=~np.isin(c.members, members[untrained])) for c in sheets]


def _inner_plane_gap(local: np.ndarray, owner: np.ndarray, inner: np.ndarray, inner_sheet: np.ndarray,
                     k: int = 16) -> np.ndarray:
    """``(m,)`` distance in height of each point from the plane of its sheet's inner points nearest to it.

    ``local`` (m, 3) holds the chart's points (u, v, height), ``owner`` (m,) their sheets;
    ``inner`` are the indices of the sheets' inner points and ``inner_sheet`` their sheets.
    Every point but the inner ones is compared with the least-trimmed-squares plane through
    the ``k`` inner points of its own sheet nearest to it; the inner points get 0.
    """
    gap = np.zeros(len(local))
    for s in np.unique(owner):
        own = inner[inner_sheet == s]
        rest = np.setdiff1d(np.flatnonzero(owner == s), own)
        if len(own) < 3 or len(rest) == 0:
            continue
        nb = own[cKDTree(local[own, :2]).query(local[rest, :2], k=min(k, len(own)))[1].reshape(len(rest), -1)]
        planes, _ = trimmed_planes(local[nb, :2] - local[rest, None, :2], local[nb, 2])
        gap[rest] = np.abs(local[rest, 2] - planes[:, 0])
    return gap


def _inner(uv: np.ndarray, sheet: np.ndarray) -> np.ndarray:
    """``(m,)`` bool: sheet points whose ``LINK_NEIGHBOURS`` nearest sheet points (uv (m, 2)) share their sheet.

    An edge ghost whose height is the other level's is a point of that level's sheet, on the
    wrong side of the step (within a spacing of it): had it claimed its place, it would have
    judged itself an inlier. Points next to another sheet's are left to the claim of the inner
    ones, which puts the boundary midway between their fronts (protocol step, 10 data seeds:
    worst recall of the >= 5 sigma outliers 0.932 / 0.950 / 0.936 -> 0.959 / 0.964 / 0.952 at
    10 / 20 / 40 %).
    """
    nearest = cKDTree(uv).query(uv, k=min(LINK_NEIGHBOURS + 1, len(uv)))[1]
    return np.all(sheet[nearest] == sheet[:, None], axis=1)


def _levels_frame(normals: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Axes (3, 3) whose normal is the median of the point ``normals`` (m, 3) (turned to ``rotation[2]``).

    The principal axes of a chart that holds a step are tilted towards the step (least squares
    through two levels: slope 0.15 for the protocol's step), and in that tilted frame the edge
    ghosts' column between the levels leans into a ramp that links them (step at 20 % outliers:
    one sheet). Most points lie on a level, so their median normal is the levels' normal.
    """
    flipped = np.where((normals @ rotation[2] < 0.0)[:, None], -normals, normals)
    normal = np.median(flipped, axis=0)
    return frames_from_normals(normal[None] / np.linalg.norm(normal))[0].T
