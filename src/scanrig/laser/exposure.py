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

It does not correct a gain that varies over the frame (the rolling shutter's bands under
flickering light) or a different scene (something moved).
"""

from __future__ import annotations

import cv2
import numpy as np

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
    full_scale = float(np.iinfo(image.dtype).max)
    low, high = (level * full_scale for level in USABLE_LEVELS)
    step = max(1, int(np.sqrt(image.shape[0] * image.shape[1] / SAMPLE_PIXELS)))
    channels = 1 if image.ndim == 2 else image.shape[2]
    on, off = (np.ascontiguousarray(f[::step, ::step].reshape(-1, channels).T, dtype=np.float32) for f in (image, dark))
    usable = (off >= low) & (off < high) & (on < high)  # (C, n)
    gains = np.ones(channels)
    for c in np.flatnonzero(np.count_nonzero(usable, axis=1) >= MIN_PIXELS):
        ratio = on[c, usable[c]] / off[c, usable[c]]
        gains[c] = np.partition(ratio, ratio.size // 2)[ratio.size // 2]  # the median (upper, for even sizes)
    return gains


def mismatched(gains: np.ndarray) -> np.ndarray:
    """Channels ``(C,)`` bool whose gains ``(C,)`` (:func:`exposure_gains`) depart from 1 by more
    than ``GAIN_TOLERANCE``."""
    return np.abs(gains - 1.0) > GAIN_TOLERANCE


def exposure_matched(image: np.ndarray, dark: np.ndarray) -> np.ndarray:
    """The laser-off frame ``dark`` at the exposure of ``image`` (arrays as for :func:`exposure_gains`).

    Returns
    -------
    array like ``dark``
        ``dark`` itself where no channel is :func:`mismatched`; else a new array, each such
        channel times its gain (:func:`exposure_gains`), rounded and held within the dtype's
        range, its pixels at the dtype's maximum kept there.
    """
    gains = exposure_gains(image, dark)
    off = mismatched(gains)
    if not off.any():
        return dark
    scale = np.where(off, gains, 1.0)
    full_scale = np.iinfo(dark.dtype).max
    if dark.dtype == np.uint8:  # a lookup table per channel, one pass over the frame in OpenCV
        table = np.minimum(np.rint(np.arange(256.0)[:, None] * scale), 255).astype(np.uint8)  # (256, C)
        table[255] = 255
        return cv2.LUT(dark, table.reshape(256, 1, -1) if dark.ndim == 3 else table[:, 0])
    matched = np.minimum(np.rint(dark * scale.astype(np.float32)), full_scale).astype(dark.dtype)
    np.copyto(matched, dark, where=dark == full_scale)
    return matched
