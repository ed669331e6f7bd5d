"""Sub-pixel chessboard corners by fitting a blurred-saddle model to the image.

Around an X-corner the printed pattern is the product of two step edges crossing at the corner;
seen through a lens with a roughly Gaussian blur of width ``s`` it is, near the corner::

    I(x) = m + A · erf(d1 / (√2 s)) · erf(d2 / (√2 s)),    d_k = n(θ_k) · (x - c)

with ``c`` the corner, ``θ_1, θ_2`` the normals of the two edges (any angle between them, so
perspective tilts are modelled), ``m`` the mean level and ``A`` the contrast. A pixel integrates
the image over its area: the model is averaged over ``SUBSAMPLES²`` points of the pixel, each
carrying the rest of the box's variance as a Gaussian (:data:`SUB_VAR`). A Gaussian stand-in for
the whole box (one sample per pixel) mis-locates sharp edges that run along the pixel grid by up
to 0.2 px, depending on their sub-pixel phase; sub-sampling removes that. The seven parameters
are fitted to the pixels of a window by Gauss–Newton with Levenberg damping, all corners of an
image at once (batched numpy). Unlike ``cornerSubPix`` (a gradient-orthogonality criterion that
blur and noise bias) and the Radon-transform detector (a fixed kernel), the fit uses every pixel
with its actual blur, which is what the acceptance bench measures
(benchmarks/bench_calibration.py).

Each corner may have its own window and its own pixel weights (e.g. ChArUco corners, whose
white squares carry markers: only the pixels where the saddle model holds are used; see
:func:`refine_charuco_corners`).

Written here because OpenCV has no model-fitting corner refiner; only the pixel gather and the
7x7 solves are per corner, both vectorised.
"""

from __future__ import annotations

import numpy as np
from scipy.special import erf

#: Gauss–Newton iterations (the fit converges in 5-8 from an OpenCV start).
ITERATIONS = 15
#: The fit stops when no corner moves by more than this in an accepted or rejected step, px.
STEP_TOL_PX = 1e-4
#: A refined corner further than this from its start (pixels) is a failed fit; the start is kept.
MAX_SHIFT_PX = 2.0
#: Largest window half-width, pixels.
MAX_HALF_WINDOW = 12
#: Smallest window half-width, pixels.
MIN_HALF_WINDOW = 3
#: Variance (px²) of a pixel's box integration.
PIXEL_BOX_VAR = 1.0 / 12.0
#: Sub-samples per pixel axis for the pixel's box integration.
SUBSAMPLES = 3
_SUB = (np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES - 0.5
SUB_X, SUB_Y = (a.ravel() for a in np.meshgrid(_SUB, _SUB))
#: Variance left to each sub-sample (a box of 1/SUBSAMPLES px), as a Gaussian.
SUB_VAR = PIXEL_BOX_VAR / SUBSAMPLES ** 2


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


def window_offsets(half: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel offsets (x, y), each (P,), of a (2 half + 1)² window, row-major."""
    off = np.arange(-half, half + 1)
    ox, oy = np.meshgrid(off, off)
    return ox.ravel(), oy.ravel()


def fit_saddles(img: np.ndarray, uv0: np.ndarray, theta0: np.ndarray, half, pixel_weight=None):
    """Fit the blurred-saddle model at many corners (see the module docstring).

    Parameters
    ----------
    img : ndarray of shape (H, W), float
    uv0 : ndarray of shape (N, 2)
        Starting corners, pixels.
    theta0 : ndarray of shape (N, 2)
        Starting normal angles of the two edges, radians.
    half : int or ndarray of shape (N,)
        Window half-width, pixels (per corner, or one for all).
    pixel_weight : ndarray of shape (N, P), optional
        Extra weight of each window pixel, P = (2 max(half) + 1)² in :func:`window_offsets`
        order around ``round(uv0)``; 0 excludes a pixel.

    Returns
    -------
    uv : ndarray of shape (N, 2)
    ok : ndarray of shape (N,), bool
    """
    n = len(uv0)
    halves = np.broadcast_to(np.asarray(half, dtype=np.int64), (n,))
    big = int(halves.max()) if n else 1
    ox, oy = window_offsets(big)
    centre = np.round(uv0).astype(np.int64)
    px = centre[:, 0:1] + ox[None, :]                 # (N, P) pixel columns
    py = centre[:, 1:2] + oy[None, :]
    h, w = img.shape
    in_win = (np.abs(ox)[None, :] <= halves[:, None]) & (np.abs(oy)[None, :] <= halves[:, None])
    in_img = (px >= 0) & (py >= 0) & (px < w) & (py < h)
    inside = np.all(in_img | ~in_win, axis=1)
    values = img[np.clip(py, 0, h - 1), np.clip(px, 0, w - 1)]
    # Gaussian taper: pixels far from the corner (nearer the next corner) count less.
    hh = halves[:, None].astype(np.float64)
    taper = np.exp(-0.5 * (ox[None, :] ** 2 + oy[None, :] ** 2) / (0.6 * hh) ** 2) * in_win
    if pixel_weight is not None:
        taper = taper * pixel_weight
    used = taper > 0
    wsum = np.maximum(taper.sum(axis=1), 1e-12)
    # Sub-sample positions (N, P, K).
    sx = px[:, :, None] + SUB_X[None, None, :]
    sy = py[:, :, None] + SUB_Y[None, None, :]

    c = uv0.astype(np.float64).copy()
    th = theta0.astype(np.float64).copy()
    s = np.full(n, 1.0)
    # Linear start for m and A given the geometry (weighted).
    e1, e2 = _edges(sx, sy, c, th, s)[:2]
    basis = (e1 * e2).mean(axis=2)
    bm = np.sum(taper * basis, axis=1) / wsum
    vm = np.sum(taper * values, axis=1) / wsum
    A = np.sum(taper * (basis - bm[:, None]) * (values - vm[:, None]), axis=1) \
        / np.maximum(np.sum(taper * (basis - bm[:, None]) ** 2, axis=1), 1e-12)
    m = vm - A * bm
    p = np.column_stack([c, th, s, m, A])             # (N, 7)
    lam = np.full(n, 1e-3)
    cost = _cost(p, sx, sy, values, taper)
    for _ in range(ITERATIONS):
        r, J = _residual_jacobian(p, sx, sy, values)
        Jw = J * taper[:, :, None]
        H = np.einsum("npi,npj->nij", Jw, J)
        g = np.einsum("npi,np->ni", Jw, r)
        diag = np.einsum("nii->ni", H)
        step = np.linalg.solve(H + lam[:, None, None] * np.eye(7)[None] * diag[:, None, :] + 1e-12 * np.eye(7),
                               -g[:, :, None])[:, :, 0]
        p_new = p + step
        p_new[:, 4] = np.abs(p_new[:, 4])
        cost_new = _cost(p_new, sx, sy, values, taper)
        better = cost_new < cost
        p[better], cost[better] = p_new[better], cost_new[better]
        lam = np.where(better, lam * 0.3, lam * 10.0)
        if np.all((np.abs(step[:, :2]).max(axis=1) < STEP_TOL_PX) | ~np.isfinite(cost)):
            break
    uv = p[:, :2]
    ok = inside & np.all(np.isfinite(uv), axis=1) & (np.linalg.norm(uv - uv0, axis=1) < MAX_SHIFT_PX) \
        & (p[:, 4] < halves) & (used.sum(axis=1) >= 12)
    return np.where(ok[:, None], uv, uv0), ok


def _edges(sx, sy, c, th, s):
    """erf edge terms, their derivatives and the signed distances (all (N, P, K))."""
    dx = sx - c[:, 0, None, None]
    dy = sy - c[:, 1, None, None]
    c1, s1 = np.cos(th[:, 0])[:, None, None], np.sin(th[:, 0])[:, None, None]
    c2, s2 = np.cos(th[:, 1])[:, None, None], np.sin(th[:, 1])[:, None, None]
    d1 = c1 * dx + s1 * dy
    d2 = c2 * dx + s2 * dy
    k = (1.0 / (np.sqrt(2.0) * np.sqrt(s ** 2 + SUB_VAR)))[:, None, None]
    e1, e2 = erf(d1 * k), erf(d2 * k)
    g1 = (2.0 / np.sqrt(np.pi)) * k * np.exp(-(d1 * k) ** 2)       # d e1 / d d1
    g2 = (2.0 / np.sqrt(np.pi)) * k * np.exp(-(d2 * k) ** 2)
    return e1, e2, g1, g2, d1, d2, dx, dy, (c1, s1), (c2, s2)


def _cost(p, sx, sy, values, taper):
    e1, e2 = _edges(sx, sy, p[:, :2], p[:, 2:4], p[:, 4])[:2]
    r = p[:, 5:6] + p[:, 6:7] * (e1 * e2).mean(axis=2) - values
    cost = np.sum(taper * r ** 2, axis=1)
    return np.where(np.isfinite(cost), cost, np.inf)


def _residual_jacobian(p, sx, sy, values):
    """Residuals (N, P) and Jacobian (N, P, 7) of the model with respect to (u, v, θ1, θ2, s, m, A)."""
    c, th, s, m, A = p[:, :2], p[:, 2:4], p[:, 4], p[:, 5:6], p[:, 6:7]
    e1, e2, g1, g2, d1, d2, dx, dy, (c1, s1), (c2, s2) = _edges(sx, sy, c, th, s)
    Ak = A[:, :, None]
    r = m + A * (e1 * e2).mean(axis=2) - values
    J = np.empty(sx.shape[:2] + (7,))
    ge2, e1g = g1 * e2, e1 * g2
    J[:, :, 0] = -(Ak * (ge2 * c1 + e1g * c2)).mean(axis=2)
    J[:, :, 1] = -(Ak * (ge2 * s1 + e1g * s2)).mean(axis=2)
    J[:, :, 2] = (Ak * ge2 * (-s1 * dx + c1 * dy)).mean(axis=2)
    J[:, :, 3] = (Ak * e1g * (-s2 * dx + c2 * dy)).mean(axis=2)
    s_eff2 = (s ** 2 + SUB_VAR)[:, None, None]                      # d s_eff / d s = s / s_eff
    J[:, :, 4] = -(Ak * (ge2 * d1 + e1g * d2) * s[:, None, None] / s_eff2).mean(axis=2)
    J[:, :, 5] = 1.0
    J[:, :, 6] = (e1 * e2).mean(axis=2)
    return r, J


#: Pixels kept clear of the ends of a saddle's valid region (blur and the start's error), px.
CHARUCO_GUARD_PX = 1.5
#: Smallest foreshortening (ratio of the smaller to the larger singular value of the board's
#: local image Jacobian, about the cosine of the viewing angle) at which a ChArUco corner is
#: fitted: cos 72°. Steeper, the marker-free strips of the white squares shrink to a few pixels
#: and the fit's error grows fast: on rendered cube sessions (8-bit, simulated noise) 0.009-0.010
#: px RMS up to 70°, 0.016 px at 70-73°, 0.024 px at 73-75° and 0.04-0.3 px beyond, where a
#: calibration rejected most of them as outliers. Such a corner is reported as failed.
CHARUCO_MIN_FORESHORTENING = 0.31


def refine_charuco_corners(grey: np.ndarray, uv: np.ndarray, xy_board: np.ndarray, square_m: float,
                           marker_m: float, margin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Refine the ChArUco corners of one board with the saddle fit, markers masked out.

    The board-to-image homography of the detected corners gives, at every corner, the image of
    one square along each board axis (edge directions, window size) and the board position of
    every window pixel. A pixel is used when it lies within one square of the corner along both
    axes, and, in the two white squares (which carry markers), in the marker-free strip along
    the edges, all with :data:`CHARUCO_GUARD_PX` to spare. So a corner of a face seen at a
    grazing angle is fitted only where the saddle model holds, instead of a square window that
    reaches markers and neighbouring corners. A corner seen more steeply than
    :data:`CHARUCO_MIN_FORESHORTENING` allows (beyond about 72°) fails.

    Parameters
    ----------
    grey : ndarray of shape (H, W)
    uv : ndarray of shape (N, 2)
        Detected corners (pixels), N >= 4.
    xy_board : ndarray of shape (N, 2)
        Their board coordinates, metres (margin included).
    square_m, marker_m, margin_m : float
        Board geometry.

    Returns
    -------
    uv_refined : ndarray of shape (N, 2)
        The input position where the fit failed.
    ok : ndarray of shape (N,), bool
    """
    import cv2

    uv = np.asarray(uv, dtype=np.float64)
    xy = np.asarray(xy_board, dtype=np.float64)
    n = len(uv)
    if n < 4:
        return uv.copy(), np.zeros(n, dtype=bool)
    H, _ = cv2.findHomography(xy, uv, 0)
    if H is None or not np.all(np.isfinite(H)):
        return uv.copy(), np.zeros(n, dtype=bool)
    Hinv = np.linalg.inv(H)
    # Image of one square along board x and y at each corner (Jacobian of the homography).
    hom = np.column_stack([xy, np.ones(n)]) @ H.T
    w = hom[:, 2:3]
    proj = hom[:, :2] / w
    ex = (H[:2, 0][None, :] - proj * H[2, 0]) / w * square_m
    ey = (H[:2, 1][None, :] - proj * H[2, 1]) / w * square_m
    len_x, len_y = np.linalg.norm(ex, axis=1), np.linalg.norm(ey, axis=1)
    theta = np.column_stack([np.arctan2(ex[:, 0], -ex[:, 1]), np.arctan2(ey[:, 0], -ey[:, 1])])
    half = np.clip(np.ceil(0.6 * np.maximum(len_x, len_y)), MIN_HALF_WINDOW, MAX_HALF_WINDOW).astype(np.int64)
    ox, oy = window_offsets(int(half.max()))
    centre = np.round(uv)
    px = centre[:, 0:1] + ox[None, :]
    py = centre[:, 1:2] + oy[None, :]
    hp = Hinv[None, :, 0:1] * px[:, None, :] + Hinv[None, :, 1:2] * py[:, None, :] + Hinv[None, :, 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (hp[:, 0] / hp[:, 2] - xy[:, 0:1]) / square_m          # board offset from the corner, squares
        b = (hp[:, 1] / hp[:, 2] - xy[:, 1:2]) / square_m
    da = (CHARUCO_GUARD_PX / len_x)[:, None]
    db = (CHARUCO_GUARD_PX / len_y)[:, None]
    valid = (np.abs(a) < 1 - da) & (np.abs(b) < 1 - db)
    # Square indices of the corner (a grid-line crossing) and colour of each pixel's square:
    # square (i, j) is black when i + j is even (top-left square black).
    ic = np.round((xy[:, 0] - margin_m) / square_m).astype(np.int64)[:, None]
    jc = np.round((xy[:, 1] - margin_m) / square_m).astype(np.int64)[:, None]
    white = ((ic + (a < 0) * -1 + jc + (b < 0) * -1) % 2) == 1
    strip = 0.5 * (square_m - marker_m) / square_m
    clear = (np.abs(a) < strip - da) | (np.abs(b) < strip - db)
    valid &= ~white | clear
    valid &= np.isfinite(a) & np.isfinite(b)
    uv_fit, ok = fit_saddles(np.asarray(grey, dtype=np.float64), uv, theta, half, valid.astype(np.float64))
    singular = np.linalg.svd(np.stack([ex, ey], axis=2), compute_uv=False)       # (N, 2), descending
    ok &= singular[:, 1] >= CHARUCO_MIN_FORESHORTENING * singular[:, 0]
    return np.where(ok[:, None], uv_fit, uv), ok
