"""Bits of the ``flags`` field of ``points.ply`` (uint16).

A point with ``flags == 0`` was triangulated from at least two views that agreed and had no
competing candidates. Bits say what else happened; none of them by itself makes a point wrong,
except :attr:`Flag.AMBIGUOUS`, whose points are left out unless asked for.
"""

from __future__ import annotations

from enum import IntFlag


class Flag(IntFlag):
    """Per-point flags (bit values are part of the ``points.ply`` contract)."""

    #: Another consistent combination of candidates gives a point beyond the uncertainty of both,
    #: and it has as many agreeing views or shares no candidate with the winner (a second lit
    #: point, such as a reflection on a matte surface): the data cannot decide. Left out of
    #: ``points.ply`` unless ``keep_ambiguous``.
    AMBIGUOUS = 1
    #: A camera that had candidates in this frame disagreed with the others and was dropped.
    DROPPED_VIEW = 2
    #: A camera that was used also had other candidates (e.g. a secondary reflection) that were
    #: rejected.
    REJECTED_CANDIDATES = 4
    #: One of the detections used was saturated.
    SATURATED = 8
    #: Stripe point seen by one camera, intersected with the light plane fitted to the frame's
    #: multi-view points.
    PLANE_SINGLE_VIEW = 16
    #: Classic single-camera mode: ray intersected with a calibrated light plane.
    CALIBRATED_PLANE = 32
    #: Multi-view stripe point farther from the frame's light plane than its uncertainty allows.
    OFF_PLANE = 64
