"""Stripe candidates ranked by continuity: a laser stripe is a long thin curve, texture is short.

The scan lines cross every stripe at 45° or more from lengthwise (:mod:`scanrig.laser.stripes`),
so from one line to the next a stripe's centre moves by at most about a pixel, over long runs of
lines. A printed dot's edge or the gap between two dots gives candidates on a few lines only; a
glint is a blob. Each candidate is linked to its nearest candidate on the next line within
``MAX_STEP_PX`` per line plus ``JITTER_PX`` (one or two lines without one within reach are
skipped, ``MAX_GAP_LINES``); where several link to one, only the nearest keeps its link. The links
make simple chains, so a texture candidate beside a stripe does not join the stripe's chain. The
candidates of a line are ranked by the number of lines their chain spans, counted up to ``CHAIN_CAP_LINES``, then by prominence: a
long trace outranks a stronger short one, and two long traces (two lasers, a reflection) both
stay, the more prominent first.

Sorting and binary search only (O(n log n)); the chains are the connected components of the
link graph (:func:`scipy.sparse.csgraph.connected_components`).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from scanrig.errors import ShapeError
from scanrig.laser.stripe_candidates import rank_on_lines

#: Largest move of a stripe's centre along the scan lines per line, px (a crossing at 45°).
MAX_STEP_PX = 1.0
#: Allowance for the scatter of two fitted centres and a little curvature, px.
JITTER_PX = 1.0
#: Lines without a candidate within reach that a chain may skip (a noisy or occluded line).
MAX_GAP_LINES = 2
#: Chains spanning at least this many lines rank alike (then by prominence): a stripe's chain is
#: cut where its scan direction changes, and a long printed line is no better than a stripe.
CHAIN_CAP_LINES = 24


def chain_lengths(line: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Number of lines spanned by the chain of each candidate.

    Parameters
    ----------
    line : (n,) int array
        Scan line of each candidate.
    centre : (n,) float array
        Centre along its scan line, px.

    Returns
    -------
    (n,) int64 array
        1 for a candidate linked to none; the same count for every candidate of one chain (from its
        first line to its last, skipped lines included).

    Raises
    ------
    ShapeError
        When ``line`` and ``centre`` are not 1-D arrays of one length.
    """
    line, centre = np.asarray(line), np.asarray(centre, dtype=np.float64)
    if line.ndim != 1 or line.shape != centre.shape:
        raise ShapeError(f"line and centre must be 1-D arrays of one length, got shapes {line.shape} and "
                         f"{centre.shape}")
    n = line.size
    if n == 0:
        return np.zeros(0, np.int64)
    line = line.astype(np.int64)
    forward, distance, order = _links(line, centre)
    line, centre = line[order], centre[order]
    linked = np.flatnonzero(forward >= 0)
    # of the candidates linking to one, the nearest keeps its link: chains do not branch
    nearest = np.full(n, np.inf)
    np.minimum.at(nearest, forward[linked], distance[linked])
    linked = linked[distance[linked] == nearest[forward[linked]]]
    graph = coo_matrix((np.ones(linked.size, np.int8), (linked, forward[linked])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    first, last = np.full(count, line[-1]), np.full(count, line[0])
    np.minimum.at(first, label, line)
    np.maximum.at(last, label, line)
    lengths = np.empty(n, np.int64)
    lengths[order] = (last - first + 1)[label]
    return lengths


def rank_by_continuity(line: np.ndarray, centre: np.ndarray, prominence: np.ndarray) -> np.ndarray:
    """0 for the candidate of each line in the longest chain (counted up to ``CHAIN_CAP_LINES``),
    the most prominent among equals; 1 for the next, ...

    Parameters
    ----------
    line : (n,) int array
        Scan line of each candidate.
    centre : (n,) float array
        Centre along its scan line, px.
    prominence : (n,) float array
        Prominence, positive (any unit; only its order on a line counts).

    Returns
    -------
    (n,) int32 array
        Rank of each candidate on its line.
    """
    line = np.asarray(line)
    if np.all(line[1:] > line[:-1]):  # one candidate per line: nothing to rank
        return np.zeros(line.size, np.int32)
    capped = np.minimum(chain_lengths(line, centre), CHAIN_CAP_LINES)
    # prominence / (2 max) lies in (0, 1/2]: it orders candidates of equal length only
    return rank_on_lines(line, capped + prominence / (2.0 * np.max(prominence)))


#: Lines searched after a candidate, nearest first.
_STEPS = np.arange(1, MAX_GAP_LINES + 2)
#: Reach on the line ``_STEPS`` away, px.
_GATE_PX = _STEPS[:, None] * MAX_STEP_PX + JITTER_PX


def _links(line: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each candidate's link on the lines after it: on the nearest line within ``MAX_GAP_LINES + 1``
    that holds a candidate within reach, the nearest one there (-1 where there is none), and its
    distance along the line (px); indices into the candidates sorted by (line, centre), and that
    order.

    One float key per candidate, ``(line − first line) · stride + centre − low``, sorts them by line,
    then centre. The stride exceeds the centres' range by more than twice the largest reach, so a
    key searched on the line ``s`` away, ``key + s · stride``, differs from any key of another line
    by more than the reach and from one on that line by exactly the distance along it.
    """
    reach = float(_GATE_PX.max())
    low = centre.min() - reach
    stride = centre.max() - low + reach + 1.0
    key = (line - line.min()) * stride + (centre - low)
    order = np.argsort(key)
    key = key[order]
    query = key + _STEPS[:, None] * stride  # (steps, n)
    right = np.searchsorted(key, query)
    padded = np.r_[-np.inf, key, np.inf]
    to_left, to_right = query - padded[right], padded[right + 1] - query
    nearest = np.where(to_left <= to_right, right - 1, right)
    distance = np.minimum(to_left, to_right)
    within = distance <= _GATE_PX
    first = np.argmax(within, axis=0)  # the nearest line with a candidate within reach
    columns = np.arange(key.size)
    found = within[first, columns]
    return np.where(found, nearest[first, columns], -1), distance[first, columns], order
