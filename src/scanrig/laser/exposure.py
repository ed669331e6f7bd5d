"""A laser-off frame taken at another exposure than its laser-on frame, brought to the frame's.

A camera left on automatic exposure or white balance (most webcams and phones are, by default)
does not take the laser-off frame at the laser-on frame's settings: between the two the whole
scene changes brightness, per channel. Subtracted as it is, the laser-off frame then leaves the
scene's texture in the signal, scaled by the mismatch: with the laser-off frame at 0.8 of the
exposure, rank 0 lay on the stripe on 97.1 % of the real Ciclop bust's rows instead of 99.4 %, and
within 0.5 px on 94.3 % of the rendered stripes on printed paper instead of 98.6 %
(``benchmarks/bench_colour_stripes.py``).

Away from the laser the two frames show the same scene, so in each channel one frame is the other
times a gain (an exposure, gain or white-balance change; a power-law tone curve keeps it a gain).
The gain is the median of the ratio laser-on / laser-off over the pixels that both frames show
well: the laser lights a few per cent of them, which the median ignores. Where a channel's gain
departs from 1 by more than ``GAIN_TOLERANCE`` the laser-off frame is scaled by it; its pixels at
the dtype's maximum stay there (clipped, their value unknown).

Under flickering light (mains-powered LED or fluorescent lamps, 100 or 120 Hz) a rolling shutter
exposes each row at its own phase of the flicker: the frame shows horizontal bands, and the two
frames of a pair show them at different phases, so that the gain varies from row to row
(:func:`row_gains`). Each band of ``BAND_ROWS`` rows gets a gain per channel, taken as a profile
over the rows times a factor per channel; where the profile's running median departs from its
level by more than ``GAIN_TOLERANCE`` (and more than the bands' noise), each row of the laser-off
frame is scaled by its own gain. The laser's light, a horizontal line or a bright object moves
one or two bands, or one channel, and is told apart. With ±20 % bands over 300 rows on the
laser-off frame, rank 0 lay within 0.5 px on 97.1 % of the rendered stripes' rows matched as a
whole, 98.6 % matched row by row, as without bands; on the real Ciclop bust's stripe on 98.8-98.9 %
of the rows over 300-700 rows (99.1-99.2 % row by row), 99.4 % without bands.

It does not correct a gain that varies along the rows, or a different scene (something moved).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import median_filter

#: A channel whose gain is within this of 1 is left as it is (1 % of a 200 DN scene is 2 DN,
#: about the noise of an 8-bit camera).
GAIN_TOLERANCE = 0.01
#: Pixels taken for the gain, about this many, on a regular grid: the median of 10^4 ratios that
#: spread by 5 % is exact to about 6 x 10^-4, a sixteenth of ``GAIN_TOLERANCE``.
SAMPLE_PIXELS = 10_000
#: Pixels whose laser-off value lies between these fractions of the dtype's maximum take part:
#: dark ones have coarse ratios, bright ones may be clipped in either frame (or by white balance).
USABLE_LEVELS = (0.1, 0.97)
#: Fewest usable pixels for a gain; with fewer the frames are left as they are.
MIN_PIXELS = 1000
#: Rows per band of the row gains: flicker bands span hundreds of rows (a 100 Hz flicker read out
#: over 1/30 s: a period in a third of the frame).
BAND_ROWS = 16
#: Pixels sampled per band, about: the median of 256 ratios that spread by 5 % is exact to 0.4 %.
BAND_SAMPLES = 256
#: Fewest usable pixels for a band's gain; a band with fewer takes its neighbours'.
MIN_BAND_PIXELS = 64
#: Bands of the running median over the band gains.
SMOOTH_BANDS = 5
#: The band gains' running median departs from its level when by more than this many of the bands'
#: standard errors and of their scatter about it (and by more than ``GAIN_TOLERANCE``).
K_BAND_SIGMA = 4.0
#: Fewest bands with a gain for a row correction (about a sixth of a 480-row frame).
MIN_BANDS = 5
#: A band whose gain departs from its neighbours' running median by more than this many times the
#: significance limit takes that median instead.
OUTLIER_LIMITS = 3.0


def exposure_gains(image: np.ndarray, dark: np.ndarray) -> np.ndarray:
    """Per channel, the gain that takes the laser-off frame to the laser-on frame's exposure.

    Parameters
    ----------
    image, dark : (H, W) or (H, W, C) uint8 or uint16 arrays
        The laser-on frame and its laser-off frame, same shape and dtype.

    Returns
    -------
    (C,) float array
        The median of ``image / dark`` over some ``SAMPLE_PIXELS`` pixels on a grid, in each
        channel over those whose laser-off value lies within ``USABLE_LEVELS`` of full scale and
        whose laser-on value is below the upper one; 1 where fewer than ``MIN_PIXELS`` are.
        ``C = 1`` for a grey frame.
    """
    step = max(1, int(np.sqrt(image.shape[0] * image.shape[1] / SAMPLE_PIXELS)))
    channels = 1 if image.ndim == 2 else image.shape[2]
    on, off = (np.ascontiguousarray(f[::step, ::step].reshape(-1, channels).T, dtype=np.float32) for f in (image, dark))
    usable = _usable(on, off, image.dtype)  # (C, n)
    gains = np.ones(channels)
    for c in np.flatnonzero(np.count_nonzero(usable, axis=1) >= MIN_PIXELS):
        ratio = on[c, usable[c]] / off[c, usable[c]]
        gains[c] = np.partition(ratio, ratio.size // 2)[ratio.size // 2]  # the median (upper, for even sizes)
    return gains


def mismatched(gains: np.ndarray) -> np.ndarray:
    """Channels ``(C,)`` bool whose gains ``(C,)`` (:func:`exposure_gains`) depart from 1 by more
    than ``GAIN_TOLERANCE``."""
    return np.abs(gains - 1.0) > GAIN_TOLERANCE


def _usable(on: np.ndarray, off: np.ndarray, dtype) -> np.ndarray:
    """Pixels whose ratio measures the gain: laser-off value within ``USABLE_LEVELS`` of the full
    scale of ``dtype``, laser-on value below the upper one (arrays of one shape, bool the same)."""
    full_scale = float(np.iinfo(dtype).max)
    low, high = (level * full_scale for level in USABLE_LEVELS)
    return (off >= low) & (off < high) & (on < high)


def row_gains(image: np.ndarray, dark: np.ndarray) -> np.ndarray | None:
    """Per row and channel, the gain that takes the laser-off frame to the laser-on frame's
    exposure, where it varies from row to row (flicker bands; see the module notes).

    The bands' gains (:func:`_band_gains`) are taken as a profile over the bands times a factor per
    channel (one step of a median polish: the profile is the median over the channels, so that a
    band brighter in red only, the red laser's light, does not move it; the factor the median over
    the bands). In a colour frame a band's profile needs two channels, and channels that do not
    move together (the laser's light, a changed scene) are not taken for flicker.

    Parameters
    ----------
    image, dark : (H, W) or (H, W, C) uint8 or uint16 arrays
        As for :func:`exposure_gains`.

    Returns
    -------
    (H, C) float array or None
        Each row's gain, the profile interpolated between the bands' centres times each channel's
        factor, where the profile's running median over ``SMOOTH_BANDS`` bands departs from its
        level by more than the limit (``GAIN_TOLERANCE``, ``K_BAND_SIGMA`` times the bands' standard
        error and their scatter about it); None where it does not, or where fewer than
        ``MIN_BANDS`` bands have a gain. ``C = 1`` for a grey frame.
    """
    n_bands = image.shape[0] // BAND_ROWS
    if n_bands < MIN_BANDS:
        return None
    band, std_error = _band_gains(image, dark, n_bands)
    has = np.isfinite(band)
    channels = band.shape[1]
    profile = _nan_median_of_rows(band)
    factor = _nan_median_of_rows((band / profile[:, None]).T) if channels > 1 else np.ones(1)
    factor[np.isnan(factor)] = 1.0  # a channel without usable pixels: the profile alone
    profile = _nan_median_of_rows(band / factor)
    known = has.sum(axis=1) >= min(channels, 2)
    if known.sum() < MIN_BANDS:
        return None
    limit = max(GAIN_TOLERANCE, K_BAND_SIGMA * float(np.median(std_error[has])))
    misfit = np.abs(band[known] / (profile[known, None] * factor) - 1.0)
    if channels > 1 and np.median(misfit[has[known]]) > limit:
        return None  # the channels do not move together: not a gain per row
    # Flicker moves many bands together, the laser's light or a bright object one or two: the
    # bands' running median, away from the ends (where it is the end band's own gain), must depart
    # from its level beyond the limit and the scatter of the bands about it (the bands' gains
    # scatter more than their standard errors say on a textured 8-bit frame); a band far off the
    # running median takes it, the others keep their own (a running median flattens the
    # flicker's crests, by 1.1 % at ±20 % over 300 rows).
    profile = profile[known]
    running = median_filter(profile, size=SMOOTH_BANDS, mode="nearest")
    off_running = np.abs(profile / running - 1.0)
    limit = max(limit, K_BAND_SIGMA * 1.4826 * float(np.median(off_running)))
    inner = running[SMOOTH_BANDS // 2:len(running) - SMOOTH_BANDS // 2]
    if not np.any(np.abs(inner / np.median(running) - 1.0) > limit):
        return None
    profile = np.where(off_running > OUTLIER_LIMITS * limit, running, profile)
    centres = (np.flatnonzero(known) + 0.5) * BAND_ROWS - 0.5
    return np.interp(np.arange(image.shape[0]), centres, profile)[:, None] * factor


def _band_gains(image: np.ndarray, dark: np.ndarray, n_bands: int) -> tuple[np.ndarray, np.ndarray]:
    """Gain ``(n_bands, C)`` of each channel in each band of ``BAND_ROWS`` rows from the top, and its
    relative standard error; NaN where fewer than ``MIN_BAND_PIXELS`` pixels are usable.

    About ``BAND_SAMPLES`` pixels per band on a grid (every other row), those within
    ``USABLE_LEVELS`` as for :func:`exposure_gains`. The gain is the mean of the middle half of
    their ratios laser-on / laser-off: robust as their median, which 8-bit frames quantise in steps
    of 1 DN (1 % at 100 DN). Its standard error is from the interquartile range (/ 1.349), with
    the middle half's mean's efficiency (about 0.84).
    """
    channels = 1 if image.ndim == 2 else image.shape[2]
    row_step = 2
    col_step = max(1, int(round(image.shape[1] * (BAND_ROWS // row_step) / BAND_SAMPLES)))
    rows = slice(0, n_bands * BAND_ROWS, row_step)
    on, off = (np.asarray(f[rows, ::col_step], np.float32).reshape(n_bands, -1, channels).transpose(0, 2, 1)
               for f in (image, dark))  # (bands, C, n): the sorts and sums below along contiguous rows
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(_usable(on, off, image.dtype), on / off, np.inf)
    ratio.sort(axis=-1)  # the unusable (inf) last
    count = np.count_nonzero(np.isfinite(ratio), axis=-1)  # (bands, C)
    first, stop = count // 4, count - count // 4
    summed = np.cumsum(np.where(np.isfinite(ratio), ratio, 0.0), axis=-1)
    below = np.where(first > 0, _along(summed, first - 1), 0.0)
    has = count >= MIN_BAND_PIXELS
    with np.errstate(invalid="ignore", divide="ignore"):  # bands without usable pixels (not used)
        band = np.where(has, (_along(summed, stop - 1) - below) / np.maximum(stop - first, 1), np.nan)
        spread = (_along(ratio, stop - 1) - _along(ratio, first)) / 1.349
        std_error = np.where(has, spread / np.sqrt(0.84 * np.maximum(count, 1)) / band, np.nan)
    return band, std_error


def _nan_median_of_rows(values: np.ndarray) -> np.ndarray:
    """Median of each row of ``values (n, k)`` over its finite entries (NaN where none):
    np.nanmedian's masked arrays cost more than the few numbers here."""
    ordered = np.sort(np.where(np.isfinite(values), values, np.inf), axis=1)
    k = np.count_nonzero(np.isfinite(ordered), axis=1)
    return np.where(k > 0, 0.5 * (_along(ordered, (k - 1) // 2) + _along(ordered, k // 2)), np.nan)


def _along(values: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``values[..., index]`` with one index per row of ``values`` (``index`` its shape without the
    last axis), held within the row."""
    index = np.clip(index, 0, values.shape[-1] - 1)
    return np.take_along_axis(values, index[..., None], axis=-1)[..., 0]


def exposure_matched(image: np.ndarray, dark: np.ndarray) -> np.ndarray:
    """The laser-off frame ``dark`` at the exposure of ``image`` (arrays as for :func:`exposure_gains`).

    Returns
    -------
    array like ``dark``
        ``dark`` itself where no channel is :func:`mismatched` and no row's gain varies
        (:func:`row_gains`); else a new array, each such channel times its gain (each row times its
        own where it varies), rounded and held within the dtype's range, its pixels at the dtype's
        maximum kept there.
    """
    full_scale = np.iinfo(dark.dtype).max
    by_row = row_gains(image, dark)
    if by_row is not None:  # each row times its gains: OpenCV's saturating, rounding product
        per_row = by_row.astype(np.float32)[:, None, :] if dark.ndim == 3 else by_row.astype(np.float32)
        scale = cv2.repeat(per_row, 1, dark.shape[1])  # (H, W[, C])
        matched = cv2.multiply(dark, scale, dtype=cv2.CV_8U if dark.dtype == np.uint8 else cv2.CV_16U)
    else:
        gains = exposure_gains(image, dark)
        off = mismatched(gains)
        if not off.any():
            return dark
        gains = np.where(off, gains, 1.0)
        if dark.dtype == np.uint8:  # a lookup table per channel, one pass over the frame in OpenCV
            table = np.minimum(np.rint(np.arange(256.0)[:, None] * gains), 255).astype(np.uint8)  # (256, C)
            table[255] = 255
            return cv2.LUT(dark, table.reshape(256, 1, -1) if dark.ndim == 3 else table[:, 0])
        matched = np.minimum(np.rint(dark * gains.astype(np.float32)), full_scale).astype(dark.dtype)
    np.copyto(matched, dark, where=dark == full_scale)
    return matched
