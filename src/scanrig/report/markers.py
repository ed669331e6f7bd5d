"""Detection crops for the report: markers that outline what they mark, so the laser stays visible.

A spot gets a circle well outside its blob (radius 3 x its width plus a gap); a stripe detection
gets two ticks on either side of the stripe, along the scan line that measured it (rows when
``cov_vv`` is 0, columns when ``cov_uu`` is 0), so the stripe itself is never painted over. The
crop is enlarged by nearest-neighbour repetition so that a 1-px stripe and its ticks are apart on
screen. Rank-0 candidates are green, the others orange (as :mod:`scanrig.laser.overlay`).
"""

from __future__ import annotations

import numpy as np

from scanrig.laser.overlay import OTHER_RGB, RANK0_RGB

#: Enlargement of a crop (nearest neighbour), so that the stripe and its ticks are apart on screen.
ZOOM = 2
#: Gap between a stripe's centre and its ticks, and between a spot's blob and its circle, pixels
#: of the frame.
GAP_PX = 3
#: Length of a stripe tick along the scan line, pixels of the frame.
TICK_PX = 2
#: Stretch of the frame: its brightness at this percentile becomes white.
STRETCH_PERCENTILE = 99.9


def outlined_crop(image: np.ndarray, table, u0: int, v0: int, size_px: int) -> np.ndarray:
    """A crop of a frame with its detections outlined, enlarged :data:`ZOOM` times.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 or uint16 array
    table : pyarrow.Table
        Traces of this frame and camera (``u, v, width_px, rank, kind, cov_uu, cov_vv``).
    u0, v0 : int
        Top-left pixel of the crop in the frame.
    size_px : int
        Side of the crop, frame pixels.

    Returns
    -------
    (size_px * ZOOM, size_px * ZOOM, 3) uint8 array, RGB (smaller at the frame's border)
    """
    import cv2

    crop = image[v0:v0 + size_px, u0:u0 + size_px].astype(np.float32)
    top = max(float(np.percentile(image, STRETCH_PERCENTILE)), 1.0)
    rgb = np.clip(crop * (255.0 / top), 0, 255).astype(np.uint8)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[:, :, None], 3, axis=2)
    rgb = np.ascontiguousarray(np.repeat(np.repeat(rgb, ZOOM, axis=0), ZOOM, axis=1))
    u = (table.column("u").to_numpy() - u0 + 0.5) * ZOOM - 0.5      # pixel centres in the enlarged crop
    v = (table.column("v").to_numpy() - v0 + 0.5) * ZOOM - 0.5
    rank, width = table.column("rank").to_numpy(), table.column("width_px").to_numpy()
    kinds = table.column("kind").to_numpy(zero_copy_only=False)
    colour = np.where((rank == 0)[:, None], RANK0_RGB, OTHER_RGB).astype(np.uint8)
    spots = np.flatnonzero(kinds == "spot")
    for k in spots[np.argsort(-rank[spots], kind="stable")]:       # a handful per frame; rank 0 on top
        radius = round((3.0 * width[k] + GAP_PX) * ZOOM)
        cv2.circle(rgb, (round(u[k]), round(v[k])), radius, tuple(int(c) for c in colour[k]), 1, cv2.LINE_AA)
    stripe = np.flatnonzero(kinds == "stripe")
    if stripe.size:
        # The scan line's direction: the coordinate the detector measured has the variance.
        along_u = table.column("cov_uu").to_numpy()[stripe] >= table.column("cov_vv").to_numpy()[stripe]
        h, w = rgb.shape[:2]
        order = stripe[np.argsort(-rank[stripe], kind="stable")]      # rank 0 drawn last, on top
        along_u = along_u[np.argsort(-rank[stripe], kind="stable")]
        offsets = np.arange(GAP_PX * ZOOM, (GAP_PX + TICK_PX) * ZOOM)
        for side in (-1, 1):
            du = np.where(along_u[:, None], side * offsets[None, :], 0)
            dv = np.where(along_u[:, None], 0, side * offsets[None, :])
            cols = np.rint(u[order][:, None] + du).astype(int)
            rows = np.rint(v[order][:, None] + dv).astype(int)
            inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
            idx = np.broadcast_to(np.arange(len(order))[:, None], cols.shape)
            rgb[rows[inside], cols[inside]] = colour[order][idx[inside]]
    return rgb
