"""Real cameras through OpenCV's ``VideoCapture`` (USB/UVC webcams, IP streams, video files).

Synchronisation is OpenCV's: :meth:`VideoCaptureCameras.grab` first calls ``grab()`` on every
camera (latching a frame in each, back to back), then ``retrieve()`` on each to decode, so the
exposures are as close in time as the driver allows. Hardware-triggered cameras are exact.
"""

from __future__ import annotations

import numpy as np

from scanrig.errors import InputError
from scanrig.scan.protocol import RigError


class VideoCaptureCameras:
    """Synchronised ``cv2.VideoCapture`` sources; implements the ``Cameras`` protocol.

    Parameters
    ----------
    sources : dict of str to (int or str)
        ``{camera name: device index, URL or video file}`` in rig order.
    colour : bool
        Return RGB ``(H, W, 3)`` images; default grey ``(H, W)`` uint8.
    """

    def __init__(self, sources: dict[str, int | str], colour: bool = False):
        import cv2

        if not sources:
            raise InputError("sources must name at least one camera, got none")
        self.names = list(sources)
        self.colour = colour
        self._captures = {}
        for name, source in sources.items():
            cap = cv2.VideoCapture(source)
            if not cap.isOpened():
                self.close()
                raise InputError(f"camera {name!r}: cannot open video source {source!r}")
            self._captures[name] = cap

    def grab(self) -> dict[str, np.ndarray]:
        """One frame per camera: latch all, then decode all.

        Raises
        ------
        RigError
            If a camera delivers no frame (unplugged, end of stream).
        """
        import cv2

        latched = {name: cap.grab() for name, cap in self._captures.items()}
        images = {}
        for name, cap in self._captures.items():
            ok, bgr = cap.retrieve() if latched[name] else (False, None)
            if not ok or bgr is None:
                raise RigError(f"camera {name!r} delivered no frame (disconnected or end of stream)")
            if bgr.ndim == 2:
                images[name] = bgr
            else:
                images[name] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB if self.colour else cv2.COLOR_BGR2GRAY)
        return images

    def close(self) -> None:
        for cap in self._captures.values():
            cap.release()
        self._captures = {}
