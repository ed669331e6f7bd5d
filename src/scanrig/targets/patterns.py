"""Printed appearance of boards: reflectance at board coordinates, rasterised to images.

Every board kind defines its look as a vectorised function ``reflectance(xy_board) -> (N,)``
(0 = black ink, 1 = white paper) of board coordinates in metres. Images are sampled from that
function, so a pattern is exact at any resolution and a renderer may sample it directly at
ray-hit points instead of going through an image.

Image convention: pixel ``(u, v)`` has its centre at board coordinates
``((u + 0.5) / px_per_m, (v + 0.5) / px_per_m)``; x runs along columns, y along rows.
"""

from __future__ import annotations

import numpy as np

from scanrig.errors import InputError


def chessboard_reflectance(xy: np.ndarray, squares: tuple[int, int], square_m: float,
                           margin_m: float) -> np.ndarray:
    """Reflectance of a chessboard whose top-left square is black, with a white margin.

    Parameters
    ----------
    xy : ndarray of shape (N, 2)
        Board coordinates, metres.
    squares : (int, int)
        Number of squares along x (columns) and y (rows).
    square_m, margin_m : float
        Square side and white border width, metres.

    Returns
    -------
    ndarray of shape (N,)
        1.0 on white, 0.0 on black.
    """
    ij = np.floor((xy - margin_m) / square_m)
    inside = np.all((ij >= 0) & (ij < np.asarray(squares)), axis=1)
    black = inside & ((ij[:, 0] + ij[:, 1]) % 2 == 0)
    return np.where(black, 0.0, 1.0)


def charuco_reflectance(xy: np.ndarray, squares: tuple[int, int], square_m: float, margin_m: float,
                        marker_m: float, marker_corners_m: np.ndarray, marker_bits: np.ndarray) -> np.ndarray:
    """Reflectance of a ChArUco board: a chessboard with an ArUco marker in every white square.

    Parameters
    ----------
    xy : ndarray of shape (N, 2)
        Board coordinates, metres.
    squares : (int, int)
        Squares along x and y (OpenCV's ``CharucoBoard`` size).
    square_m, margin_m, marker_m : float
        Square side, white border and marker side, metres.
    marker_corners_m : ndarray of shape (n_markers, 2)
        Top-left corner of each marker in board coordinates (margin included), metres.
    marker_bits : ndarray of shape (n_markers, c, c)
        Each marker's cells including its black border (1 = white), as drawn by OpenCV.

    Returns
    -------
    ndarray of shape (N,)
    """
    value = chessboard_reflectance(xy, squares, square_m, margin_m)
    n_cells = marker_bits.shape[1]
    # The square each sample falls in picks at most one marker: look it up by square index.
    ij = np.floor((xy - margin_m) / square_m).astype(np.int64)
    marker_ij = np.floor((marker_corners_m - margin_m) / square_m).astype(np.int64)
    lookup = -np.ones((squares[1], squares[0]), dtype=np.int64)
    lookup[marker_ij[:, 1], marker_ij[:, 0]] = np.arange(len(marker_ij))
    inside = np.all((ij >= 0) & (ij < np.asarray(squares)), axis=1)
    k = np.full(len(xy), -1)
    k[inside] = lookup[ij[inside, 1], ij[inside, 0]]
    has = k >= 0
    cell = np.floor((xy[has] - marker_corners_m[k[has]]) / marker_m * n_cells).astype(np.int64)
    in_marker = np.all((cell >= 0) & (cell < n_cells), axis=1)
    idx = np.flatnonzero(has)[in_marker]
    c = cell[in_marker]
    value[idx] = marker_bits[k[idx], c[:, 1], c[:, 0]]
    return value


def circles_reflectance(xy: np.ndarray, centres_m: np.ndarray, spacing_m: float,
                        diameter_m: float) -> np.ndarray:
    """Reflectance of black discs on white paper.

    Parameters
    ----------
    xy : ndarray of shape (N, 2)
        Board coordinates, metres.
    centres_m : ndarray of shape (M, 2)
        Disc centres, metres; neighbouring centres are at least ``spacing_m`` apart.
    spacing_m, diameter_m : float
        Grid spacing and disc diameter, metres.

    Returns
    -------
    ndarray of shape (N,)
    """
    # Bucket the centres on a grid of cell `spacing_m` (at most one centre per cell); a disc can only
    # cover samples in its own cell or the 8 neighbours, so each sample checks 9 cells.
    origin = centres_m.min(axis=0) - 1.5 * spacing_m  # centres mid-cell: no rounding ties
    cell_of = np.floor((centres_m - origin) / spacing_m).astype(np.int64)
    shape = cell_of.max(axis=0) + 3
    grid = -np.ones((shape[1], shape[0]), dtype=np.int64)
    grid[cell_of[:, 1], cell_of[:, 0]] = np.arange(len(centres_m))
    cell = np.floor((xy - origin) / spacing_m).astype(np.int64)
    r2 = (0.5 * diameter_m) ** 2
    black = np.zeros(len(xy), dtype=bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            cx, cy = cell[:, 0] + dx, cell[:, 1] + dy
            ok = (cx >= 0) & (cy >= 0) & (cx < shape[0]) & (cy < shape[1])
            k = np.full(len(xy), -1)
            k[ok] = grid[cy[ok], cx[ok]]
            hit = k >= 0
            d2 = np.sum((xy[hit] - centres_m[k[hit]]) ** 2, axis=1)
            black[np.flatnonzero(hit)[d2 <= r2]] = True
    return np.where(black, 0.0, 1.0)


def rasterise(reflectance, size_m: tuple[float, float], px_per_m: float, supersample: int = 1) -> np.ndarray:
    """Sample a reflectance function into an 8-bit image.

    Parameters
    ----------
    reflectance : callable
        ``(N, 2) board coordinates (m) -> (N,)`` values in [0, 1].
    size_m : (float, float)
        Width and height of the printed area, metres.
    px_per_m : float
        Resolution, pixels per metre.
    supersample : int
        Samples per pixel along each axis (box-filter anti-aliasing); 1 samples pixel centres.

    Returns
    -------
    ndarray of shape (H, W), uint8
        ``W = round(width * px_per_m)``, ``H = round(height * px_per_m)``; 0 black, 255 white.
    """
    if not px_per_m > 0:
        raise InputError(f"px_per_m must be positive, got {px_per_m!r}")
    if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or supersample < 1:
        raise InputError(f"supersample must be a positive integer, got {supersample!r}")
    width, height = (int(round(s * px_per_m)) for s in size_m)
    offsets = (np.arange(supersample) + 0.5) / supersample
    u = (np.arange(width)[:, None] + offsets[None, :]).ravel()
    v = (np.arange(height)[:, None] + offsets[None, :]).ravel()
    uu, vv = np.meshgrid(u, v)
    xy = np.column_stack([uu.ravel(), vv.ravel()]) / px_per_m
    value = reflectance(xy).reshape(height, supersample, width, supersample).mean(axis=(1, 3))
    return np.round(value * 255.0).astype(np.uint8)
