"""Large clouds filtered tile by tile, so that memory is bounded by the tile, not the cloud.

A cloud of more than ``TILE_POINTS`` points is cut into boxes of at most that many points
(recursively at the median of the longest side, :func:`split_tiles`). Each tile is filtered with
the points of a margin around its box (one chart radius, :func:`tile_margin`), so that the charts
near its border see the surface beyond it as they would in the whole cloud; only the tile's own
points take their outputs from it. Each tile has its own random generator spawned from the
caller's, and ``workers`` tiles are filtered side by side (threads; the caller gives each one
thread): the result does not depend on the number of threads nor on the order the tiles end in.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from scanrig.surface.robust_fit import concatenate_fits

#: Clouds with more points are filtered in tiles of at most this many (before their margins).
#: 100 000 points filtered at once peaked at 0.6-0.7 GB.
TILE_POINTS = 150_000
#: Most tiles filtered at the same time (one per core of the 2-core machine the filter is
#: benchmarked on): memory is that of as many tiles.
TILE_WORKERS = 2
#: Points whose distance to their ``max_chart_points / 2``-th neighbour sets the margin
#: (:func:`tile_margin`).
MARGIN_SAMPLES = 64


def split_tiles(points: np.ndarray, max_points: int) -> list[np.ndarray]:
    """Partition a cloud into boxes of at most ``max_points`` points.

    Parameters
    ----------
    points : (N, 3) float array
        Metres.
    max_points : int
        Largest tile.

    Returns
    -------
    list of int arrays
        Sorted indices of each tile's points; together a partition of ``range(N)``, in a fixed
        order (lower half before upper half at every cut).
    """
    pending, tiles = [np.arange(len(points))], []
    while pending:
        idx = pending.pop(0)
        if len(idx) <= max_points:
            tiles.append(idx)
            continue
        own = points[idx]
        axis = int(np.argmax(np.ptp(own, axis=0)))
        order = np.argsort(own[:, axis], kind="stable")  # halves of equal size, even on ties
        half = len(idx) // 2
        pending += [np.sort(idx[order[:half]]), np.sort(idx[order[half:]])]
    return tiles


def tile_margin(points: np.ndarray, max_chart_points: int, rng: np.random.Generator) -> float:
    """Width of the margin around each tile's box: a chart's radius, metres.

    The median, over ``MARGIN_SAMPLES`` points drawn from the cloud, of the distance to the
    ``max_chart_points / 2``-th nearest point: a chart of ``max_chart_points`` points on a
    surface sampled that densely reaches about that far from its middle.

    Parameters
    ----------
    points : (N, 3) float array
    max_chart_points : int
    rng : numpy.random.Generator
        Draws the sample points.
    """
    k = int(min(max(2, max_chart_points // 2), len(points)))
    sample = rng.choice(len(points), size=min(MARGIN_SAMPLES, len(points)), replace=False)
    distance, _ = cKDTree(points).query(points[sample], k=[k])
    return float(np.median(distance))


def filter_in_tiles(points: np.ndarray, filter_tile: Callable, *, rng: np.random.Generator, max_points: int,
                    margin: float, workers: int = 1):
    """Filter each tile with its margin and join the tiles' results.

    Parameters
    ----------
    points : (N, 3) float array
        Metres.
    filter_tile : callable
        ``filter_tile(indices, rng) -> FilterResult`` for the points ``indices`` (sorted) of
        the cloud.
    rng : numpy.random.Generator
        Spawns one generator per tile.
    max_points : int
        Largest tile before its margin (:func:`split_tiles`).
    margin : float
        Metres added to every side of a tile's box.
    workers : int
        Tiles filtered at the same time (threads), each with its own points and generator; memory
        is that of as many tiles.

    Returns
    -------
    FilterResult
        Per-point outputs from each point's own tile; the charts whose core holds a tile's own
        point (:func:`own_charts`), tile after tile, with their fits and scales.
    """
    n = len(points)
    per_point = {"denoised": np.empty((n, 3)), "inlier": np.empty(n, bool), "score": np.empty(n),
                 "residual": np.empty(n), "sigma": np.empty(n), "sparse": np.zeros(n, bool)}
    charts, fits, scales = [], [], []
    tiles = split_tiles(points, max_points)

    def run(tile: np.ndarray, tile_rng: np.random.Generator):
        low, high = points[tile].min(axis=0) - margin, points[tile].max(axis=0) + margin
        work = np.flatnonzero(np.all((points >= low) & (points <= high), axis=1))
        return work, filter_tile(work, tile_rng)

    with ThreadPoolExecutor(max(1, workers)) as pool:  # the tiles' numpy and torch work releases the GIL
        done = pool.map(run, tiles, rng.spawn(len(tiles)))
        for tile, (work, result) in zip(tiles, done):  # in the tiles' order, whichever ends first
            own = np.isin(work, tile, assume_unique=True)
            for name, values in per_point.items():
                values[work[own]] = getattr(result, name)[own]
            tile_charts, kept = own_charts(result.charts, work, own)
            charts += tile_charts
            fits.append((result.fits, kept))
            scales.append((result.uv_scale[kept], result.z_scale[kept]))
    offsets = np.cumsum([0] + [len(kept) for _, kept in fits[:-1]])
    rows = np.concatenate([offset + np.flatnonzero(kept) for offset, (_, kept) in zip(offsets, fits)])
    return replace(result, **per_point, charts=charts,
                   fits=concatenate_fits([f for f, _ in fits], rows),
                   uv_scale=np.concatenate([s[0] for s in scales]), z_scale=np.concatenate([s[1] for s in scales]),
                   measured=points)


def own_charts(charts: list, work: np.ndarray, own: np.ndarray) -> tuple[list, np.ndarray]:
    """A tile's charts in the cloud's indices, their cores cut to the tile's own points.

    Parameters
    ----------
    charts : list of Chart
        In the tile's indices.
    work : (n,) int array
        Cloud index of each tile point.
    own : (n,) bool array
        The tile's own points.

    Returns
    -------
    charts : list of Chart
        Those whose core holds a point of the tile's own (cores: those points only, so that the
        cores of all tiles' charts partition the cloud; members: all, in the cloud's indices).
    kept : (C,) bool array
        Which of the input charts were kept.
    """
    kept = np.array([own[c.core].any() for c in charts])
    out = [replace(c, core=work[c.core[own[c.core]]], members=work[c.members])
           for c, k in zip(charts, kept) if k]
    return out, kept
