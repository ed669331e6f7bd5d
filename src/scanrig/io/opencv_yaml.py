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
import yaml

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

    Parsed in Python (PyYAML with a constructor for ``!!opencv-matrix``), not by
    ``cv2.FileStorage``: OpenCV's parser aborts the whole process on some malformed files, which no
    caller could catch.

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
    path = Path(path)
    doc = _load_yaml(path)
    if "camera_count" in doc:
        count = doc["camera_count"]
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= 1000:
            raise FileFormatError(path, f"camera_count must be a whole number from 1 to 1000, got {count!r}")
        cams = [_read_camera(doc.get(f"camera_{i}"), f"camera_{i}", None, path) for i in range(count)]
    elif "camera_matrix" in doc:
        cams = [_read_camera(doc, "top level", name, path)]
    else:
        raise FileFormatError(path, "expected a 'camera_count' node (scanrig layout) or 'camera_matrix' (OpenCV calibration layout)")
    try:
        return Rig(cams)
    except InputError as exc:
        raise FileFormatError(path, str(exc)) from None


class _OpenCVLoader(yaml.SafeLoader):
    """PyYAML's safe loader plus OpenCV's ``!!opencv-matrix`` tag."""


def _construct_matrix(loader, node):
    fields = loader.construct_mapping(node, deep=True)
    rows, cols, data = fields.get("rows"), fields.get("cols"), fields.get("data")
    if not isinstance(rows, int) or not isinstance(cols, int) or not isinstance(data, list):
        raise yaml.constructor.ConstructorError(None, None, "opencv-matrix needs integer rows, cols and a data list", node.start_mark)
    try:
        values = np.array([float(v) for v in data], dtype=np.float64)
    except (TypeError, ValueError):
        raise yaml.constructor.ConstructorError(None, None, "opencv-matrix data must be numbers", node.start_mark) from None
    if values.size != rows * cols:
        raise yaml.constructor.ConstructorError(None, None, f"opencv-matrix has {values.size} values for {rows}x{cols}", node.start_mark)
    return values.reshape(rows, cols)


_OpenCVLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _construct_matrix)


def _load_yaml(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileFormatError(path, "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FileFormatError(path, f"not readable as text: {exc}") from None
    if text.startswith("%YAML:"):  # OpenCV writes a YAML 1.0 directive PyYAML does not know
        text = text.split("\n", 1)[1] if "\n" in text else ""
    try:
        doc = yaml.load(text, Loader=_OpenCVLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise FileFormatError(path, f"not valid OpenCV YAML: {exc}") from None
    if not isinstance(doc, dict):
        raise FileFormatError(path, "expected a map of named nodes at the top level")
    return doc


def _read_camera(node, where: str, name: str | None, path: Path) -> Camera:
    if not isinstance(node, dict):
        raise FileFormatError(path, f"{where}: missing or not a map")

    def need(key):
        if key not in node:
            raise FileFormatError(path, f"{where}: missing node {key!r}")
        return node[key]

    def matrix(key, default):
        value = node.get(key, default)
        if not isinstance(value, np.ndarray):
            raise FileFormatError(path, f"{where}: {key} must be an !!opencv-matrix")
        return value

    K = matrix("camera_matrix", None)
    dist = matrix("distortion_coefficients", np.zeros((1, 0))).ravel()
    R = matrix("R_cam_from_world", np.eye(3))
    t = matrix("t_cam_from_world", np.zeros((3, 1))).ravel()
    cam_name = name if name is not None else need("name")
    sizes = []
    for key in ("image_width", "image_height"):
        value = need(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise FileFormatError(path, f"{where}: {key} must be a whole number of pixels, got {value!r}")
        sizes.append(value)
    try:
        return Camera.from_opencv(str(cam_name), K, dist, R, t, *sizes)
    except InputError as exc:
        raise FileFormatError(path, f"{where}: {exc}") from None
