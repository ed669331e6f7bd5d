"""The design input: candidate cameras, the allowed mounting region, the laser and the target.

A design is described by a small TOML file (every table and field optional; absent values are
derived from the object's size by :func:`default_spec`)::

    [camera]                       # the candidate camera: one sensor, one or more lenses
    width_px = 1280
    height_px = 1024
    pixel_pitch_m = 4.8e-6
    focal_lengths_m = [0.012, 0.016]
    f_number = 4.0
    circle_of_confusion_px = 2.0   # blur accepted as "in focus" (depth of field)

    [mounting]                     # where cameras may go; each looks at look_at
    shape = "cylinder"             # "cylinder" (axis along up) or "sphere" (around look_at)
    radius_m = [0.8, 1.2]          # cylinder: distance from the axis; sphere: from look_at
    height_m = [0.0, 0.6]          # cylinder only: height above look_at along up
    elevation_deg = [10.0, 60.0]   # sphere only: elevation above the plane normal to up
    look_at = [0.0, 0.0, 0.1]
    up = [0.0, 0.0, 1.0]
    n_candidates = 50
    rig = "poses.toml"             # optional: explicit candidate poses (a rig file) instead

    [laser]
    mode = "spot"                  # or "stripe"
    sigma_px = 0.3                 # detection noise, 1-sigma, from the detection benchmarks
    wavelength_m = 650e-9
    speckle_contrast = 1.0
    step_m = 1e-3                  # spacing of spots (or stripes) on the surface

    [target]
    sigma_m = 5e-4                 # accuracy target: largest-axis 1-sigma of each point
    min_views = 2
    max_incidence_deg = 75.0       # views more oblique than this do not count

    [calibration]                  # optional calibration uncertainty of every camera pose
    rotation_sigma_rad = 0.0
    translation_sigma_m = 0.0

Errors name the file and the field (:class:`~scanrig.errors.FileFormatError`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError
from scanrig.io.toml_fields import check_keys, read_toml


@dataclass(frozen=True)
class CameraSpec:
    """The candidate camera: sensor and lenses.

    Attributes
    ----------
    width_px, height_px : int
        Sensor size in pixels.
    pixel_pitch_m : float
        Pixel size, metres.
    focal_lengths_m : tuple of float
        Lenses that may be fitted, metres; an empty tuple means "one lens that frames the object".
    f_number : float
        Aperture f-number (sets the depth of field and the speckle grain).
    circle_of_confusion_px : float
        Largest blur spot diameter accepted as in focus, pixels.
    """

    width_px: int = 1280
    height_px: int = 1024
    pixel_pitch_m: float = 4.8e-6
    focal_lengths_m: tuple[float, ...] = ()
    f_number: float = 4.0
    circle_of_confusion_px: float = 2.0

    def __post_init__(self):
        _validate(self, "camera")


@dataclass(frozen=True)
class MountingSpec:
    """The allowed mounting region (see the module docstring); ``None`` = derived from the object."""

    shape: str = "cylinder"
    radius_m: tuple[float, float] | None = None
    height_m: tuple[float, float] | None = None
    elevation_deg: tuple[float, float] = (10.0, 60.0)
    look_at: tuple[float, float, float] | None = None
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    n_candidates: int = 50
    rig: Path | None = None

    def __post_init__(self):
        _validate(self, "mounting")


@dataclass(frozen=True)
class LaserSpec:
    """The laser trace and its detection noise."""

    mode: str = "spot"
    sigma_px: float = 0.3
    wavelength_m: float = 650e-9
    speckle_contrast: float = 1.0
    step_m: float | None = None

    def __post_init__(self):
        _validate(self, "laser")


@dataclass(frozen=True)
class TargetSpec:
    """What counts as covered: seen by ``min_views`` cameras with predicted sigma <= ``sigma_m``."""

    sigma_m: float | None = None
    min_views: int = 2
    max_incidence_deg: float = 75.0

    def __post_init__(self):
        _validate(self, "target")


@dataclass(frozen=True)
class CalibrationSpec:
    """1-sigma calibration uncertainty of every camera's pose (rotation per axis, translation)."""

    rotation_sigma_rad: float = 0.0
    translation_sigma_m: float = 0.0

    def __post_init__(self):
        _validate(self, "calibration")


@dataclass(frozen=True)
class DesignSpec:
    """Everything a design needs besides the object and the number of cameras."""

    camera: CameraSpec = field(default_factory=CameraSpec)
    mounting: MountingSpec = field(default_factory=MountingSpec)
    laser: LaserSpec = field(default_factory=LaserSpec)
    target: TargetSpec = field(default_factory=TargetSpec)
    calibration: CalibrationSpec = field(default_factory=CalibrationSpec)


_TABLES = {
    "camera": CameraSpec,
    "mounting": MountingSpec,
    "laser": LaserSpec,
    "target": TargetSpec,
    "calibration": CalibrationSpec,
}


def load_spec(path: str | Path) -> DesignSpec:
    """Read a design TOML file.

    Parameters
    ----------
    path : str or Path
        The file (format in the module docstring).

    Returns
    -------
    DesignSpec
        Absent fields keep their defaults (``None`` ones are filled by :func:`default_spec`).

    Raises
    ------
    FileFormatError
        Naming the file and the field for unknown tables or fields and invalid values.
    """
    path = Path(path)
    doc = read_toml(path)
    check_keys(doc, _TABLES, (), path, "top level")
    parts = {}
    for name, cls in _TABLES.items():
        table = doc.get(name, {})
        if not isinstance(table, dict):
            raise FileFormatError(path, f"[{name}] must be a table")
        check_keys(table, [f.name for f in fields(cls)], (), path, f"[{name}]")
        values = dict(table)
        if name == "mounting" and "rig" in values:
            values["rig"] = (path.parent / str(values["rig"])).resolve()
        try:
            parts[name] = cls(**{k: _tuple(v) for k, v in values.items()})
        except (InputError, TypeError) as exc:
            raise FileFormatError(path, str(exc)) from None
    return DesignSpec(**parts)


def _tuple(value):
    return tuple(value) if isinstance(value, list) else value


def _validate(part, table: str) -> None:
    """Raise :class:`InputError` naming ``[table] field`` for a value out of its domain."""

    def need(ok: bool, name: str, expected: str):
        if not ok:
            raise InputError(f"[{table}] {name} must be {expected}, got {getattr(part, name)!r}")

    def positive(name):
        value = getattr(part, name)
        need(value is None or (_is_number(value) and value > 0), name, "a positive number")

    def interval(name, lo=-math.inf):
        value = getattr(part, name)
        need(value is None or (len(value) == 2 and all(_is_number(v) for v in value)
                               and lo <= value[0] <= value[1]), name, f"[min, max] with {lo} <= min <= max")

    def vector(name):
        value = getattr(part, name)
        need(value is None or (len(value) == 3 and all(_is_number(v) for v in value)), name, "[x, y, z]")

    if isinstance(part, CameraSpec):
        for name in ("width_px", "height_px"):
            need(isinstance(getattr(part, name), int) and getattr(part, name) > 0, name, "a positive integer")
        for name in ("pixel_pitch_m", "f_number", "circle_of_confusion_px"):
            positive(name)
        need(all(_is_number(f) and f > 0 for f in part.focal_lengths_m), "focal_lengths_m",
             "a list of positive numbers")
    elif isinstance(part, MountingSpec):
        need(part.shape in ("cylinder", "sphere"), "shape", '"cylinder" or "sphere"')
        interval("radius_m", lo=0.0)
        interval("height_m")
        interval("elevation_deg", lo=-90.0)
        need(part.elevation_deg[1] <= 90.0, "elevation_deg", "within [-90, 90]")
        vector("look_at")
        vector("up")
        need(np.linalg.norm(part.up) > 0, "up", "a non-zero vector")
        need(isinstance(part.n_candidates, int) and part.n_candidates >= 1, "n_candidates", "a positive integer")
    elif isinstance(part, LaserSpec):
        need(part.mode in ("spot", "stripe"), "mode", '"spot" or "stripe"')
        for name in ("sigma_px", "wavelength_m", "step_m"):
            positive(name)
        need(_is_number(part.speckle_contrast) and 0 <= part.speckle_contrast <= 1, "speckle_contrast",
             "a number in [0, 1]")
    elif isinstance(part, TargetSpec):
        positive("sigma_m")
        need(isinstance(part.min_views, int) and part.min_views >= 2, "min_views", "an integer >= 2")
        need(_is_number(part.max_incidence_deg) and 0 < part.max_incidence_deg < 90, "max_incidence_deg",
             "a number in (0, 90)")
    elif isinstance(part, CalibrationSpec):
        for name in ("rotation_sigma_rad", "translation_sigma_m"):
            need(_is_number(getattr(part, name)) and getattr(part, name) >= 0, name, "a number >= 0")


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def default_spec(spec: DesignSpec, center_m: np.ndarray, radius_m: float) -> DesignSpec:
    """Fill the fields left ``None`` from the object's bounding sphere.

    Parameters
    ----------
    spec : DesignSpec
    center_m : (3,) float array
        Centre of the object's bounding sphere, world frame, metres.
    radius_m : float
        Its radius, metres.

    Returns
    -------
    DesignSpec
        Mounting on a cylinder at 2.5–4 object radii from the axis, from the centre's height to
        two radii above it, looking at the centre; one lens that frames the object at the mean
        distance; laser step 1/200 of the object size; target 0.1 % of the object size (the
        vendor figure quoted in the laser-scanning notes, §5).
    """
    mount = spec.mounting
    mount = replace(
        mount,
        look_at=mount.look_at if mount.look_at is not None else tuple(float(v) for v in center_m),
        radius_m=mount.radius_m if mount.radius_m is not None else (2.5 * radius_m, 4.0 * radius_m),
        height_m=mount.height_m if mount.height_m is not None else (0.0, 2.0 * radius_m),
    )
    camera = spec.camera
    if not camera.focal_lengths_m:
        mean_distance = float(np.mean(mount.radius_m))
        if mount.shape == "cylinder":
            mean_distance = math.hypot(mean_distance, float(np.mean(mount.height_m)))
        sensor_m = min(camera.width_px, camera.height_px) * camera.pixel_pitch_m
        camera = replace(camera, focal_lengths_m=(0.9 * sensor_m * mean_distance / (2.0 * radius_m),))
    laser = spec.laser
    if laser.step_m is None:
        laser = replace(laser, step_m=2.0 * radius_m / 200.0)
    target = spec.target
    if target.sigma_m is None:
        target = replace(target, sigma_m=1e-3 * 2.0 * radius_m)
    return replace(spec, camera=camera, mounting=mount, laser=laser, target=target)
