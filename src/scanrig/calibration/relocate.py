"""Re-localisation: a moved camera's new pose from points of known world position.

PnP (SQPnP) with the camera's calibrated intrinsics held fixed, then a Levenberg–Marquardt
refinement of the six pose parameters with the analytic Jacobian; the pose covariance is
``sigma² (JᵀJ)⁻¹`` with ``sigma`` measured from the residuals (or given).

``known_points.csv`` columns (header required)::

    point,x,y,z,u,v            # x y z: world metres; u v: pixel in the camera to relocate
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanrig.calibration.lm import levenberg_marquardt, solve_spd
from scanrig.calibration.uncertainty import center_jacobian
from scanrig.errors import EstimationError, FileFormatError, InputError
from scanrig.geometry.camera import Camera
from scanrig.geometry.transform import RigidTransform, canonical_rvec_jacobian
from scanrig.io.csv_rows import read_csv_rows

#: Fewest known points (6 pose unknowns; 5 points give 4 redundant residuals for the sigma).
MIN_POINTS = 5
#: A pose change larger than this many sigmas (centre or rotation) means the camera moved.
MOVED_SIGMAS = 3.0


@dataclass
class Relocation:
    """Outcome of :func:`relocate_camera`.

    Attributes
    ----------
    camera : Camera
        The camera at its new pose (intrinsics unchanged).
    shift_m : float
        Distance between the old and new optical centres, metres.
    rotation_deg : float
        Angle of the rotation between the old and new orientation, degrees.
    center_std_m : ndarray of shape (3,)
        Standard deviation of the new centre (world x, y, z), metres.
    rotation_std_deg : float
        RMS standard deviation of the new rotation vector's components, degrees.
    rms_px : float
        Reprojection RMS of the known points at the new pose.
    sigma_px : float
        Pixel noise used for the covariance.
    moved : bool
        Whether the change exceeds :data:`MOVED_SIGMAS` times its uncertainty.
    """

    camera: Camera
    shift_m: float
    rotation_deg: float
    center_std_m: np.ndarray
    rotation_std_deg: float
    rms_px: float
    sigma_px: float
    moved: bool


def read_known_points(path: str | Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Read ``known_points.csv``.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    names : list of str
    p_world : ndarray of shape (N, 3)
        World points, metres.
    uv : ndarray of shape (N, 2)
        Their pixels.

    Raises
    ------
    FileFormatError
        Missing file or column, a row whose cells do not match the header, a non-numeric or
        non-finite value, or fewer than :data:`MIN_POINTS` points.
    """
    path = Path(path)
    rows = read_csv_rows(path, ("point", "x", "y", "z", "u", "v"), "known points file")
    values = np.array([_point_values(path, line, row) for line, row in rows]).reshape(-1, 5)
    if len(rows) < MIN_POINTS:
        raise FileFormatError(path, f"{len(rows)} known points; at least {MIN_POINTS} are needed")
    return [row["point"] for _, row in rows], values[:, :3].copy(), values[:, 3:].copy()


def _point_values(path: Path, line: int, row: dict) -> list[float]:
    """``x, y, z, u, v`` of one row of ``known_points.csv``, checked to be finite numbers."""
    try:
        values = [float(row[c]) for c in "xyzuv"]
    except ValueError as exc:
        raise FileFormatError(path, f"line {line}: non-numeric value: {exc}") from None
    if not np.all(np.isfinite(values)):
        raise FileFormatError(path, f"line {line}: x, y, z, u, v must be finite numbers, got {values}")
    return values


def relocate_camera(camera: Camera, p_world: np.ndarray, uv: np.ndarray, sigma_px: float | None = None) -> Relocation:
    """New pose of ``camera`` from known world points and their pixels (intrinsics fixed).

    Parameters
    ----------
    camera : Camera
        The calibrated camera at its old pose.
    p_world : ndarray of shape (N, 3)
        World points, metres (N >= :data:`MIN_POINTS`, not all collinear).
    uv : ndarray of shape (N, 2)
        Their pixels in the camera now.
    sigma_px : float, optional
        Pixel noise for the covariance; default measured from the residuals.
    """
    import cv2

    # contiguous copies: OpenCV rejects non-contiguous arrays such as column slices
    p_world = np.ascontiguousarray(p_world, dtype=np.float64)
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    if p_world.ndim != 2 or p_world.shape[1] != 3 or uv.shape != (len(p_world), 2):
        raise InputError(f"p_world must be (N, 3) and uv (N, 2) with the same N, got {p_world.shape}, {uv.shape}")
    if len(p_world) < MIN_POINTS:
        raise InputError(f"{len(p_world)} known points; at least {MIN_POINTS} are needed to relocate a camera")
    ok, rvec, tvec = cv2.solvePnP(p_world, uv, camera.K, camera.dist, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise EstimationError("PnP found no pose; check that the points and pixels correspond")

    def fun(x, jac):
        cam = camera.with_pose(RigidTransform.from_rvec_tvec(x[:3], x[3:]))
        if not jac:
            return (cam.project(p_world) - uv).ravel()
        q, _, J_pose, _ = cam.project_with_jacobians(p_world)
        J_pose[:, :, :3] = J_pose[:, :, :3] @ canonical_rvec_jacobian(x[:3])  # x may have passed π
        return (q - uv).ravel(), J_pose.reshape(-1, 6)

    res = levenberg_marquardt(fun, np.concatenate([rvec.ravel(), tvec.ravel()]))
    new = camera.with_pose(RigidTransform.from_rvec_tvec(res.x[:3], res.x[3:]))
    r, J = fun(np.concatenate([new.cam_from_world.rvec, new.cam_from_world.t]), True)  # canonical chart
    if not np.all(np.isfinite(r)):
        raise EstimationError("relocated pose puts known points behind the camera; check the point list")
    dof = 2 * len(p_world) - 6
    sigma = float(np.sqrt(r @ r / dof)) if sigma_px is None else float(sigma_px)
    cov = solve_spd(J.T @ J, np.eye(6)) * sigma ** 2
    J_c = center_jacobian(new.cam_from_world)
    center_std = np.sqrt(np.maximum(np.diag(J_c @ cov @ J_c.T), 0.0))
    rot_std = float(np.degrees(np.sqrt(np.trace(cov[:3, :3]) / 3.0)))
    shift = float(np.linalg.norm(new.center_world - camera.center_world))
    delta = new.cam_from_world @ camera.cam_from_world.inverse()
    angle = float(np.degrees(np.linalg.norm(delta.rvec)))
    moved = shift > MOVED_SIGMAS * float(np.linalg.norm(center_std)) or angle > MOVED_SIGMAS * rot_std * np.sqrt(3)
    rms = float(np.sqrt(np.mean(np.sum(r.reshape(-1, 2) ** 2, axis=1))))
    return Relocation(new, shift, angle, center_std, rot_std, rms, sigma, moved)
