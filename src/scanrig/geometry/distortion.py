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
#: Of those, the steps taken block by block before a block's unconverged points are gathered
#: (compacted) and given the rest; two or three suffice for typical lenses.
UNDISTORT_BLOCK_ITER = 4
#: Points per block of the Newton solve: its 18 scratch arrays of 128 kB stay in the CPU caches,
#: where whole-array numpy operations run several times faster than on millions of points at
#: once, while a block is long enough for numpy's per-call overhead not to matter (16k-32k points
#: measured fastest).
UNDISTORT_BLOCK = 16384
#: Damped Newton iterations allowed for the points the fast path leaves (near a fold).
UNDISTORT_MAX_ITER = 40
#: Newton steps per stage of the continuation from the optical axis that solves the points the
#: other solves leave (see :func:`_continuation`).
UNDISTORT_CONTINUATION_STEPS = 4
#: Fractions of the way to the target at which the continuation stops: evenly to 1/2, then
#: halving the remaining distance down to 2**-24, because close to a fold the solution moves
#: far for a small move of the target.
_CONTINUATION_FRACTIONS = np.concatenate([np.arange(1, 9) / 16.0, 1.0 - 0.5 ** np.arange(2, 25)])
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
    xd, yd = distort_components(xy[:, 0], xy[:, 1], d)
    return np.stack([xd, yd], axis=-1)


def distort_components(x: np.ndarray, y: np.ndarray, d: np.ndarray):
    """:func:`distort` on separate coordinate arrays: returns ``(xd, yd)``, same shape as ``x``."""
    r2 = x * x + y * y
    k4, k5, k6 = d[5:8]
    radial = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))
    if k4 or k5 or k6:
        radial /= 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    return _distorted_from_radial(x, y, r2, radial, d)


def _distorted_from_radial(x: np.ndarray, y: np.ndarray, r2: np.ndarray, radial: np.ndarray, d: np.ndarray):
    """Distorted coordinates from the radial factor: the tangential and thin-prism terms added.

    Parameters
    ----------
    x, y : ndarray, any shape
        Undistorted normalised coordinates.
    r2 : ndarray, same shape
        ``x² + y²``.
    radial : ndarray, same shape
        The radial factor (numerator over denominator of the module formula) at ``r2``.
    d : ndarray of shape (12,)
        Full coefficient vector.

    Returns
    -------
    xd, yd : ndarray, same shape as ``x``
        Distorted normalised coordinates.
    """
    p1, p2 = d[2], d[3]
    xy2 = 2.0 * x * y
    xd = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + p2 * xy2
    s1, s2, s3, s4 = d[8:12]
    if s1 or s2 or s3 or s4:
        xd += r2 * (s1 + s2 * r2)
        yd += r2 * (s3 + s4 * r2)
    return xd, yd


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
    xd, yd = _distorted_from_radial(x, y, r2, radial, d)
    j00 = radial + two_dradial * x * x + 2.0 * (p1 * y + 3.0 * p2 * x)
    j01 = two_dradial * x * y + 2.0 * (p1 * x + p2 * y)
    j11 = radial + two_dradial * y * y + 2.0 * (3.0 * p1 * y + p2 * x)
    j10 = j01
    s1, s2, s3, s4 = d[8:12]
    if s1 or s2 or s3 or s4:
        ds_x = 2.0 * (s1 + 2.0 * s2 * r2)  # d(s1 r2 + s2 r4)/d r2, times d r2/d x / x
        ds_y = 2.0 * (s3 + 2.0 * s4 * r2)
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

    Each point starts from one fixed-point step of the radial factor and takes plain Newton
    steps with the analytic 2x2 Jacobian (:func:`undistort_components`: in place, on blocks of
    :data:`UNDISTORT_BLOCK` points that stay in the CPU cache); points that have not converged
    after :data:`UNDISTORT_FAST_ITER` steps, or that converged to a root beyond a fold, are
    restarted from the distorted coordinates with capped steps that are halved whenever they
    would increase the residual, and what is still left is solved by continuation from the
    optical axis. A point counts as converged when the residual falls below
    :data:`UNDISTORT_TOL` *and* the distortion map is one-to-one between the optical axis and
    the solution (positive Jacobian determinant at :data:`FOLD_CHECK_SAMPLES` points along that
    segment). Beyond the fold of a strongly distorting lens a pixel has no preimage, or one on
    the far side of the fold that the lens cannot physically image; both are reported as not
    converged.

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
    x, y, converged = undistort_components(xy_d[:, 0], xy_d[:, 1], d)
    xy = np.empty((x.shape[0], 2))
    xy[:, 0], xy[:, 1] = x, y
    return xy, converged


def undistort_components(xd: np.ndarray, yd: np.ndarray, d: np.ndarray, scale=None):
    """:func:`undistort` on separate coordinate arrays, optionally from pixels.

    Parameters
    ----------
    xd, yd : ndarray of shape (N,)
        Distorted normalised coordinates (any strides), or pixels when ``scale`` is given.
    d : ndarray of shape (12,)
        Full coefficient vector.
    scale : tuple (fx, fy, cx, cy), optional
        Intrinsics: the inputs are pixels ``u, v`` and the distorted normalised coordinates are
        ``((u - cx) / fx, (v - cy) / fy)``, formed block by block.

    Returns
    -------
    x, y : ndarray of shape (N,)
        Contiguous undistorted normalised coordinates, NaN where not converged.
    converged : ndarray of shape (N,), bool
    """
    if np.any(d):
        x, y, converged = _solve_undistortion(xd, yd, d, scale)
    else:  # a pinhole camera: nothing to invert
        x, y = _targets_of(xd, yd, scale)
        converged = np.isfinite(x)
        converged &= np.isfinite(y)
    if not converged.all():
        x[~converged] = np.nan
        y[~converged] = np.nan
    return x, y, converged


def _solve_undistortion(xd: np.ndarray, yd: np.ndarray, d: np.ndarray, scale):
    """The solves of :func:`undistort_components` for a lens that distorts (``d`` not all zero).

    Takes and returns what :func:`undistort_components` does, except that ``x, y`` keep the
    last iterate where ``converged`` is False.
    """
    n = xd.shape[0]
    work = _NewtonWork(d, min(max(n, 1), UNDISTORT_BLOCK))
    x, y = np.empty(n), np.empty(n)
    res2 = np.empty(n)
    finite = np.ones(n, bool)
    # Points outside the radius where the map is known one-to-one need the fold check.
    r_safe2 = one_to_one_radius(tuple(float(c) for c in d)) ** 2
    far = []
    with np.errstate(all="ignore"):
        for start in range(0, n, UNDISTORT_BLOCK):
            s = slice(start, min(start + UNDISTORT_BLOCK, n))
            tx, ty = work.targets(xd[s], yd[s], scale)
            if not (np.isfinite(tx.sum()) and np.isfinite(ty.sum())):  # rare: flag and zero them
                bad = ~(np.isfinite(tx) & np.isfinite(ty))
                finite[s] = ~bad
                tx[bad] = ty[bad] = 0.0
            work.initial_guess(tx, ty, x[s], y[s])
            if work.newton(x[s], y[s], tx, ty, UNDISTORT_BLOCK_ITER, res2[s]) >= r_safe2:
                far.append(start + np.flatnonzero(work.r2(s.stop - start) >= r_safe2))
        converged = res2 <= UNDISTORT_TOL**2
        converged &= finite
        # Points still unconverged (slow convergence, or near or beyond a fold): gathered
        # into contiguous arrays and given the remaining plain Newton steps, then the
        # damped, backtracking solve.
        left = gathered = np.flatnonzero(~converged & finite)
        if left.size:
            xl, yl = x[left], y[left]
            txl, tyl = _targets_of(xd[left], yd[left], scale)
            res_l = np.empty(left.size)
            for start in range(0, left.size, UNDISTORT_BLOCK):
                s = slice(start, start + UNDISTORT_BLOCK)
                work.newton(xl[s], yl[s], txl[s], tyl[s], UNDISTORT_FAST_ITER - UNDISTORT_BLOCK_ITER,
                            res_l[s])
            ok_l = res_l <= UNDISTORT_TOL**2
            x[left], y[left] = xl, yl
            converged[left] = ok_l
            left, txl, tyl = left[~ok_l], txl[~ok_l], tyl[~ok_l]
        if left.size:
            _backtrack(x, y, converged, left, txl, tyl, d)
        # Fold check of the far points (blocks found them; the gathered ones are added). A
        # plain Newton solve can land on a root beyond the fold while one inside exists:
        # those points get the damped solve from the distorted point, and a second check.
        far = np.unique(np.concatenate(far + [gathered]))
        folded = _fold_check(x, y, converged, d, far)
        if left.size:  # those already had the damped solve
            folded = folded[~np.isin(folded, left)]
        if folded.size:
            _backtrack(x, y, converged, folded, *_targets_of(xd[folded], yd[folded], scale), d)
            _fold_check(x, y, converged, d, folded)
        # Last resort for what is left (strong distortion far off axis, where Newton from the
        # distorted point is drawn to a root beyond the fold): continuation from the axis.
        hard = np.flatnonzero(~converged & finite)
        if hard.size:
            x[hard], y[hard], ok_h = _continuation(work, *_targets_of(xd[hard], yd[hard], scale))
            converged[hard] = ok_h
            _fold_check(x, y, converged, d, hard)
    return x, y, converged


def _continuation(work: _NewtonWork, tx: np.ndarray, ty: np.ndarray):
    """Solve by continuation from the optical axis; returns ``x, y, converged``.

    The targets move from the axis to ``(tx, ty)`` through the fractions of
    :data:`_CONTINUATION_FRACTIONS`, each stage solved by a few Newton steps from the previous
    solution, so that the solution follows the branch through the axis instead of jumping to a
    root beyond a fold. A point is dropped as soon as a stage leaves it on a non-positive
    Jacobian determinant or a non-finite value (its path reached a fold: the target has no
    preimage on that branch).
    """
    m = tx.shape[0]
    x, y = np.zeros(m), np.zeros(m)
    ok = np.zeros(m, bool)
    idx = np.arange(m)
    xa, ya, txa, tya = x.copy(), y.copy(), tx, ty
    for frac in [*_CONTINUATION_FRACTIONS, 1.0]:
        final = frac == 1.0
        steps = UNDISTORT_FAST_ITER if final else UNDISTORT_CONTINUATION_STEPS
        sx, sy = txa * frac, tya * frac
        keep = np.empty(idx.size, bool)
        for start in range(0, idx.size, UNDISTORT_BLOCK):
            s = slice(start, min(start + UNDISTORT_BLOCK, idx.size))
            res2 = np.empty(s.stop - start)
            work.newton(xa[s], ya[s], sx[s], sy[s], steps, res2)
            keep[s] = work.det_positive(xa[s], ya[s])
            if final:
                keep[s] &= res2 <= UNDISTORT_TOL**2
            else:
                keep[s] &= np.isfinite(res2)
        if final:
            ok[idx[keep]] = True
            x[idx], y[idx] = xa, ya
            break
        if not keep.all():
            idx, xa, ya, txa, tya = idx[keep], xa[keep], ya[keep], txa[keep], tya[keep]
        if idx.size == 0:
            break
    return x, y, ok


def _backtrack(x, y, converged, idx, tx, ty, d) -> None:
    """Damped Newton from the targets for the points ``idx``; updates ``x, y, converged``."""
    xy = np.stack([tx, ty], axis=1)
    converged[idx] = _undistort_backtracking(xy, xy.copy(), d, np.arange(idx.size))
    x[idx], y[idx] = xy[:, 0], xy[:, 1]


def _fold_check(x, y, converged, d, idx) -> np.ndarray:
    """Clear ``converged`` where the map folds between the axis and the solution.

    Checks the converged points among ``idx`` outside :func:`one_to_one_radius`; returns the
    indices whose flag it cleared.
    """
    r_safe = one_to_one_radius(tuple(float(c) for c in d))
    idx = idx[converged[idx] & (x[idx] ** 2 + y[idx] ** 2 >= r_safe * r_safe)]
    if idx.size == 0:
        return idx
    ok = one_to_one_to_axis(np.stack([x[idx], y[idx]], axis=1), d, np.ones(idx.size, bool))
    converged[idx] = ok
    return idx[~ok]


def _targets_of(xd: np.ndarray, yd: np.ndarray, scale):
    """Distorted normalised coordinates from the inputs of :func:`undistort_components`."""
    if scale is None:
        return np.array(xd, dtype=np.float64), np.array(yd, dtype=np.float64)
    fx, fy, cx, cy = scale
    return (xd - cx) / fx, (yd - cy) / fy


class _NewtonWork:
    """Scratch arrays and the in-place kernels of the blocked Newton solve.

    Every array operation writes into a preallocated block-sized buffer (``out=``), and terms
    whose coefficients are zero are skipped (no rational part for ``opencv5``, no thin prism
    below ``opencv12``, no tangential part when ``p1 = p2 = 0``).
    """

    _NAMES = ("tx", "ty", "x2", "y2", "r2", "xy", "rad", "den", "a", "fx", "fy",
              "j00", "j01", "j10", "j11", "res2", "t", "u")

    def __init__(self, d: np.ndarray, size: int):
        self.d = np.asarray(d, dtype=np.float64)
        k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = (float(c) for c in self.d)
        self.k1, self.k2, self.k3, self.k4, self.k5, self.k6 = k1, k2, k3, k4, k5, k6
        self.p1, self.p2, self.s1, self.s2, self.s3, self.s4 = p1, p2, s1, s2, s3, s4
        self.rational = bool(k4 or k5 or k6)
        self.tangential = bool(p1 or p2)
        self.prism = bool(s1 or s2 or s3 or s4)
        self._buf = np.empty((len(self._NAMES), size))
        self._cache: dict[int, dict] = {}

    def _views(self, m: int) -> dict:
        """The scratch arrays cut to ``m`` points, by name (cached: blocks repeat the same sizes)."""
        views = self._cache.get(m)
        if views is None:
            views = self._cache[m] = {name: self._buf[i, :m] for i, name in enumerate(self._NAMES)}
        return views

    def targets(self, xd, yd, scale):
        """Block of distorted normalised coordinates in the ``tx``, ``ty`` buffers."""
        m = xd.shape[0]
        tx, ty = self._buf[0, :m], self._buf[1, :m]
        if scale is None:
            np.copyto(tx, xd)
            np.copyto(ty, yd)
        else:
            fx, fy, cx, cy = scale
            np.subtract(xd, cx, out=tx)
            tx /= fx
            np.subtract(yd, cy, out=ty)
            ty /= fy
        return tx, ty

    def _polys(self, v):
        """``rad`` (radial factor) and, if rational, ``den`` at ``r2`` (all views in ``v``)."""
        r2, rad, den = v["r2"], v["rad"], v["den"]
        if self.k3:
            np.multiply(r2, self.k3, out=rad)
            rad += self.k2
            rad *= r2
        else:
            np.multiply(r2, self.k2, out=rad)
        rad += self.k1
        rad *= r2
        rad += 1.0
        if self.rational:
            np.multiply(r2, self.k6, out=den)
            den += self.k5
            den *= r2
            den += self.k4
            den *= r2
            den += 1.0
            rad /= den

    def initial_guess(self, tx, ty, x, y):
        """One fixed-point step of the radial factor: ``x = x_d / radial(r_d²)``."""
        v = self._views(tx.shape[0])
        r2, rad, t = v["r2"], v["rad"], v["t"]
        np.multiply(tx, tx, out=r2)
        np.multiply(ty, ty, out=t)
        r2 += t
        self._polys(v)
        if not rad.min() > 0.1:  # strong distortion far out: start from the distorted point
            rad[~(rad > 0.1)] = 1.0
        np.divide(tx, rad, out=x)
        np.divide(ty, rad, out=y)

    def residual(self, x, y, tx, ty):
        """Distortion of ``(x, y)`` minus the targets into ``fx, fy``; squared norm in ``res2``."""
        v = self._views(x.shape[0])
        x2, y2, r2, xy, rad, fx, fy, res2, t = (
            v[k] for k in ("x2", "y2", "r2", "xy", "rad", "fx", "fy", "res2", "t"))
        np.multiply(x, x, out=x2)
        np.multiply(y, y, out=y2)
        np.add(x2, y2, out=r2)
        self._polys(v)
        np.multiply(x, rad, out=fx)
        fx -= tx
        np.multiply(y, rad, out=fy)
        fy -= ty
        if self.tangential:
            p1, p2 = self.p1, self.p2
            np.multiply(x, y, out=xy)
            # x: 2 p1 xy + p2 (r2 + 2 x2);  y: p1 (r2 + 2 y2) + 2 p2 xy
            np.add(x2, x2, out=t)
            t += r2
            t *= p2
            fx += t
            np.multiply(xy, 2.0 * p1, out=t)
            fx += t
            np.add(y2, y2, out=t)
            t += r2
            t *= p1
            fy += t
            np.multiply(xy, 2.0 * p2, out=t)
            fy += t
        if self.prism:
            np.multiply(r2, self.s2, out=t)
            t += self.s1
            t *= r2
            fx += t
            np.multiply(r2, self.s4, out=t)
            t += self.s3
            t *= r2
            fy += t
        np.multiply(fx, fx, out=res2)
        np.multiply(fy, fy, out=t)
        res2 += t
        return res2

    def _jacobian(self, x, y, v):
        """``d xy_d / d xy`` at ``(x, y)`` from the state :meth:`residual` left there; returns
        ``(j00, j01, j10, j11, det)`` (buffer views; ``det`` is only allocated, not filled)."""
        x2, y2, r2, xy, rad, den, a, j00, j01, j10, j11, t, u = (
            v[k] for k in ("x2", "y2", "r2", "xy", "rad", "den", "a", "j00", "j01", "j10", "j11", "t", "u"))
        # a = 2 d(radial)/d(r2)
        if self.k3:
            np.multiply(r2, 6.0 * self.k3, out=a)
            a += 4.0 * self.k2
            a *= r2
        else:
            np.multiply(r2, 4.0 * self.k2, out=a)
        a += 2.0 * self.k1
        if self.rational:  # a = (2 dnum - radial 2 dden) / den
            np.multiply(r2, 6.0 * self.k6, out=t)
            t += 4.0 * self.k5
            t *= r2
            t += 2.0 * self.k4
            t *= rad
            a -= t
            a /= den
        if not self.tangential:
            np.multiply(x, y, out=xy)
        np.multiply(a, x2, out=j00)
        j00 += rad
        np.multiply(a, y2, out=j11)
        j11 += rad
        np.multiply(a, xy, out=j01)
        if self.tangential:
            p1, p2 = self.p1, self.p2
            # j00 += 2 p1 y + 6 p2 x;  j11 += 6 p1 y + 2 p2 x;  j01 += 2 p1 x + 2 p2 y
            np.multiply(y, 2.0 * p1, out=t)
            j00 += t
            np.multiply(x, 2.0 * p2, out=u)
            j11 += u
            t *= 3.0
            j11 += t
            u *= 3.0
            j00 += u
            np.multiply(x, 2.0 * p1, out=t)
            j01 += t
            np.multiply(y, 2.0 * p2, out=t)
            j01 += t
        j10_ = j01
        if self.prism:
            np.copyto(j10, j01)
            j10_ = j10
            np.multiply(r2, 4.0 * self.s2, out=t)  # 2 (s1 + 2 s2 r2)
            t += 2.0 * self.s1
            np.multiply(t, x, out=u)
            j00 += u
            t *= y
            j01 += t
            np.multiply(r2, 4.0 * self.s4, out=t)
            t += 2.0 * self.s3
            np.multiply(t, x, out=u)
            j10 += u
            t *= y
            j11 += t
        return j00, j01, j10_, j11, a  # a is free again: the determinant goes there

    def step(self, x, y):
        """One Newton step in place, from the state :meth:`residual` left at ``(x, y)``."""
        v = self._views(x.shape[0])
        fx, fy, t, u = v["fx"], v["fy"], v["t"], v["u"]
        j00, j01, j10_, j11, det = self._jacobian(x, y, v)
        # Cramer: x -= (j11 fx - j01 fy) / det;  y -= (j00 fy - j10 fx) / det
        np.multiply(j00, j11, out=det)
        np.multiply(j01, j10_, out=t)
        det -= t
        np.multiply(j11, fx, out=t)
        np.multiply(j01, fy, out=u)
        t -= u
        t /= det
        x -= t
        np.multiply(j00, fy, out=t)
        np.multiply(j10_, fx, out=u)
        t -= u
        t /= det
        y -= t

    def det_positive(self, x, y) -> np.ndarray:
        """Whether the Jacobian determinant is positive at ``(x, y)`` (a new boolean array),
        from the state that :meth:`residual` (or :meth:`newton`) left there."""
        v = self._views(x.shape[0])
        j00, j01, j10_, j11, det = self._jacobian(x, y, v)
        np.multiply(j00, j11, out=det)
        np.multiply(j01, j10_, out=v["t"])
        det -= v["t"]
        return det > 0.0

    def newton(self, x, y, tx, ty, steps: int, res2_out: np.ndarray) -> float:
        """Up to ``steps`` Newton steps on one block in place.

        Stops early once every point of the block is within :data:`UNDISTORT_TOL`. Writes the
        squared residuals at the returned ``(x, y)`` to ``res2_out`` and returns the largest
        ``x² + y²`` of the block (for the fold check).
        """
        tol2 = UNDISTORT_TOL**2
        for k in range(steps + 1):
            res2 = self.residual(x, y, tx, ty)
            if k == steps or res2.max() <= tol2:
                break
            self.step(x, y)
        np.copyto(res2_out, res2)
        return self._views(x.shape[0])["r2"].max()

    def r2(self, m: int) -> np.ndarray:
        """``x² + y²`` of the last block of ``m`` points that :meth:`newton` solved."""
        return self._views(m)["r2"]


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
