"""Brown–Conrady lens distortion exactly as OpenCV defines it, as pure functions.

Coordinates are normalised image coordinates ``x = X / Z, y = Y / Z`` in the camera frame. With
``r2 = x**2 + y**2`` the distorted coordinates are::

    radial = (1 + k1 r2 + k2 r2**2 + k3 r2**3) / (1 + k4 r2 + k5 r2**2 + k6 r2**3)
    xd = x radial + 2 p1 x y + p2 (r2 + 2 x**2) + s1 r2 + s2 r2**2
    yd = y radial + p1 (r2 + 2 y**2) + 2 p2 x y + s3 r2 + s4 r2**2

Every function takes the full 12-vector ``(k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4)``
(OpenCV's order, shorter models padded with zeros by :func:`pad_coefficients`). OpenCV's tilted
sensor model (``tau_x, tau_y``, the 14-coefficient variant) is not supported.
"""

from __future__ import annotations

import functools

import numpy as np

from scanrig.errors import InputError

#: Distortion coefficient names of each model, in OpenCV's order (mrcal's LENSMODEL_OPENCVn).
MODEL_COEFFICIENTS: dict[str, tuple[str, ...]] = {
    "pinhole": (),
    "opencv4": ("k1", "k2", "p1", "p2"),
    "opencv5": ("k1", "k2", "p1", "p2", "k3"),
    "opencv8": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "opencv12": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4"),
}

N_FULL = 12

#: Plain Newton iterations tried on every point; quadratic convergence needs 3-6 away from a fold.
UNDISTORT_FAST_ITER = 8
#: Damped Newton iterations allowed for the points the fast path leaves (near a fold).
UNDISTORT_MAX_ITER = 40
#: Residual (normalised units) at which undistortion has converged: 1e-12 is ~1e-9 px at f = 1000 px.
UNDISTORT_TOL = 1e-12
#: Points sampled on the segment from the optical axis to a solution to check that the
#: distortion map is one-to-one there (positive Jacobian determinant all the way).
FOLD_CHECK_SAMPLES = 16


def model_from_n_coefficients(n: int) -> str:
    """Name of the OpenCV model with ``n`` distortion coefficients (0, 4, 5, 8 or 12)."""
    for name, coeffs in MODEL_COEFFICIENTS.items():
        if len(coeffs) == n:
            return name
    raise InputError(
        f"dist must have 0, 4, 5, 8 or 12 coefficients (OpenCV order; the 14-coefficient tilt "
        f"model is not supported), got {n}"
    )


def pad_coefficients(coeffs: np.ndarray) -> np.ndarray:
    """Pad a model's coefficients ``(n,)`` with zeros to the full ``(12,)`` vector."""
    full = np.zeros(N_FULL)
    full[: len(coeffs)] = coeffs
    return full


def _radial_terms(r2: np.ndarray, d: np.ndarray):
    """Numerator, denominator and their derivatives with respect to ``r2``."""
    k1, k2, p1, p2, k3, k4, k5, k6 = d[:8]
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)
    if k4 == 0.0 and k5 == 0.0 and k6 == 0.0:
        return num, np.ones_like(r2), dnum, 0.0
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    dden = k4 + r2 * (2.0 * k5 + 3.0 * r2 * k6)
    return num, den, dnum, dden


def distort(xy: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Apply distortion to normalised coordinates.

    Parameters
    ----------
    xy : ndarray of shape (N, 2)
        Undistorted normalised coordinates.
    d : ndarray of shape (12,)
        Full coefficient vector.

    Returns
    -------
    ndarray of shape (N, 2)
        Distorted normalised coordinates.
    """
    x, y = xy[:, 0], xy[:, 1]
    p1, p2 = d[2], d[3]
    s1, s2, s3, s4 = d[8:12]
    r2 = x * x + y * y
    k4, k5, k6 = d[5:8]
    radial = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))
    if k4 or k5 or k6:
        radial /= 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    xy2 = 2.0 * x * y
    out = np.empty_like(xy)
    out[:, 0] = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    out[:, 1] = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    if s1 or s2 or s3 or s4:
        out[:, 0] += r2 * (s1 + s2 * r2)
        out[:, 1] += r2 * (s3 + s4 * r2)
    return out


def _distort_and_jacobian_xy(x: np.ndarray, y: np.ndarray, d: np.ndarray):
    """Distorted coordinates and the four entries of ``d xy_d / d xy`` as arrays.

    Shared by the Newton solve, the fold check and :func:`distort_with_jacobians`; kept free of
    the (N, 2, 12) coefficient Jacobian, and skipping the rational and thin-prism terms when
    their coefficients are zero, because it is the hot loop of undistortion.

    Returns
    -------
    xd, yd, j00, j01, j10, j11, r2, den : ndarray
        Same shape as ``x``; ``den`` is the rational denominator (1 without k4..k6).
    """
    k1, k2, p1, p2, k3, k4, k5, k6 = d[:8]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)
    den = 1.0
    if k4 or k5 or k6:
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        dden = k4 + r2 * (2.0 * k5 + 3.0 * r2 * k6)
        dradial = (dradial * den - radial * dden) / (den * den)
        radial = radial / den
    two_dradial = 2.0 * dradial
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    j00 = radial + two_dradial * x * x + 2.0 * (p1 * y + 3.0 * p2 * x)
    j01 = two_dradial * x * y + 2.0 * (p1 * x + p2 * y)
    j11 = radial + two_dradial * y * y + 2.0 * (3.0 * p1 * y + p2 * x)
    j10 = j01
    s1, s2, s3, s4 = d[8:12]
    if s1 or s2 or s3 or s4:
        ds_x = 2.0 * (s1 + 2.0 * s2 * r2)  # d(s1 r2 + s2 r4)/d r2, times d r2/d x / x
        ds_y = 2.0 * (s3 + 2.0 * s4 * r2)
        xd = xd + r2 * (s1 + s2 * r2)
        yd = yd + r2 * (s3 + s4 * r2)
        j00 = j00 + ds_x * x
        j01 = j01 + ds_x * y
        j10 = j10 + ds_y * x
        j11 = j11 + ds_y * y
    return xd, yd, j00, j01, j10, j11, r2, den


def distort_with_point_jacobian(xy: np.ndarray, d: np.ndarray):
    """Distortion and ``d xy_d / d xy`` only: ``(N, 2)``, ``(N, 2, 2)`` (see :func:`distort_with_jacobians`)."""
    xd, yd, j00, j01, j10, j11, _, _ = _distort_and_jacobian_xy(xy[:, 0], xy[:, 1], d)
    J_xy = np.empty(xy.shape[:1] + (2, 2))
    J_xy[:, 0, 0], J_xy[:, 0, 1], J_xy[:, 1, 0], J_xy[:, 1, 1] = j00, j01, j10, j11
    return np.stack([xd, yd], axis=1), J_xy


def distort_with_jacobians(xy: np.ndarray, d: np.ndarray):
    """Distortion and its analytic derivatives.

    Parameters
    ----------
    xy : ndarray of shape (N, 2)
        Undistorted normalised coordinates.
    d : ndarray of shape (12,)
        Full coefficient vector.

    Returns
    -------
    xy_d : ndarray of shape (N, 2)
        Distorted normalised coordinates.
    J_xy : ndarray of shape (N, 2, 2)
        ``d xy_d / d xy``.
    J_d : ndarray of shape (N, 2, 12)
        ``d xy_d / d coefficients`` in the full order.
    """
    x, y = xy[:, 0], xy[:, 1]
    xy_d, J_xy = distort_with_point_jacobian(xy, d)
    r2 = x * x + y * y
    den = 1.0 + r2 * (d[5] + r2 * (d[6] + r2 * d[7]))
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))) / den
    J_d = np.zeros(xy.shape[:1] + (2, N_FULL))
    for col, power in ((0, r2), (1, r4), (4, r6)):  # k1, k2, k3 act on the numerator
        J_d[:, 0, col] = x * power / den
        J_d[:, 1, col] = y * power / den
    for col, power in ((5, r2), (6, r4), (7, r6)):  # k4, k5, k6 act on the denominator
        J_d[:, 0, col] = -x * radial * power / den
        J_d[:, 1, col] = -y * radial * power / den
    J_d[:, 0, 2], J_d[:, 1, 2] = 2.0 * x * y, r2 + 2.0 * y * y
    J_d[:, 0, 3], J_d[:, 1, 3] = r2 + 2.0 * x * x, 2.0 * x * y
    J_d[:, 0, 8], J_d[:, 0, 9] = r2, r4
    J_d[:, 1, 10], J_d[:, 1, 11] = r2, r4
    return xy_d, J_xy, J_d


def undistort(xy_d: np.ndarray, d: np.ndarray):
    """Invert the distortion by Newton's method, vectorised over points.

    The solve starts at the distorted coordinates and takes Newton steps with the analytic 2x2
    Jacobian; points that have not converged after :data:`UNDISTORT_FAST_ITER` plain steps are
    restarted with capped steps that are halved whenever they would increase the residual. A point counts as
    converged when the residual falls below :data:`UNDISTORT_TOL` *and* the distortion map is
    one-to-one between the optical axis and the solution (positive Jacobian determinant at
    :data:`FOLD_CHECK_SAMPLES` points along that segment). Beyond the fold of a strongly
    distorting lens a pixel has no preimage, or one on the far side of the fold that the lens
    cannot physically image; both are reported as not converged.

    Parameters
    ----------
    xy_d : ndarray of shape (N, 2)
        Distorted normalised coordinates.
    d : ndarray of shape (12,)
        Full coefficient vector.

    Returns
    -------
    xy : ndarray of shape (N, 2)
        Undistorted normalised coordinates, NaN where not converged.
    converged : ndarray of shape (N,), bool
        Per-point convergence flag.
    """
    n = xy_d.shape[0]
    finite = np.all(np.isfinite(xy_d), axis=1)
    if not np.any(d):  # a pinhole camera: nothing to invert
        return np.where(finite[:, None], xy_d, np.nan), finite
    xy = np.where(finite[:, None], xy_d, 0.0)
    # Start from one fixed-point step of the radial part: saves a Newton iteration.
    r2 = np.einsum("ij,ij->i", xy, xy)
    start = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))
    xy /= np.where(start > 0.1, start, 1.0)[:, None]
    converged = np.zeros(n, bool)
    # Fast path: plain Newton on every point, evaluating the distortion and its Jacobian once per
    # iteration on contiguous 1-D arrays; nearly all points converge here in two or three steps.
    active = np.flatnonzero(finite)
    x, y = xy[active, 0], xy[active, 1]
    tx, ty = xy_d[active, 0], xy_d[active, 1]
    for _ in range(UNDISTORT_FAST_ITER):
        if active.size == 0:
            break
        xd, yd, j00, j01, j10, j11, _, _ = _distort_and_jacobian_xy(x, y, d)
        r0, r1 = xd - tx, yd - ty
        done = r0 * r0 + r1 * r1 <= UNDISTORT_TOL**2
        if done.any():
            xy[active[done], 0], xy[active[done], 1] = x[done], y[done]
            converged[active[done]] = True
            todo = ~done
            active = active[todo]
            x, y, tx, ty, j00, j01, j10, j11, r0, r1 = (
                a[todo] for a in (x, y, tx, ty, j00, j01, j10, j11, r0, r1))
        det = j00 * j11 - j01 * j10
        det[np.abs(det) < 1e-300] = 1e-300
        x = x - (j11 * r0 - j01 * r1) / det
        y = y - (j00 * r1 - j10 * r0) / det
    # Robust path for the rest (strong distortion, near a fold): restart from the distorted
    # coordinates with capped, backtracking Newton steps.
    if active.size:
        xy[active] = xy_d[active]
        converged[active] = _undistort_backtracking(xy, xy_d, d, active)
    converged &= one_to_one_to_axis(xy, d, converged)
    xy[~converged] = np.nan
    return xy, converged


def _undistort_backtracking(xy: np.ndarray, xy_d: np.ndarray, d: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Damped Newton on the points ``active`` of ``xy`` (updated in place); returns their flags."""
    res_norm = np.full(xy.shape[0], np.inf)
    res_norm[active] = _residual_norm(xy[active], xy_d[active], d)
    stalled = np.zeros(xy.shape[0], bool)
    for _ in range(UNDISTORT_MAX_ITER):
        idx = active[(res_norm[active] > UNDISTORT_TOL) & ~stalled[active]]
        if idx.size == 0:
            break
        cur = xy[idx]
        xd, yd, j00, j01, j10, j11, _, _ = _distort_and_jacobian_xy(cur[:, 0], cur[:, 1], d)
        step = _solve2(j00, j01, j10, j11, xd - xy_d[idx, 0], yd - xy_d[idx, 1])
        # Cap a step at the current radius plus one: near a fold a Newton step can jump far off.
        limit = 1.0 + np.hypot(cur[:, 0], cur[:, 1])
        step *= np.minimum(1.0, limit / np.maximum(np.hypot(step[:, 0], step[:, 1]), 1e-300))[:, None]
        for _halving in range(8):  # backtracking: accept the first step that lowers the residual
            trial = cur - step
            trial_norm = _residual_norm(trial, xy_d[idx], d)
            better = trial_norm < res_norm[idx]
            xy[idx[better]] = trial[better]
            res_norm[idx[better]] = trial_norm[better]
            idx, cur, step = idx[~better], cur[~better], 0.5 * step[~better]
            if idx.size == 0:
                break
        stalled[idx] = True
    return res_norm[active] <= UNDISTORT_TOL


def _residual_norm(xy: np.ndarray, xy_d: np.ndarray, d: np.ndarray) -> np.ndarray:
    res = distort(xy, d) - xy_d
    return np.hypot(res[:, 0], res[:, 1])


def _solve2(j00, j01, j10, j11, r0, r1) -> np.ndarray:
    """Solve the 2x2 systems ``J @ s = r`` element-wise (Cramer's rule); returns (N, 2)."""
    det = j00 * j11 - j01 * j10
    det = np.where(np.abs(det) < 1e-300, 1e-300, det)
    return np.stack([(j11 * r0 - j01 * r1) / det, (j00 * r1 - j10 * r0) / det], axis=1)


def one_to_one_to_axis(xy: np.ndarray, d: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Whether the distortion Jacobian stays positive on the segment from the axis to each point.

    Points inside the lens's one-to-one radius (:func:`one_to_one_radius`) pass without work;
    the others are checked at :data:`FOLD_CHECK_SAMPLES` points along their segment.

    Parameters
    ----------
    xy : ndarray of shape (N, 2)
        Undistorted normalised coordinates.
    d : ndarray of shape (12,)
        Full coefficient vector.
    mask : ndarray of shape (N,), bool
        Points to check; the others are returned as False.

    Returns
    -------
    ndarray of shape (N,), bool
    """
    ok = mask.copy()
    r_safe = one_to_one_radius(tuple(float(c) for c in d))
    idx = np.flatnonzero(mask)
    idx = idx[np.hypot(xy[idx, 0], xy[idx, 1]) >= r_safe]
    if idx.size == 0:
        return ok
    fractions = np.linspace(1.0 / FOLD_CHECK_SAMPLES, 1.0, FOLD_CHECK_SAMPLES)
    samples = fractions[:, None, None] * xy[idx][None, :, :]
    _, _, j00, j01, j10, j11, _, _ = _distort_and_jacobian_xy(samples[..., 0], samples[..., 1], d)
    ok[idx] = ((j00 * j11 - j01 * j10) > 0.0).all(axis=0)
    return ok


#: Polar grid on which :func:`one_to_one_radius` searches for the nearest fold.
_FOLD_GRID_ANGLES = 360
_FOLD_GRID_RADII = np.linspace(0.0, 4.0, 1001)[1:]
#: Fraction of the nearest fold radius found on the grid that is trusted without a check; the
#: Jacobian determinant is smooth, so 2 % covers what falls between the grid's rays and radii.
_FOLD_SAFETY = 0.98


@functools.lru_cache(maxsize=64)
def one_to_one_radius(d: tuple[float, ...]) -> float:
    """Normalised radius within which the distortion map is one-to-one in every direction.

    The smallest radius, over 360 directions and radii 0.004 apart, at which the Jacobian determinant first turns
    non-positive (searched out to r = 4, i.e. 76° off axis), times a 2 % safety margin. Cached per
    coefficient vector: a camera computes it once.
    """
    d_arr = np.asarray(d)
    if not np.any(d_arr):
        return np.inf
    angles = np.linspace(0.0, 2.0 * np.pi, _FOLD_GRID_ANGLES, endpoint=False)
    x = np.cos(angles)[:, None] * _FOLD_GRID_RADII[None, :]
    y = np.sin(angles)[:, None] * _FOLD_GRID_RADII[None, :]
    _, _, j00, j01, j10, j11, _, _ = _distort_and_jacobian_xy(x, y, d_arr)
    bad = (j00 * j11 - j01 * j10) <= 0.0
    if not bad.any():
        return _FOLD_GRID_RADII[-1] * _FOLD_SAFETY
    first_bad = np.where(bad.any(axis=1), bad.argmax(axis=1), len(_FOLD_GRID_RADII) - 1)
    return float(_FOLD_GRID_RADII[first_bad].min() * _FOLD_SAFETY)
