"""Gathers over images: pixel blocks, 3 × 3 box sums, and per-cell maps looked up at pixels.

Shared by the noise model (:mod:`scanrig.laser.noise`), the signal of a frame
(:mod:`scanrig.laser.image`) and the candidate search (:mod:`scanrig.laser.peaks`).
"""

from __future__ import annotations

import numpy as np


def pixel_blocks(a: np.ndarray, top: np.ndarray, left: np.ndarray, height: int, width: int) -> np.ndarray:
    """The blocks ``a[top + i, left + j]``, ``i < height``, ``j < width``, of an image, its edge
    repeated beyond it.

    Blocks inside the image are copied whole from a sliding-window view, without an index per
    value (three times faster), except from a transposed view, whose rows are strided (there the
    index per value is as fast).

    Parameters
    ----------
    a : (H, W) or (H, W, C) array
    top, left : (n,) int arrays
        Block corners, pixels; blocks may reach beyond the image.
    height, width : int
        Block size, pixels.

    Returns
    -------
    (n, height, width) or (n, height, width, C) array of ``a``'s dtype
    """
    n_rows, n_cols = a.shape[:2]
    inside = (top >= 0) & (top + height <= n_rows) & (left >= 0) & (left + width <= n_cols)
    inside &= a.strides[1] <= a.strides[0]
    if top.size and inside.all():
        return np.ascontiguousarray(_windows(a, top, left, height, width))
    out = np.empty((top.size, height, width) + a.shape[2:], a.dtype)
    whole = np.flatnonzero(inside)
    if whole.size:  # (never in an image smaller than a block)
        out[whole] = _windows(a, top[whole], left[whole], height, width)
    edge = np.flatnonzero(~inside)
    rows = np.clip(top[edge, None] + np.arange(height), 0, n_rows - 1)
    cols = np.clip(left[edge, None] + np.arange(width), 0, n_cols - 1)
    out[edge] = a[rows[:, :, None], cols[:, None, :]]
    return out


def _windows(a, top, left, height, width) -> np.ndarray:
    """:func:`pixel_blocks` lying inside ``a``, from its sliding-window view (channels last)."""
    from numpy.lib.stride_tricks import sliding_window_view

    return np.moveaxis(sliding_window_view(a, (height, width), axis=(0, 1))[top, left], (-2, -1), (1, 2))


def padded_box_sums(signal: np.ndarray) -> np.ndarray:
    """3 × 3 box sums of an image, DN, with one ring beyond its edges.

    Parameters
    ----------
    signal : (H, W) array, DN

    Returns
    -------
    (H + 2, W + 2) uint16 (8-bit image) or float32 array
        The sums centred on rows −1 .. H and columns −1 .. W, the image's edge pixels repeated
        beyond it. Exact: nine bytes sum to at most 2295, and the signals of
        :func:`~scanrig.laser.image.prepare_image` are multiples of ½ DN far below 2**23. Half the bytes for 8-bit
        data make the filters over them twice as fast.
    """
    import cv2

    h, w = signal.shape
    depth, dtype = (cv2.CV_16U, np.uint16) if signal.dtype == np.uint8 else (cv2.CV_32F, np.float32)
    out = np.empty((h + 2, w + 2), dtype)
    cv2.boxFilter(np.ascontiguousarray(signal), depth, (3, 3), dst=out[1:-1, 1:-1], normalize=False,
                  borderType=cv2.BORDER_REPLICATE)
    # the ring: the sums there hold the edge row (column) three times, and its neighbours
    for ring, edge in ((out[0], signal[0]), (out[-1], signal[-1]), (out[:, 0], signal[:, 0]),
                       (out[:, -1], signal[:, -1])):
        e = np.concatenate([edge[:1], edge[:1], edge, edge[-1:], edge[-1:]]).astype(np.float32)
        ring[:] = 3 * (e[:-2] + e[1:-1] + e[2:])
    return out


def cell_lookup(cells: np.ndarray, cell: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The values of ``cells`` at pixels ``u``, ``v`` (same shape); ``cell`` is a power of two,
    so the cell index is a shift (integer division is several times slower)."""
    hc, wc = cells.shape
    shift = cell.bit_length() - 1
    flat = np.minimum(np.right_shift(v, shift), hc - 1) * wc + np.minimum(np.right_shift(u, shift), wc - 1)
    return np.ascontiguousarray(cells).ravel().take(flat)


def cells_shape(shape, cell: int) -> tuple[int, int]:
    return -(-shape[0] // cell), -(-shape[1] // cell)
