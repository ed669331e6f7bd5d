"""The laser's colours, their channels in an RGB frame, and the margin under a channel's clip level
from which a pixel counts as clipped.

Shared by :mod:`~scanrig.laser.image` (the signal and its clipped pixels) and
:mod:`~scanrig.laser.bright_scene` (a scene near the clip level).
"""

from __future__ import annotations

LASER_COLORS = ("grey", "red", "green", "blue")
#: Index of a colour laser's channel in an RGB frame.
CHANNEL = {"red": 0, "green": 1, "blue": 2}
#: A pixel within this fraction of the saturation level counts as clipped.
CLIP_MARGIN = 0.03
