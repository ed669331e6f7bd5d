"""Laser spots: every candidate in a frame with a 2-D Gaussian fit, its covariance and SNR.

A frame may hold the true spot and secondary reflections (shiny surfaces, inter-reflections);
all of them are reported, ranked by fitted peak, and the decision which one is real is left to
reconstruction, where other cameras can vote.
"""

from __future__ import annotations

import functools

import numpy as np

from scanrig.laser.colour_check import checked_detection
from scanrig.laser.colour_fit import fit_clipped_spots
from scanrig.laser.fit import MIN_PEAK_DN, MIN_WIDTH_PX, fit_batch, minor_model_2d, parameter_covariance
from scanrig.laser.image import prepare_image
from scanrig.laser.peaks import Candidates, find_candidates, suppress_2d
from scanrig.laser.traces import empty_table, make_table

#: A fitted centre that moves further than this from its seed pixel has converged onto a
#: neighbouring peak (or diverged); the candidate is dropped.
MAX_SHIFT_PX = 2.0


def detect_spots(
    image: np.ndarray,
    *,
    color: str = "grey",
    dark: np.ndarray | None = None,
    roi: tuple[int, int, int, int] | None = None,
    noise_sigma: float | None = None,
    saturation_level: float | str | None = None,
    k_detect: float = 6.0,
    min_separation_px: float = 3.0,
    max_width_px: float = 3.0,
    max_candidates: int = 32,
    camera: str = "",
    frame: str = "",
    check_color: bool = True,
):
    """All laser-spot candidates of one frame, each with a sub-pixel centre and its uncertainty.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 or uint16 array
        The frame (RGB for colour), DN.
    color : {"grey", "red", "green", "blue"}
        Laser colour (see :mod:`scanrig.laser.image`).
    dark : array like ``image``, optional
        Laser-off frame to subtract.
    roi : (u0, v0, u1, v1) ints, optional
        Region of interest, pixels, end-exclusive; output coordinates stay full-frame.
    noise_sigma : float, optional
        Known noise σ of the signal, DN; estimated robustly from the frame when omitted.
    saturation_level : float or "auto", optional
        DN at which pixels clip (default: dtype maximum); ``"auto"`` finds each channel's level from
        the frames (:func:`~scanrig.laser.clip_level.channel_clip_levels`), as ``scanrig detect`` does:
        use it for a colour camera, whose white balance can clip a channel below 255, and for 10- to
        14-bit data in 16-bit files. Clipped pixels are left out of the fit.
    k_detect : float
        Detection threshold: the 3 × 3 box sum above background, in units of its noise.
    min_separation_px : float
        Candidates closer than this are merged (the stronger stays).
    max_width_px : float
        Largest Gaussian σ fitted; the fit window is ±ceil(3 · max_width_px) pixels.
    max_candidates : int
        At most this many candidates (the strongest) are fitted.
    camera, frame : str
        Written into every row.
    check_color : bool
        Raise when the frame's laser shows in another channel than ``color``'s
        (:func:`~scanrig.laser.colour_check.check_laser_colour`: questioned only where no bright
        laser was found, so a right-colour frame costs some 15 µs more); False for a caller that
        checks its frames' colour itself, as ``scanrig detect`` does once per camera.

    Returns
    -------
    pyarrow.Table
        One row per candidate with the columns of ``traces.parquet`` (``kind = "spot"``,
        ``line = -1``), ranked by fitted peak (rank 0 = brightest). Empty for a dark frame.
        ``sigma_px`` is the square root of the larger eigenvalue of the centre covariance.

    Raises
    ------
    ShapeError, InputError
        On an image of the wrong type or shape, or invalid options; InputError also where another
        colour than ``color`` finds far more laser light (``check_color``).

    Examples
    --------
    >>> import numpy as np, scanrig
    >>> img = np.full((64, 64), 10, np.uint8); img[30:33, 40:43] = 200
    >>> t = scanrig.detect_spots(img, noise_sigma=2.0)
    >>> [round(x, 2) for x in (t["u"][0].as_py(), t["v"][0].as_py())]
    [41.0, 31.0]
    """
    detect = functools.partial(_detect_spots, image, dark=dark, roi=roi, noise_sigma=noise_sigma,
                               saturation_level=saturation_level, k_detect=k_detect,
                               min_separation_px=min_separation_px, max_width_px=max_width_px,
                               max_candidates=max_candidates, camera=camera, frame=frame)
    return checked_detection(detect, color, False, k_detect, check_color)


def _detect_spots(image, color, *, dark, roi, noise_sigma, saturation_level, k_detect, min_separation_px,
                  max_width_px, max_candidates, camera, frame):
    """:func:`detect_spots` without the colour check: the table and the frame's
    :class:`~scanrig.laser.image.LaserImage`."""
    li = prepare_image(image, color, dark, roi, saturation_level, noise_sigma)
    cand = find_candidates(li, "2d", k_detect=k_detect)
    cand = cand.take(suppress_2d(cand.u, cand.v, cand.score, min_separation_px))
    if cand.u.size > max_candidates:
        cand = cand.take(np.argsort(-cand.score, kind="stable")[:max_candidates])
    if cand.u.size == 0:
        return empty_table(), li
    cols = _fit_spots(li, cand, max_width_px)
    keep = suppress_2d(cols["u"], cols["v"], cols["peak"], min_separation_px)  # seeds that met
    cols = {k: a[keep] for k, a in cols.items()}
    order = np.argsort(-cols["peak"], kind="stable")
    cols = {k: a[order] for k, a in cols.items()}
    cols["rank"] = np.arange(order.size, dtype=np.int32)
    cols["line"] = np.full(order.size, -1, np.int32)
    cols["u"] = cols["u"] + li.origin[0]
    cols["v"] = cols["v"] + li.origin[1]
    return make_table("spot", cols, camera, frame), li


def _fit_spots(li, cand: Candidates, max_width_px: float) -> dict[str, np.ndarray]:
    """Fit every candidate (a clipped spot of a colour frame from all its channels, the others on
    the laser signal); failed fits are dropped."""
    half = int(np.ceil(3.0 * max_width_px))
    offs = np.arange(-half, half + 1)
    if li.saturated is not None:
        cand = _centre_of_saturated_core(li.saturated, cand, offs)
    clipped = np.zeros(cand.u.size, bool)
    if li.colour is not None and li.saturated is not None:
        clipped = li.saturated[cand.v, cand.u]
    parts = []
    if not clipped.all():
        parts.append(_fit_signal(li, cand.take(~clipped), half, max_width_px))
    if clipped.any():
        parts.append(_fit_colour(li, cand.take(clipped), half))
    return {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}


def _fit_colour(li, cand: Candidates, half: int) -> dict[str, np.ndarray]:
    """Clipped spots of a colour frame, fitted from every channel (:mod:`scanrig.laser.colour_fit`)
    in a window grown by the clipped core's radius."""
    run = li.saturated[np.clip(cand.v[:, None] + np.arange(-half, half + 1), 0, li.saturated.shape[0] - 1),
                       cand.u[:, None]].sum(axis=1)
    fit = fit_clipped_spots(li.colour, cand.u, cand.v, half + int(run.max()) // 2, MAX_SHIFT_PX)
    return _spot_columns(fit["u"], fit["v"], fit["cov"], fit["peak"], fit["width_px"], fit["snr"],
                         np.ones(fit["u"].size, bool))


def _fit_signal(li, cand: Candidates, half: int, max_width_px: float) -> dict[str, np.ndarray]:
    """Fit a separable pixel-integrated Gaussian to the laser signal around every candidate. The
    windows are stacked candidate-minor, ``(Wv, Wu, n)`` (see :mod:`scanrig.laser.fit`)."""
    offs = np.arange(-half, half + 1)
    h, w = li.signal.shape
    rows = offs[:, None] + cand.v
    cols = offs[:, None] + cand.u
    inside = ((rows >= 0) & (rows < h))[:, None, :] & ((cols >= 0) & (cols < w))[None, :, :]
    rr = np.minimum(np.maximum(rows, 0), h - 1)[:, None, :]
    cc = np.minimum(np.maximum(cols, 0), w - 1)[None, :, :]
    y = li.signal[rr, cc].astype(np.float64)
    mask = inside & _nearest_mask(cand, offs)
    saturated = None if li.saturated is None else li.saturated[rr, cc]
    if saturated is not None:
        mask &= ~saturated
    n = cand.u.size
    background = li.background_at(cand.u, cand.v).astype(np.float64)
    p0 = _start(y, background, half, max_width_px, saturated)
    lower = np.array([MIN_PEAK_DN, -half, -half, MIN_WIDTH_PX, MIN_WIDTH_PX, -np.inf])
    upper = np.array([np.inf, half, half, max_width_px, max_width_px, np.inf])
    x = offs.astype(float)
    res = fit_batch(minor_model_2d(x, x), y.reshape(-1, n), mask.reshape(-1, n), p0, lower, upper, minor=True)
    p = res.params
    noise = li.noise_at(cand.u, cand.v).astype(np.float64)
    cov = parameter_covariance(res, noise, centre=(1, 2))[:, 1:3, 1:3]
    ok = (np.all(np.isfinite(cov), axis=(1, 2)) & (np.abs(p[:, 1]) <= MAX_SHIFT_PX)
          & (np.abs(p[:, 2]) <= MAX_SHIFT_PX) & (res.dof > 0))
    core = (np.zeros(n, bool) if saturated is None
            else saturated[half - 1 : half + 2, half - 1 : half + 2].any(axis=(0, 1)))
    out = _spot_columns(cand.u + p[:, 1], cand.v + p[:, 2], cov, p[:, 0], np.sqrt(p[:, 3] * p[:, 4]),
                        p[:, 0] / noise, core)
    return {k: a[ok] for k, a in out.items()}


def _spot_columns(u, v, cov, peak, width_px, snr, saturated) -> dict[str, np.ndarray]:
    """The columns of :func:`_fit_spots` of ``n`` fitted spots, from either fit.

    Parameters
    ----------
    u, v : (n,) float arrays
        Fitted centres, signal pixels.
    cov : (n, 2, 2) float array
        Covariance of each centre ``(u, v)``, px².
    peak, width_px, snr : (n,) float arrays
        Fitted peak (DN), Gaussian σ (px) and peak over noise.
    saturated : (n,) bool array
        Whether the spot's core is clipped.

    Returns
    -------
    dict of (n,) arrays
        ``u, v, sigma_px, peak, width_px, snr, cov_uu, cov_uv, cov_vv, saturated``; ``sigma_px`` is
        the square root of the covariance's larger eigenvalue.
    """
    cov_uu, cov_uv, cov_vv = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    return {"u": u, "v": v, "sigma_px": np.sqrt(np.abs(_larger_eigenvalue(cov_uu, cov_uv, cov_vv))),
            "peak": peak, "width_px": width_px, "snr": snr, "cov_uu": cov_uu, "cov_uv": cov_uv,
            "cov_vv": cov_vv, "saturated": saturated}


def _larger_eigenvalue(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Larger eigenvalue of the symmetric 2 × 2 matrices ``[[a, b], [b, c]]``."""
    with np.errstate(invalid="ignore"):
        return 0.5 * (a + c) + np.hypot(0.5 * (a - c), b)


def _centre_of_saturated_core(saturated, cand: Candidates, offs) -> Candidates:
    """Move seeds on a clipped plateau (found at one of its corners) to the pixel nearest the
    centroid of the clipped pixels in their window."""
    h, w = saturated.shape
    rr = np.clip(cand.v[:, None] + offs, 0, h - 1)[:, :, None]
    cc = np.clip(cand.u[:, None] + offs, 0, w - 1)[:, None, :]
    sat = saturated[rr, cc]
    count = np.maximum(sat.sum(axis=(1, 2)), 1)
    on = sat[:, offs.size // 2, offs.size // 2]
    du = np.rint((sat.sum(axis=1) * offs).sum(axis=1) / count).astype(np.int64)
    dv = np.rint((sat.sum(axis=2) * offs).sum(axis=1) / count).astype(np.int64)
    return Candidates(np.where(on, cand.u + du, cand.u), np.where(on, cand.v + dv, cand.v), cand.score)


def _nearest_mask(cand: Candidates, offs: np.ndarray) -> np.ndarray:
    """(W, W, n) True where a window pixel is at least as near its own candidate as any other."""
    n = cand.u.size
    if n < 2:
        return np.ones((offs.size, offs.size, n), bool)
    du = cand.u[None, :] - cand.u[:, None]  # (n, n): other minus own
    dv = cand.v[None, :] - cand.v[:, None]
    reach = 2 * offs[-1]
    near = (np.abs(du) <= reach) & (np.abs(dv) <= reach)
    np.fill_diagonal(near, False)
    i, j = np.nonzero(near)  # pairs of candidates within two windows of each other: few
    mask = np.ones((offs.size, offs.size, n), bool)
    if i.size == 0:
        return mask
    own_d2 = offs[:, None] ** 2 + offs[None, :] ** 2
    other_d2 = ((offs[None, :, None] - dv[i, j][:, None, None]) ** 2
                + (offs[None, None, :] - du[i, j][:, None, None]) ** 2)
    nearer = np.ones((n, offs.size, offs.size), bool)
    np.logical_and.at(nearer, i, own_d2[None] <= other_d2)
    mask[...] = nearer.transpose(1, 2, 0)
    return mask


def _start(y: np.ndarray, background: np.ndarray, half: int, max_width_px: float,
           saturated: np.ndarray | None) -> np.ndarray:
    """Start values ``(n, 6)`` from windows ``y (Wv, Wu, n)``: peak, centroid and width from the
    excess volume of the 5 × 5 core; for a clipped core, width and peak from the areas above the
    clip level and above half of it (``A exp(−r²/2s²)`` crosses each level on a circle of area π r²)."""
    core = y[half - 2 : half + 3, half - 2 : half + 3] - background
    excess = np.clip(core, 0.0, None)
    peak = np.maximum(core.max(axis=(0, 1)), 1e-3)
    total = np.maximum(excess.sum(axis=(0, 1)), 1e-9)
    grid = np.arange(-2.0, 3.0)[:, None]
    u0 = (excess.sum(axis=0) * grid).sum(axis=0) / total
    v0 = (excess.sum(axis=1) * grid).sum(axis=0) / total
    width = np.sqrt(total / (2.0 * np.pi * peak))
    clipped = None if saturated is None else saturated[half, half]
    if clipped is not None and clipped.any():
        ys, sat, bg = y[:, :, clipped], saturated[:, :, clipped], background[clipped]
        # the clip level in signal units (a lower bound when the signal mixes channels)
        level = np.where(sat, ys, np.inf).min(axis=(0, 1)) - bg
        r2_sat = sat.sum(axis=(0, 1)) / np.pi
        r2_half = (ys - bg >= level / 2).sum(axis=(0, 1)) / np.pi
        width[clipped] = np.sqrt(np.maximum(r2_half - r2_sat, 0.25) / (2 * np.log(2.0)))
        peak[clipped] = level * np.exp(np.minimum(r2_sat / (2 * width[clipped] ** 2), 5.0))
        u0[clipped] = v0[clipped] = 0.0
    width = np.clip(width, 0.5, max_width_px)
    return np.stack([peak, u0, v0, width, width, background], axis=1)
