"""First-order propagation of pixel uncertainty into triangulated 3-D points.

A point seen by cameras ``i`` with pixel covariances ``Σ_i`` and projection Jacobians
``J_i = dq_i / dp_world`` (2×3) has the information matrix ``H = Σ_i J_iᵀ Σ_i⁻¹ J_i`` and, to
first order, the covariance ``H⁻¹`` (the Cramér–Rao bound of the least-squares estimate; the
same as mrcal's triangulation uncertainty without the calibration term).

Batches of symmetric 3×3 matrices are handled in closed form (adjugate inverse, trigonometric
eigenvalues) because ``numpy.linalg`` loops over LAPACK calls per matrix, which is ten times
slower for millions of tiny matrices.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scanrig.errors import InputError, ShapeError
from scanrig.geometry.camera import Camera
from scanrig.geometry.checks import check_points

#: Median absolute deviation -> standard deviation of Gaussian errors (1 / Φ⁻¹(3/4)): the robust
#: scale every estimator of the package uses.
MAD_TO_SIGMA = 1.4826
#: Relative determinant below which a symmetric 3×3 matrix counts as singular: the determinant
#: is compared with the cube of the mean diagonal, so the test does not depend on units.
SINGULAR_RTOL = 1e-12


def inv_sym3(A: np.ndarray):
    """Inverse of symmetric 3×3 matrices by the adjugate.

    Parameters
    ----------
    A : ndarray of shape (N, 3, 3)
        Symmetric matrices (only the upper triangle is read).

    Returns
    -------
    inv : ndarray of shape (N, 3, 3)
        Inverses; NaN where the matrix is singular.
    singular : ndarray of shape (N,), bool
        True where ``|det| <= SINGULAR_RTOL * (trace / 3)**3``.
    """
    upper = (A[:, 0, 0], A[:, 1, 1], A[:, 2, 2], A[:, 0, 1], A[:, 0, 2], A[:, 1, 2])
    inv, singular = inv_sym3_components(*upper)
    return sym3_from_components(*inv), singular


def inv_sym3_components(xx, yy, zz, xy, xz, yz):
    """Adjugate inverse of symmetric 3×3 matrices given as six ``(N,)`` component arrays.

    Returns the six components of the inverse in the same order (NaN where singular) and the
    ``(N,)`` singular mask of :func:`inv_sym3`.
    """
    # Written with in-place operations: this runs on millions of points (triangulation).
    c_xx = yy * zz
    t = yz * yz
    c_xx -= t
    c_xy = xz * yz
    np.multiply(xy, zz, out=t)
    c_xy -= t
    c_xz = xy * yz
    np.multiply(xz, yy, out=t)
    c_xz -= t
    c_yy = xx * zz
    np.multiply(xz, xz, out=t)
    c_yy -= t
    c_yz = xy * xz
    np.multiply(xx, yz, out=t)
    c_yz -= t
    c_zz = xx * yy
    np.multiply(xy, xy, out=t)
    c_zz -= t
    det = xx * c_xx
    np.multiply(xy, c_xy, out=t)
    det += t
    np.multiply(xz, c_xz, out=t)
    det += t
    scale = xx + yy
    scale += zz
    scale /= 3.0
    np.multiply(scale, scale, out=t)
    t *= scale  # (trace / 3)**3
    np.abs(t, out=t)
    t *= SINGULAR_RTOL
    singular = ~(np.abs(det) > t)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = np.divide(1.0, det, out=det)
    if singular.any():
        inv_det[singular] = np.nan
    for c in (c_xx, c_yy, c_zz, c_xy, c_xz, c_yz):
        c *= inv_det
    return (c_xx, c_yy, c_zz, c_xy, c_xz, c_yz), singular


def sym3_from_components(xx, yy, zz, xy, xz, yz) -> np.ndarray:
    """Assemble ``(N, 3, 3)`` symmetric matrices from six ``(N,)`` component arrays."""
    out = np.empty((np.shape(xx)[0], 3, 3))
    out[:, 0, 0], out[:, 1, 1], out[:, 2, 2] = xx, yy, zz
    out[:, 0, 1] = out[:, 1, 0] = xy
    out[:, 0, 2] = out[:, 2, 0] = xz
    out[:, 1, 2] = out[:, 2, 1] = yz
    return out


def max_eigenvalue_sym3(A: np.ndarray) -> np.ndarray:
    """Largest eigenvalue of symmetric 3×3 matrices (Smith 1961, trigonometric closed form).

    Parameters
    ----------
    A : ndarray of shape (N, 3, 3)
        Symmetric matrices.

    Returns
    -------
    ndarray of shape (N,)
        Largest eigenvalue; NaN where ``A`` has a NaN.
    """
    return max_eigenvalue_sym3_components(A[:, 0, 0], A[:, 1, 1], A[:, 2, 2], A[:, 0, 1], A[:, 0, 2], A[:, 1, 2])


def max_eigenvalue_sym3_components(xx, yy, zz, xy, xz, yz) -> np.ndarray:
    """:func:`max_eigenvalue_sym3` of symmetric matrices given as six ``(N,)`` component arrays."""
    q = xx + yy
    q += zz
    q /= 3.0
    b00, b11, b22 = xx - q, yy - q, zz - q
    p = b00 * b00
    t = b11 * b11
    p += t
    np.multiply(b22, b22, out=t)
    p += t
    for c in (xy, xz, yz):  # + 2 × the squared off-diagonal
        np.multiply(c, c, out=t)
        t += t
        p += t
    p /= 6.0
    np.sqrt(p, out=p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_p = np.divide(1.0, p)
        b00 *= inv_p
        b11 *= inv_p
        b22 *= inv_p
        b01, b02, b12 = xy * inv_p, xz * inv_p, yz * inv_p
        # det(B) = b00 (b11 b22 − b12²) − b01 (b01 b22 − b12 b02) + b02 (b01 b12 − b11 b02)
        det_b = b11 * b22
        np.multiply(b12, b12, out=t)
        det_b -= t
        det_b *= b00
        u = b01 * b22
        np.multiply(b12, b02, out=t)
        u -= t
        u *= b01
        det_b -= u
        np.multiply(b01, b12, out=u)
        np.multiply(b11, b02, out=t)
        u -= t
        u *= b02
        det_b += u
        det_b *= 0.5
        np.clip(det_b, -1.0, 1.0, out=det_b)
        phi = np.arccos(det_b, out=det_b)
    phi /= 3.0
    np.cos(phi, out=phi)
    phi *= p
    phi += phi
    phi += q  # q + 2 p cos(phi)
    # p == 0 means A = q I (all eigenvalues equal); B is NaN there.
    return np.where(p > 0.0, phi, q)


def sigma_from_covariance(cov: np.ndarray) -> np.ndarray:
    """Standard deviation along the largest axis of 3-D covariances.

    Parameters
    ----------
    cov : ndarray of shape (N, 3, 3)
        Covariances, m².

    Returns
    -------
    ndarray of shape (N,)
        ``sqrt(largest eigenvalue)``, metres (the ``sigma`` field of ``points.ply``).
    """
    return np.sqrt(np.maximum(max_eigenvalue_sym3(cov), 0.0))


def pixel_weights(cov_px: np.ndarray) -> np.ndarray:
    """Inverse pixel covariances ``Σ⁻¹`` of shape ``(..., 2, 2)`` (px⁻²); NaN where singular."""
    a, b, d = cov_px[..., 0, 0], cov_px[..., 0, 1], cov_px[..., 1, 1]
    det = a * d - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = np.where(det > 0.0, 1.0 / det, np.nan)
    W = np.empty_like(cov_px)
    W[..., 0, 0] = d * inv_det
    W[..., 1, 1] = a * inv_det
    W[..., 0, 1] = W[..., 1, 0] = -b * inv_det
    return W


def information_matrix(J_point: np.ndarray, W_px: np.ndarray, used: np.ndarray) -> np.ndarray:
    """Sum of the views' Fisher information ``Σ_i J_iᵀ W_i J_i``.

    Parameters
    ----------
    J_point : ndarray of shape (n_cams, N, 2, 3)
        ``dq / dp_world`` per view, px/m.
    W_px : ndarray of shape (n_cams, N, 2, 2)
        Inverse pixel covariances, px⁻².
    used : ndarray of shape (n_cams, N), bool
        Views that take part; the others contribute nothing (their NaNs are ignored).

    Returns
    -------
    ndarray of shape (N, 3, 3)
        Information matrix, m⁻².
    """
    J = np.where(used[..., None, None], J_point, 0.0)
    W = np.where(used[..., None, None], W_px, 0.0)
    # Explicit products over the 2x3 blocks: einsum on (n_cams, N, 2, 3) operands is several
    # times slower than these whole-array multiply-adds.
    WJ = [[W[..., r, 0] * J[..., 0, k] + W[..., r, 1] * J[..., 1, k] for k in range(3)] for r in range(2)]
    H = np.empty((J.shape[1], 3, 3))
    for i in range(3):
        for k in range(i, 3):
            H[:, i, k] = H[:, k, i] = (J[..., 0, i] * WJ[0][k] + J[..., 1, i] * WJ[1][k]).sum(axis=0)
    return H


def point_covariance(
    cameras: Sequence[Camera],
    p_world,
    sigma_px=1.0,
    visible: np.ndarray | None = None,
) -> np.ndarray:
    """First-order covariance of points triangulated from the cameras that see them.

    Parameters
    ----------
    cameras : sequence of Camera
        The cameras (a :class:`~scanrig.geometry.rig.Rig`'s ``.cameras`` or any list).
    p_world : array_like of shape (N, 3)
        Points, world frame, metres.
    sigma_px : float or array_like of shape (n_cams, N)
        Isotropic 1-σ pixel noise of each view, pixels.
    visible : ndarray of shape (n_cams, N), bool, optional
        Which cameras observe each point. Default: the point is in front of the camera and
        projects inside its image.

    Returns
    -------
    ndarray of shape (N, 3, 3)
        Covariance, m², world frame; NaN where fewer than two views or the geometry is
        degenerate (parallel rays).
    """
    p = check_points(p_world, 3, "p_world")
    cameras = list(cameras)
    if not cameras:
        raise InputError("cameras must contain at least one Camera")
    n_cams, n = len(cameras), p.shape[0]
    sigma = np.asarray(sigma_px, dtype=np.float64)
    if sigma.ndim == 0:
        sigma = np.full((n_cams, n), float(sigma))
    if sigma.shape != (n_cams, n):
        raise ShapeError(f"sigma_px must be a scalar or have shape ({n_cams}, {n}), got {sigma.shape}")
    q = np.empty((n_cams, n, 2))
    J = np.empty((n_cams, n, 2, 3))
    for i, cam in enumerate(cameras):
        q[i], J[i] = cam.project_with_point_jacobian(p)
    if visible is None:
        sizes = np.array([[cam.width, cam.height] for cam in cameras], dtype=np.float64)
        inside = (q >= -0.5) & (q <= sizes[:, None, :] - 0.5)
        visible = np.all(inside, axis=2)
    elif np.shape(visible) != (n_cams, n):
        raise ShapeError(f"visible must have shape ({n_cams}, {n}), got {np.shape(visible)}")
    used = np.asarray(visible, bool) & np.all(np.isfinite(J), axis=(2, 3)) & (sigma > 0)
    W = np.zeros((n_cams, n, 2, 2))
    W[..., 0, 0] = W[..., 1, 1] = np.where(used, 1.0 / np.where(used, sigma, 1.0) ** 2, 0.0)
    cov, singular = inv_sym3(information_matrix(J, W, used))
    cov[(used.sum(axis=0) < 2) | singular] = np.nan
    return cov
