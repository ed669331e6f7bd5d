"""Export a rig as COLMAP's text model (``cameras.txt``, ``images.txt``).

COLMAP's ``FULL_OPENCV`` model has OpenCV's parameters ``fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6``;
``OPENCV`` has ``fx fy cx cy k1 k2 p1 p2``. ``images.txt`` stores ``cam_from_world`` as a unit
quaternion ``QW QX QY QZ`` and ``TX TY TZ``. COLMAP puts pixel (0, 0) at the *corner* of the
top-left pixel, so the principal point is shifted by +0.5 px on export.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from scanrig.errors import InputError
from scanrig.geometry.distortion import pad_coefficients
from scanrig.geometry.rig import Rig
from scanrig.io.atomic import write_text_atomic

#: Half a pixel: COLMAP's pixel origin is the top-left corner, ours its centre.
COLMAP_PIXEL_SHIFT = 0.5


def export_colmap_text(rig: Rig, folder: str | Path) -> tuple[Path, Path]:
    """Write ``cameras.txt`` and ``images.txt`` (atomically) into ``folder``.

    Each camera becomes one COLMAP camera and one image named ``<camera>.png``. Cameras with
    thin-prism coefficients (``opencv12``) have no COLMAP equivalent and raise :class:`InputError`.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cam_lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    img_lines = ["# Image list with two lines of data per image:",
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for i, cam in enumerate(rig.cameras, start=1):
        d = pad_coefficients(cam.params[4:])
        if np.any(d[8:]):
            raise InputError(f"camera {cam.name!r}: thin-prism coefficients (opencv12) have no COLMAP model")
        fx, fy, cx, cy = cam.params[:4]
        pinhole = [fx, fy, cx + COLMAP_PIXEL_SHIFT, cy + COLMAP_PIXEL_SHIFT]
        if np.any(d[4:8]):
            model, params = "FULL_OPENCV", pinhole + list(d[:8])
        else:
            model, params = "OPENCV", pinhole + list(d[:4])
        cam_lines.append(f"{i} {model} {cam.width} {cam.height} " + " ".join(repr(float(p)) for p in params))
        x, y, z, w = Rotation.from_matrix(cam.cam_from_world.R).as_quat()
        qt = [w, x, y, z, *cam.cam_from_world.t]
        img_lines.append(f"{i} " + " ".join(repr(float(v)) for v in qt) + f" {i} {cam.name}.png")
        img_lines.append("")
    cameras_path, images_path = folder / "cameras.txt", folder / "images.txt"
    write_text_atomic(cameras_path, "\n".join(cam_lines) + "\n")
    write_text_atomic(images_path, "\n".join(img_lines) + "\n")
    return cameras_path, images_path
