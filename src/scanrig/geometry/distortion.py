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

#: Newton iterations allowed when undistorting; quadratic convergence needs 4-6 away from a fold.
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
    p1, p2 = d[2], d[3]
    s1, s2, s3, s4 = d[8:12]
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    num, den, dnum, dden = _radial_terms(r2, d)
    radial = num / den
    dradial = (dnum * den - num * dden) / (den * den)
    ds_x = s1 + 2.0 * s2 * r2  # d(s1 r2 + s2 r4)/d r2
    ds_y = s3 + 2.0 * s4 * r2

    xy_d = np.empty_like(xy)
    xy_d[:, 0] = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + r2 * (s1 + s2 * r2)
    xy_d[:, 1] = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + r2 * (s3 + s4 * r2)

    J_xy = np.empty(xy.shape[:1] + (2, 2))
    J_xy[:, 0, 0] = radial + 2.0 * x * (x * dradial + ds_x) + 2.0 * p1 * y + 6.0 * p2 * x
    J_xy[:, 0, 1] = 2.0 * y * (x * dradial + ds_x) + 2.0 * p1 * x + 2.0 * p2 * y
    J_xy[:, 1, 0] = 2.0 * x * (y * dradial + ds_y) + 2.0 * p1 * x + 2.0 * p2 * y
    J_xy[:, 1, 1] = radial + 2.0 * y * (y * dradial + ds_y) + 6.0 * p1 * y + 2.0 * p2 * x

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


def _det2(J: np.ndarray) -> np.ndarray:
    return J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]


def undistort(xy_d: np.ndarray, d: np.ndarray):
    """Invert the distortion by a damped Newton solve, vectorised over points.

    The solve starts at the distorted coordinates, takes Newton steps with the analytic 2x2
    Jacobian and halves a step whenever it would increase the residual. A point counts as
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
    xy = np.where(finite[:, None], xy_d, 0.0)
    res_norm = np.full(n, np.inf)
    res_norm[finite] = _residual_norm(xy[finite], xy_d[finite], d)
    stalled = ~finite
    for _ in range(UNDISTORT_MAX_ITER):
        idx = np.flatnonzero((res_norm > UNDISTORT_TOL) & ~stalled)
        if idx.size == 0:
            break
        cur = xy[idx]
        xy_now, J, _ = distort_with_jacobians(cur, d)
        step = _solve2(J, xy_now - xy_d[idx])
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
    converged = (res_norm <= UNDISTORT_TOL) & finite
    converged &= one_to_one_to_axis(xy, d, converged)
    xy[~converged] = np.nan
    return xy, converged


def _residual_norm(xy: np.ndarray, xy_d: np.ndarray, d: np.ndarray) -> np.ndarray:
    res = distort(xy, d) - xy_d
    return np.hypot(res[:, 0], res[:, 1])


def _solve2(J: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Solve the 2x2 systems ``J @ s = r`` row by row (Cramer's rule), shapes (N,2,2), (N,2)."""
    det = _det2(J)
    det = np.where(np.abs(det) < 1e-300, 1e-300, det)
    s = np.empty_like(r)
    s[:, 0] = (J[:, 1, 1] * r[:, 0] - J[:, 0, 1] * r[:, 1]) / det
    s[:, 1] = (J[:, 0, 0] * r[:, 1] - J[:, 1, 0] * r[:, 0]) / det
    return s


def one_to_one_to_axis(xy: np.ndarray, d: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Whether the distortion Jacobian stays positive on the segment from the axis to each point.

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
    ok = np.zeros(xy.shape[0], bool)
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return ok
    fractions = np.linspace(1.0 / FOLD_CHECK_SAMPLES, 1.0, FOLD_CHECK_SAMPLES)
    samples = (fractions[:, None, None] * xy[idx][None, :, :]).reshape(-1, 2)
    _, J, _ = distort_with_jacobians(samples, d)
    positive = (_det2(J) > 0.0).reshape(FOLD_CHECK_SAMPLES, idx.size).all(axis=0)
    ok[idx] = positive
    return ok
