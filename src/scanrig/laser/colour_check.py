"""Frames whose colour is not what the laser colour assumes: grey frames stored as colour, and
frames whose laser shows in another channel (red and blue swapped, a wrong ``laser_color``).

A colour laser's signal is its channel minus the mean of the two others
(:mod:`scanrig.laser.image`): in a grey frame stored as three equal channels it is 0 everywhere,
and with red and blue swapped the stripe is negative. Neither is an error the detectors can see
on their own, so they are checked here: :func:`grey_frames` turns equal channels into the grey
frame they are, and :func:`colour_shown` names the colour that finds far more laser than the one
asked for.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: The colours a colour frame's laser may have (one channel each).
CHANNEL_COLOURS = ("red", "green", "blue")
#: Another colour must find at least this many times the light (or pixels) of the requested one to
#: be named. Measured on the real Ciclop frames (rank-0 peaks summed over the scan lines): the
#: right colour finds 3.5-180 times what the best other one does (bust, pattern, with and without
#: the laser-off frame), so with red and blue swapped the asked-for colour finds 3.5-180 times less.
FEWER_FACTOR = 3.0
#: Every this-many-th row is compared first; the whole frame only when those rows are equal.
_SAMPLE_ROW_STEP = 32


def equal_channels(image: np.ndarray) -> bool:
    """Whether a frame's three channels are equal everywhere (a grey frame stored as colour).

    Rows ``0, _SAMPLE_ROW_STEP, 2 _SAMPLE_ROW_STEP, ...`` are compared first, so that a colour
    frame costs a thirty-second of a full comparison; only when they are equal is the whole frame.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The frame, DN.

    Returns
    -------
    bool
        False for an ``(H, W)`` frame (it has no channels to compare).
    """
    if image.ndim != 3:
        return False
    return all(_same_channels(rows) for rows in (image[::_SAMPLE_ROW_STEP], image))


def _same_channels(image: np.ndarray) -> bool:
    """Channel 0 equals channels 1 and 2 at every pixel of ``image`` ``(H, W, 3)``."""
    return bool(np.array_equal(image[:, :, 0], image[:, :, 1]) and np.array_equal(image[:, :, 0], image[:, :, 2]))


def grey_frames(image: np.ndarray, dark: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """A frame and its laser-off frame as grey ``(H, W)`` when their channels are equal.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The frame, DN.
    dark : array like ``image``, optional
        Its laser-off frame.

    Returns
    -------
    image, dark : arrays
        Channel 0 of each (contiguous) when both have three equal channels (or ``dark`` is None),
        else the inputs unchanged.
    """
    if not equal_channels(image) or (dark is not None and not equal_channels(dark)):
        return image, dark
    return tuple(None if f is None else np.ascontiguousarray(f[:, :, 0]) for f in (image, dark))


def colour_shown(image: np.ndarray, color: str, found_with: Callable[[str], float], least: float) -> str | None:
    """The laser colour a frame shows when it is not the requested one.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The frame, DN.
    color : {"grey", "red", "green", "blue"}
        The requested laser colour.
    found_with : callable
        ``found_with(colour) -> float``: how much laser the detector finds in ``image`` with that
        colour (pixels on the target, DN summed over the traces, ...; larger is more). Called only
        for a colour frame, once per colour.
    least : float
        Another colour is named only when it finds at least this much.

    Returns
    -------
    str or None
        The colour among red, green and blue (``color`` left out) that finds the most, when that
        is at least ``least`` and more than ``FEWER_FACTOR`` times what ``color`` finds; None for a
        grey frame (2-D or three equal channels, where every colour is the same signal) or when
        no colour does.
    """
    if image.ndim != 3 or equal_channels(image):
        return None
    others = {other: found_with(other) for other in CHANNEL_COLOURS if other != color}
    best = max(others, key=others.get)
    if others[best] < least or others[best] <= FEWER_FACTOR * found_with(color):
        return None
    return best


def colour_advice(colour: str) -> str:
    """How to ask for ``colour``: ``"use --color red (or laser_color = 'red' in session.toml)"``."""
    return f"use --color {colour} (or laser_color = {colour!r} in session.toml)"
