"""Candidate camera poses in the allowed mounting region, and the symmetric ring baseline.

Every candidate looks at the region's ``look_at`` point with the image's "down" along ``-up``.
Positions are a Halton low-discrepancy sample of the region (deterministic, evenly spread, no
clumps), so the same spec always gives the same candidates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from scanrig.errors import InputError
from scanrig.geometry.camera import Camera
from scanrig.geometry.transform import RigidTransform

from .spec import CameraSpec, MountingSpec


class MountingError(InputError):
    """The mounting region cannot hold a camera that sees the object."""


@dataclass(frozen=True)
class Candidate:
    """One candidate camera: a pose in the region fitted with one of the lenses.

    Attributes
    ----------
    camera : Camera
        The camera, posed.
    pose_id : int
        Index of the position; candidates sharing it are the same mount with other lenses.
    focal_length_m : float
        The lens, metres.
    """

    camera: Camera
    pose_id: int
    focal_length_m: float


def look_at_pose(center_world, target_world, up_world) -> RigidTransform:
    """``cam_from_world`` of a camera at ``center_world`` looking at ``target_world``.

    Parameters
    ----------
    center_world, target_world : (3,) float array
        Optical centre and the point on the optical axis, world frame, metres.
    up_world : (3,) float array
        World "up"; the image's v axis (down) is ``-up`` projected across the optical axis.

    Raises
    ------
    InputError
        If the centre and the target coincide or the view is along ``up``.
    """
    c = np.asarray(center_world, dtype=np.float64)
    z = np.asarray(target_world, dtype=np.float64) - c
    if np.linalg.norm(z) == 0:
        raise InputError(f"camera centre {c.tolist()} coincides with its look-at point")
    z /= np.linalg.norm(z)
    up = np.asarray(up_world, dtype=np.float64)
    y = -(up - (up @ z) * z)
    if np.linalg.norm(y) < 1e-9 * np.linalg.norm(up):
        raise InputError(f"camera at {c.tolist()} looks along 'up' {up.tolist()}: image orientation undefined")
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z])                   # rows: camera axes in world coordinates
    return RigidTransform(R, -R @ c)


def make_camera(name: str, camera: CameraSpec, focal_length_m: float, cam_from_world: RigidTransform) -> Camera:
    """A distortion-free camera of the candidate sensor with one lens.

    The principal point is the image centre, ``((W - 1) / 2, (H - 1) / 2)`` in pixel-centre
    coordinates.
    """
    f_px = focal_length_m / camera.pixel_pitch_m
    params = [f_px, f_px, (camera.width_px - 1) / 2.0, (camera.height_px - 1) / 2.0]
    return Camera(name, "pinhole", np.array(params), camera.width_px, camera.height_px, cam_from_world)


def mounting_positions(mounting: MountingSpec) -> np.ndarray:
    """Evenly spread positions in the mounting region.

    Returns
    -------
    (n_candidates, 3) float array
        Optical centres, world frame, metres.
    """
    look_at = np.asarray(mounting.look_at, dtype=np.float64)
    up, e1, e2 = up_basis(mounting.up)
    u = qmc.Halton(d=3, scramble=False).random(mounting.n_candidates + 1)[1:]  # skip the all-zero first point
    azimuth = 2.0 * np.pi * u[:, 0]
    r_lo, r_hi = mounting.radius_m
    radius = r_lo + (r_hi - r_lo) * u[:, 1]
    if mounting.shape == "cylinder":
        h_lo, h_hi = mounting.height_m
        height = h_lo + (h_hi - h_lo) * u[:, 2]
        horizontal = radius
    else:
        el_lo, el_hi = np.radians(mounting.elevation_deg)
        # uniform in area on the spherical zone: sin(elevation) uniform
        elevation = np.arcsin(np.sin(el_lo) + (np.sin(el_hi) - np.sin(el_lo)) * u[:, 2])
        height = radius * np.sin(elevation)
        horizontal = radius * np.cos(elevation)
    return (look_at + horizontal[:, None] * (np.cos(azimuth)[:, None] * e1 + np.sin(azimuth)[:, None] * e2)
            + height[:, None] * up)


def ring_positions(mounting: MountingSpec, n_cameras: int) -> np.ndarray:
    """A symmetric ring of ``n_cameras`` in the middle of the mounting region (the baseline).

    Cameras are evenly spaced in azimuth (starting at azimuth 0) at the middle radius and the
    middle height (cylinder) or middle elevation (sphere).
    """
    look_at = np.asarray(mounting.look_at, dtype=np.float64)
    up, e1, e2 = up_basis(mounting.up)
    azimuth = 2.0 * np.pi * np.arange(n_cameras) / n_cameras
    radius = float(np.mean(mounting.radius_m))
    if mounting.shape == "cylinder":
        horizontal, height = radius, float(np.mean(mounting.height_m))
    else:
        elevation = np.radians(np.mean(mounting.elevation_deg))
        horizontal, height = radius * np.cos(elevation), radius * np.sin(elevation)
    return (look_at + horizontal * (np.cos(azimuth)[:, None] * e1 + np.sin(azimuth)[:, None] * e2)
            + height * up)


def candidates_from_positions(positions: np.ndarray, camera: CameraSpec, mounting: MountingSpec,
                              prefix: str = "cand") -> list[Candidate]:
    """One candidate per position and lens, each looking at ``mounting.look_at``."""
    out = []
    for i, center in enumerate(positions):
        pose = look_at_pose(center, mounting.look_at, mounting.up)
        for j, f in enumerate(camera.focal_lengths_m):
            name = f"{prefix}{i}" if len(camera.focal_lengths_m) == 1 else f"{prefix}{i}_f{j}"
            out.append(Candidate(make_camera(name, camera, f, pose), i, f))
    return out


def candidates_from_rig(rig, camera: CameraSpec) -> list[Candidate]:
    """Explicit candidate poses: the cameras of a rig file, each taken as it is (one lens)."""
    return [Candidate(cam, i, float(cam.params[0] * camera.pixel_pitch_m)) for i, cam in enumerate(rig.cameras)]


def check_region(mounting: MountingSpec, center_m: np.ndarray, radius_m: float) -> None:
    """Reject a mounting region that lies inside the object's bounding sphere.

    Raises
    ------
    MountingError
        Naming the field and the object's extent.
    """
    far = mounting.radius_m[1]
    if mounting.shape == "cylinder":
        far = float(np.hypot(far, max(abs(h) for h in mounting.height_m)))
    offset = float(np.linalg.norm(np.asarray(mounting.look_at) - center_m))
    if far + offset <= radius_m:
        raise MountingError(
            f"[mounting] radius_m {list(mounting.radius_m)}: every allowed position lies inside the object's "
            f"bounding sphere (radius {radius_m:.4g} m around {np.round(center_m, 4).tolist()}); "
            f"cameras must be at least {radius_m:.4g} m from its centre")


def up_basis(up) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit ``up`` and two unit vectors spanning the plane normal to it."""
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = helper - (helper @ up) * up
    e1 /= np.linalg.norm(e1)
    return up, e1, np.cross(up, e1)
