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
image at once (batched numpy); a corner leaves the batch once it has converged. Unlike
``cornerSubPix`` (a gradient-orthogonality criterion that blur and noise bias) and the
Radon-transform detector (a fixed kernel), the fit uses every pixel with its actual blur, which
is what the acceptance bench measures (benchmarks/bench_calibration.py).

Each corner may have its own window and its own pixel weights (e.g. ChArUco corners, whose
white squares carry markers: only the pixels where the saddle model holds are used; see
:func:`refine_charuco_corners`).

Written here because OpenCV has no model-fitting corner refiner; only the pixel gather and the
7x7 solves are per corner, both vectorised. Speed: the per-sub-sample work (9 x 625 samples a
corner for a 25-pixel window) takes the distances to the edges from one affine matrix product
and evaluates erf and exp(-x²) only within a few blur widths of each edge, in blocks of corners
whose arrays stay in the cache; one model evaluation per iteration serves both the trial's cost
and the next Jacobian. On the 16 Ciclop webcam views (66 corners, 960 x 1280) that takes the
median CPU time per view from 1.2-1.4 s to 0.17-0.23 s (``python benchmarks/bench_calibration.py
--sections 1`` prints it beside cornerSubPix's 2 ms). It stays float64: in float32 (1.6 times
as fast) the round-off decides when a corner's step falls below :data:`STEP_TOL_PX`, and views
rotated by 90 degrees no longer give the rotated intrinsics to 1e-6 px (6e-5 px).
"""

from __future__ import annotations

import numpy as np

#: Most Gauss–Newton iterations. From an OpenCV start the fit converges in about 5 on rendered
#: boards, 8-15 on real webcam views (sharp JPEG edges: large residuals, linear convergence).
ITERATIONS = 15
#: A corner leaves the fit once a step, accepted or rejected, would move it by less than this, px.
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


def fit_saddles(img: np.ndarray, uv0: np.ndarray, theta0: np.ndarray, half,
                pixel_weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Fit the blurred-saddle model at many corners (see the module docstring).

    Levenberg–Marquardt on the seven parameters, started from the closed-form mean level and
    contrast of the starting geometry. A corner leaves the batch once its step is below
    :data:`STEP_TOL_PX`; one model evaluation per iteration gives both the trial's cost and, if
    it is accepted, the Jacobian of the next step.

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
    ox, oy = window_offsets(int(halves.max()) if n else 1)
    centre = np.round(uv0).astype(np.int64)
    values, taper, inside = _gather_windows(img, centre, halves, ox, oy, pixel_weight)
    # Sub-sample offsets (x, y) from the window centre and ones, (3, K, P), the same for every corner.
    sub_xy1 = np.stack([ox[None, :] + SUB_X[:, None], oy[None, :] + SUB_Y[:, None],
                        np.ones((len(SUB_X), len(ox)))])
    # Parameters (N, 7): corner offset from its window centre (px), edge normals (rad), blur (px),
    # mean level and contrast (image units), the last two fitted to the starting geometry.
    params = np.column_stack([uv0 - centre, theta0, np.ones(n), np.zeros((n, 2))])
    basis, d_basis = _saddle_basis(params, sub_xy1)
    params[:, 5:] = _linear_fit(basis, values, taper)
    fit = _fit_terms(params, basis, d_basis, values, taper)
    lam = np.full(n, 1e-3)
    active = np.arange(n)
    for _ in range(ITERATIONS):
        if active.size == 0:
            break
        step = _damped_step(fit, taper[active], lam[active], active)
        trial = params[active] + step
        trial[:, 4] = np.abs(trial[:, 4])
        new = _fit_terms(trial, *_saddle_basis(trial, sub_xy1), values[active], taper[active])
        better = new["cost"] < fit["cost"][active]
        _accept(fit, new, active[better], better)
        params[active[better]] = trial[better]
        lam[active] *= np.where(better, 0.3, 10.0)
        done = (np.abs(step[:, :2]).max(axis=1) < STEP_TOL_PX) | ~np.isfinite(fit["cost"][active])
        active = active[~done]
    uv = params[:, :2] + centre
    ok = inside & np.all(np.isfinite(uv), axis=1) & (np.linalg.norm(uv - uv0, axis=1) < MAX_SHIFT_PX) \
        & (params[:, 4] < halves) & (np.count_nonzero(taper, axis=1) >= 12)
    return np.where(ok[:, None], uv, uv0), ok


def _gather_windows(img, centre, halves, ox, oy, pixel_weight):
    """Pixel values (N, P), fit weights (N, P) and whether each window lies inside the image (N,).

    The weight is a Gaussian taper (pixels nearer the next corner count less), zero outside a
    corner's own window, times ``pixel_weight`` when given.
    """
    px = centre[:, 0:1] + ox[None, :]                 # (N, P) pixel columns
    py = centre[:, 1:2] + oy[None, :]
    h, w = img.shape
    in_win = (np.abs(ox)[None, :] <= halves[:, None]) & (np.abs(oy)[None, :] <= halves[:, None])
    in_img = (px >= 0) & (py >= 0) & (px < w) & (py < h)
    inside = np.all(in_img | ~in_win, axis=1)
    values = img[np.clip(py, 0, h - 1), np.clip(px, 0, w - 1)].astype(np.float64)
    hh = halves[:, None].astype(np.float64)
    taper = np.exp(-0.5 * (ox[None, :] ** 2 + oy[None, :] ** 2) / (0.6 * hh) ** 2) * in_win
    if pixel_weight is not None:
        taper = taper * pixel_weight
    return values, taper, inside


def _damped_step(fit, taper, lam, active):
    """Levenberg–Marquardt step (n, 7) of the active corners from their Jacobian and residuals."""
    J = fit["jac"][active]                            # (n, P, 7)
    Jw_T = np.swapaxes(J * taper[:, :, None], 1, 2)   # (n, 7, P)
    H = Jw_T @ J
    g = Jw_T @ fit["res"][active][:, :, None]
    diag = np.einsum("nii->ni", H)
    damped = H + (lam[:, None] * diag)[:, :, None] * np.eye(7) + 1e-12 * np.eye(7)
    return np.linalg.solve(damped, -g)[:, :, 0]


def _accept(fit, new, rows, better):
    """Copy the improved trial fits (``better`` of the active rows) into ``fit`` at ``rows``."""
    for key, value in new.items():
        fit[key][rows] = value[better]


def _fit_terms(params, basis, d_basis, values, taper):
    """Cost, residuals and Jacobian at parameters ``params`` (n, 7) of the model
    ``m + A · basis`` (u, v from the window centre, θ1, θ2, s, m, A), given the saddle basis
    (n, P) and its derivatives (n, P, 5) there (:func:`_saddle_basis`).

    Returns
    -------
    dict
        ``cost`` (n,) weighted squared residuals (inf where not finite), ``res`` (n, P) residuals
        (model - image), ``jac`` (n, P, 7) Jacobian with respect to (u, v, θ1, θ2, s, m, A).
    """
    mean, contrast = params[:, 5], params[:, 6]
    res = mean[:, None] + contrast[:, None] * basis - values
    jac = np.empty(basis.shape + (7,))
    jac[:, :, :5] = contrast[:, None, None] * d_basis
    jac[:, :, 5] = 1.0
    jac[:, :, 6] = basis
    cost = np.sum(taper * res ** 2, axis=1)
    return {"cost": np.where(np.isfinite(cost), cost, np.inf), "res": res, "jac": jac}


def _linear_fit(basis, values, taper):
    """Weighted least-squares mean level and contrast (n, 2) of ``values ≈ m + A · basis``."""
    wsum = np.maximum(taper.sum(axis=1), 1e-12)
    bm = np.sum(taper * basis, axis=1) / wsum
    vm = np.sum(taper * values, axis=1) / wsum
    db = basis - bm[:, None]
    contrast = np.sum(taper * db * (values - vm[:, None]), axis=1) \
        / np.maximum(np.sum(taper * db ** 2, axis=1), 1e-12)
    return np.column_stack([vm - contrast * bm, contrast])


#: Corners whose sub-samples are processed together: a block's (n, K, P) arrays (8 x 9 x 625
#: float64, 360 kB) stay in the cache, where all corners' arrays (3 MB each) would not.
BLOCK_CORNERS = 8


def _saddle_basis(geom, sub_xy1):
    """:func:`_saddle_block` over blocks of :data:`BLOCK_CORNERS` corners: (n, P), (n, P, 5)."""
    blocks = [_saddle_block(geom[i:i + BLOCK_CORNERS], sub_xy1)
              for i in range(0, max(len(geom), 1), BLOCK_CORNERS)]
    return tuple(np.concatenate(parts) for parts in zip(*blocks))


def _saddle_block(geom, sub_xy1):
    """Pixel-averaged product of the two erf edges (n, P) and its derivatives (n, P, 5).

    ``geom`` (n, >= 5) holds the corner offset from the window centre (px), the two edge normals
    (rad) and the blur (px); ``sub_xy1`` (3, K, P) the sub-sample offsets (x, y) from the
    centre and ones. The per-sub-sample work is laid out (n, K, P).
    """
    blur = geom[:, 4]
    k = 1.0 / np.sqrt(2.0 * (blur ** 2 + SUB_VAR))   # (n,) 1 / (√2 s_eff)
    kc, ks = k[:, None] * np.cos(geom[:, 2:4]), k[:, None] * np.sin(geom[:, 2:4])   # (n, 2)
    u, v = geom[:, 0:1], geom[:, 1:2]
    # Scaled distances across (x_i = k d_i) and along (y_i) edge i as affine maps of the
    # sub-sample offsets, all four in one matrix product: (4, n, 3) @ (3, K P).
    affine = np.concatenate([np.stack([kc, ks, -(kc * u + ks * v)], axis=2),
                             np.stack([-ks, kc, ks * u - kc * v], axis=2)], axis=1)   # (n, 4, 3)
    affine = np.ascontiguousarray(affine.transpose(1, 0, 2)).reshape(-1, 3)
    x1, x2, y1, y2 = (affine @ sub_xy1.reshape(3, -1)).reshape((4, len(geom)) + sub_xy1.shape[1:])
    e1, gauss1 = _edge_terms(x1)
    e2, gauss2 = _edge_terms(x2)
    g1e2 = gauss1 * e2                                # d(e1 e2)/d x1 · √π / 2
    e1g2 = e1 * gauss2

    def mean_k(a, b):
        """Average over the sub-samples of a product, (n, P), without the (n, K, P) temporary."""
        return np.einsum("nkp,nkp->np", a, b) / a.shape[1]

    basis = mean_k(e1, e2)
    mean_g1e2, mean_e1g2 = g1e2.mean(axis=1), e1g2.mean(axis=1)
    along1, along2 = mean_k(g1e2, y1), mean_k(e1g2, y2)
    mean_across = mean_k(g1e2, x1) + mean_k(e1g2, x2)
    slope = 2.0 / np.sqrt(np.pi)                      # erf'(0)
    d_basis = np.empty(basis.shape + (5,))
    d_basis[:, :, 0] = -slope * (kc[:, 0, None] * mean_g1e2 + kc[:, 1, None] * mean_e1g2)   # d x_i / d u = -k cos θ_i
    d_basis[:, :, 1] = -slope * (ks[:, 0, None] * mean_g1e2 + ks[:, 1, None] * mean_e1g2)
    d_basis[:, :, 2] = slope * along1                 # d x_1 / d θ_1 = y_1
    d_basis[:, :, 3] = slope * along2
    d_basis[:, :, 4] = -slope * mean_across * (blur / (blur ** 2 + SUB_VAR))[:, None]   # d x_i / d s = -x_i s / s_eff²
    return basis, d_basis


#: Beyond this scaled distance from an edge, erf is ±1 and exp(-x²) 0 to the accuracy of :func:`_erf`
#: (erfc(4) = 1.5e-8, exp(-16) = 1.1e-7).
ERF_SATURATION = 4.0


def _edge_terms(x):
    """erf(x) and exp(-x²), same shape and type as ``x``, computed only within
    :data:`ERF_SATURATION` of the edge (a sharp edge's band is a few pixels of a 25-pixel window;
    beyond it exp would also underflow, which is slow)."""
    near = np.flatnonzero(np.abs(x) < ERF_SATURATION)
    x_near = x.reshape(-1).take(near)
    gauss_near = _gauss(x_near)
    erf_x = np.sign(x)
    erf_x.reshape(-1).put(near, _erf(x_near, gauss_near))
    gauss = np.zeros_like(x)
    gauss.reshape(-1).put(near, gauss_near)
    return erf_x, gauss


def _gauss(x):
    """exp(-x²), same shape and type as ``x``."""
    out = np.square(x)
    np.negative(out, out=out)
    return np.exp(out, out=out)


#: Abramowitz & Stegun 7.1.26: erf(x) = 1 - t (a1 + a2 t + ... + a5 t⁴) exp(-x²), t = 1 / (1 + p x).
_ERF_P = 0.3275911
_ERF_A = (0.254829592, -0.284496736, 1.421413741, -1.453152027, 1.061405429)


def _erf(x, gauss):
    """erf(x) from x and exp(-x²), any shape, |error| < 1.5e-7.

    Written here because scipy.special.erf is not vectorised (~45 ns a value here, 2/3 of the
    fit's time before) and the fit needs exp(-x²) anyway; the error is 1.5e-5 DN for a contrast
    of 100 DN.
    """
    t = np.abs(x) * _ERF_P
    t += 1.0
    np.reciprocal(t, out=t)
    poly = _ERF_A[4] * t
    for a in _ERF_A[3::-1]:
        poly += a
        poly *= t
    poly *= gauss
    np.subtract(1.0, poly, out=poly)
    return np.copysign(poly, x, out=poly)


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
