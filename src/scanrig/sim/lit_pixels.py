"""Which pixels of a laser window the laser can light: sub-pixel rays only where light may land.

A laser window (:meth:`scanrig.sim.render.CameraView.laser_window`) is the union of discs around
the laser's footprints, wide enough for the footprint's extent and the lens blur; most of its
pixels receive no laser light. Rendering a pixel costs ``s²`` sub-pixel rays, each cast, shaded
and shadow-tested; here one ray through each pixel centre decides which pixels need them.

A pixel's sub-pixel samples lie within half a pixel of its centre along each axis, so on a
continuous surface their hit points lie within ``reach = 0.75 (|J_u| + |J_v|)`` of the centre's
hit, ``J`` the larger of the distances to the centre hits of the left and right (upper and lower)
neighbours: the first-order bound ``0.5 (|J_u| + |J_v|)`` with half again as margin for the
surface's curvature. A pixel is rendered when any source may light a point within that reach
(:meth:`LightSheet.may_light`, :meth:`GaussianBeams.may_light`: light above
``exp(-2 FOOTPRINT_RADII²)`` ≈ 1.5e-8 of the beam's peak, the cut the window itself makes; for
beamlets evaluated near their landings only, any light), and always where the surface is not
continuous across the pixel: a centre ray or a neighbour's misses, hits another object, or the
distances to the two neighbours along an axis differ by more than :data:`MAX_ASYMMETRY` (a depth
step). Each source is evaluated only at the samples of the pixels it may light; elsewhere its
radiance is zero.
"""

from __future__ import annotations

import numpy as np

#: Sub-pixel sample reach in units of the centre-to-neighbour distances (0.5, and half again).
SAMPLE_REACH = 0.75
#: Largest ratio of the distances from a pixel's centre hit to its two neighbours' along one
#: image axis on a continuous surface (a larger ratio marks a depth step across the pixel).
MAX_ASYMMETRY = 2.0


def lit_pixels(view, mask: np.ndarray, u0: int, v0: int, sources) -> np.ndarray:
    """Which pixels of a window each of the laser's sources may light.

    Parameters
    ----------
    view : CameraView
        The camera (its ray table) and scene (its raycaster).
    mask : ndarray of shape (h, w), uint8
        The window's pixels (non-zero), rows ``v0:v0+h`` and columns ``u0:u0+w`` of the image.
    u0, v0 : int
        The window's first column and row, pixels.
    sources : list of LightSheet or GaussianBeams
        The laser's emitters (:attr:`LaserTrace.sources`).

    Returns
    -------
    ndarray of shape (n, len(sources)), bool
        Per pixel of ``mask``, in ``np.nonzero(mask)`` order, and per source: True where the
        source's light must be rendered.
    """
    import cv2

    h, w = mask.shape
    table = view.ray_table
    cam = view.camera
    # centre hits of the window and a one-pixel border around it (NaN beyond the image or on a miss)
    grown = cv2.dilate(np.pad(mask, 1), np.ones((3, 3), np.uint8))
    rr, cc = np.nonzero(grown)
    v, u = rr + v0 - 1, cc + u0 - 1
    inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    rr, cc, v, u = rr[inside], cc[inside], v[inside], u[inside]
    idx, hits = view.scene.raycaster.first_hits(table.origin, table.to_world(table.xy[v, u]))
    point = np.full((h + 2, w + 2, 3), np.nan)
    obj = np.full((h + 2, w + 2), -1, dtype=np.int64)
    point[rr[idx], cc[idx]] = hits.point
    obj[rr[idx], cc[idx]] = hits.obj

    rows, cols = np.nonzero(mask)
    r, c = rows + 1, cols + 1
    centre = point[r, c]
    continuous = obj[r, c] >= 0
    reach = np.zeros(len(r))
    for (ra, ca), (rb, cb) in (((r, c - 1), (r, c + 1)), ((r - 1, c), (r + 1, c))):
        continuous &= (obj[ra, ca] == obj[r, c]) & (obj[rb, cb] == obj[r, c])
        da = np.linalg.norm(point[ra, ca] - centre, axis=1)
        db = np.linalg.norm(point[rb, cb] - centre, axis=1)
        continuous &= np.maximum(da, db) <= MAX_ASYMMETRY * np.minimum(da, db)
        reach += np.fmax(da, db)
    need = np.repeat(~continuous[:, None], len(sources), axis=1)
    smooth = np.flatnonzero(continuous)
    if smooth.size:
        reach_m = SAMPLE_REACH * reach[smooth]
        for j, source in enumerate(sources):
            need[smooth, j] = source.may_light(centre[smooth], reach_m)
    return need
