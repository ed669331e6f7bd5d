"""How sure the calibration is: parameter covariance, projection uncertainty, degeneracy warnings.

Covariance of the solved parameters is ``sigma² (JᵀJ)⁻¹`` with the weighted Jacobian at the
solution and ``sigma`` the measured residual scale (so it already includes the real detection
noise). The gauge is fixed (target pose of the reference shot = world), so ``JᵀJ`` is regular
unless the data cannot determine some parameter; then the near-null directions are reported and
the pseudo-inverse is used.

A parameter is *poorly determined* when one standard deviation of it moves some pixel of its
camera's image by more than :data:`POORLY_DETERMINED_PX` — a unit-free test that works alike for
focal lengths, principal points and distortion coefficients. Every such parameter is listed in
:attr:`Uncertainty.poorly_determined` (for the report); the warnings name them in one line per
camera and cause: distortion here, the focal length and principal point in
:func:`scanrig.calibration.intrinsics_prior.undetermined_intrinsics`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.calibration.bundle import BundleResult, rotation_jacobians
from scanrig.geometry.camera import PINHOLE_PARAMS, Camera
from scanrig.geometry.transform import RigidTransform

#: One sigma of an intrinsic parameter moving some image pixel by more than this is reported.
POORLY_DETERMINED_PX = 0.5
#: Relative eigenvalue of the scaled (unit-diagonal) normal matrix below which a direction is
#: unobservable (float64 round-off on JᵀJ is ~1e-16 relative; 1e-12 leaves four decades of margin).
SINGULAR_RTOL = 1e-12
#: Pixels per image side sampled for projection-uncertainty maps.
MAP_SAMPLES = (32, 24)


@dataclass
class Uncertainty:
    """Covariance of a bundle-adjustment solution, by camera.

    Attributes
    ----------
    covariance : ndarray of shape (n, n)
        Of the parameter vector (layout of the :class:`BundleResult`).
    params_std : dict
        ``camera -> (n_params,)`` standard deviation of each intrinsic parameter (0 when fixed).
    center_std_m : dict
        ``camera -> (3,)`` standard deviation of the camera centre along world x, y, z, metres.
    rotation_cov_rad2 : dict
        ``camera -> (3, 3)`` covariance of the camera's rotation error vector ``rvec(R_est R_trueᵀ)``,
        rad² (the solver's Rodrigues-vector covariance mapped through d(R p)/d rvec, see
        :func:`rotation_error_covariance`).
    rotation_std_deg : dict
        ``camera -> float`` RMS standard deviation of that rotation error over the three axes, degrees.
    poorly_determined : dict
        ``camera -> [(parameter, std, moved_px), ...]``: the parameters whose 1 sigma moves some
        pixel by ``moved_px`` > :data:`POORLY_DETERMINED_PX`, largest first.
    warnings : list of str
        One line per camera whose distortion the data leave open, and one per unobservable
        direction.
    flex_std_m : ndarray of shape (2,) or None
        Standard deviation of the target's flex terms ``(c_x, c_y)``, metres; None for a rigid
        target.
    """

    covariance: np.ndarray
    params_std: dict
    center_std_m: dict
    rotation_cov_rad2: dict
    rotation_std_deg: dict
    poorly_determined: dict
    warnings: list
    flex_std_m: np.ndarray | None = None


def covariance(result: BundleResult) -> Uncertainty:
    """Covariance of every solved parameter (see the module docstring), and the per-camera figures
    and warnings drawn from it."""
    cov, warnings = parameter_covariance(result)
    layout, state = result.layout, result.state
    params_std, center_std, rot_cov, rot_std, poor = {}, {}, {}, {}, {}
    for c, cam in enumerate(state.cameras):
        index = layout.intrinsics[c]
        std = np.zeros(len(cam.params))
        free = index >= 0
        std[free] = np.sqrt(np.maximum(np.diag(cov)[index[free]], 0.0))
        params_std[cam.name] = std
        moved = std * _pixel_effect(cam)
        poor[cam.name] = [(cam.param_names[k], float(std[k]), float(moved[k]))
                          for k in np.argsort(-moved, kind="stable") if free[k] and moved[k] > POORLY_DETERMINED_PX]
        warnings += distortion_warning(cam.name, poor[cam.name])
        pose = layout.camera_pose[c]
        if pose is None:
            center_std[cam.name] = np.zeros(3)
            rot_cov[cam.name] = np.zeros((3, 3))
            rot_std[cam.name] = 0.0
            continue
        C = cov[pose, pose]
        J_center = center_jacobian(cam.cam_from_world)
        center_std[cam.name] = np.sqrt(np.maximum(np.diag(J_center @ C @ J_center.T), 0.0))
        rot_cov[cam.name] = rotation_error_covariance(cam.cam_from_world.rvec, C[:3, :3])
        rot_std[cam.name] = float(np.degrees(np.sqrt(np.trace(rot_cov[cam.name]) / 3.0)))
    flex_std = None if layout.flex is None else np.sqrt(np.maximum(np.diag(cov)[layout.flex], 0.0))
    return Uncertainty(cov, params_std, center_std, rot_cov, rot_std, poor, warnings, flex_std)


def parameter_covariance(result: BundleResult) -> tuple[np.ndarray, list[str]]:
    """Covariance of every solved parameter, ``σ² (JᵀJ)⁻¹`` (the pseudo-inverse when rank-deficient),
    alone: what the cross-validation's halves need, without :func:`covariance`'s per-camera figures.

    Returns
    -------
    cov : ndarray of shape (n_params, n_params)
        In the units of the parameter vector ``result.x``.
    warnings : list of str
        One line per combination of parameters the data cannot determine.
    """
    from scanrig.calibration.lm import normal_equations, solve_spd

    A, _ = normal_equations(result.jacobian, np.zeros(result.jacobian.shape[0]))
    scale = np.sqrt(np.maximum(A.diagonal(), 1e-300))
    A_scaled = (A.multiply(1.0 / scale[:, None]).multiply(1.0 / scale[None, :])).tocsc()
    names = _parameter_names(result)
    warnings = []
    try:
        inv_scaled = solve_spd(A_scaled, np.eye(A.shape[0]))
        singular_params = np.flatnonzero(np.diag(inv_scaled) > 1.0 / SINGULAR_RTOL)
    except RuntimeError:
        inv_scaled, singular_params = None, np.arange(0)
    if inv_scaled is None or len(singular_params):
        # Rank-deficient: name the parameters of the null directions, use the pseudo-inverse.
        evals, evecs = np.linalg.eigh(A_scaled.toarray())
        singular = evals < SINGULAR_RTOL * evals.max()
        inv_scaled = (evecs * np.where(singular, 0.0, 1.0 / np.where(singular, 1.0, evals))) @ evecs.T
        for k in np.flatnonzero(singular):
            top = np.argsort(-np.abs(evecs[:, k]))[:3]
            warnings.append("the data cannot determine a combination of " + ", ".join(names[i] for i in top)
                            + "; add views with other tilts and positions of the target")
    return inv_scaled / scale[:, None] / scale[None, :] * result.sigma_px ** 2, warnings


def distortion_warning(camera: str, poorly_determined: list) -> list[str]:
    """The one-line warning (as a list of 0 or 1) for a camera whose distortion terms are poorly
    determined; ``poorly_determined`` as :attr:`Uncertainty.poorly_determined`. The focal length
    and principal point have their own line."""
    loose = [(p, s, px) for p, s, px in poorly_determined if p not in PINHOLE_PARAMS]
    if not loose:
        return []
    terms = ", ".join(f"{p} ±{s:.2g} ({px:.2g} px)" for p, s, px in loose[:3])
    more = f" and {len(loose) - 3} more" if len(loose) > 3 else ""
    return [f"{camera}: distortion not determined by these views ({terms}{more}; 1 sigma moves the image by "
            "that much): add views reaching the image corners, or use a simpler model"]


def rotation_error_covariance(rvec: np.ndarray, cov_rvec: np.ndarray) -> np.ndarray:
    """(3, 3) covariance of the rotation error vector from that of the Rodrigues vector ``rvec``.

    d(R p)/dr = -R [p]x M (:func:`scanrig.calibration.bundle.rotation_jacobians`), so a change dr
    turns R into exp([R M dr]x) R: the error vector is ``R M dr``. For large rotations the raw
    Rodrigues components' sigmas differ from the rotation's own (by ~20 % at 120 deg).

    Parameters
    ----------
    rvec : ndarray of shape (3,)
    cov_rvec : ndarray of shape (3, 3)
        Covariance of ``rvec``, rad².
    """
    R, M = rotation_jacobians(np.asarray(rvec, dtype=float)[None, :])
    A = R[0] @ M[0]
    return A @ cov_rvec @ A.T


def _parameter_names(result: BundleResult) -> list[str]:
    names = [""] * result.layout.size
    for c, cam in enumerate(result.state.cameras):
        for k, i in enumerate(result.layout.intrinsics[c]):
            if i >= 0:
                names[i] = f"{cam.name}.{cam.param_names[k]}"
        pose = result.layout.camera_pose[c]
        if pose is not None:
            for k, label in enumerate(("rx", "ry", "rz", "tx", "ty", "tz")):
                names[pose.start + k] = f"{cam.name}.{label}"
    for s, pose in enumerate(result.layout.shot_pose):
        if pose is not None:
            for k, label in enumerate(("rx", "ry", "rz", "tx", "ty", "tz")):
                names[pose.start + k] = f"shot {result.obs.shot_names[s]}.{label}"
    if result.layout.flex is not None:
        names[result.layout.flex] = ["target.flex_x", "target.flex_y"]
    return names


def image_grid(cam: Camera, samples=MAP_SAMPLES) -> np.ndarray:
    """(n, 2) pixels on a regular grid spanning the whole image."""
    u = np.linspace(0, cam.width - 1, samples[0])
    v = np.linspace(0, cam.height - 1, samples[1])
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


def grid_points_cam(cam: Camera, depth_m: float, samples=MAP_SAMPLES):
    """Pixels of the image grid and their points at ``depth_m`` in the camera frame (NaN where the
    distortion cannot be inverted)."""
    q = image_grid(cam, samples)
    xy, ok = cam.unproject(q)
    p = np.column_stack([xy, np.ones(len(xy))]) * depth_m
    p[~ok] = np.nan
    return q, p


def _pixel_effect(cam: Camera) -> np.ndarray:
    """(n_params,) largest pixel displacement over the image per unit change of each parameter."""
    at_origin = cam.with_pose(RigidTransform.identity())
    _, p = grid_points_cam(at_origin, 1.0, (9, 7))
    p = p[np.all(np.isfinite(p), axis=1)]
    _, _, _, J_intr = at_origin.project_with_jacobians(p)
    return np.nanmax(np.linalg.norm(J_intr, axis=1), axis=0)


def center_jacobian(cam_from_world: RigidTransform) -> np.ndarray:
    """(3, 6) derivative of the centre ``-Rᵀ t`` with respect to (rvec, tvec), numerically.

    Central differences with a step of 1e-7 (rad or m): the truncation error is ~1e-14, far
    below any covariance it is used for.
    """
    x0 = np.concatenate([cam_from_world.rvec, cam_from_world.t])
    step = 1e-7
    J = np.zeros((3, 6))
    for k in range(6):
        dx = np.zeros(6)
        dx[k] = step
        plus = RigidTransform.from_rvec_tvec((x0 + dx)[:3], (x0 + dx)[3:]).inverse().t
        minus = RigidTransform.from_rvec_tvec((x0 - dx)[:3], (x0 - dx)[3:]).inverse().t
        J[:, k] = (plus - minus) / (2 * step)
    return J


def projection_uncertainty(result: BundleResult, unc: Uncertainty, camera: int, depth_m: float,
                           samples=MAP_SAMPLES):
    """Worst-direction 1-sigma uncertainty of projecting world points, over one camera's image.

    For each pixel of a grid, the world point seen there at ``depth_m`` is projected with the
    camera's solved intrinsics and pose; the joint covariance of those parameters is propagated
    to the pixel and the larger axis of the 2x2 covariance is reported.

    Returns
    -------
    q : ndarray of shape (n, 2)
        Grid pixels.
    sigma_px : ndarray of shape (n,)
        Worst-direction standard deviation, pixels (NaN where the model cannot be inverted).
    """
    cam = result.state.cameras[camera]
    layout = result.layout
    q, p_cam = grid_points_cam(cam, depth_m, samples)
    # only the pixels whose point exists (projecting a stand-in point at the centre divides by 0)
    inverted = np.all(np.isfinite(p_cam), axis=1)
    p_world = cam.cam_from_world.inverse().apply(p_cam[inverted])
    _, _, J_pose, J_intr = cam.project_with_jacobians(p_world)
    index = layout.intrinsics[camera]
    cols = list(index[index >= 0])
    J = J_intr[:, :, index >= 0]
    if layout.camera_pose[camera] is not None:
        cols += list(range(layout.camera_pose[camera].start, layout.camera_pose[camera].stop))
        J = np.concatenate([J, J_pose], axis=2)
    C = unc.covariance[np.ix_(cols, cols)]
    S = J @ C @ np.swapaxes(J, 1, 2)
    sigma = np.full(len(q), np.nan)
    sigma[inverted] = np.sqrt(np.maximum(np.linalg.eigvalsh(S)[:, -1], 0.0))
    return q, sigma
