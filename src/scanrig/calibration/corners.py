"""Sub-pixel chessboard corners by fitting a blurred-saddle model to the image.

Around an X-corner the printed pattern is the product of two step edges crossing at the corner;
seen through a lens with a roughly Gaussian blur of width ``s`` it is, near the corner::

    I(x) = m + A · erf(d1 / (√2 s)) · erf(d2 / (√2 s)),    d_k = n(θ_k) · (x - c)

with ``c`` the corner (``s`` includes the pixel's own box integration, see
:data:`PIXEL_BOX_VAR`), ``θ_1, θ_2`` the normals of the two edges (any angle between them, so
perspective tilts are modelled), ``m`` the mean level and ``A`` the contrast. The seven
parameters are fitted to the pixels of a window by Gauss–Newton with Levenberg damping, all
corners of an image at once (batched numpy). Unlike ``cornerSubPix`` (a gradient-orthogonality
criterion that blur and noise bias) and the Radon-transform detector (a fixed kernel), the fit
uses every pixel with its actual blur, which is what the acceptance bench measures
(benchmarks/bench_calibration.py).

Written here because OpenCV has no model-fitting corner refiner; only the pixel gather and the
7x7 solves are per corner, both vectorised.
"""

from __future__ import annotations

import numpy as np
from scipy.special import erf

#: Gauss–Newton iterations (the fit converges in 5-8 from an OpenCV start).
ITERATIONS = 15
#: A refined corner further than this from its start (pixels) is a failed fit; the start is kept.
MAX_SHIFT_PX = 2.0
#: Largest window half-width, pixels.
MAX_HALF_WINDOW = 12
#: Smallest window half-width, pixels.
MIN_HALF_WINDOW = 3
#: Variance (px²) of a pixel's box integration, approximated by a Gaussian: the model's edge
#: width is ``sqrt(s² + 1/12)``, so a perfectly sharp edge stays a one-pixel ramp, not a step the
#: fit cannot locate within a pixel.
PIXEL_BOX_VAR = 1.0 / 12.0


def refine_corners(grey: np.ndarray, uv: np.ndarray, size: tuple[int, int],
                   half_window: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Refine the inner corners of a detected chessboard.

    Parameters
    ----------
    grey : ndarray of shape (H, W)
        Grey image (any numeric type).
    uv : ndarray of shape (cols * rows, 2)
        Corners in row-major grid order (as ``findChessboardCorners`` gives), pixels.
    size : (int, int)
        Inner corners (cols, rows).
    half_window : int, optional
        Fit window half-width; default 40 % of the smallest neighbour distance (3..12 px).

    Returns
    -------
    uv_refined : ndarray of shape (N, 2)
        Refined corners; the input position where the fit failed.
    ok : ndarray of shape (N,), bool
        Where the fit succeeded.
    """
    cols, rows = size
    grid = uv.reshape(rows, cols, 2)
    # Edge directions at each corner from its grid neighbours (central differences).
    along_row = np.gradient(grid, axis=1).reshape(-1, 2)
    along_col = np.gradient(grid, axis=0).reshape(-1, 2)
    if half_window is None:
        spacing = np.minimum(np.linalg.norm(along_row, axis=1), np.linalg.norm(along_col, axis=1))
        half_window = int(np.clip(np.floor(0.4 * spacing.min()), MIN_HALF_WINDOW, MAX_HALF_WINDOW))
    theta = np.column_stack([np.arctan2(along_row[:, 0], -along_row[:, 1]),     # normal of a row edge
                             np.arctan2(along_col[:, 0], -along_col[:, 1])])
    return fit_saddles(np.asarray(grey, dtype=np.float64), uv, theta, half_window)


def fit_saddles(img: np.ndarray, uv0: np.ndarray, theta0: np.ndarray, half: int):
    """Fit the blurred-saddle model at many corners (see the module docstring).

    Parameters
    ----------
    img : ndarray of shape (H, W), float
    uv0 : ndarray of shape (N, 2)
        Starting corners, pixels.
    theta0 : ndarray of shape (N, 2)
        Starting normal angles of the two edges, radians.
    half : int
        Window half-width, pixels.

    Returns
    -------
    uv : ndarray of shape (N, 2)
    ok : ndarray of shape (N,), bool
    """
    n = len(uv0)
    off = np.arange(-half, half + 1)
    ox, oy = np.meshgrid(off, off)
    ox, oy = ox.ravel(), oy.ravel()
    centre = np.round(uv0).astype(np.int64)
    px = centre[:, 0:1] + ox[None, :]                 # (N, P) pixel columns
    py = centre[:, 1:2] + oy[None, :]
    h, w = img.shape
    inside = (px.min(axis=1) >= 0) & (py.min(axis=1) >= 0) & (px.max(axis=1) < w) & (py.max(axis=1) < h)
    values = img[np.clip(py, 0, h - 1), np.clip(px, 0, w - 1)]
    # Gaussian taper: pixels far from the corner (nearer the next corner) count less.
    taper = np.exp(-0.5 * (ox ** 2 + oy ** 2) / (0.6 * half) ** 2)[None, :]

    c = uv0.astype(np.float64).copy()
    th = theta0.astype(np.float64).copy()
    s = np.full(n, 1.0)
    # Linear start for m and A given the geometry.
    e1, e2 = _edges(px, py, c, th, s)[:2]
    basis = e1 * e2
    bm = basis.mean(axis=1)
    A = np.sum((basis - bm[:, None]) * (values - values.mean(axis=1, keepdims=True)), axis=1) \
        / np.maximum(np.sum((basis - bm[:, None]) ** 2, axis=1), 1e-12)
    m = values.mean(axis=1) - A * bm
    p = np.column_stack([c, th, s, m, A])             # (N, 7)
    lam = np.full(n, 1e-3)
    cost = _cost(p, px, py, values, taper)
    for _ in range(ITERATIONS):
        r, J = _residual_jacobian(p, px, py, values)
        Jw = J * taper[:, :, None]
        H = np.einsum("npi,npj->nij", Jw, J)
        g = np.einsum("npi,np->ni", Jw, r)
        diag = np.einsum("nii->ni", H)
        step = np.linalg.solve(H + lam[:, None, None] * np.eye(7)[None] * diag[:, None, :] + 1e-12 * np.eye(7),
                               -g[:, :, None])[:, :, 0]
        p_new = p + step
        p_new[:, 4] = np.abs(p_new[:, 4])
        cost_new = _cost(p_new, px, py, values, taper)
        better = cost_new < cost
        p[better], cost[better] = p_new[better], cost_new[better]
        lam = np.where(better, lam * 0.3, lam * 10.0)
    uv = p[:, :2]
    ok = inside & np.all(np.isfinite(uv), axis=1) & (np.linalg.norm(uv - uv0, axis=1) < MAX_SHIFT_PX) \
        & (p[:, 4] < half)
    return np.where(ok[:, None], uv, uv0), ok


def _edges(px, py, c, th, s):
    """erf edge terms, their derivatives and the signed distances (all (N, P))."""
    dx = px - c[:, 0:1]
    dy = py - c[:, 1:2]
    n1 = np.stack([np.cos(th[:, 0]), np.sin(th[:, 0])], axis=1)
    n2 = np.stack([np.cos(th[:, 1]), np.sin(th[:, 1])], axis=1)
    d1 = n1[:, 0:1] * dx + n1[:, 1:2] * dy
    d2 = n2[:, 0:1] * dx + n2[:, 1:2] * dy
    k = 1.0 / (np.sqrt(2.0) * np.sqrt(s[:, None] ** 2 + PIXEL_BOX_VAR))
    e1, e2 = erf(d1 * k), erf(d2 * k)
    g1 = (2.0 / np.sqrt(np.pi)) * k * np.exp(-(d1 * k) ** 2)       # d e1 / d d1
    g2 = (2.0 / np.sqrt(np.pi)) * k * np.exp(-(d2 * k) ** 2)
    return e1, e2, g1, g2, d1, d2, dx, dy, n1, n2


def _cost(p, px, py, values, taper):
    e1, e2 = _edges(px, py, p[:, :2], p[:, 2:4], p[:, 4])[:2]
    r = p[:, 5:6] + p[:, 6:7] * e1 * e2 - values
    cost = np.sum(taper * r ** 2, axis=1)
    return np.where(np.isfinite(cost), cost, np.inf)


def _residual_jacobian(p, px, py, values):
    """Residuals (N, P) and Jacobian (N, P, 7) of the model with respect to (u, v, θ1, θ2, s, m, A)."""
    c, th, s, m, A = p[:, :2], p[:, 2:4], p[:, 4], p[:, 5:6], p[:, 6:7]
    e1, e2, g1, g2, d1, d2, dx, dy, n1, n2 = _edges(px, py, c, th, s)
    r = m + A * e1 * e2 - values
    J = np.empty(px.shape + (7,))
    J[:, :, 0] = -A * (g1 * e2 * n1[:, 0:1] + e1 * g2 * n2[:, 0:1])
    J[:, :, 1] = -A * (g1 * e2 * n1[:, 1:2] + e1 * g2 * n2[:, 1:2])
    J[:, :, 2] = A * g1 * e2 * (-np.sin(th[:, 0:1]) * dx + np.cos(th[:, 0:1]) * dy)
    J[:, :, 3] = A * e1 * g2 * (-np.sin(th[:, 1:2]) * dx + np.cos(th[:, 1:2]) * dy)
    s2 = s[:, None] ** 2 + PIXEL_BOX_VAR                      # d s_eff / d s = s / s_eff
    J[:, :, 4] = -A * (g1 * d1 * e2 + e1 * g2 * d2) * s[:, None] / s2
    J[:, :, 5] = 1.0
    J[:, :, 6] = e1 * e2
    return r, J
