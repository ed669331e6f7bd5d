"""Edge pixels on one flat, matte, evenly lit surface: their sub-pixel rays need no ray casting.

Most pixels that the background re-renders with ``s × s`` rays (:mod:`scanrig.sim.render`) are
texture edges: a printed square or marker of a calibration board, a floor's pattern. Where the
pixel and its eight neighbours all see the same plane of one matte object, with the same lamp
light (no shadow boundary, flat shading), every ray through the pixel meets that plane and its
shading differs only by the albedo there. Those rays are intersected with the plane in closed
form, and the lamp light of the centre ray is reused: no ray-triangle search and no shadow rays,
which were about three quarters of a calibration shot's time.

An edge of another surface or of a shadow that crosses the pixel puts a neighbour's centre on its
other side (the neighbours are one pixel away, the crossing within half a pixel of the centre),
unless the edge turns back within the pixel: a feature under a pixel wide between centres is
missed, as the one-ray-per-pixel pass misses it too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Largest difference of unit normals (per component) and of plane offsets, metres, between hits
#: that count as one plane; rounding is ~1e-16 and ~1e-13 m, and no two surfaces lie that close.
NORMAL_TOL = 1e-9
OFFSET_TOL_M = 1e-9
#: Largest relative difference of lamp irradiance that counts as the same light.
LIGHT_RTOL = 1e-9


@dataclass(frozen=True)
class FlatHits:
    """Per camera ray: the plane it meets where the hit is flat and matte, and the lamp light there.

    Attributes
    ----------
    normal : ndarray of shape (N, 3)
        Unit geometric normal of the hit, facing the ray (any value on a miss).
    offset_m : ndarray of shape (N,)
        ``normal · point``, metres; NaN on a miss and where the hit is shiny or smooth-shaded.
    lamp_W_m2 : ndarray of shape (N,)
        Lamp irradiance on the hit, shadows included (W/m²).
    """

    normal: np.ndarray
    offset_m: np.ndarray
    lamp_W_m2: np.ndarray

    @classmethod
    def empty(cls, n: int) -> FlatHits:
        """``n`` rays, all missing (NaN offsets)."""
        return cls(np.zeros((n, 3)), np.full(n, np.nan), np.zeros(n))


def planar_pixels(pixels: np.ndarray, obj: np.ndarray, hits: FlatHits) -> np.ndarray:
    """Which of ``pixels`` see one flat, matte, evenly lit plane of one object with their eight
    neighbours (pixels on the image's border never do).

    Parameters
    ----------
    pixels : ndarray of shape (n,), int
        Row-major indices into the image.
    obj : ndarray of shape (H, W), int
        Object hit by each pixel's centre ray (-1 on a miss).
    hits : FlatHits
        Of every pixel's centre ray, row-major (H * W rays).

    Returns
    -------
    ndarray of shape (n,), bool
    """
    h, w = obj.shape
    row, col = np.divmod(pixels, w)
    ok = (row > 0) & (row < h - 1) & (col > 0) & (col < w - 1) & np.isfinite(hits.offset_m[pixels])
    centre = pixels[ok]
    flat_obj = obj.ravel()
    normal, offset, light = hits.normal[centre], hits.offset_m[centre], hits.lamp_W_m2[centre]
    same = np.ones(centre.size, dtype=bool)
    for step in (-w - 1, -w, -w + 1, -1, 1, w - 1, w, w + 1):
        near = centre + step
        same &= flat_obj[near] == flat_obj[centre]
        same &= np.abs(hits.offset_m[near] - offset) <= OFFSET_TOL_M   # False where NaN
        same &= (np.abs(hits.normal[near] - normal) <= NORMAL_TOL).all(axis=1)
        same &= np.abs(hits.lamp_W_m2[near] - light) <= LIGHT_RTOL * np.maximum(np.abs(light), 1e-300)
    ok[ok] = same
    return ok


def plane_points(origin: np.ndarray, dirs: np.ndarray, normal: np.ndarray, offset_m: np.ndarray) -> np.ndarray:
    """Where rays ``origin`` (3,) + t ``dirs`` (n, m, 3) meet the planes ``normal · x = offset_m``
    ((n, 3), (n,)), one plane per ``m`` rays; world metres, shape (n, m, 3)."""
    t = (offset_m - normal @ origin)[:, None] / np.einsum("nj,nmj->nm", normal, dirs)
    return origin + t[..., None] * dirs
