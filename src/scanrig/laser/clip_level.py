"""The level at which each channel of a camera clips, found from its frames."""

from __future__ import annotations

import numpy as np

#: A channel clips below the dtype's maximum at a value ``L`` (see :func:`channel_clip_levels`) that
#: holds at least ``_PILE_MIN_SHARE`` of the pixels (and ``_PILE_MIN_PIXELS``), ``_PILE_RATIO``
#: times as many as any of the ``_PILE_BELOW`` values under it (gain can leave every third value
#: empty, so not only the next one), at most ``_ABOVE_SHARE`` of its count above it, and whose
#: plateau's neighbouring pixels have a median below ``L`` but at least ``_RIM_FRACTION`` of the
#: way up from the channel's median to ``L``.
_PILE_MIN_SHARE = 1e-4
_PILE_MIN_PIXELS = 16
_PILE_RATIO = 5.0
_PILE_BELOW = 4
_ABOVE_SHARE = 0.01
_RIM_FRACTION = 0.5
#: Bit depths of cameras whose data 16-bit files hold as stored (low bits): such frames never
#: exceed ``2**bits - 1``, and pixels at that value are clipped.
_SENSOR_BITS = (10, 12, 14)
#: Where no value piles up, an 8-bit colour frame's laser channel clips below full scale when at
#: least ``_MIN_PEAK_LINES`` of the laser's peaks along rows and columns (falling by ``_PEAK_DROP``
#: of their maximum on both sides within ``_PEAK_WINDOW_PX``; with a laser-off frame, the laser
#: adding ``_ADDED_SHARE`` of it) top out in one band ``±_BAND_DN`` wide (JPEG's spread of a clipped
#: plateau) in the upper half of the range and below full scale, with at most ``_BAND_ABOVE_SHARE``
#: of that count above the band and ``_BELOW_RATIO`` times the count of the band of the same width
#: under it; the level is the ``_PLATEAU_QUANTILE`` % quantile of those peaks' pixels within
#: ``_BAND_DN`` of their maxima, and the frame's pixels about it are at most ``_MAX_FRAME_SHARE``
#: of the frame (:func:`_peak_band_level`).
_MIN_PEAK_LINES = 32
_PEAK_DROP = 0.25
_PEAK_WINDOW_PX = 24
_ADDED_SHARE = 0.1
_BAND_DN = 12
_BAND_ABOVE_SHARE = 0.25
_BELOW_RATIO = 2.5
_PLATEAU_QUANTILE = 25.0
_MAX_FRAME_SHARE = 0.1


def channel_clip_levels(image: np.ndarray, dark: np.ndarray | None = None, laser_channel: int | None = None
                        ) -> np.ndarray:
    """The level, DN, at which each channel of a camera clips, found from its frames.

    Webcams often clip a channel below the dtype's maximum (their processing maps the sensor's
    full scale to a lower value), and the clipped pixels then pile up at that one value. A value
    ``L`` of a channel's histogram (frame and dark frame together) is its clip level when

    - it holds many pixels (``_PILE_MIN_SHARE`` of them, at least ``_PILE_MIN_PIXELS``), at least
      ``_PILE_RATIO`` times as many as each of the ``_PILE_BELOW`` values under it: noise spreads
      an unclipped flat area over several values, clipping stacks it on one;
    - few pixels lie above it (``_ABOVE_SHARE`` of its count): it is the top of the channel's range;
    - the pixels next to the plateau are bright too, but below it (their median is below ``L``
      and at least ``_RIM_FRACTION`` of the way up from the channel's median to ``L``): the light
      continues past the clip, so its run is entered from high values, whereas a flat printed or
      rendered area ends in a step down to the scene, or up to a brighter trace crossing it.

    The highest such value is the level. When there is none: for the ``laser_channel`` of an 8-bit
    colour frame, the level its lines' clipped peaks show (:func:`_peak_band_level`: JPEG spreads
    a plateau clipped below 255 over some 15 values, so none piles up); else the dtype's maximum,
    or for a 16-bit frame (with its dark frame) whose largest value in any channel is ``2**b - 1``
    for ``b`` in ``_SENSOR_BITS``, that value (a ``b``-bit camera's data in 16-bit files, reaching
    its top).

    Parameters
    ----------
    image : (H, W) or (H, W, C) uint8 or uint16 array
        The frame, DN.
    dark : array like ``image``, optional
        The laser-off frame of the same camera settings.
    laser_channel : int, optional
        The laser's channel of an ``(H, W, 3)`` frame.

    Returns
    -------
    (C,) float array
        Clip level of each channel, DN (``C = 1`` for an ``(H, W)`` frame).
    """
    import cv2

    full_scale = int(np.iinfo(image.dtype).max)
    frames = [np.ascontiguousarray(f if f.ndim == 3 else f[:, :, None]) for f in (image, dark) if f is not None]
    # per channel, (array, channel index) of each frame for OpenCV's histogram, which is fastest on the
    # interleaved 8-bit frame but on a 16-bit channel extracted first (about 4 times as fast, extraction
    # included: its 65,536 bins are counted one plane at a time)
    sources = [[(f, c) if image.dtype == np.uint8 else (cv2.extractChannel(f, c)[:, :, None], 0) for f in frames]
               for c in range(frames[0].shape[2])]
    histograms = [sum(cv2.calcHist([f], [k], None, [full_scale + 1], [0, full_scale + 1]).ravel()
                      for f, k in channel).astype(np.int64) for channel in sources]
    top = _sensor_top(max(int(np.flatnonzero(counts)[-1]) for counts in histograms), full_scale)
    levels = np.full(len(histograms), float(top))
    for c, counts in enumerate(histograms):
        above = counts.sum() - np.cumsum(counts)
        # the largest count of the _PILE_BELOW values under each value (0 below 0)
        padded = np.r_[np.zeros(_PILE_BELOW, counts.dtype), counts]
        below = np.maximum.reduce([padded[k : k + counts.size] for k in range(_PILE_BELOW)])
        pile = ((counts >= max(_PILE_MIN_PIXELS, _PILE_MIN_SHARE * counts.sum()))
                & (counts >= _PILE_RATIO * below) & (above <= _ABOVE_SHARE * counts))
        pile[top:] = False  # the default level, and nothing is above it
        median = int(np.searchsorted(np.cumsum(counts), 0.5 * counts.sum()))
        for level in np.flatnonzero(pile)[::-1]:
            rim = []
            for plane in (f[:, :, k] for f, k in sources[c]):
                plateau = (plane == level).view(np.uint8)
                ring = cv2.dilate(plateau, np.ones((3, 3), np.uint8)) > plateau
                rim.append(plane[ring])
            rim = np.concatenate(rim)
            # a plateau without a rim fills the channel: a flat channel, nothing clipped
            if rim.size and median + _RIM_FRACTION * (level - median) <= np.median(rim) < level:
                levels[c] = float(level)
                break
    if laser_channel is not None and image.dtype == np.uint8 and levels[laser_channel] == top:
        levels[laser_channel] = _peak_band_level(image, dark, laser_channel, top) or top
    return levels


def _peak_band_level(image: np.ndarray, dark: np.ndarray | None, laser_channel: int, top: int) -> float | None:
    """The level, DN, below ``top`` at which the ``laser_channel`` of the 8-bit colour frame
    ``image`` (H, W, 3) clips, read from the laser's peaks along its rows and columns; None when
    they show none.

    A laser clipped at ``L`` tops every line that crosses its core at ``L``; after JPEG the
    plateau's pixels scatter some 10 DN about ``L``, and the lines' maxima pile up in a band a
    little above it with nothing of the laser beyond. A line's maximum is a peak when the line
    falls by ``_PEAK_DROP`` of it within ``_PEAK_WINDOW_PX`` on both sides (a bright flat area does
    not) and, given ``dark``, the laser added ``_ADDED_SHARE`` of it there. The band
    ``c ± _BAND_DN`` holding the most peak maxima (all of it between ``top / 2`` and ``top``) is
    the clip when it holds at least ``_MIN_PEAK_LINES``, at most ``_BAND_ABOVE_SHARE`` of its
    count lies above it (a beam clipped at ``top`` tops its lines there), and the band of the same
    width under it holds at most ``1 / _BELOW_RATIO`` of its count (an unclipped laser's maxima
    spread with its brightness). The level is the ``_PLATEAU_QUANTILE`` % quantile of the pixels
    within ``_BAND_DN`` of those lines' maxima around them: below the plateau's median, as a level
    set low only takes some unclipped pixels for clipped ones, whereas one set high leaves clipped
    pixels as measured. Last, the frame's pixels from ``_BAND_DN`` under the level to the band's
    top must be at most ``_MAX_FRAME_SHARE`` of it: a laser's plateau is a small part of the frame,
    whereas the brightest level of the scene (paper between printed dots, in a frame without the
    laser) is a large one.

    A laser that is not clipped but equally bright on every line (a flat, even target) shows such
    a band too; its peaks' top pixels are then left out of their fits, at little cost
    (docs/detection.md).
    """
    import cv2

    laser = cv2.extractChannel(image, laser_channel)
    peaks, windows = [], []
    for transposed in (False, True):
        line, at, peak, window = _line_peaks(cv2.transpose(laser) if transposed else laser)
        if dark is not None:  # where the laser added ``_ADDED_SHARE`` of the peak
            v, u = (at, line) if transposed else (line, at)
            keep = peak - dark[v, u, laser_channel] >= _ADDED_SHARE * peak
            peak, window = peak[keep], window[keep]
        peaks.append(peak)
        windows.append(window)
    peak, window = np.concatenate(peaks), np.concatenate(windows)  # (n,), (n, 2 _PEAK_WINDOW_PX + 1)
    counts = np.bincount(peak, minlength=top + 1)
    band = np.convolve(counts, np.ones(2 * _BAND_DN + 1, np.int64))[_BAND_DN : _BAND_DN + top + 1]  # c ± _BAND_DN
    lowest = top // 2 + _BAND_DN  # the band's centre: the whole band above half of full scale, below it
    centre = lowest + int(np.argmax(band[lowest : top - _BAND_DN]))
    held = band[centre]
    above = counts[centre + _BAND_DN + 1 :].sum()
    under = counts[centre - 3 * _BAND_DN - 1 : centre - _BAND_DN].sum()
    if held < _MIN_PEAK_LINES or above > _BAND_ABOVE_SHARE * held or _BELOW_RATIO * under > held:
        return None
    lines = np.abs(peak - centre) <= _BAND_DN
    top_pixels = window[lines] >= (peak[lines] - _BAND_DN)[:, None]
    level = float(np.percentile(window[lines][top_pixels], _PLATEAU_QUANTILE))
    in_band = cv2.countNonZero(cv2.inRange(laser, level - _BAND_DN, centre + _BAND_DN))
    return level if in_band <= _MAX_FRAME_SHARE * laser.size else None


def _line_peaks(lines: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The peaks of the rows of ``lines`` (H, W) uint8 (the laser's channel, or its transpose): the
    rows whose maximum the row falls from by ``_PEAK_DROP`` of it within ``_PEAK_WINDOW_PX`` on both
    sides, that window inside the frame (see :func:`_peak_band_level`).

    Returns
    -------
    row, column : (k,) int arrays
        The peaks' rows and the columns of their maxima.
    peak : (k,) int array
        Their maxima, DN.
    window : (k, 2 _PEAK_WINDOW_PX + 1) int array
        The rows' values around them, DN.
    """
    w = lines.shape[1]
    at = lines.argmax(axis=1)
    row = np.flatnonzero((at >= _PEAK_WINDOW_PX) & (at < w - _PEAK_WINDOW_PX))
    column = at[row]
    window = lines[row[:, None], column[:, None] + np.arange(-_PEAK_WINDOW_PX, _PEAK_WINDOW_PX + 1)].astype(np.int64)
    peak = window[:, _PEAK_WINDOW_PX]
    sides = np.maximum(window[:, :_PEAK_WINDOW_PX].min(axis=1), window[:, _PEAK_WINDOW_PX + 1 :].min(axis=1))
    keep = peak - sides >= _PEAK_DROP * peak
    return row[keep], column[keep], peak[keep], window[keep]


def _sensor_top(largest: int, full_scale: int) -> int:
    """The value a frame whose largest value is ``largest`` DN cannot exceed: ``2**b - 1`` when
    ``largest`` is exactly that for ``b`` in ``_SENSOR_BITS`` (and the dtype is 16-bit), else
    ``full_scale``."""
    tops = [2**bits - 1 for bits in _SENSOR_BITS if 2**bits - 1 < full_scale]
    return largest if largest in tops else full_scale
