"""Board patterns computed one coordinate at a time: the same bits as the (N, 2) pair form."""

from __future__ import annotations

import numpy as np

from scanrig.targets import patterns
from scanrig.targets.boards import CharucoBoard


def _charuco_pairwise(xy, squares, square_m, margin_m, marker_m, corners, bits):
    """charuco_reflectance as it was written on (N, 2) pairs of coordinates."""
    ij = np.floor((xy - margin_m) / square_m)
    inside = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < squares[0]) & (ij[:, 1] < squares[1])
    with np.errstate(invalid="ignore"):
        i, j = ij.astype(np.int64).T
    value = 1.0 - (((i + j) & 1) ^ 1) * inside
    n_sq, n_cells = squares[0] * squares[1], bits.shape[1]
    marker_ij = np.floor((corners - margin_m) / square_m).astype(np.int64)
    lookup = np.full(n_sq + 1, -1)
    lookup[marker_ij[:, 1] * squares[0] + marker_ij[:, 0]] = np.arange(len(marker_ij))
    k = lookup[np.where(inside, j * squares[0] + i, n_sq)]
    idx = np.flatnonzero(k >= 0)
    k = k[idx]
    cell = np.floor((xy[idx] - corners[k]) / marker_m * n_cells).astype(np.int64)
    ok = ((cell >= 0) & (cell < n_cells)).all(axis=1)
    value[idx[ok]] = bits.reshape(-1)[(k[ok] * n_cells + cell[ok, 1]) * n_cells + cell[ok, 0]]
    return value


def test_charuco_by_columns_is_the_pairwise_forms_bits():
    board = CharucoBoard("test")
    corners, bits = board.marker_layout
    rng = np.random.default_rng(5)
    w, h = board.size_m
    points = np.column_stack([rng.uniform(-0.01, w + 0.01, 50000), rng.uniform(-0.01, h + 0.01, 50000),
                              np.zeros(50000)])
    xy = points[:, :2]                              # a view of (N, 3) points, as a renderer passes
    args = (board.squares, board.square_m, board.margin_m, board.marker_m, corners, bits)
    got = patterns.charuco_reflectance(xy, *args)
    want = _charuco_pairwise(xy, *args)
    assert np.unique(got).size == 2 and 0.2 < got.mean() < 0.8
    assert np.array_equal(got, want)
