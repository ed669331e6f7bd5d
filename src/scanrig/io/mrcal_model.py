"""Export cameras as mrcal ``.cameramodel`` files.

A ``.cameramodel`` is a Python dict literal (mrcal reads it with ``ast.literal_eval``)::

    {
        'lensmodel':  'LENSMODEL_OPENCV5',
        'intrinsics': [ fx, fy, cx, cy, k1, k2, p1, p2, k3 ],
        'extrinsics': [ rx, ry, rz, tx, ty, tz ],     # rt_cam_ref: Rodrigues vector, translation
        'imagersize': [ width, height ],
    }

mrcal's ``LENSMODEL_OPENCVn`` uses OpenCV's coefficient order, so the parameters move unchanged;
mrcal has no 5-less-than-4 model, so a distortion-free camera is ``LENSMODEL_PINHOLE``. Its
reference frame is our world frame, and pixel (0, 0) is the centre of the top-left pixel in both.
"""

from __future__ import annotations

from pathlib import Path

from scanrig.geometry.camera import Camera
from scanrig.io.atomic import write_text_atomic

#: scanrig model name -> mrcal lens model name.
MRCAL_LENSMODELS = {
    "pinhole": "LENSMODEL_PINHOLE",
    "opencv4": "LENSMODEL_OPENCV4",
    "opencv5": "LENSMODEL_OPENCV5",
    "opencv8": "LENSMODEL_OPENCV8",
    "opencv12": "LENSMODEL_OPENCV12",
}


def cameramodel_text(camera: Camera, comments: tuple[str, ...] = ()) -> str:
    """The text of a ``.cameramodel`` for one camera (floats in shortest round-trip form)."""
    pose = camera.cam_from_world
    extrinsics = [*pose.rvec.tolist(), *pose.t.tolist()]
    lines = [f"# {c}" for c in comments]
    lines += [
        "{",
        f"    'lensmodel':  '{MRCAL_LENSMODELS[camera.model]}',",
        f"    # intrinsics are {', '.join(camera.param_names)}",
        f"    'intrinsics': [ {', '.join(repr(float(v)) for v in camera.params)} ],",
        "    # extrinsics are rt_cam_ref: Rodrigues rotation vector (rad), translation (m)",
        f"    'extrinsics': [ {', '.join(repr(float(v)) for v in extrinsics)} ],",
        f"    'imagersize': [ {camera.width}, {camera.height} ],",
        "}",
    ]
    return "\n".join(lines) + "\n"


def export_cameramodels(cameras, folder: str | Path) -> list[Path]:
    """Write ``<folder>/<name>.cameramodel`` for each camera (atomically); returns the paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for cam in cameras:
        path = folder / f"{cam.name}.cameramodel"
        write_text_atomic(path, cameramodel_text(cam, (f"camera {cam.name!r} written by scanrig",)))
        paths.append(path)
    return paths
