"""The rig protocol: what the scan loop needs from cameras and from a laser positioner.

The classes are structural (:class:`typing.Protocol`): the simulator's ``VirtualRig``, the replay
rig, OpenCV cameras and the G-code positioner all implement them without importing this module.
See ``docs/architecture.md`` ("Rig protocol") and ``docs/scanning.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from scanrig.errors import InputError, ScanrigError
from scanrig.geometry.checks import check_matrix

#: Largest accepted deviation of a beam direction's norm from 1 (a direction that went through a
#: text file with 17 significant digits is unit to ~1e-16; this only rejects real mistakes).
UNIT_TOL = 1e-6


class RigError(ScanrigError):
    """The rig failed while scanning: a camera stopped delivering frames, the positioner refused a move.

    Everything captured before the failure stays valid; the message says what failed and how to
    continue (``scanrig scan --resume``).
    """


@runtime_checkable
class Cameras(Protocol):
    """Synchronised cameras of a rig."""

    names: list[str]
    """Camera names in rig order (the session's camera folder names)."""

    def grab(self) -> dict[str, np.ndarray]:
        """One synchronised frame per camera: ``{name: image}``, ``(H, W)`` or ``(H, W, 3)`` uint8/uint16."""


@runtime_checkable
class LaserPositioner(Protocol):
    """Something that points the laser: a pan-tilt head, a gantry, a robot."""

    def move_to(self, beam: Beam) -> None:
        """Move the beam to ``beam``; blocks until it is there."""

    def set_laser(self, on: bool) -> None:
        """Switch the laser on or off."""


@dataclass(frozen=True, eq=False)
class Beam:
    """A laser beam in the world frame (metres).

    Parameters
    ----------
    origin : (3,) float array
        Where the beam leaves the laser, world frame, metres.
    direction : (3,) float array
        Unit propagation direction, world frame (checked, not renormalised, so that a beam read
        back from a file is bit-identical to the one commanded).
    fan_axis : (3,) float array, optional
        Stripe lasers only: unit vector perpendicular to ``direction`` spanning the light plane.
    """

    origin: np.ndarray
    direction: np.ndarray
    fan_axis: np.ndarray | None = None

    def __post_init__(self):
        origin = check_matrix(self.origin, (3,), "beam origin")
        direction = _unit(self.direction, "beam direction")
        object.__setattr__(self, "origin", _frozen(origin))
        object.__setattr__(self, "direction", _frozen(direction))
        if self.fan_axis is not None:
            fan_axis = _unit(self.fan_axis, "beam fan_axis")
            if abs(fan_axis @ direction) > UNIT_TOL:
                raise InputError("beam fan_axis must be perpendicular to direction, "
                                 f"got dot {fan_axis @ direction:.3g}")
            object.__setattr__(self, "fan_axis", _frozen(fan_axis))

    def as_row(self) -> list[float]:
        """``[ox, oy, oz, dx, dy, dz, fx, fy, fz]``; the fan axis is NaN for a spot laser."""
        fan = self.fan_axis if self.fan_axis is not None else np.full(3, np.nan)
        return [*map(float, self.origin), *map(float, self.direction), *map(float, fan)]

    @classmethod
    def from_row(cls, row) -> Beam:
        """Inverse of :meth:`as_row`."""
        row = np.asarray(row, dtype=np.float64)
        if row.shape != (9,):
            raise InputError(f"a beam row has 9 numbers (origin, direction, fan axis), got shape {row.shape}")
        fan = None if np.all(np.isnan(row[6:])) else row[6:]
        return cls(row[:3], row[3:6], fan)

    def __eq__(self, other) -> bool:
        if not isinstance(other, Beam):
            return NotImplemented
        return np.array_equal(self.as_row(), other.as_row(), equal_nan=True)

    def __hash__(self) -> int:
        return hash(np.nan_to_num(np.asarray(self.as_row())).tobytes())


def _unit(vector, name: str) -> np.ndarray:
    v = check_matrix(vector, (3,), name)
    norm = np.linalg.norm(v)
    if abs(norm - 1.0) > UNIT_TOL:
        raise InputError(f"{name} must be a unit vector, got norm {norm:.6g}")
    return v


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a
