"""A laser-off frame made from the scan itself: the per-pixel median of a camera's frames.

A laser swept over a fixed scene lights each pixel in only a few of its frames, so the median over
the frames is the scene without the laser: subtracting it removes texture, printed ink and
background light as a real laser-off frame does (:func:`scanrig.laser.image.prepare_image`). It
does not hold when the object moves between frames (a turntable) or the laser dwells on the same
pixels in half of the frames or more.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError
from scanrig.io.session import describe_image, read_image

#: Fewest frames whose median is taken for a laser-off frame.
MIN_FRAMES = 5
#: Most frames read for it (spread evenly over the scan; an odd number, so the median is a pixel
#: value): bounds memory at this many frames.
MAX_FRAMES = 31
#: Rows of the stack ordered at a time (keeps the partition's working set small).
_ROWS = 64


def median_dark(paths: Sequence[Path], camera: str) -> np.ndarray:
    """The per-pixel median of a camera's scan frames, as a laser-off frame.

    Parameters
    ----------
    paths : sequence of Path
        The camera's scan frames in scan order (at least :data:`MIN_FRAMES`); at most
        :data:`MAX_FRAMES` of them, spread evenly, are read.
    camera : str
        Named in errors.

    Returns
    -------
    ndarray of shape (H, W) or (H, W, 3)
        Of the frames' dtype.

    Raises
    ------
    InputError
        Fewer than :data:`MIN_FRAMES` frames.
    FileFormatError
        Naming a frame that cannot be read, or whose size or bit depth differs from the first.
    """
    if len(paths) < MIN_FRAMES:
        raise InputError(f"camera {camera!r}: a median laser-off frame needs at least {MIN_FRAMES} scan "
                         f"frames, found {len(paths)}")
    n = min(len(paths), MAX_FRAMES)
    n -= 1 - n % 2
    picks = np.round(np.linspace(0, len(paths) - 1, n)).astype(int)
    first = read_image(paths[picks[0]])
    stack = np.empty((n,) + first.shape, first.dtype)
    stack[0] = first
    for i, k in enumerate(picks[1:], start=1):
        image = read_image(paths[k])
        if image.shape != first.shape or image.dtype != first.dtype:
            raise FileFormatError(paths[k], f"frame is {describe_image(image.shape, image.dtype)} but "
                                            f"{paths[picks[0]].name} of camera {camera!r} is "
                                            f"{describe_image(first.shape, first.dtype)}")
        stack[i] = image
    for a in range(0, first.shape[0], _ROWS):
        stack[:, a:a + _ROWS].partition(n // 2, axis=0)
    return stack[n // 2].copy()
