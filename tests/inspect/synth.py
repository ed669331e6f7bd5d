"""Synthetic parts for the inspection tests and benchmark: a CAD mesh, and a scan of it with known
bumps and dents, noise, partial coverage, outliers and a random rigid motion.

The part is a 20 mm thick bracket: an asymmetric profile (a rectangle with a step and a rounded
corner of 15 mm radius) extruded along z, so it has planes and a cylindrical face and no symmetry
(the alignment is unique). Bumps (height > 0) and dents (< 0) are Gaussian displacements along the
surface normal, added to the sampled points only; the CAD stays nominal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

#: Noise sigma per axis, metres (the acceptance figures are stated for 20 um).
NOISE_M = 20e-6
#: Bumps: (face selector, centre in the CAD frame in mm, height in mm, Gaussian sigma in mm).
BUMPS_MM = (((20.0, 12.0, 20.0), 0.5, 2.5),     # top face, a bump
            ((45.0, 8.0, 20.0), -0.3, 2.5),     # top face, a dent
            ((30.0, 0.0, 10.0), 0.2, 2.0),      # front side face (y = 0)
            ((0.0, 20.0, 10.0), -0.1, 2.0))     # left side face (x = 0)
#: Bump displacement is cut off beyond this many sigmas (keeps it on its own face).
BUMP_CUTOFF_SIGMAS = 3.0
#: Side the partial scan looks from (a camera up, left and in front of the part).
VIEW_DIRECTION = np.array([-0.5, -1.0, 1.0]) / np.linalg.norm([-0.5, -1.0, 1.0])
#: Outliers are spread uniformly over the part's bounding box grown by this margin, metres.
OUTLIER_MARGIN_M = 0.01


def bracket_mesh() -> trimesh.Trimesh:
    """The CAD part, metres: a watertight, outward-wound extruded bracket 60 x 40 x 20 mm."""
    arc = np.deg2rad(np.linspace(0.0, 90.0, 25))
    outline_mm = np.vstack([[0.0, 0.0], [60.0, 0.0],
                            np.column_stack([45.0 + 15.0 * np.cos(arc), 12.0 + 15.0 * np.sin(arc)]),
                            [20.0, 27.0], [20.0, 40.0], [0.0, 40.0]])
    # The outline is star-shaped from this point, so a fan from it triangulates the profile.
    vertices_mm = np.vstack([[10.0, 15.0], outline_mm])
    n = len(outline_mm)
    faces = np.column_stack([np.zeros(n, int), 1 + np.arange(n), 1 + (np.arange(n) + 1) % n])
    mesh = trimesh.creation.extrude_triangulation(vertices_mm * 1e-3, faces, 0.02)
    assert mesh.is_watertight and mesh.volume > 0
    return mesh


@dataclass(frozen=True)
class Scan:
    """A synthetic scan: ``points_m`` in the cloud frame and the truth behind it."""

    points_m: np.ndarray            # (N, 3) cloud frame
    cad_from_cloud: np.ndarray      # (4, 4) true transform
    outlier: np.ndarray             # (N,) bool
    designed_m: np.ndarray          # (N,) designed deviation (bump profile), NaN for outliers
    bump: np.ndarray                # (N,) index of the bump a point lies on (-1: none)
    bump_height_m: np.ndarray       # (n_bumps,) designed heights


def random_motion(rng: np.random.Generator, max_angle_deg: float = 30.0, max_shift_m: float = 0.05) -> np.ndarray:
    """A (4, 4) rigid motion: a rotation up to ``max_angle_deg`` about a random axis, a shift up to ``max_shift_m``."""
    axis = rng.normal(size=3)
    rotvec = axis / np.linalg.norm(axis) * np.deg2rad(rng.uniform(0.0, max_angle_deg))
    shift = rng.normal(size=3)
    m = np.eye(4)
    m[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    m[:3, 3] = shift / np.linalg.norm(shift) * rng.uniform(0.0, max_shift_m)
    return m


def scan_of(mesh: trimesh.Trimesh, rng: np.random.Generator, n_points: int, *, partial: bool = True,
            outlier_fraction: float = 0.1, noise_m: float = NOISE_M, max_angle_deg: float = 30.0,
            max_shift_m: float = 0.05) -> Scan:
    """``n_points`` scan points (outliers included) of ``mesh`` with the bumps of :data:`BUMPS_MM`."""
    n_out = round(outlier_fraction * n_points)
    n_surface = n_points - n_out
    normals = mesh.face_normals
    weight = mesh.area_faces * ((normals @ VIEW_DIRECTION > 0) if partial else 1.0)
    face = rng.choice(len(weight), n_surface, p=weight / weight.sum())
    u, v = rng.random((2, n_surface))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = mesh.triangles[face]
    p = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    n = normals[face]
    designed = np.zeros(n_surface)
    bump = np.full(n_surface, -1)
    heights = []
    for k, (centre_mm, height_mm, sigma_mm) in enumerate(BUMPS_MM):
        c, h, s = np.array(centre_mm) * 1e-3, height_mm * 1e-3, sigma_mm * 1e-3
        r = np.linalg.norm(p - c, axis=1)
        on = r < BUMP_CUTOFF_SIGMAS * s
        designed[on] += h * np.exp(-0.5 * (r[on] / s) ** 2)
        bump[r < 0.5 * s] = k
        heights.append(h)
    p = p + designed[:, None] * n + rng.normal(scale=noise_m, size=p.shape)
    lo, hi = mesh.bounds[0] - OUTLIER_MARGIN_M, mesh.bounds[1] + OUTLIER_MARGIN_M
    junk = rng.uniform(lo, hi, size=(n_out, 3))
    points_cad = np.vstack([p, junk])
    order = rng.permutation(n_points)
    cloud_from_cad = random_motion(rng, max_angle_deg, max_shift_m)
    points = (points_cad @ cloud_from_cad[:3, :3].T + cloud_from_cad[:3, 3])[order]
    outlier = np.r_[np.zeros(n_surface, bool), np.ones(n_out, bool)][order]
    return Scan(points, np.linalg.inv(cloud_from_cad), outlier,
                np.r_[designed, np.full(n_out, np.nan)][order], np.r_[bump, np.full(n_out, -1)][order],
                np.array(heights))


def alignment_error_m(scan: Scan, cad_from_cloud: np.ndarray) -> float:
    """RMS distance between the surface points mapped by the true and the estimated transform, metres."""
    p = scan.points_m[~scan.outlier]
    d_rotation = cad_from_cloud[:3, :3] - scan.cad_from_cloud[:3, :3]
    diff = p @ d_rotation.T + (cad_from_cloud[:3, 3] - scan.cad_from_cloud[:3, 3])
    return float(np.sqrt(np.mean(np.sum(diff ** 2, axis=1))))


def deviation_error_m(scan: Scan, deviation_m: np.ndarray) -> float:
    """RMS of measured minus designed deviation over the surface points, metres (~ the noise sigma)."""
    e = deviation_m[~scan.outlier] - scan.designed_m[~scan.outlier]
    return float(np.sqrt(np.mean(e ** 2)))


def bump_height_errors_m(scan: Scan, deviation_m: np.ndarray) -> np.ndarray:
    """Per bump: median measured minus median designed deviation near its centre, metres."""
    return np.array([np.median(deviation_m[scan.bump == k]) - np.median(scan.designed_m[scan.bump == k])
                     for k in range(len(scan.bump_height_m))])
