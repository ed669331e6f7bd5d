"""N-view triangulation: the point nearest to all lines of sight, with its uncertainty.

For unit ray directions ``d_i`` from camera centres ``c_i`` the least-squares point solves the
3×3 system ``Σ w_i (I − d_i d_iᵀ) p = Σ w_i (I − d_i d_iᵀ) c_i`` (the "midpoint" of N rays). A
first pass uses ``w_i = 1``; the second uses ``w_i = (f_i / (σ_i t_i))²`` with ``t_i`` the range
along the ray, so each ray's perpendicular miss is measured in units of its own expected error
(an angle ``σ_i / f_i`` at range ``t_i``). An optional Gauss–Newton refinement then minimises the
reprojection error weighted by each detection's pixel covariance, which is the maximum-likelihood
point for Gaussian pixel noise; the covariance is the inverse of the information matrix at the
solution (:mod:`scanrig.geometry.uncertainty`). See ``docs/reconstruction.md`` and the reference
notes (laser-scanning anchors §3): with well-spread views the weighted midpoint is already within
a percent of the optimum, and the refinement matters for the covariance and the residuals.

Every step is vectorised over points; per-point failures are NaN plus a :class:`Reason` code.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from scanrig.errors import InputError, ShapeError
from scanrig.geometry import distortion
from scanrig.geometry.camera import Camera
from scanrig.geometry.uncertainty import (
    information_matrix,
    inv_sym3,
    inv_sym3_components,
    max_eigenvalue_sym3_components,
    sigma_from_covariance,
    sym3_from_components,
)

#: Smallest angle between the two most divergent rays of a point for it to count as
#: triangulated. Below 1° a 0.3 px error at 1 m (f = 2400 px) moves the point by ~7 mm along the
#: rays; COLMAP uses 1.5° for sparse reconstruction.
MIN_TRIANGULATION_ANGLE_RAD = float(np.deg2rad(1.0))
#: Gauss–Newton iterations after the weighted closed form. The closed form starts within a
#: fraction of the noise of the optimum, so two steps reach it to < 1e-6 of σ (see the tests).
GN_ITERATIONS = 2
#: Points processed per block: whole-array numpy steps on blocks that fit in the CPU cache run
#: two to three times faster than on millions of points at once, and memory stays bounded.
CHUNK_POINTS = 32768


class Reason(IntEnum):
    """Why a point failed (``TriangulationInfo.reason``, uint8)."""

    OK = 0
    #: Fewer than two usable views (unobserved, non-positive sigma, or a pixel that cannot be
    #: unprojected).
    FEW_VIEWS = 1
    #: The rays are (nearly) parallel: largest ray angle below the gate, or a singular system.
    PARALLEL = 2
    #: The intersection lies on or behind the image plane of a camera that saw it.
    BEHIND = 3
    #: The Gauss–Newton refinement produced a non-finite point.
    DIVERGED = 4


@dataclass(frozen=True)
class TriangulationInfo:
    """Per-point quality of a triangulation (all arrays have N rows).

    Attributes
    ----------
    cov : ndarray of shape (N, 3, 3)
        Covariance of the point, m², world frame (NaN where failed).
    sigma : ndarray of shape (N,)
        Standard deviation along the covariance's largest axis, metres.
    residual_px : ndarray of shape (N,)
        RMS over the views of the reprojection error norm, pixels.
    chi2 : ndarray of shape (N,)
        ``Σ_i r_iᵀ Σ_i⁻¹ r_i`` over the views (χ² with ``2 n_views − 3`` degrees of freedom).
    n_views : ndarray of shape (N,), uint8
        Views used.
    min_angle_rad, max_angle_rad : ndarray of shape (N,)
        Smallest and largest angle between two of the point's rays, radians.
    reason : ndarray of shape (N,), uint8
        :class:`Reason` code, 0 where the point is valid.
    used : ndarray of shape (n_cams, N), bool
        Which views entered the solution.
    """

    cov: np.ndarray
    sigma: np.ndarray
    residual_px: np.ndarray
    chi2: np.ndarray
    n_views: np.ndarray
    min_angle_rad: np.ndarray
    max_angle_rad: np.ndarray
    reason: np.ndarray
    used: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        """Mask ``(N,)`` of valid points."""
        return self.reason == Reason.OK


def triangulate(
    rig,
    q_obs,
    sigma_px=None,
    cov_px=None,
    refine: bool = True,
    min_angle_rad: float = MIN_TRIANGULATION_ANGLE_RAD,
    dirs: np.ndarray | None = None,
):
    """Triangulate points from their pixels in several cameras.

    Parameters
    ----------
    rig : Rig or sequence of Camera
        The cameras, in the order of ``q_obs``'s first axis.
    q_obs : array_like of shape (n_cams, N, 2)
        Observed pixels ``(u, v)``; NaN where a camera has no view.
    sigma_px : float or array_like of shape (n_cams, N), optional
        Isotropic 1-σ pixel noise of each detection (pixels). Default 1 px, so that ``cov`` is
        then per pixel² of noise.
    cov_px : array_like of shape (n_cams, N, 2, 2), optional
        Full pixel covariances (px², e.g. ``cov_uu, cov_uv, cov_vv`` from ``traces.parquet``);
        overrides ``sigma_px``.
    refine : bool
        Run the Gauss–Newton refinement of the weighted reprojection error and take the
        covariance from the exact projection Jacobians. Without it the point is the weighted
        closed form and the covariance its ray approximation ``(Σ (I − d dᵀ) / s_i²)⁻¹``
        (``s_i = σ_i t_i / f_i``), which ignores the obliquity of off-axis views (a few percent
        at the image corners).
    min_angle_rad : float
        Points whose largest ray angle is below this fail with :attr:`Reason.PARALLEL`.
    dirs : ndarray of shape (n_cams, N, 3), optional
        Unit world ray directions of ``q_obs`` when already known (from ``Camera.rays``), to
        save the unprojection when many hypotheses share detections.

    Returns
    -------
    p_world : ndarray of shape (N, 3)
        Points, world frame, metres; NaN where ``info.reason != 0``.
    info : TriangulationInfo
        Per-point covariance, residuals, views, ray angles and failure reasons.

    Raises
    ------
    ShapeError
        If the shapes disagree with each other or with the number of cameras.
    """
    cams = _camera_list(rig)
    q = np.asarray(q_obs, dtype=np.float64)
    n_cams = len(cams)
    if q.ndim != 3 or q.shape[0] != n_cams or q.shape[2] != 2:
        raise ShapeError(f"q_obs must have shape ({n_cams}, N, 2) for {n_cams} cameras, got {q.shape}")
    n = q.shape[1]
    sigma_iso, cov = _pixel_noise(sigma_px, cov_px, n_cams, n)
    if dirs is not None and np.shape(dirs) != (n_cams, n, 3):
        raise ShapeError(f"dirs must have shape ({n_cams}, {n}, 3), got {np.shape(dirs)}")
    # Outputs are allocated once and filled block by block.
    p = np.empty((n, 3))
    info = TriangulationInfo(
        cov=np.empty((n, 3, 3)),
        sigma=np.empty(n),
        residual_px=np.empty(n),
        chi2=np.empty(n),
        n_views=np.empty(n, np.uint8),
        min_angle_rad=np.empty(n),
        max_angle_rad=np.empty(n),
        reason=np.empty(n, np.uint8),
        used=np.empty((n_cams, n), bool),
    )
    rig_arrays = _RigArrays(cams)
    for start in range(0, n, CHUNK_POINTS):
        s = slice(start, min(start + CHUNK_POINTS, n))
        sigma_s, W_s = (sigma_iso[:, s], None) if cov is None else _noise_from_cov(cov[:, s])
        _triangulate_chunk(
            cams, rig_arrays, q[:, s], sigma_s, W_s, None if dirs is None else dirs[:, s], refine, min_angle_rad,
            p, info, s,
        )
    return p, info


class _RigArrays:
    """Per-camera constants of a triangulation, computed once per call rather than per block."""

    def __init__(self, cams: Sequence[Camera]):
        #: Optical centres ``(n_cams, 3)``.
        self.centers = np.array([cam.center_world for cam in cams])
        #: Geometric-mean focal lengths (px).
        self.focal = [float(np.sqrt(cam.params[0] * cam.params[1])) for cam in cams]
        #: ``[R_i | t_i]`` stacked, ``(3 n_cams, 4)``: world to every camera frame in one product.
        self.to_cameras = np.concatenate([np.c_[cam.cam_from_world.R, cam.cam_from_world.t] for cam in cams])


def _triangulate_chunk(cams, rig_arrays, q, sigma_iso, W, dirs, refine, min_angle_rad, p_out, out, s):
    """:func:`triangulate` on a block of points (arguments already validated).

    ``W`` is None (isotropic ``sigma_iso``) or the components ``(W_uu, W_uv, W_vv)``, each
    ``(n_cams, n)``, of the inverse pixel covariances. Writes rows ``s`` of ``p_out`` and of the
    arrays of ``out``. Works on ``(n_cams, n)`` component arrays (ray directions as
    ``D[k, camera, point]``) and per-point ``(n,)`` arrays: whole-array numpy operations on
    blocks that stay in the CPU cache, without ``(n, 3, 3)`` stacks.
    """
    n_cams, n = q.shape[:2]
    u, v = q[..., 0], q[..., 1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        used = (sigma_iso > 0) & (sigma_iso < np.inf)  # also false for NaN
        used &= np.isfinite(u)
        used &= np.isfinite(v)
        D = np.empty((3, n_cams, n))
        if dirs is None:
            for i, cam in enumerate(cams):
                cam.ray_directions(u[i], v[i], D[0, i], D[1, i], D[2, i])  # NaN where not invertible
            used &= np.isfinite(D[0])
        else:
            for k in range(3):
                D[k] = dirs[..., k]
            used &= np.isfinite(D).all(axis=0)
        all_used = bool(used.all())
        if not all_used:
            D[:, ~used] = 0.0
        centers, focal = rig_arrays.centers, rig_arrays.focal
        dc = _dot_centers(D, centers)

        # Unweighted pass: ranges t_i = (p − c_i) · d_i give the weights of the second pass.
        p0, _, _ = _nearest_point(D, dc, centers, None if all_used else used.astype(np.float64))
        w = np.empty((n_cams, n))
        for i in range(n_cams):
            t = p0[0] * D[0, i]
            t += p0[1] * D[1, i]
            t += p0[2] * D[2, i]
            t -= dc[i]
            t *= sigma_iso[i]
            np.divide(focal[i], t, out=t)
            np.multiply(t, t, out=w[i])
        unusable = ~np.isfinite(w)
        if not all_used:
            unusable |= ~used
        if unusable.any():
            w[unusable] = 0.0
        p, inv, singular = _nearest_point(D, dc, centers, w, with_inverse=True)

        n_views = used.sum(axis=0)
        min_angle, max_angle = _ray_angles_components(D, used, all_used)
        reason = np.zeros(n, np.uint8)
        reason[singular | ~(max_angle >= min_angle_rad)] = Reason.PARALLEL
        reason[n_views < 2] = Reason.FEW_VIEWS

        rsum = np.zeros(n)  # Σ |r_i|² over the used views
        chi2 = np.zeros(n)
        if refine:
            reason[(reason == 0) & _behind_components(cams, p, used)] = Reason.BEHIND
            good = reason == 0
            p_arr = np.stack(p, axis=1)
            p_arr[~good] = np.nan
            p_arr, q_hat, cov = _gauss_newton(cams, q, _weights_array(sigma_iso, W), used, p_arr, good)
            diverged = good & ~np.all(np.isfinite(p_arr), axis=1)
            reason[diverged] = Reason.DIVERGED
            p = (p_arr[:, 0], p_arr[:, 1], p_arr[:, 2])
            reason[good & ~diverged & _behind_components(cams, p, used)] = Reason.BEHIND
            for i in range(n_cams):
                _add_residual(u[i] - q_hat[i, :, 0], v[i] - q_hat[i, :, 1], i, used, all_used,
                              sigma_iso, W, rsum, chi2)
        else:
            behind = np.zeros(n, bool)
            p_cam = _to_cameras(rig_arrays.to_cameras, p)
            for i, cam in enumerate(cams):
                u_hat, v_hat, z = _project_components(cam, p_cam[3 * i:3 * i + 3])
                z_bad = ~(z > 0.0)
                if not all_used:
                    z_bad &= used[i]
                behind |= z_bad
                np.subtract(u[i], u_hat, out=u_hat)
                np.subtract(v[i], v_hat, out=v_hat)
                _add_residual(u_hat, v_hat, i, used, all_used, sigma_iso, W, rsum, chi2)
            reason[(reason == 0) & behind] = Reason.BEHIND
        good = reason == 0
        residual_px = np.sqrt(rsum / n_views)

        all_good = bool(good.all())
        bad = None if all_good else ~good
        p_rows = p_out[s]
        for k in range(3):
            p_rows[:, k] = p[k]
        if not all_good:
            p_rows[bad] = np.nan
            residual_px[bad] = np.nan
            chi2[bad] = np.nan
        cov_rows = out.cov[s]
        if refine:
            cov_rows[...] = cov
            if not all_good:
                cov_rows[bad] = np.nan
            out.sigma[s] = sigma_from_covariance(cov_rows)
        else:
            if not all_good:
                for c in inv:
                    c[bad] = np.nan
            ixx, iyy, izz, ixy, ixz, iyz = inv
            cov_rows[:, 0, 0], cov_rows[:, 1, 1], cov_rows[:, 2, 2] = ixx, iyy, izz
            cov_rows[:, 0, 1] = cov_rows[:, 1, 0] = ixy
            cov_rows[:, 0, 2] = cov_rows[:, 2, 0] = ixz
            cov_rows[:, 1, 2] = cov_rows[:, 2, 1] = iyz
            lam = max_eigenvalue_sym3_components(*inv)
            np.maximum(lam, 0.0, out=lam)
            out.sigma[s] = np.sqrt(lam, out=lam)
    out.residual_px[s] = residual_px
    out.chi2[s] = chi2
    out.n_views[s] = n_views
    out.min_angle_rad[s] = min_angle
    out.max_angle_rad[s] = max_angle
    out.reason[s] = reason
    out.used[:, s] = used


def _nearest_point(D, dc, centers, weights, with_inverse=False):
    """Weighted least-squares point nearest to the rays, on component arrays.

    Parameters
    ----------
    D : ndarray of shape (3, n_cams, N)
        Unit directions by component; zero for unused views.
    dc : ndarray of shape (n_cams, N)
        ``d_i · c_i``.
    centers : ndarray of shape (n_cams, 3)
        Ray origins.
    weights : ndarray of shape (n_cams, N) or None
        Ray weights (0 = unused); None for all ones.

    Returns
    -------
    p : tuple of three (N,) arrays
        The point's coordinates (NaN where singular).
    inv : tuple of six (N,) arrays or None
        Components ``xx, yy, zz, xy, xz, yz`` of the inverse normal matrix, if asked.
    singular : ndarray of shape (N,), bool
    """
    n_cams, n = dc.shape
    acc9 = np.empty((9, n))  # Σ w d dᵀ (xx, yy, zz, xy, xz, yz) and Σ w d (d·c) (x, y, z)
    axx, ayy, azz, axy, axz, ayz, bx, by, bz = acc9
    t = np.empty(n)
    if weights is None:
        sw = float(n_cams)
        bc = centers.sum(axis=0)
    else:
        sw = weights.sum(axis=0)
        bc = None
    for i in range(n_cams):
        dx, dy, dz = D[0, i], D[1, i], D[2, i]
        if weights is None:
            wx, wy, wz = dx, dy, dz
        else:
            wi = weights[i]
            wx, wy, wz = wi * dx, wi * dy, wi * dz
        for acc, a, b in ((axx, wx, dx), (ayy, wy, dy), (azz, wz, dz), (axy, wx, dy), (axz, wx, dz),
                          (ayz, wy, dz), (bx, wx, dc[i]), (by, wy, dc[i]), (bz, wz, dc[i])):
            if i == 0:
                np.multiply(a, b, out=acc)
            else:
                np.multiply(a, b, out=t)
                acc += t
    # A = Σ w (I − d dᵀ); b = Σ w (c − d (d·c))
    np.subtract(sw, axx, out=axx)
    np.subtract(sw, ayy, out=ayy)
    np.subtract(sw, azz, out=azz)
    np.negative(axy, out=axy)
    np.negative(axz, out=axz)
    np.negative(ayz, out=ayz)
    if bc is not None:
        np.subtract(bc[0], bx, out=bx)
        np.subtract(bc[1], by, out=by)
        np.subtract(bc[2], bz, out=bz)
    else:
        wc = centers.T @ weights  # (3, N)
        np.subtract(wc[0], bx, out=bx)
        np.subtract(wc[1], by, out=by)
        np.subtract(wc[2], bz, out=bz)
    inv, singular = inv_sym3_components(axx, ayy, azz, axy, axz, ayz)
    ixx, iyy, izz, ixy, ixz, iyz = inv
    px = ixx * bx
    px += ixy * by
    px += ixz * bz
    py = ixy * bx
    py += iyy * by
    py += iyz * bz
    pz = ixz * bx
    pz += iyz * by
    pz += izz * bz
    return (px, py, pz), (inv if with_inverse else None), singular


def _to_cameras(M: np.ndarray, p) -> np.ndarray:
    """The points ``p = (x, y, z)`` in every camera's frame: rows ``X_0, Y_0, Z_0, X_1, ...``.

    One matrix product ``[R_i | t_i] @ [p; 1]`` for all cameras (``M``, ``(3 n_cams, 4)``): a
    single pass over the points.
    """
    P = np.empty((4, p[0].shape[0]))
    P[0], P[1], P[2] = p
    P[3] = 1.0
    return M @ P


def _project_components(cam: Camera, p_cam):
    """Pixels ``u, v`` and depth ``Z`` of camera-frame points ``p_cam = (X, Y, Z)``."""
    Z = p_cam[2]
    inv_z = np.divide(1.0, Z)
    X = p_cam[0] * inv_z
    Y = p_cam[1] * inv_z
    d = cam._dist_full
    if np.any(d):
        X, Y = distortion.distort_components(X, Y, d)
    fx, fy, cx, cy = cam.params[:4]
    X *= fx
    X += cx
    Y *= fy
    Y += cy
    return X, Y, Z


def _add_residual(ru, rv, i, used, all_used, sigma_iso, W, rsum, chi2) -> None:
    """Add view ``i``'s residual ``(ru, rv)`` (observed − predicted, px) to ``Σ|r|²`` and χ²."""
    r2 = ru * ru
    r2 += rv * rv
    if W is None:
        term = r2 / (sigma_iso[i] * sigma_iso[i])
    else:
        term = W[0][i] * ru * ru
        term += 2.0 * W[1][i] * ru * rv
        term += W[2][i] * rv * rv
    if not all_used:
        unused = ~used[i]
        r2[unused] = 0.0
        term[unused] = 0.0
    rsum += r2
    chi2 += term


def _ray_angles_components(D: np.ndarray, used: np.ndarray, all_used: bool):
    """Smallest and largest angle between two used rays of each point (NaN below two rays)."""
    n_cams, n = used.shape
    cos_hi = np.full(n, np.nan)  # cosine of the smallest angle
    cos_lo = np.full(n, np.nan)  # cosine of the largest angle
    for i in range(n_cams):
        for j in range(i + 1, n_cams):
            c = D[0, i] * D[0, j]
            c += D[1, i] * D[1, j]
            c += D[2, i] * D[2, j]
            if not all_used:
                c[~(used[i] & used[j])] = np.nan
            np.fmax(cos_hi, c, out=cos_hi)  # fmax/fmin skip the NaNs of unused pairs
            np.fmin(cos_lo, c, out=cos_lo)
    np.clip(cos_hi, -1.0, 1.0, out=cos_hi)
    np.clip(cos_lo, -1.0, 1.0, out=cos_lo)
    return np.arccos(cos_hi, out=cos_hi), np.arccos(cos_lo, out=cos_lo)


def _behind_components(cams: Sequence[Camera], p, used: np.ndarray) -> np.ndarray:
    """Points ``p = (x, y, z)`` on or behind the image plane of any camera that uses them."""
    out = np.zeros(used.shape[1], bool)
    for i, cam in enumerate(cams):
        R, t = cam.cam_from_world.R, cam.cam_from_world.t
        z = R[2, 0] * p[0] + R[2, 1] * p[1] + R[2, 2] * p[2] + t[2]
        out |= used[i] & ~(z > 0.0)
    return out


def intersect_rays(centers: np.ndarray, dirs: np.ndarray, weights: np.ndarray, with_inverse: bool = True):
    """Weighted least-squares point nearest to several rays, batched over points.

    Parameters
    ----------
    centers : ndarray of shape (n_cams, 3)
        Ray origins (camera centres), world frame, metres.
    dirs : ndarray of shape (n_cams, N, 3)
        Unit directions, world frame; rows of unused views must be zero, not NaN.
    weights : ndarray of shape (n_cams, N)
        Non-negative weight of each ray (0 = unused), m⁻² for a metric normal matrix.

    Returns
    -------
    p_world : ndarray of shape (N, 3)
        Minimiser of ``Σ_i w_i |(I − d_i d_iᵀ)(p − c_i)|²``; NaN where singular.
    A_inv : ndarray of shape (N, 3, 3)
        Inverse of the normal matrix ``Σ_i w_i (I − d_i d_iᵀ)``: the point's covariance when
        the weights are inverse variances of the rays' perpendicular misses (m²).
        ``None`` when ``with_inverse`` is false.
    singular : ndarray of shape (N,), bool
        Where the rays do not determine a point (fewer than two, or parallel).
    """
    D = np.moveaxis(np.asarray(dirs, dtype=np.float64), 2, 0)
    centers = np.asarray(centers, dtype=np.float64)
    p, inv, singular = _nearest_point(D, _dot_centers(D, centers), centers, np.asarray(weights, np.float64),
                                      with_inverse)
    return np.stack(p, axis=1), (sym3_from_components(*inv) if with_inverse else None), singular


def _dot_centers(D: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """``d_i · c_i`` of shape ``(n_cams, N)`` for directions ``D`` ``(3, n_cams, N)``."""
    dc = D[0] * centers[:, 0:1]
    dc += D[1] * centers[:, 1:2]
    dc += D[2] * centers[:, 2:3]
    return dc


def _camera_list(rig) -> list[Camera]:
    cams = list(rig.cameras) if hasattr(rig, "cameras") else list(rig)
    if not cams or not all(isinstance(c, Camera) for c in cams):
        raise InputError("rig must be a Rig or a non-empty sequence of Camera objects")
    return cams


def _pixel_noise(sigma_px, cov_px, n_cams: int, n: int):
    """Validated pixel noise: ``(sigma (n_cams, N), None)`` or ``(None, cov (n_cams, N, 2, 2))``."""
    if cov_px is not None:
        cov = np.asarray(cov_px, dtype=np.float64)
        if cov.shape != (n_cams, n, 2, 2):
            raise ShapeError(f"cov_px must have shape ({n_cams}, {n}, 2, 2), got {cov.shape}")
        return None, cov
    sigma = np.asarray(1.0 if sigma_px is None else sigma_px, dtype=np.float64)
    if sigma.ndim == 0:
        sigma = np.broadcast_to(sigma, (n_cams, n))  # read-only view: no (n_cams, N) copy
    if sigma.shape != (n_cams, n):
        raise ShapeError(f"sigma_px must be a scalar or have shape ({n_cams}, {n}), got {sigma.shape}")
    return sigma, None


def _noise_from_cov(cov: np.ndarray):
    """Isotropic sigma and inverse-covariance components of a block of pixel covariances.

    Returns ``sigma (n_cams, n)`` (``sqrt(trace / 2)``, which weights the closed form; NaN
    where the covariance is not positive definite) and ``(W_uu, W_uv, W_vv)``, the components
    of ``Σ⁻¹`` as :func:`~scanrig.geometry.uncertainty.pixel_weights` computes them.
    """
    a, b, d = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    det = a * d
    det -= b * b
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv_det = np.divide(1.0, det)
        inv_det[~(det > 0.0)] = np.nan
        W = (d * inv_det, -b * inv_det, a * inv_det)
        ok = np.isfinite(W[0])
        ok &= np.isfinite(W[1])
        ok &= np.isfinite(W[2])
        sigma = a + d
        sigma *= 0.5
        np.sqrt(sigma, out=sigma)
    sigma[~ok] = np.nan
    return sigma, W


def _weights_array(sigma: np.ndarray, W) -> np.ndarray:
    """Inverse pixel covariances ``(n_cams, n, 2, 2)`` from :func:`_noise_from_cov`'s components,
    or ``I / σ²`` when ``W`` is None."""
    if W is None:
        return _isotropic_weights(sigma)
    out = np.empty(sigma.shape + (2, 2))
    out[..., 0, 0], out[..., 1, 1] = W[0], W[2]
    out[..., 0, 1] = out[..., 1, 0] = W[1]
    return out


def _isotropic_weights(sigma: np.ndarray) -> np.ndarray:
    """Weights ``I / σ²`` of shape ``(n_cams, N, 2, 2)``."""
    W = np.zeros(sigma.shape + (2, 2))
    with np.errstate(divide="ignore"):
        W[..., 0, 0] = W[..., 1, 1] = 1.0 / sigma**2
    return W


def _gauss_newton(cams, q, W, used, p, active):
    """Minimise ``Σ_i r_iᵀ W_i r_i`` over each point; returns the point, its projections and covariance."""
    n_cams, n = used.shape
    idx = np.flatnonzero(active)
    q_hat = np.full((n_cams, n, 2), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    if idx.size == 0:
        return p, q_hat, cov
    qa, Wa, ua = q[:, idx], W[:, idx], used[:, idx]
    Wz = np.where(ua[..., None, None], Wa, 0.0)
    pa = p[idx]
    for it in range(GN_ITERATIONS + 1):
        proj = [cam.project_with_point_jacobian(pa) for cam in cams]
        qh = np.stack([pr[0] for pr in proj])
        J = np.stack([pr[1] for pr in proj])
        H = information_matrix(J, Wa, ua)
        H_inv, _ = inv_sym3(H)
        if it == GN_ITERATIONS:
            break
        r = np.where(ua[..., None], qa - qh, 0.0)
        Jz = np.where(ua[..., None, None], J, 0.0)
        Wr = np.stack([Wz[..., j, 0] * r[..., 0] + Wz[..., j, 1] * r[..., 1] for j in range(2)], axis=-1)
        g = (Jz[..., 0, :] * Wr[..., 0:1] + Jz[..., 1, :] * Wr[..., 1:2]).sum(axis=0)
        pa = pa + np.einsum("nij,nj->ni", H_inv, g)
    p = p.copy()
    p[idx] = pa
    q_hat[:, idx] = qh
    cov[idx] = H_inv
    return p, q_hat, cov
