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


def channel_clip_levels(image: np.ndarray, dark: np.ndarray | None = None) -> np.ndarray:
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

    The highest such value is the level. When there is none: the dtype's maximum, or for a 16-bit
    frame (with its dark frame) whose largest value in any channel is ``2**b - 1`` for ``b`` in
    ``_SENSOR_BITS``, that value (a ``b``-bit camera's data in 16-bit files, reaching its top).

    Parameters
    ----------
    image : (H, W) or (H, W, C) uint8 or uint16 array
        The frame, DN.
    dark : array like ``image``, optional
        The laser-off frame of the same camera settings.

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
    return levels


def _sensor_top(largest: int, full_scale: int) -> int:
    """The value a frame whose largest value is ``largest`` DN cannot exceed: ``2**b - 1`` when
    ``largest`` is exactly that for ``b`` in ``_SENSOR_BITS`` (and the dtype is 16-bit), else
    ``full_scale``."""
    tops = [2**bits - 1 for bits in _SENSOR_BITS if 2**bits - 1 < full_scale]
    return largest if largest in tops else full_scale
