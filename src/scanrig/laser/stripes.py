"""Laser stripes: on every scan line across the stripe, every peak above the noise, fitted in 1-D.

The scan lines are the image rows where the stripe runs mostly vertically and the columns where it
runs mostly horizontally, decided per 4 × 4 pixel block from the pre-scan's structure and the
candidates, and both where it runs at about 45° to them, so a stripe curving over a surface is
crossed at a steep angle everywhere (or forced by ``direction``). On each line every local maximum
that passes the detection test is a candidate, not only the brightest, so a secondary reflection
never hides the true stripe; each is fitted with a pixel-integrated Gaussian along the line,
vectorised over all (line, peak) pairs of the frame.

The centre is the stripe's crossing with the scan line: for rows ``v`` is exactly the row index
and only ``u`` is uncertain (``cov_vv = cov_uv = 0``), and vice versa for columns. On a tilted
stripe the profile along the line is wider by 1/cos(tilt); ``width_px`` is that width along the
line.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError
from scanrig.laser.clipped_runs import fit_unknown_runs, unknown_laser
from scanrig.laser.colour_check import checked_detection
from scanrig.laser.colour_fit import fit_clipped
from scanrig.laser.continuity import rank_by_continuity
from scanrig.laser.fit import (
    MIN_PEAK_DN,
    MIN_WIDTH_PX,
    FitResult,
    fit_batch,
    minor_model_1d,
    parameter_covariance,
)
from scanrig.laser.image import prepare_image
from scanrig.laser.peaks import direction_map, prescan, worth_scanning
from scanrig.laser.pixels import pixel_blocks
from scanrig.laser.stacked_linalg import cholesky_solve
from scanrig.laser.stripe_candidates import (
    LineCandidates,
    crossed_steeply,
    neighbour_gaps,
    prominent,
    strongest_per_line,
)
from scanrig.laser.traces import empty_table, make_table

DIRECTIONS = ("auto", "rows", "columns")
#: A fitted centre further than this from its seed pixel has converged onto another peak.
MAX_SHIFT_PX = 2.0
#: Fits on one line whose centres lie closer than this are one peak fitted twice, px.
SAME_PEAK_PX = 0.5
#: A window whose χ²/dof exceeds this many times its misfit quantile is not a stripe the model
#: describes (texture, printed edges): its fit stops in units of its residual variance over this
#: many times that quantile (``misfit_stop`` of :func:`~scanrig.laser.fit.fit_batch`).
HOPELESS_MISFIT = 4.0


def detect_stripe(
    image: np.ndarray,
    *,
    color: str = "grey",
    dark: np.ndarray | None = None,
    roi: tuple[int, int, int, int] | None = None,
    direction: str = "auto",
    noise_sigma: float | None = None,
    saturation_level: float | str | None = None,
    k_detect: float = 6.0,
    min_separation_px: float = 3.0,
    max_width_px: float = 3.0,
    max_per_line: int = 8,
    camera: str = "",
    frame: str = "",
    check_color: bool = True,
):
    """All laser-stripe candidates of one frame: every peak on every scan line.

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
    direction : {"auto", "rows", "columns"}
        Scan lines: rows (for a near-vertical stripe), columns, or decided locally from the frame.
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
        Peaks on one line closer than this are merged (the stronger stays).
    max_width_px : float
        Largest Gaussian σ fitted, along the line; the window is ±ceil(3 · max_width_px) pixels.
    max_per_line : int
        At most this many peaks per line (the strongest) are fitted.
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
        One row per (line, peak) with the columns of ``traces.parquet`` (``kind = "stripe"``;
        ``line`` = full-frame row index where rows were scanned (then ``cov_vv = 0``) or column index
        where columns were (then ``cov_uu = 0``); rank 0 = the peak of its line on the longest continuous
        trace, the most prominent among equals, :mod:`scanrig.laser.continuity`). Empty for a
        dark frame.

    Raises
    ------
    ShapeError, InputError
        On an image of the wrong type or shape, or invalid options; InputError also where another
        colour than ``color`` finds far more laser light (``check_color``).

    Examples
    --------
    >>> import numpy as np, scanrig
    >>> img = np.full((64, 64), 10, np.uint8); img[:, 20:23] = 200
    >>> t = scanrig.detect_stripe(img, noise_sigma=2.0)
    >>> len(t), round(t["u"][0].as_py(), 2)
    (64, 21.0)
    """
    if direction not in DIRECTIONS:
        raise InputError(f"direction must be one of {DIRECTIONS}, got {direction!r}")
    detect = functools.partial(_detect_stripe, image, dark=dark, roi=roi, direction=direction, noise_sigma=noise_sigma,
                               saturation_level=saturation_level, k_detect=k_detect,
                               min_separation_px=min_separation_px, max_width_px=max_width_px,
                               max_per_line=max_per_line, camera=camera, frame=frame)
    return checked_detection(detect, color, True, k_detect, check_color)


def _detect_stripe(image, color, *, dark, roi, direction, noise_sigma, saturation_level, k_detect, min_separation_px,
                   max_width_px, max_per_line, camera, frame):
    """:func:`detect_stripe` without the colour check: the table and the frame's
    :class:`~scanrig.laser.image.LaserImage`."""
    li = prepare_image(image, color, dark, roi, saturation_level, noise_sigma)
    excess = prescan(li)
    if direction == "auto":
        found = _crossings(li, excess, k_detect, min_separation_px, max_width_px)
    else:
        found = {direction: prominent(li, direction, excess, k_detect, min_separation_px, max_width_px)}
    # where the laser channel is unknown (needs a laser-off frame): found once, fitted per direction
    unknown = unknown_laser(li) if li.colour is not None and li.colour.dark is not None else None
    fitted = {along: _fit_along(li, along, c.take(strongest_per_line(c.line, c.prominence, max_per_line)),
                                max_width_px, unknown)
              for along, c in found.items()}
    fitted = {along: f for along, f in fitted.items() if f is not None}
    # the unclipped candidates of both directions in one batch: one fit's fixed cost per iteration
    plain = {along: _line_windows(li, along, f[1], max_width_px) for along, f in fitted.items() if f[1].line.size}
    plain_fits = dict(zip(plain, _fit_lines(list(plain.values()), max_width_px)))
    parts = [_line_table(li, along, f[0] + ([plain_fits[along]] if along in plain_fits else []))
             for along, f in fitted.items()]
    if not parts:
        return empty_table(), li
    return make_table("stripe", {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, camera, frame), li


def _crossings(li, excess, k_detect, min_separation_px, max_width_px) -> dict[str, LineCandidates]:
    """Candidates along rows and along columns, each scanned where it may cross a stripe steeply
    (:func:`~scanrig.laser.peaks.worth_scanning`) and kept where it does
    (:func:`~scanrig.laser.stripe_candidates.crossed_steeply`)."""
    found = {along: prominent(li, along, blocks, k_detect, min_separation_px, max_width_px)
             for along, blocks in zip(("rows", "columns"), worth_scanning(excess))}
    if min(c.line.size for c in found.values()) == 0:  # candidates along one direction only: the
        return found  # direction map gives every block to it, and all its candidates stay
    row_share = direction_map(found["rows"].block_weights(True, excess.shape),
                              found["columns"].block_weights(False, excess.shape))
    return {along: c.take(crossed_steeply(c, row_share, along == "rows", max_width_px))
            for along, c in found.items()}


def _fit_along(li, along, cand: LineCandidates, max_width_px,
               unknown_pixels) -> tuple[list[dict[str, np.ndarray]], LineCandidates] | None:
    """Sub-pixel centres of the clipped candidates of one scan direction and of the runs of
    ``unknown_pixels`` along it (:mod:`scanrig.laser.clipped_runs`; None without a laser-off frame),
    as columns of :func:`_line_table`, and the candidates left to fit as unclipped
    (:func:`_line_windows`); None when there are none."""
    unknown = None if unknown_pixels is None else fit_unknown_runs(li, along == "rows", unknown_pixels)
    if cand.line.size == 0 and unknown is None:
        return None
    clipped = cand.run_half > 0 if li.colour is not None else np.zeros(cand.line.size, bool)
    parts = [] if unknown is None else [unknown]
    if clipped.any():
        wide = cand.take(clipped)
        fit = fit_clipped(li.colour, along == "rows", wide.line, wide.pos,
                          int(np.ceil(3.0 * max_width_px)) + int(wide.run_half.max()),
                          MAX_SHIFT_PX + wide.run_half / 2.0)
        index = fit.pop("index")
        fit.update(line=wide.line[index], sigma_px=np.sqrt(fit["var"]), saturated=np.ones(index.size, bool),
                   prominence=wide.prominence[index])
        parts.append(fit)
        # A colour fit that converged elsewhere followed a step in reflectance under the beam (its
        # background is one level per channel; a printed edge is a step in all three): fitted as
        # unclipped instead, on the laser signal, where grey steps cancel, its clipped pixels left out.
        converged = np.zeros(wide.line.size, bool)
        converged[index] = True
        clipped[np.flatnonzero(clipped)[~converged]] = False
    return parts, cand.take(~clipped)


def _line_table(li, along, parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The fits ``parts`` of one scan direction (signal coordinates along the lines) as full-frame
    columns of the traces table, one per distinct peak (:func:`distinct_peaks`), ranked by
    continuity."""
    rows = along == "rows"
    cols = {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}
    keep = distinct_peaks(cols["line"], cols["centre"], cols["var"])
    cols = {k: a[keep] for k, a in cols.items()}
    centre = cols.pop("centre")
    var = cols.pop("var")
    zero = np.zeros_like(var)
    if rows:
        cols.update(u=centre + li.origin[0], v=cols["line"] + float(li.origin[1]), cov_uu=var, cov_vv=zero)
        cols["line"] = cols["line"] + li.origin[1]
    else:
        cols.update(u=cols["line"] + float(li.origin[0]), v=centre + li.origin[1], cov_uu=zero, cov_vv=var)
        cols["line"] = cols["line"] + li.origin[0]
    cols["cov_uv"] = zero
    cols["rank"] = rank_by_continuity(cols["line"], centre, cols.pop("prominence"))
    cols["line"] = cols["line"].astype(np.int32)
    return cols


def distinct_peaks(line: np.ndarray, centre: np.ndarray, var: np.ndarray) -> np.ndarray:
    """Keep-mask of the fits that are distinct peaks: fits on one line whose centres follow each
    other within ``SAME_PEAK_PX`` are one peak fitted twice (two seeds a few pixels apart that
    converged onto it), and of them the best determined (smallest ``var``) stays.

    Parameters
    ----------
    line : (n,) int array
        Scan line of each fit.
    centre : (n,) float array
        Fitted centre along its line, px.
    var : (n,) float array
        Variance of the centre, px².

    Returns
    -------
    (n,) bool array
    """
    order = np.lexsort((centre, line))
    line, centre = line[order], centre[order]
    # a peak's group starts where the line changes or the centre moves on by more than SAME_PEAK_PX
    starts = np.r_[True, (line[1:] != line[:-1]) | (centre[1:] - centre[:-1] > SAME_PEAK_PX)]
    keep = np.ones(order.size, bool)
    if starts.all():
        return keep
    group = np.cumsum(starts)
    best = np.lexsort((var[order], group))  # by group, then variance: the first of each group stays
    keep[:] = False
    keep[order[best[np.r_[True, group[best][1:] != group[best][:-1]]]]] = True
    return keep


@dataclass(frozen=True)
class _LineWindows:
    """The fit windows of one scan direction's unclipped candidates (:func:`_line_windows`), for
    :func:`_fit_lines`.

    Attributes
    ----------
    y, mask : (W, n) float and bool arrays
        The windows along the lines, DN, candidate-minor, and their fitted pixels.
    p0 : (n, 4) float array
        Start values (:data:`~scanrig.laser.fit.PARAMS_1D`).
    noise : (n,) float array
        Noise σ at each candidate, DN.
    saturated : (W, n) bool array or None
        The windows' clipped pixels.
    cand : LineCandidates
        The candidates.
    correlation : (L,) float array or None
        The noise's correlation along the lines (None: white).
    shot_slope : float or None
        Known shot-noise slope (None: pooled from these windows' residuals).
    """

    y: np.ndarray
    mask: np.ndarray
    p0: np.ndarray
    noise: np.ndarray
    saturated: np.ndarray | None
    cand: LineCandidates
    correlation: np.ndarray | None = None
    shot_slope: float | None = None


def _line_windows(li, along, plain: LineCandidates, max_width_px) -> _LineWindows:
    """The windows of the unclipped candidates ``plain`` of one scan direction, on the laser signal
    or, in a colour frame with a laser-off frame in which luma carries the laser, on the luma
    difference (:mod:`scanrig.laser.luma`). There a candidate without a peak in luma is not the
    laser (the colour difference rings beside printed edges): its fit fails and it is dropped (on
    the rendered colour set 90 of 706 candidates per frame, none on the beam)."""
    rows = along == "rows"
    saturated = None if li.saturated is None else (li.saturated if rows else li.saturated.T)
    uv = (plain.pos, plain.line) if rows else (plain.line, plain.pos)
    if li.colour is not None and li.colour.dark is not None and li.luma.carries_laser(li.colour.laser_channel):
        luma = li.luma
        return _windows(luma.plane if rows else luma.plane.T, saturated, plain, np.zeros(plain.line.size),
                        luma.sigma_at(*uv), max_width_px, luma.correlation(rows), luma.shot_slope(li.colour.laser_channel))
    return _windows(li.signal if rows else li.signal.T, saturated, plain, li.background_at(*uv), plain.noise,
                    max_width_px)


def _windows(signal, saturated, cand: LineCandidates, background, noise, max_width_px, correlation=None,
             shot_slope=None) -> _LineWindows:
    """The window of every candidate along its line (axis 1 of ``signal``), cut halfway to the
    nearest local maxima on its line (:attr:`LineCandidates.maxima`), and its start values."""
    half = int(np.ceil(3.0 * max_width_px))
    offs = np.arange(-half, half + 1)
    line, pos = cand.line, cand.pos
    window = (line, pos - half, 1, 2 * half + 1)  # beyond the frame its edge repeats (and is masked)
    y = np.ascontiguousarray(pixel_blocks(signal, *window)[:, 0].T, dtype=np.float64)
    mask = _nearest_on_line(line, pos, cand.maxima, offs)
    mask &= (offs[:, None] >= -pos) & (offs[:, None] < signal.shape[1] - pos)  # inside the frame
    sat = None if saturated is None else np.ascontiguousarray(pixel_blocks(saturated, *window)[:, 0].T)
    if sat is not None:
        mask &= ~sat
    p0 = _start(y, background.astype(np.float64), half, max_width_px, sat)
    return _LineWindows(y, mask, p0, noise, sat, cand, correlation, shot_slope)


def _fit_lines(windows: list[_LineWindows], max_width_px) -> list[dict[str, np.ndarray]]:
    """Fit the windows of every scan direction (:func:`_line_windows`) in one batch, so that the
    fit's fixed cost per iteration is paid once (on the rendered 1080p colour frame, 1,430
    texture windows along rows and columns: 30 ms instead of 40); each direction's covariance
    apart (:func:`~scanrig.laser.fit.parameter_covariance`: its noise and shot-noise slope).
    Returns per direction the columns of :func:`_line_table`, failed fits dropped."""
    if not windows:
        return []
    half = int(np.ceil(3.0 * max_width_px))
    offs = np.arange(-half, half + 1)
    y, mask = (np.concatenate([getattr(w, k) for w in windows], axis=1) for k in ("y", "mask"))
    noise = np.concatenate([w.noise for w in windows])
    lower = np.array([MIN_PEAK_DN, -half, MIN_WIDTH_PX, -np.inf])
    upper = np.array([np.inf, half, max_width_px, np.inf])
    res = fit_batch(minor_model_1d(offs.astype(float)), y, mask, np.concatenate([w.p0 for w in windows]), lower,
                    upper, minor=True, noise_var=noise**2, misfit_stop=HOPELESS_MISFIT)
    ends = np.cumsum([w.cand.line.size for w in windows])
    return [_line_fits(w, _part(res, slice(end - w.cand.line.size, end)), half) for w, end in zip(windows, ends)]


def _part(res: FitResult, part: slice) -> FitResult:
    """The fits ``part`` of a batch."""
    return FitResult(res.params[part], res.info_inv[part], res.chi2_unit[part], res.dof[part], res.model,
                     res.y[:, part], None if res.weights is None else res.weights[:, part])


def _line_fits(w: _LineWindows, res: FitResult, half: int) -> dict[str, np.ndarray]:
    """The columns of :func:`_line_table` of the fits ``res`` of the windows ``w``, failed fits
    dropped."""
    p, cand = res.params, w.cand
    var = parameter_covariance(res, w.noise, correlation=w.correlation, shot_slope=w.shot_slope)[:, 1, 1]
    ok = np.isfinite(var) & (np.abs(p[:, 1]) <= MAX_SHIFT_PX) & (res.dof > 0)
    out = {
        "line": cand.line, "centre": cand.pos + p[:, 1], "var": var, "sigma_px": np.sqrt(np.abs(var)),
        "peak": p[:, 0], "width_px": p[:, 2], "snr": p[:, 0] / w.noise,
        "saturated": (np.zeros(cand.line.size, bool) if w.saturated is None
                      else w.saturated[half - 1 : half + 2].any(axis=0)),
        "prominence": cand.prominence,
    }
    return {k: a[ok] for k, a in out.items()}


def _nearest_on_line(line, pos, maxima, offs) -> np.ndarray:
    """(W, n) True where a window pixel at ``offs`` from its peak ``(line, pos)`` is nearer it
    than the neighbouring local maxima on the same line, ``maxima`` (sorted
    :func:`~scanrig.laser.stripe_candidates.line_keys`): texture peaks the detection test
    rejected still bound a fit beside them, which does not model them."""
    before, after = neighbour_gaps(line, pos, maxima)
    twice = 2 * offs[:, None]
    return (twice > -before) & (twice < after)


#: Widths tried for the start of a fit whose core is clipped, pixels.
_CLIPPED_START_WIDTHS = np.array([0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0])
#: A trial width is used where its profile reaches about this share of its peak on the unclipped pixels.
_MIN_FLANK_SHARE = 0.1


def _start(y, background, half, max_width_px, saturated) -> np.ndarray:
    """Start values ``(n, 4)`` from windows ``y (W, n)``: the Gaussian fitted to the five central
    pixels (:func:`_log_parabola`), else peak, centroid and width from the excess area of that
    ±2 px core.

    A clipped core has no usable peak or area; there the centre starts at the middle of the
    clipped run and the width at the best of a few trial widths, each with peak and background
    solved linearly from the unclipped pixels.
    """
    core = y[half - 2 : half + 3] - background
    excess = np.clip(core, 0.0, None)
    peak = np.maximum(core.max(axis=0), 1e-3)
    total = np.maximum(excess.sum(axis=0), 1e-9)
    x0 = (excess * np.arange(-2.0, 3.0)[:, None]).sum(axis=0) / total
    width = total / (np.sqrt(2 * np.pi) * peak)
    _log_parabola(core, peak, x0, width)
    start = np.stack([peak, x0, np.clip(width, 0.5, max_width_px), background], axis=1)
    if saturated is not None:
        clipped = saturated[half]
        if clipped.any():
            start[clipped] = _clipped_start(y[:, clipped].T, saturated[:, clipped].T, half, max_width_px)
    return start


def _log_parabola(excess, peak, x0, width) -> None:
    """Where the five central pixels ``excess (5, n)`` above the background curve down in log,
    overwrite ``peak, x0, width (n,)`` by the Gaussian fitted to them: a parabola fitted to their
    logarithms by least squares, each weighted by its squared excess (the inverse variance of its
    log under white noise; pixels at or below the background left out, at least three needed),
    the pixel-integrated profile's width ``√(s² + 1/12)`` taken as that of the samples. From this
    start one Levenberg–Marquardt step satisfies the fit's statistical stop rule for most windows
    (for 97 % of the rows of a grey stripe of width 1.5 px at SNR 90, 70 % at width 2.5 px)."""
    x = np.arange(-2.0, 3.0)
    positive = excess > 0.0
    with np.errstate(divide="ignore", invalid="ignore"):  # (those not positive are left out)
        log = np.where(positive, np.log(excess), 0.0)
    weight = np.where(positive, excess * excess, 0.0)
    powers = x ** np.arange(5.0)[:, None]  # (5, 5): x^k
    moments = powers @ weight  # Σ w x^k, k = 0 .. 4
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # log = c0 + c1 x + c2 x²: normal equations (3, 3, n), singular (NaN) with fewer than three pixels
        c = cholesky_solve(moments[np.add.outer(np.arange(3), np.arange(3))], powers[:3] @ (weight * log))
        sampled_var = -0.5 / c[2]
        offset = c[1] * sampled_var
        width_px = np.sqrt(np.maximum(sampled_var - 1.0 / 12.0, MIN_WIDTH_PX**2))
        top = np.exp(c[0] + 0.5 * offset**2 / sampled_var) * np.sqrt(sampled_var) / width_px
    use = np.isfinite(top) & (sampled_var > 0.0) & (np.abs(offset) < 1.0)
    np.copyto(peak, top, where=use)
    np.copyto(x0, offset, where=use)
    np.copyto(width, width_px, where=use)


def _clipped_start(y, saturated, half, max_width_px) -> np.ndarray:
    """Start values (peak, x0, width, background) for windows whose centre pixel is clipped."""
    right = np.cumprod(saturated[:, half:], axis=1).sum(axis=1)
    left = np.cumprod(saturated[:, half::-1], axis=1).sum(axis=1)
    x0 = (right - left) / 2.0
    widths = _CLIPPED_START_WIDTHS[_CLIPPED_START_WIDTHS <= max_width_px]
    x = np.arange(-half, half + 1, dtype=float)
    g = np.exp(-0.5 * ((x[None, None, :] - x0[:, None, None]) / widths[None, :, None]) ** 2)  # (n, k, W)
    w = (~saturated)[:, None, :].astype(float)
    # weighted linear least squares of y ≈ A g + b per (candidate, width)
    s_w, s_g, s_y = w.sum(-1), (w * g).sum(-1), (w * y[:, None, :]).sum(-1)
    s_gg, s_gy = (w * g * g).sum(-1), (w * g * y[:, None, :]).sum(-1)
    det = s_w * s_gg - s_g**2
    with np.errstate(divide="ignore", invalid="ignore"):  # all pixels clipped: no solution, NaN
        amp = (s_w * s_gy - s_g * s_y) / det
        bg = (s_y - amp * s_g) / s_w
        resid = (w * (y[:, None, :] - amp[..., None] * g - bg[..., None]) ** 2).sum(-1)
    # a trial width whose profile hardly reaches the unclipped pixels (its squares there summing to
    # less than those of one pixel at a tenth of its peak) leaves its amplitude free: it fitted a
    # wide clipped run's flat flanks exactly at 1e26 DN, a start the fit then overflowed from
    usable = np.isfinite(resid) & (amp > 0) & (s_gg >= _MIN_FLANK_SHARE**2)
    resid = np.where(usable, resid, np.inf)
    best = np.argmin(resid, axis=1)
    pick = np.arange(y.shape[0])
    found = usable[pick, best]
    return np.stack([np.where(found, amp[pick, best], 1.0), x0, widths[best],
                     np.where(found, bg[pick, best], 0.0)], axis=1)
