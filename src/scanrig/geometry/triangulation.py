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
from scanrig.geometry.camera import Camera
from scanrig.geometry.uncertainty import (
    information_matrix,
    inv_sym3,
    inv_sym3_components,
    pixel_weights,
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
    sigma_iso, W = _pixel_noise(sigma_px, cov_px, n_cams, n)
    if dirs is not None and np.shape(dirs) != (n_cams, n, 3):
        raise ShapeError(f"dirs must have shape ({n_cams}, {n}, 3), got {np.shape(dirs)}")
    parts = []
    for start in range(0, max(n, 1), CHUNK_POINTS):
        s = slice(start, start + CHUNK_POINTS)
        parts.append(_triangulate_chunk(
            cams, q[:, s], sigma_iso[:, s], None if W is None else W[:, s],
            None if dirs is None else dirs[:, s], refine, min_angle_rad,
        ))
    p = np.concatenate([part[0] for part in parts])
    fields = {
        name: np.concatenate([getattr(part[1], name) for part in parts], axis=1 if name == "used" else 0)
        for name in TriangulationInfo.__dataclass_fields__
    }
    return p, TriangulationInfo(**fields)


def _triangulate_chunk(cams, q, sigma_iso, W, dirs, refine, min_angle_rad):
    """:func:`triangulate` on a block of points (arguments already validated)."""
    n_cams, n = q.shape[:2]
    used = np.all(np.isfinite(q), axis=2) & np.isfinite(sigma_iso) & (sigma_iso > 0)
    if dirs is None:
        dirs = np.full((n_cams, n, 3), np.nan)
        for i, cam in enumerate(cams):
            _, dirs[i, used[i]] = cam.rays(q[i, used[i]])
    used &= np.all(np.isfinite(dirs), axis=2)
    dirs = np.where(used[..., None], dirs, 0.0)
    centers = np.array([cam.center_world for cam in cams])
    focal = np.array([np.sqrt(cam.params[0] * cam.params[1]) for cam in cams])

    p, _, _ = intersect_rays(centers, dirs, used.astype(np.float64), with_inverse=False)
    ranges = np.einsum("cni,cni->cn", p[None] - centers[:, None, :], dirs)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = (focal[:, None] / (sigma_iso * ranges)) ** 2
    w = np.where(used & np.isfinite(w), w, 0.0)
    p, cov_p, singular = intersect_rays(centers, dirs, w)

    n_views = used.sum(axis=0)
    min_angle, max_angle = _ray_angles(dirs, used)
    reason = np.zeros(n, np.uint8)
    reason[singular | ~(max_angle >= min_angle_rad)] = Reason.PARALLEL
    reason[n_views < 2] = Reason.FEW_VIEWS
    reason[(reason == 0) & _behind(cams, p, used)] = Reason.BEHIND
    good = reason == 0

    if refine:
        if W is None:
            W = _isotropic_weights(sigma_iso)
        p[~good] = np.nan
        p, q_hat, cov_p = _gauss_newton(cams, q, W, used, p, good)
        diverged = good & ~np.all(np.isfinite(p), axis=1)
        reason[diverged] = Reason.DIVERGED
        reason[good & ~diverged & _behind(cams, p, used)] = Reason.BEHIND
    else:
        q_hat = np.stack([cam.project(p) for cam in cams])
    good = reason == 0
    r = np.where(used[..., None], q - q_hat, 0.0)
    r2 = r[..., 0] ** 2 + r[..., 1] ** 2
    if W is None:
        chi2 = np.sum(np.where(used, r2 / sigma_iso**2, 0.0), axis=0)
    else:
        Wz = np.where(used[..., None, None], W, 0.0)
        chi2 = np.sum(Wz[..., 0, 0] * r[..., 0] ** 2 + 2.0 * Wz[..., 0, 1] * r[..., 0] * r[..., 1]
                      + Wz[..., 1, 1] * r[..., 1] ** 2, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        residual_px = np.sqrt(r2.sum(axis=0) / n_views)

    p[~good] = np.nan
    cov_p[~good] = np.nan
    residual_px[~good] = np.nan
    chi2[~good] = np.nan
    info = TriangulationInfo(
        cov=cov_p,
        sigma=sigma_from_covariance(cov_p),
        residual_px=residual_px,
        chi2=chi2,
        n_views=n_views.astype(np.uint8),
        min_angle_rad=min_angle,
        max_angle_rad=max_angle,
        reason=reason,
        used=used,
    )
    return p, info


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
    # Component arithmetic on (n_cams, N) arrays; einsum over (N, 3, 3) is several times slower.
    dx, dy, dz = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    wx, wy, wz = weights * dx, weights * dy, weights * dz
    sw = weights.sum(axis=0)
    A = (sw - (wx * dx).sum(0), sw - (wy * dy).sum(0), sw - (wz * dz).sum(0),
         -(wx * dy).sum(0), -(wx * dz).sum(0), -(wy * dz).sum(0))
    # b = Σ w (c − d (d·c))
    dc = dx * centers[:, 0:1] + dy * centers[:, 1:2] + dz * centers[:, 2:3]
    b = weights.T @ centers - np.stack([(wx * dc).sum(0), (wy * dc).sum(0), (wz * dc).sum(0)], axis=1)
    (ixx, iyy, izz, ixy, ixz, iyz), singular = inv_sym3_components(*A)
    p = np.stack([ixx * b[:, 0] + ixy * b[:, 1] + ixz * b[:, 2],
                  ixy * b[:, 0] + iyy * b[:, 1] + iyz * b[:, 2],
                  ixz * b[:, 0] + iyz * b[:, 1] + izz * b[:, 2]], axis=1)
    A_inv = sym3_from_components(ixx, iyy, izz, ixy, ixz, iyz) if with_inverse else None
    return p, A_inv, singular


def _camera_list(rig) -> list[Camera]:
    cams = list(rig.cameras) if hasattr(rig, "cameras") else list(rig)
    if not cams or not all(isinstance(c, Camera) for c in cams):
        raise InputError("rig must be a Rig or a non-empty sequence of Camera objects")
    return cams


def _pixel_noise(sigma_px, cov_px, n_cams: int, n: int):
    """Isotropic sigma ``(n_cams, N)`` px and, for full covariances, weights ``(n_cams, N, 2, 2)``.

    The isotropic sigma of a full covariance is ``sqrt(trace / 2)``; it weights the closed form.
    """
    if cov_px is not None:
        cov = np.asarray(cov_px, dtype=np.float64)
        if cov.shape != (n_cams, n, 2, 2):
            raise ShapeError(f"cov_px must have shape ({n_cams}, {n}, 2, 2), got {cov.shape}")
        W = pixel_weights(cov)
        sigma = np.sqrt(0.5 * (cov[..., 0, 0] + cov[..., 1, 1]))
        return np.where(np.all(np.isfinite(W), axis=(2, 3)), sigma, np.nan), W
    sigma = np.asarray(1.0 if sigma_px is None else sigma_px, dtype=np.float64)
    if sigma.ndim == 0:
        sigma = np.full((n_cams, n), float(sigma))
    if sigma.shape != (n_cams, n):
        raise ShapeError(f"sigma_px must be a scalar or have shape ({n_cams}, {n}), got {sigma.shape}")
    return sigma, None


def _isotropic_weights(sigma: np.ndarray) -> np.ndarray:
    """Weights ``I / σ²`` of shape ``(n_cams, N, 2, 2)``."""
    W = np.zeros(sigma.shape + (2, 2))
    with np.errstate(divide="ignore"):
        W[..., 0, 0] = W[..., 1, 1] = 1.0 / sigma**2
    return W


def _ray_angles(dirs: np.ndarray, used: np.ndarray):
    """Smallest and largest angle between two used rays of each point (NaN below two rays)."""
    n_cams, n = used.shape
    cos_hi = np.full(n, -np.inf)  # cosine of the smallest angle
    cos_lo = np.full(n, np.inf)  # cosine of the largest angle
    for i in range(n_cams):
        for j in range(i + 1, n_cams):
            both = used[i] & used[j]
            c = dirs[i, :, 0] * dirs[j, :, 0] + dirs[i, :, 1] * dirs[j, :, 1] + dirs[i, :, 2] * dirs[j, :, 2]
            cos_hi = np.where(both, np.maximum(cos_hi, c), cos_hi)
            cos_lo = np.where(both, np.minimum(cos_lo, c), cos_lo)
    with np.errstate(invalid="ignore"):
        lo = np.arccos(np.clip(np.where(np.isfinite(cos_hi), cos_hi, np.nan), -1.0, 1.0))
        hi = np.arccos(np.clip(np.where(np.isfinite(cos_lo), cos_lo, np.nan), -1.0, 1.0))
    return lo, hi


def _behind(cams: Sequence[Camera], p: np.ndarray, used: np.ndarray) -> np.ndarray:
    """Points on or behind the image plane of any camera that uses them."""
    out = np.zeros(p.shape[0], bool)
    for i, cam in enumerate(cams):
        pose = cam.cam_from_world
        z = p @ pose.R[2] + pose.t[2]
        out |= used[i] & ~(z > 0.0)
    return out


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
