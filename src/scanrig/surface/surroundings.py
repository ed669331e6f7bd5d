"""Judge the points of untrusted charts by the trusted surface around them.

A chart whose fit does not follow its points at the cloud's noise is not trusted (see
:data:`~scanrig.surface.filter.TRUST_FACTOR`): it moves none of them and scores them against the
reference noise, but against its own fit. When the chart is a piece of a blob of reflections,
that fit runs through the blob and the blob points near it pass: on 100 000 points of the
protocol's scan (five blobs of ~2000 points, 74 of 123 charts cut from them) 1284 of the 1628
missed >= 5 sigma outliers were such points; judged as below, recall 0.817 -> 0.919, inlier
false rejections unchanged (0.0011), 0.5 s of the 56 s.

Here the core points of such a chart, unless a trusted chart owns them, are judged again by the
surface of the trusted inliers around them when the chart's points are no surface at the
reference noise *in the frame of that surrounding surface*: the least-trimmed-squares plane of
each point's 16 nearest points in that plane (as in the robust start; all points over the
chart's place, between the surrounding surface and the chart's highest or lowest point) has a
trimmed scale above ``SURFACE_SCALE_FACTOR`` noise scales or misses the point by more than
``r``. A patch of reflections spreads its heights over many noise scales above the surface; a
true surface in a chart that failed for another reason (a side too small to be a sheet, the top
of a second object) is smooth in that frame too and keeps its chart's judgement. Not in the
chart's own frame: a dense blob is a slab of points, and a chart cut from it is tilted (normals
up to 60 degrees from the surface's) so that its points' nearest neighbours lie on a plane
through the slab at the noise level.

The surrounding surface of a point is a least-squares quadratic through its ``k`` nearest
trusted inliers, in the frame of their mean normal (not of their principal axes: around a blob
the nearest trusted points are a strip along its rim, whose thinnest axis may lie in the
surface), used where it fits them within ``SURFACE_SCALE_FACTOR`` noise scales (one smooth
surface, not two sides of an edge). The point's score is its distance from the quadratic over
the standard deviation of that distance, ``sigma_ref sqrt(1 + g)`` with ``g`` the quadratic's
prediction variance at the point in units of the noise variance: far from the trusted points
(extrapolation) the score shrinks instead of raising false alarms.

Deep inside a blob wider than that neighbourhood the ``k`` nearest trusted points lie on the
nearest stretch of its rim, and the quadratic extrapolates (``g`` of tens to thousands: the
score of a point 10 noise scales off falls below ``r``). So the quadratic is also fitted to the
``k`` nearest of random thinnings of the trusted points, to one in 4, 16, ... 1024
(``THINNING_LEVELS``), whose neighbourhoods are 4, 16, ... times wider and reach round the
blob; each point is scored by the fit of least ``g`` among those that pass the surface test.
Which points are judged is still decided by the nearest fit alone: it must pass the surface
test, and the test whether a chart's points form a surface keeps its frame (the normal of the
surface next to the chart). A thinned neighbourhood can reach another surface: on the demo's
cloud, 13 good points of a part's face whose nearest trusted points straddle its edge (a nearest
fit 40-60 noise scales rough) have a smooth thinned fit through the floor 700 noise scales away,
and would be rejected if that fit could decide that they are judged.
``benchmarks/bench_filter.py --timing-only``, seed 0: recall of the >= 5 sigma outliers 0.936 ->
0.960 on 100 000 points and 0.884 -> 0.950 on the million points (blobs of radius ~0.35 m, 35
spacings), inlier false rejections unchanged (0.0011, 0.0007); about 8 s more on the million
points' ~370 s.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from scanrig.surface.charts import Chart, frames_from_normals
from scanrig.surface.local_start import SURFACE_SCALE_FACTOR, quadratic_basis, trimmed_planes

#: Trusted inliers the surrounding quadratic is fitted to.
SURROUNDING_POINTS = 96
#: Random thinnings of the trusted points, to one in 4, 16, ..., 4**THINNING_LEVELS, whose
#: quadratics are tried as well.
THINNING_LEVELS = 5
#: Neighbours (in the plane of the surrounding surface) of the test whether a chart's points
#: form a surface.
OWN_NEIGHBOURS = 16


def surroundings_score(points: np.ndarray, normals: np.ndarray, charts: list[Chart], owned: np.ndarray,
                       reference: np.ndarray, sigma_ref: float, r: float, k: int = SURROUNDING_POINTS, *,
                       rng: np.random.Generator, workers: int = 1) -> np.ndarray:
    """Score of the core points of untrusted charts against the trusted surface around them.

    Parameters
    ----------
    points, normals : (N, 3) float arrays
        The cloud (metres) and its unit normals.
    charts : list of Chart
        The untrusted charts.
    owned : (N,) bool array
        Points owned by a trusted chart (never judged here).
    reference : (n_ref,) int array
        Trusted inliers; with fewer than ``k`` every score is NaN.
    sigma_ref : float
        Reference noise, metres (> 0).
    r : float
        Rejection point, in noise scales.
    k : int
        Reference points per quadratic (>= 7).
    rng : numpy.random.Generator
        Draws the thinnings of the reference points.
    workers : int
        Threads of the neighbour queries and of the charts' tests (the same scores whatever
        their number).

    Returns
    -------
    (N,) float array
        ``|distance from the quadratic| / (sigma_ref sqrt(1 + g))`` at the judged points; NaN
        elsewhere: owned points, points of other charts, charts' points that form a surface,
        points whose surrounding trusted points form none.
    """
    score = np.full(len(points), np.nan)
    cores = [chart.core[~owned[chart.core]] for chart in charts]
    candidates = np.concatenate(cores + [np.zeros(0, int)]).astype(int)
    if candidates.size == 0 or len(reference) < k:
        return score
    nearest = _quadratics(points, normals, candidates, reference, k, workers)
    best = _least_variance(nearest, points, normals, candidates, reference, k, sigma_ref, rng, workers)
    bounds = np.cumsum([0] + [core.size for core in cores])

    def chart_rough(i: int) -> np.ndarray:  # one vectorised set of planes per chart (tens of charts)
        sl = slice(bounds[i], bounds[i + 1])
        return _rough(points, cores[i], _mean_axis(nearest.normal[None, sl])[0], nearest.height[sl], sigma_ref, r)

    rough = np.zeros(len(points), bool)
    tested = [i for i, core in enumerate(cores) if core.size]
    with ThreadPoolExecutor(max(1, workers)) as pool:  # numpy and SciPy release the GIL inside
        for i, chart_is_rough in zip(tested, pool.map(chart_rough, tested)):
            rough[cores[i]] = chart_is_rough
    judged = rough[candidates] & (nearest.spread <= SURFACE_SCALE_FACTOR * sigma_ref)
    score[candidates[judged]] = np.abs(best.height[judged]) / (sigma_ref * np.sqrt(1.0 + best.g[judged]))
    return score


class _Quadratics(NamedTuple):
    """Per candidate (m,): its height above the quadratic, the quadratic's prediction variance
    over the noise variance at it, the residual scale of the fit (metres) and the frame's normal
    (m, 3)."""

    height: np.ndarray
    g: np.ndarray
    spread: np.ndarray
    normal: np.ndarray


def _least_variance(nearest, points, normals, candidates, reference, k, sigma_ref, rng, workers) -> _Quadratics:
    """Per candidate: of its quadratic through the nearest reference points (``nearest``) and
    those through random thinnings of them to one point in 4, 16, ... (``THINNING_LEVELS``, while
    ``k`` remain), the one of least prediction variance among those that fit their points within
    ``SURFACE_SCALE_FACTOR`` times ``sigma_ref``; the nearest where none does."""
    best = _Quadratics(*(a.copy() for a in nearest))
    fits = best.spread <= SURFACE_SCALE_FACTOR * sigma_ref
    order = rng.permutation(reference)  # nested random thinnings: one point in 4, 16, 64, ...
    for level in range(1, THINNING_LEVELS + 1):
        if len(reference) < k * 4**level:
            break
        thinned = np.sort(order[: len(reference) // 4**level])
        fit = _quadratics(points, normals, candidates, thinned, k, workers)
        fits_here = fit.spread <= SURFACE_SCALE_FACTOR * sigma_ref
        better = fits_here & (~fits | (fit.g < best.g))
        for kept, new in zip(best, fit):
            kept[better] = new[better]
        fits |= fits_here
    return best


def _quadratics(points, normals, candidates, reference, k, workers) -> _Quadratics:
    """Per candidate: the quadratic of its ``k`` nearest reference points in their normal's frame
    (neighbour queries on ``workers`` threads)."""
    p = points[candidates]
    _, nb = cKDTree(points[reference]).query(p, k=k, workers=workers)
    offsets = points[reference[nb]] - p[:, None, :]  # the candidate at the origin
    axes = frames_from_normals(_mean_axis(normals[reference[nb]]))
    local = offsets @ axes  # matmul over the stack: einsum was this function's largest cost
    design, h = quadratic_basis(local[..., :2]), local[..., 2]
    design_t = design.transpose(0, 2, 1)
    gram = design_t @ design + 1e-12 * np.eye(6)
    coef = np.linalg.solve(gram, design_t @ h[..., None])
    spread = np.sqrt(np.sum((h - (design @ coef)[..., 0]) ** 2, axis=1) / (k - 6))
    g = np.linalg.solve(gram, np.broadcast_to(np.eye(6)[:, :1], (len(p), 6, 1)))[:, 0, 0]
    return _Quadratics(-coef[:, 0, 0], g, spread, axes[:, :, 2])


def _mean_axis(normals: np.ndarray) -> np.ndarray:
    """Mean direction of sets of unoriented unit vectors (m, n, 3): the principal axis of each
    set's scatter, (m, 3)."""
    return np.linalg.eigh(normals.transpose(0, 2, 1) @ normals)[1][..., -1]


def _rough(points: np.ndarray, core: np.ndarray, normal: np.ndarray, height: np.ndarray, sigma_ref: float,
           r: float) -> np.ndarray:
    """(n,) bool: core points whose neighbourhood is no plane at ``sigma_ref`` in the frame whose
    height axis is ``normal``.

    The neighbourhood is taken among all points over the core's place in that frame, from the
    surrounding surface (``height`` above it, (n,)) to the core's highest or lowest point: not
    among the chart's members, which lie in its height window (a chart cut from a blob is a
    thin horizontal slice of it, flat at the noise level).
    """
    local = points @ frames_from_normals(normal[None])[0]
    own = local[core]
    centre = own[:, :2].mean(axis=0)
    radius = np.max(np.linalg.norm(own[:, :2] - centre, axis=1))
    surface = own[:, 2] - height  # the surrounding surface's level under each core point
    low = min(surface.min(), own[:, 2].min()) - r * sigma_ref
    high = max(surface.max(), own[:, 2].max()) + r * sigma_ref
    pool = np.flatnonzero((np.linalg.norm(local[:, :2] - centre, axis=1) <= 1.5 * radius + 1e-12)
                          & (local[:, 2] >= low) & (local[:, 2] <= high))
    if len(pool) < 4:
        return np.zeros(len(core), bool)
    _, nb = cKDTree(local[pool, :2]).query(own[:, :2], k=min(OWN_NEIGHBOURS + 1, len(pool)))
    nb = pool[nb[:, 1:]]  # the core point itself is its own nearest
    plane, scale = trimmed_planes(local[nb, :2] - own[:, None, :2], local[nb, 2])
    return (scale > SURFACE_SCALE_FACTOR * sigma_ref) | (np.abs(own[:, 2] - plane[:, 0]) > r * sigma_ref)
