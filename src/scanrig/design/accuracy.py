"""Predicted accuracy of a triangulated point: pixel noise, speckle, depth of field, 3-D uncertainty.

A point seen by cameras ``i`` is the least-squares intersection of their lines of sight, so to
first order its covariance is ``(sum_i J_i^T W_i J_i)^-1`` with ``J_i = dq_i/dp`` (2x3, from
:meth:`Camera.project_with_jacobians`) and ``W_i`` the inverse 2x2 covariance of the detected
centre in camera ``i``. The per-camera terms ``J_i^T W_i J_i`` ("information") add up, which is
what makes the camera-selection search cheap: a candidate's term is computed once.

Information matrices are ``(N, 3, 3)``, in 1/m²; the algebra on them is
:mod:`scanrig.geometry.uncertainty`'s.
"""

from __future__ import annotations

import math

import numpy as np

from scanrig.geometry.camera import Camera
from scanrig.geometry.uncertainty import information_matrix, inv_sym3, pixel_weights, sigma_from_covariance

from .spec import CalibrationSpec, CameraSpec, LaserSpec

def speckle_sigma_px(camera: CameraSpec, laser: LaserSpec) -> float:
    """1-sigma displacement of the laser-trace centre caused by speckle, pixels.

    Notes
    -----
    Dorsch, Häusler & Herrmann (Appl. Opt. 33(7), 1994) give the speckle-limited depth
    uncertainty ``dz = C lambda / (2 pi sin(u_obs) sin(theta))`` (laser-scanning notes §2). Its
    lateral part, ``dx = C lambda / (2 pi sin(u_obs))`` at distance ``d``, with
    ``sin(u_obs) = (f / 2N) / d``, images to ``dx f / (d p) = C lambda N / (pi p)`` pixels: the same for
    every distance and focal length, set by the f-number ``N`` and the pixel pitch ``p``. Views
    separated by more than their apertures see independent speckle, so it acts as independent
    pixel noise in each camera.
    """
    return laser.speckle_contrast * laser.wavelength_m * camera.f_number / (math.pi * camera.pixel_pitch_m)


def pixel_sigma_px(camera: CameraSpec, laser: LaserSpec) -> float:
    """Total 1-sigma centre noise per image axis: detection and speckle, independent, in pixels."""
    return math.hypot(laser.sigma_px, speckle_sigma_px(camera, laser))


def speckle_floor_m(camera: CameraSpec, laser: LaserSpec, n_cameras: int, nearest_m: float) -> float:
    """Lower bound of the largest-axis sigma any rig of these cameras can reach (detection noise 0).

    Parameters
    ----------
    camera : CameraSpec
        Its longest lens and widest field are assumed (the most favourable).
    laser : LaserSpec
    n_cameras : int
        Cameras seeing the point.
    nearest_m : float
        Smallest camera-to-surface distance the mounting region allows, metres.

    Notes
    -----
    Each camera's information is ``J^T J / s^2`` with ``s`` the speckle sigma in pixels; for a
    pinhole camera its trace is at most ``(f/d)^2 (2 + r^2)(1 + r^2)``, ``r`` the normalised
    image radius of the corner. The smallest eigenvalue of a sum of ``k`` such terms is at most a
    third of the trace, so ``sigma >= s (d/f) sqrt(3 / (k (2 + r^2)(1 + r^2)))``.
    """
    f_px = max(camera.focal_lengths_m) / camera.pixel_pitch_m
    r2 = ((camera.width_px / 2.0) ** 2 + (camera.height_px / 2.0) ** 2) / f_px**2
    trace_factor = (2.0 + r2) * (1.0 + r2)
    return speckle_sigma_px(camera, laser) * nearest_m / f_px * math.sqrt(3.0 / (n_cameras * trace_factor))


def depth_of_field(focal_length_m: float, f_number: float, coc_m: float, focus_m: np.ndarray):
    """Near and far limits of acceptable sharpness (thin lens).

    Parameters
    ----------
    focal_length_m, f_number : float
    coc_m : float
        Acceptable circle of confusion on the sensor, metres.
    focus_m : float or array
        Focus distance, metres.

    Returns
    -------
    near_m, far_m : float or array
        ``far_m`` is ``inf`` at or beyond the hyperfocal distance.
    """
    f = focal_length_m
    hyperfocal = f * f / (f_number * coc_m) + f
    focus_m = np.asarray(focus_m, dtype=np.float64)
    near = focus_m * (hyperfocal - f) / (hyperfocal + focus_m - 2.0 * f)
    with np.errstate(divide="ignore"):
        far = np.where(focus_m < hyperfocal, focus_m * (hyperfocal - f) / (hyperfocal - focus_m), np.inf)
    return near, far


def information(camera: Camera, points_world: np.ndarray, sigma_px: float,
                calibration: CalibrationSpec | None = None):
    """Per-point information ``J^T W J`` of one camera's observation of each point.

    Parameters
    ----------
    camera : Camera
    points_world : (N, 3) float array
        Points seen by the camera, world frame, metres.
    sigma_px : float
        1-sigma centre noise per image axis, pixels.
    calibration : CalibrationSpec, optional
        Pose uncertainty of the camera; it adds ``J_pose P J_pose^T`` to the centre covariance
        (``P`` diagonal: rotation-vector and translation variances).

    Returns
    -------
    info : (N, 3, 3) float array
        Information, 1/m².
    jtj : (N, 3, 3) float array
        ``J^T J`` (px²/m²), the information per unit pixel weight, for rescaling to other noise.
    """
    _, J, J_pose, _ = camera.project_with_jacobians(points_world)
    used = np.ones((1, J.shape[0]), dtype=bool)
    cov_px = np.broadcast_to(sigma_px**2 * np.eye(2), (J.shape[0], 2, 2))
    if calibration is not None:
        pose_var = np.r_[np.full(3, calibration.rotation_sigma_rad**2), np.full(3, calibration.translation_sigma_m**2)]
        cov_px = cov_px + np.einsum("nik,k,njk->nij", J_pose, pose_var, J_pose)
    info = information_matrix(J[None], pixel_weights(cov_px)[None], used)
    jtj = information_matrix(J[None], np.broadcast_to(np.eye(2), (1, J.shape[0], 2, 2)), used)
    return info, jtj


def sigma_from_information(info: np.ndarray, n_views: np.ndarray, min_views: int = 2) -> np.ndarray:
    """Largest-axis 1-sigma of the point covariance ``info^-1``.

    Parameters
    ----------
    info : (N, 3, 3) float array
        Summed information, 1/m².
    n_views : (N,) int array
        Cameras that contributed.
    min_views : int
        Fewer views give ``inf``.

    Returns
    -------
    (N,) float array
        Square root of the covariance's largest eigenvalue, metres (the ``sigma`` of
        ``points.ply``); ``inf`` where the point is not triangulable (too few views, parallel rays).
    """
    cov, singular = inv_sym3(info)
    sigma = sigma_from_covariance(cov)
    sigma[(n_views < min_views) | singular | ~np.isfinite(sigma)] = np.inf
    return sigma
