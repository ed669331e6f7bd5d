"""Rigs as OpenCV FileStorage YAML, readable by ``cv2.FileStorage`` (doubles round-trip exactly).

Layout written (one map per camera, in rig order)::

    %YAML:1.0
    camera_count: 2
    camera_0:
       name: cam0
       image_width: 1280
       image_height: 1024
       model: opencv5
       camera_matrix: !!opencv-matrix (3x3)
       distortion_coefficients: !!opencv-matrix (1xN, OpenCV order)
       R_cam_from_world: !!opencv-matrix (3x3)
       t_cam_from_world: !!opencv-matrix (3x1, metres)

:func:`import_opencv_yaml` reads that layout and also OpenCV's single-camera calibration output
(``camera_matrix``, ``distortion_coefficients``, ``image_width``, ``image_height`` at top level,
as written by ``samples/cpp/calibration.cpp``), which becomes one camera at the world origin.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError
from scanrig.geometry.camera import Camera
from scanrig.geometry.rig import Rig
from scanrig.io.atomic import write_text_atomic


def export_opencv_yaml(rig: Rig, path: str | Path) -> None:
    """Write ``rig`` as OpenCV FileStorage YAML (atomically).

    Parameters
    ----------
    rig : Rig
    path : str or Path
        Output file; ``.yml``/``.yaml``.
    """
    import cv2

    path = Path(path)
    # FileStorage writes in place; write to a temporary name via memory, then rename atomically.
    fs = cv2.FileStorage(".yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("camera_count", len(rig))
    for i, cam in enumerate(rig.cameras):
        K, dist, R, t = cam.to_opencv()
        fs.startWriteStruct(f"camera_{i}", cv2.FILE_NODE_MAP)
        fs.write("name", cam.name)
        fs.write("image_width", cam.width)
        fs.write("image_height", cam.height)
        fs.write("model", cam.model)
        fs.write("camera_matrix", K)
        fs.write("distortion_coefficients", dist.reshape(1, -1) if dist.size else np.zeros((1, 0)))
        fs.write("R_cam_from_world", R)
        fs.write("t_cam_from_world", t.reshape(3, 1))
        fs.endWriteStruct()
    write_text_atomic(path, fs.releaseAndGetString())


def import_opencv_yaml(path: str | Path, name: str = "cam0") -> Rig:
    """Read a rig from OpenCV FileStorage YAML (see the module docstring for the layouts).

    Parameters
    ----------
    path : str or Path
    name : str
        Camera name used for the single-camera layout, which stores none.

    Raises
    ------
    FileFormatError
        Naming the file and the missing or malformed node.
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "file not found")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise FileFormatError(path, f"not readable as OpenCV FileStorage: {exc.err}") from None
    try:
        if not fs.getNode("camera_count").empty():
            count = int(fs.getNode("camera_count").real())
            cams = [_read_camera(fs.getNode(f"camera_{i}"), f"camera_{i}", None, path) for i in range(count)]
        elif not fs.getNode("camera_matrix").empty():
            cams = [_read_camera(fs.root(), "top level", name, path)]
        else:
            raise FileFormatError(path, "expected a 'camera_count' node (scanrig layout) or 'camera_matrix' (OpenCV calibration layout)")
    finally:
        fs.release()
    try:
        return Rig(cams)
    except InputError as exc:
        raise FileFormatError(path, str(exc)) from None


def _read_camera(node, where: str, name: str | None, path: Path) -> Camera:
    def need(key):
        child = node.getNode(key)
        if child.empty():
            raise FileFormatError(path, f"{where}: missing node {key!r}")
        return child

    K = need("camera_matrix").mat()
    dist_node = node.getNode("distortion_coefficients")
    dist = np.zeros(0) if dist_node.empty() or dist_node.mat() is None else dist_node.mat().ravel()
    R = node.getNode("R_cam_from_world").mat() if not node.getNode("R_cam_from_world").empty() else np.eye(3)
    t = node.getNode("t_cam_from_world").mat() if not node.getNode("t_cam_from_world").empty() else np.zeros(3)
    cam_name = name if name is not None else need("name").string()
    width, height = int(need("image_width").real()), int(need("image_height").real())
    try:
        return Camera.from_opencv(cam_name, K, dist, R, np.ravel(t), width, height)
    except InputError as exc:
        raise FileFormatError(path, f"{where}: {exc}") from None
