"""Virtual camera rigs: realistic industrial cameras placed on an arc, aimed at the object."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry import Camera, Rig, RigidTransform

#: Standard deviations of the per-camera variations of ``k1 k2 p1 p2 k3``. A rational (opencv8)
#: lens keeps its coefficients: its numerator and denominator are balanced against each other (a
#: fisheye's k2 of 0.005 would change sign), and its decentering terms, not divided by the
#: denominator, grow with the square of ``tan theta`` (2e-4 moves a fisheye's rim by ~40 px).
DIST_VARIATION = {"opencv5": np.array([0.01, 0.01, 2e-4, 2e-4, 0.0]), "opencv8": np.zeros(5)}


@dataclass(frozen=True)
class RigSpec:
    """Placement and lenses of the default cameras.

    Parameters
    ----------
    distance_m : float
        Distance from each camera to the aim point.
    elevation_deg : float
        Height of the cameras above the aim point, as an angle.
    spacing_deg : float
        Azimuth step between neighbouring cameras; the arc is centred on ``azimuth_deg``.
    azimuth_deg : float
        Azimuth of the arc's centre, measured from -y towards +x (0 = looking along +y).
    width, height : int
        Image size, pixels.
    fx_px : float
        Focal length, pixels (fy = fx).
    dist : tuple of 5 or 8 floats
        OpenCV ``k1 k2 p1 p2 k3`` (model ``opencv5``) or ``k1 k2 p1 p2 k3 k4 k5 k6`` (model
        ``opencv8``, e.g. the fisheye of the built-in ``fisheye`` scene) of every camera (each camera
        gets small seeded variations, :data:`DIST_VARIATION`).
    cover_field : bool
        Calibration shots spread over the cameras' whole fields of view, the target facing
        the camera that picked the shot's line of sight (as a user calibrates a wide-angle lens),
        instead of placed around the scene's ``center_m``.
    """

    distance_m: float = 1.0
    elevation_deg: float = 30.0
    spacing_deg: float = 45.0
    azimuth_deg: float = 0.0
    width: int = 1280
    height: int = 1024
    fx_px: float = 2200.0
    dist: tuple = (-0.1, 0.05, 0.0, 0.0, 0.0)
    cover_field: bool = False

    def __post_init__(self):
        if not self.distance_m > 0 or not self.fx_px > 0:
            raise InputError("rig distance_m and fx_px must be positive")
        if len(self.dist) not in (5, 8):
            raise InputError(f"rig dist must hold 5 coefficients (k1 k2 p1 p2 k3) or 8 (k1 k2 p1 p2 k3 k4 k5 "
                             f"k6), got {len(self.dist)}")

    @property
    def model(self) -> str:
        """Camera model of the rig's cameras: ``opencv5`` or ``opencv8`` (from the length of ``dist``)."""
        return "opencv5" if len(self.dist) == 5 else "opencv8"

    def scaled(self, factor: float) -> RigSpec:
        """The same cameras with image size (rounded to whole pixels) and focal length times ``factor``."""
        return replace(self, width=round(self.width * factor), height=round(self.height * factor),
                       fx_px=self.fx_px * factor)


def look_at(eye_m, target_m, up=(0.0, 0.0, 1.0)) -> RigidTransform:
    """``cam_from_world`` of a camera at ``eye_m`` looking at ``target_m`` (x right, y down, z forward).

    Raises
    ------
    InputError
        If the viewing direction is parallel to ``up``.
    """
    eye, target = np.asarray(eye_m, dtype=np.float64), np.asarray(target_m, dtype=np.float64)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise InputError(f"look_at: viewing direction {z.tolist()} is parallel to up {list(up)}")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    return RigidTransform(R, -R @ eye)


def default_rig(n_cameras: int = 3, center_m=(0.0, 0.0, 0.1), spec: RigSpec | None = None,
                seed: int = 0) -> Rig:
    """A rig of ``n_cameras`` cameras on an arc around ``center_m``, all aimed at it.

    Parameters
    ----------
    n_cameras : int
        Number of cameras (1 to 8); they are named ``cam0``, ``cam1``, ...
    center_m : (3,) float
        Aim point, world metres.
    spec : RigSpec, optional
        Lens and placement; defaults to 1280×1024 px, fx = 2200 px, 1 m away, 45° apart.
    seed : int
        Seed of the small per-camera variations of intrinsics (part of the rig, not of a run).

    Returns
    -------
    Rig
    """
    if not isinstance(n_cameras, (int, np.integer)) or not 1 <= n_cameras <= 8:
        raise InputError(f"n_cameras must be an integer from 1 to 8, got {n_cameras!r}")
    spec = spec or RigSpec()
    rng = np.random.default_rng(seed)
    center = np.asarray(center_m, dtype=np.float64)
    azimuths = np.radians(spec.azimuth_deg + spec.spacing_deg * (np.arange(n_cameras) - (n_cameras - 1) / 2))
    elev = np.radians(spec.elevation_deg)
    cams = []
    for i, az in enumerate(azimuths):
        eye = center + spec.distance_m * np.array([np.sin(az) * np.cos(elev), -np.cos(az) * np.cos(elev), np.sin(elev)])
        fx = spec.fx_px * (1 + 0.01 * rng.standard_normal())
        cx = (spec.width - 1) / 2 + 8 * rng.standard_normal()
        cy = (spec.height - 1) / 2 + 8 * rng.standard_normal()
        dist = np.asarray(spec.dist, dtype=np.float64)
        dist[:5] += DIST_VARIATION[spec.model] * rng.standard_normal(5)
        params = np.concatenate([[fx, fx * (1 + 1e-3 * rng.standard_normal()), cx, cy], dist])
        cams.append(Camera(f"cam{i}", spec.model, params, spec.width, spec.height, look_at(eye, center)))
    return Rig(cams)
