"""The local background of a frame per ``BG_CELL`` pixel cell, which a trace does not reach.

Shared by :mod:`~scanrig.laser.image` (the signal's background) and
:mod:`~scanrig.laser.bright_scene` (the scene's level and the share of clipped pixels per cell).
"""

from __future__ import annotations

import numpy as np

from scanrig.laser.pixels import cells_shape

#: Background cells are ``BG_CELL`` pixels square, sampled every ``BG_STRIDE`` pixels.
BG_CELL = 16
BG_STRIDE = 4


def background_cells(signal: np.ndarray) -> np.ndarray:
    """Local background, DN, per ``BG_CELL``-pixel cell: shape (ceil(H/cell), ceil(W/cell)).

    Cell means of every ``BG_STRIDE``-th pixel, then a 5 × 5 median over cells, which ignores
    structures (the trace) narrower than about two cells while following shading and texture.
    """
    return strided_cell_medians(signal[::BG_STRIDE, ::BG_STRIDE], signal.shape)


def strided_cell_medians(sub: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """:func:`background_cells` of a frame of ``shape`` ``(H, W)`` from its every ``BG_STRIDE``-th
    pixel ``sub`` ``(ceil(H / BG_STRIDE), ceil(W / BG_STRIDE))``: float32 ``(ceil(H / BG_CELL),
    ceil(W / BG_CELL))``, in the unit of ``sub``."""
    import cv2

    hc, wc = cells_shape(shape, BG_CELL)
    means = cv2.resize(np.ascontiguousarray(sub, dtype=np.float32), (wc, hc), interpolation=cv2.INTER_AREA)
    return cv2.medianBlur(means, 5) if min(hc, wc) >= 3 else np.full_like(means, np.median(means))
