"""Overlay images: the detections of one frame drawn on the frame, for a person to check.

Rank-0 candidates are green, the others orange; a spot is a circle of radius 3 × its width with a
cross at the centre; a stripe is one dot per (line, peak). 16-bit and dim frames are stretched to
their 99.9th percentile so the scene is visible; a colour frame keeps its colours.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from scanrig.io.session import Session, read_image, write_image

RANK0_RGB = (0, 255, 0)
OTHER_RGB = (255, 140, 0)


def render_overlay(image: np.ndarray, table: pa.Table) -> np.ndarray:
    """The frame as 8-bit RGB with the table's detections drawn on it.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 or uint16 array
    table : pyarrow.Table
        Traces of this frame (``u, v, width_px, rank, kind``).

    Returns
    -------
    (H, W, 3) uint8 array, RGB
    """
    import cv2

    img = image.astype(np.float32)
    top = max(float(np.percentile(img, 99.9)), 1.0)
    rgb = np.clip(img * (255.0 / top), 0, 255).astype(np.uint8)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[:, :, None], 3, axis=2)
    rgb = np.ascontiguousarray(rgb)
    u, v = table.column("u").to_numpy(), table.column("v").to_numpy()
    rank, width = table.column("rank").to_numpy(), table.column("width_px").to_numpy()
    kinds = table.column("kind").to_numpy(zero_copy_only=False)
    shift = 4  # sub-pixel drawing: coordinates in 1/16 px
    scale = 1 << shift
    spots = np.flatnonzero(kinds == "spot")
    for k in spots[np.argsort(-rank[spots], kind="stable")]:  # a handful per frame; rank 0 on top
        colour = RANK0_RGB if rank[k] == 0 else OTHER_RGB
        centre = (int(round(u[k] * scale)), int(round(v[k] * scale)))
        cv2.circle(rgb, centre, int(max(3.0 * width[k], 4.0) * scale), colour, 1, cv2.LINE_AA, shift)
        cv2.drawMarker(rgb, (int(round(u[k])), int(round(v[k]))), colour, cv2.MARKER_CROSS, 6, 1)
    stripe = kinds == "stripe"
    if stripe.any():  # one pixel per (line, peak): vectorised
        h, w = rgb.shape[:2]
        cols = np.clip(np.rint(u[stripe]).astype(int), 0, w - 1)
        rows = np.clip(np.rint(v[stripe]).astype(int), 0, h - 1)
        first = np.argsort(-rank[stripe], kind="stable")  # rank 0 written last, on top
        rgb[rows[first], cols[first]] = np.where((rank[stripe][first] == 0)[:, None], RANK0_RGB, OTHER_RGB)
    return rgb


def write_overlays(session: Session, frame: str, table: pa.Table) -> list[Path]:
    """Write ``SESSION/overlays/<frame>_<camera>.png`` for every camera that has the frame.

    Parameters
    ----------
    session : Session
    frame : str
        Frame stem.
    table : pyarrow.Table
        The session's traces (rows of other frames are ignored).

    Returns
    -------
    list of Path
        Files written.

    Raises
    ------
    InputError
        If no camera has a frame of that stem.
    """
    import pyarrow.compute as pc

    from scanrig.errors import InputError

    paths = session.frames("scan").get(frame)
    if not paths:
        raise InputError(f"no scan frame named {frame!r} in {session.root}")
    out_dir = session.root / "overlays"
    out_dir.mkdir(exist_ok=True)
    written = []
    for camera, path in paths.items():
        rows = table.filter(pc.and_(pc.equal(table["camera"], camera), pc.equal(table["frame"], frame)))
        out = out_dir / f"{frame}_{camera}.png"
        write_image(out, render_overlay(read_image(path), rows))
        written.append(out)
    return written
