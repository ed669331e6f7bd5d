"""Inlier probability of each point from the outliers around it: a local two-component mixture.

The Hampel weights treat alike every residual inside the rejection point ``r`` sigma. Outliers
that are one-sided and clustered in space (edge ghosts: mixtures of the two sides of an edge,
offsets spread evenly from zero to the depth difference; reflections near their blob's rim)
fall partly inside that band, where no test on a residual alone can reject them, and all on one
side: they pull the fit. On the crease of the protocol at 20 % outliers the fit sank 0.2-0.3
sigma further than the oracle's within 0.3 of the edge.

Yet the same cluster leaves a trace just beyond the rejection point. Around each point, the
neighbours with residuals in ``(r, w r]`` sigma on one side give the density of outliers per
unit of residual on that side; taken as flat down to zero (exact for offsets spread evenly
from zero, as an edge ghost's; too high where outliers are rarer near the surface, as in a
reflection blob, whose offsets start at a few sigma), it is the outlier component of a local
mixture whose inlier component is the Gaussian of the points inside the band. The posterior probability that a point of standardised residual ``s`` is an inlier::

    P(s) = f_in phi(s) / (f_in phi(s) + c_sgn(s)),
    c_+ = #{neighbours with r < s_j <= w r} / (k (w - 1) r),  c_- likewise with -s_j,

with ``f_in`` the neighbours' fraction with ``|s_j| <= r`` and ``phi`` the standard normal
density. Weighting by it is the expectation step of the mixture's EM: inliers and outliers at
the same residual get the same weight, so their weighted mean is the inliers' mean where the
mixture holds. Where no neighbour lies beyond the band, ``c = 0`` and ``P = 1``: clean
surfaces keep their Hampel weights exactly.

Our addition to Chen & Jain; :mod:`scanrig.surface.robust_fit` multiplies the robust weights
by it before the reweighting step and in its last output-layer steps.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from scanrig.errors import InputError

_SQRT_2PI = np.sqrt(2.0 * np.pi)


def chart_neighbours(uv: np.ndarray, valid: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` nearest valid points of every point of every chart (itself included).

    Parameters
    ----------
    uv : (C, n, 2) float array
        Chart coordinates; rows where ``valid`` is False are ignored.
    valid : (C, n) bool array
    k : int
        Neighbours per point (>= 1); a chart with fewer valid points gives all of them.

    Returns
    -------
    (C, n, k) int array
        Column of each neighbour in its chart, -1 where there is none (padding rows, small
        charts).
    """
    if k < 1:
        raise InputError(f"k (neighbours per point) must be >= 1, got {k}")
    n_charts, n_max = valid.shape
    out = np.full((n_charts, n_max, k), -1, dtype=np.int64)
    for c in range(n_charts):  # one tree per chart: C is tens to hundreds, each query vectorised and threaded
        cols = np.flatnonzero(valid[c])
        if cols.size == 0:
            continue
        k_c = min(k, cols.size)
        _, nb = cKDTree(uv[c, cols]).query(uv[c, cols], k=k_c, workers=-1)
        out[c, cols, :k_c] = cols[nb.reshape(cols.size, k_c)]
    return out


def inlier_posterior(s: np.ndarray, neighbours: np.ndarray, r: float, window: float) -> np.ndarray:
    """Posterior probability that each point is an inlier, given its neighbours' residuals.

    Parameters
    ----------
    s : (C, n) float array
        Residuals in units of the chart's noise scale; NaN rows are not counted.
    neighbours : (C, n, k) int array
        From :func:`chart_neighbours` (-1 = none).
    r : float
        Rejection point, in noise scales (> 0).
    window : float
        The outliers' density is counted over ``(r, window * r]`` on each side (> 1).

    Returns
    -------
    (C, n) float array
        In (0, 1]; 1 where no neighbour lies in the window on the point's side. NaN where ``s``
        is NaN.
    """
    if not window > 1.0:
        raise InputError(f"window must be > 1, got {window}")
    if not r > 0.0:
        raise InputError(f"r must be > 0, got {r}")
    # each point's class, gathered at once over its neighbours as one byte: 0 not counted (no
    # residual), 1 inside the band, 2 and 3 in the window below and above it, 4 beyond the
    # window (not comparisons of gathered (C, n, k) residuals, 1.7-2x the time)
    n_charts, n_max, _ = neighbours.shape
    with np.errstate(invalid="ignore"):
        kind = np.select([~np.isfinite(s), np.abs(s) <= r, (s < -r) & (s >= -window * r), (s > r) & (s <= window * r)],
                         [0, 1, 2, 3], 4).astype(np.int8)
    kind = np.pad(kind, ((0, 0), (0, 1)))  # column n_max: "no neighbour" (-1) counts nowhere
    nb_kind = np.take_along_axis(kind, np.where(neighbours >= 0, neighbours, n_max).reshape(n_charts, -1),
                                 axis=1).reshape(neighbours.shape)
    count = np.maximum(np.count_nonzero(nb_kind, axis=2), 1)
    f_in = np.count_nonzero(nb_kind == 1, axis=2) / count
    density = np.where(s < 0, np.count_nonzero(nb_kind == 2, axis=2),
                       np.count_nonzero(nb_kind == 3, axis=2)) / (count * (window - 1.0) * r)
    inlier = f_in * np.exp(-0.5 * s * s) / _SQRT_2PI
    with np.errstate(invalid="ignore"):
        post = np.where(density > 0, inlier / (inlier + density), 1.0)
    return np.where(np.isfinite(s), post, np.nan)
