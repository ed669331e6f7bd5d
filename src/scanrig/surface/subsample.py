"""Stratified training subsample of a dense chart: the points its networks' hidden layers train on.

A chart's networks have a fixed number of weights (two hidden layers of 24 units: about 700),
so past a few thousand points more points lower the fit's variance little while every epoch
costs in proportion to them. A chart with more than ``k`` training points trains on ``k`` of
them, drawn over its area in turn: the chart plane's bounding box is cut into about ``k``
cells, every occupied cell gives one point (in random order) before any gives a second, so
the sample keeps the chart's edges and its sparse parts as well as its dense ones. The noise
scale, the cut-offs, the scores and the inlier decisions are still computed at every point.
"""

from __future__ import annotations

import numpy as np

from scanrig.errors import InputError


def stratified_subsample(uv: np.ndarray, mask: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """At most ``k`` of each chart's ``mask`` points, spread over its area.

    Parameters
    ----------
    uv : (C, n, 2) float array
        Chart coordinates (any unit); rows outside ``mask`` are ignored.
    mask : (C, n) bool array
        Points eligible for training.
    k : int
        Most points kept per chart (>= 1); a chart with at most ``k`` keeps all of its points.
    rng : numpy.random.Generator
        Draws the order within the cells (only for charts over ``k``).

    Returns
    -------
    (C, n) bool array
        The points kept, a subset of ``mask``.
    """
    if k < 1:
        raise InputError(f"k (training points per chart) must be >= 1, got {k}")
    keep = mask.copy()
    cells_per_side = int(np.ceil(np.sqrt(k)))
    for c in np.flatnonzero(mask.sum(axis=1) > k):  # charts: tens to hundreds; each vectorised
        cols = np.flatnonzero(mask[c])
        p = uv[c, cols]
        low, span = p.min(axis=0), np.ptp(p, axis=0)
        ij = np.minimum((cells_per_side * (p - low) / np.where(span > 0, span, 1.0)).astype(np.int64),
                        cells_per_side - 1)
        cell = ij[:, 0] * cells_per_side + ij[:, 1]
        key = rng.random(cols.size)
        by_cell = np.lexsort((key, cell))  # cells in turn, random order inside each
        sorted_cell = cell[by_cell]
        first = np.r_[0, np.flatnonzero(np.diff(sorted_cell)) + 1]
        rank = np.empty(cols.size, dtype=np.int64)
        rank[by_cell] = np.arange(cols.size) - np.repeat(first, np.diff(np.r_[first, cols.size]))
        chosen = np.lexsort((key, rank))[:k]  # every cell's first point, then every cell's second ...
        keep[c] = False
        keep[c, cols[chosen]] = True
    return keep
