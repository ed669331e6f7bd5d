"""``rig.toml``: the calibration result (DESIGN.md §5), read and written exactly.

Floats are written with ``repr`` (shortest round-trip form), so ``save_rig`` then ``load_rig``
returns bit-identical parameters. Camera order is the order of the ``[[cameras]]`` tables.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
import tomli_w

from scanrig.errors import FileFormatError, InputError
from scanrig.geometry.camera import Camera
from scanrig.geometry.rig import Rig
from scanrig.geometry.transform import RigidTransform
from scanrig.io.atomic import write_text_atomic
from scanrig.io.toml_fields import check_keys, read_toml

FORMAT_VERSION = 1
_CAMERA_REQUIRED = ("name", "model", "width", "height", "params", "R_cam_from_world", "t_cam_from_world")
#: Optional per-camera quality fields written by ``scanrig calibrate``.
CAMERA_INFO_FIELDS = ("params_std", "rms_px", "n_observations", "covariance_file")
_TOP_LEVEL = ("format_version", "units", "cameras", "metadata")


def load_rig(path: str | Path) -> Rig:
    """Read a rig file.

    Parameters
    ----------
    path : str or Path
        A ``rig.toml`` (DESIGN.md §5).

    Returns
    -------
    Rig
        Cameras in file order.

    Raises
    ------
    FileFormatError
        Naming the file and the field when the file is missing, malformed or inconsistent.
    """
    return _parse(Path(path))[0]


def load_rig_info(path: str | Path) -> tuple[Rig, dict[str, dict], dict]:
    """Read a rig file with its optional quality fields.

    Returns
    -------
    rig : Rig
    camera_info : dict
        ``name -> {field: value}`` for the fields of :data:`CAMERA_INFO_FIELDS` present.
    metadata : dict
        The optional top-level ``[metadata]`` table.
    """
    return _parse(Path(path))


def _parse(path: Path):
    doc = read_toml(path)
    check_keys(doc, _TOP_LEVEL, ("format_version", "cameras"), path, "top level")
    if doc["format_version"] != FORMAT_VERSION:
        raise FileFormatError(path, f"format_version must be {FORMAT_VERSION}, got {doc['format_version']!r}")
    if doc.get("units", "m") != "m":
        raise FileFormatError(path, f"units must be \"m\", got {doc['units']!r}")
    tables = doc["cameras"]
    if not isinstance(tables, list) or not tables:
        raise FileFormatError(path, "cameras must be a non-empty array of [[cameras]] tables")
    cameras, info = [], {}
    for i, table in enumerate(tables, start=1):
        where = f"[[cameras]] #{i}"
        if not isinstance(table, Mapping):
            raise FileFormatError(path, f"{where}: expected a table")
        check_keys(table, _CAMERA_REQUIRED + CAMERA_INFO_FIELDS, _CAMERA_REQUIRED, path, where)
        where = f"{where} ({table['name']!r})"
        try:
            pose = RigidTransform(
                np.asarray(table["R_cam_from_world"], dtype=np.float64),
                np.asarray(table["t_cam_from_world"], dtype=np.float64),
            )
            cam = Camera(
                table["name"], table["model"], np.asarray(table["params"], dtype=np.float64),
                table["width"], table["height"], pose,
            )
        except (InputError, ValueError, TypeError) as exc:
            raise FileFormatError(path, f"{where}: {exc}") from None
        cameras.append(cam)
        info[cam.name] = {k: table[k] for k in CAMERA_INFO_FIELDS if k in table}
    try:
        rig = Rig(cameras)
    except InputError as exc:
        raise FileFormatError(path, str(exc)) from None
    return rig, info, dict(doc.get("metadata", {}))


def rig_to_toml(
    rig: Rig,
    camera_info: Mapping[str, Mapping] | None = None,
    metadata: Mapping | None = None,
    comments: Iterable[str] = (),
) -> str:
    """Serialise a rig to the text of a ``rig.toml``.

    Parameters
    ----------
    rig : Rig
    camera_info : mapping, optional
        ``name -> {field: value}`` with fields from :data:`CAMERA_INFO_FIELDS`.
    metadata : mapping, optional
        Written as a top-level ``[metadata]`` table (command line, seed, RMS, versions).
    comments : iterable of str
        Lines written as ``#`` comments at the top.
    """
    camera_info = camera_info or {}
    doc = {"format_version": FORMAT_VERSION, "units": "m", "cameras": []}
    for cam in rig.cameras:
        extra = dict(camera_info.get(cam.name, {}))
        unknown = set(extra) - set(CAMERA_INFO_FIELDS)
        if unknown:
            raise InputError(f"camera_info[{cam.name!r}] has unknown fields {sorted(unknown)}; allowed: {CAMERA_INFO_FIELDS}")
        table = {
            "name": cam.name,
            "model": cam.model,
            "width": cam.width,
            "height": cam.height,
            "params": [float(v) for v in cam.params],
            "R_cam_from_world": [[float(v) for v in row] for row in cam.cam_from_world.R],
            "t_cam_from_world": [float(v) for v in cam.cam_from_world.t],
        }
        table.update({k: _plain(v) for k, v in extra.items()})
        doc["cameras"].append(table)
    if metadata:
        doc["metadata"] = {k: _plain(v) for k, v in metadata.items()}
    header = "".join(f"# {line}\n" for line in comments)
    header += "# parameter order per model: fx fy cx cy, then OpenCV's k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4\n"
    return header + tomli_w.dumps(doc)


def save_rig(
    rig: Rig,
    path: str | Path,
    camera_info: Mapping[str, Mapping] | None = None,
    metadata: Mapping | None = None,
    comments: Iterable[str] = (),
) -> None:
    """Write a rig file atomically (see :func:`rig_to_toml` for the arguments)."""
    write_text_atomic(path, rig_to_toml(rig, camera_info, metadata, comments))


def _plain(value):
    """numpy scalars and arrays to plain Python values that TOML can hold."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value
