"""Which beams a positioner can produce: the reachable set used by the planner.

Model (``docs/scanning.md``, "Positioner model"): the laser sits on a pan-tilt head, and the head
can be placed at one of a few fixed *stations* (several heads, or the poses of a robot arm that
carries one). From a station the head can aim anywhere, so a beam is fully defined by its station
and its aim point: ``origin = station``, ``direction = unit(aim - station)``. A gantry that moves
a downward-looking laser is the limit of many stations on a plane, each aiming straight down.

To hit a patch perpendicularly the planner picks, among the stations on the patch's outer side,
the one whose beam is closest to the patch's inward normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry.checks import check_points
from scanrig.scan.protocol import Beam


@dataclass(frozen=True)
class Stations:
    """Fixed positions from which the pan-tilt laser can aim.

    Parameters
    ----------
    origins_m : (H, 3) float array
        Station positions (the head's pivot), world frame, metres. Station 0 makes the uniform pass.
    max_incidence_deg : float
        Largest accepted angle between a beam and a patch's normal; patches no station sees at
        a smaller angle are left out.
    """

    origins_m: np.ndarray
    max_incidence_deg: float = 75.0

    def __post_init__(self):
        origins = check_points(self.origins_m, 3, "station origins_m")
        if len(origins) == 0:
            raise InputError("station origins_m must hold at least one station, got none")
        if not 0.0 < self.max_incidence_deg < 90.0:
            raise InputError(f"max_incidence_deg must be in (0, 90), got {self.max_incidence_deg}")
        origins.setflags(write=False)
        object.__setattr__(self, "origins_m", origins)

    def beams_toward(self, aims_m: np.ndarray, station: int = 0) -> list[Beam]:
        """Beams from one station to each aim point.

        Parameters
        ----------
        aims_m : (N, 3) float array
            Aim points, world frame, metres.
        station : int
            Index into :attr:`origins_m`.
        """
        origin = self.origins_m[station]
        dirs = aims_m - origin
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        return [Beam(origin, d) for d in dirs]

    def best_station(self, aims_m: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The station whose beam to each aim is closest to the aim's inward normal.

        Parameters
        ----------
        aims_m : (N, 3) float array
            Aim points, world frame, metres.
        normals : (N, 3) float array
            Unit outward surface normals at the aims.

        Returns
        -------
        station : (N,) int array
            Chosen station index; -1 where no station is within ``max_incidence_deg``.
        cos_incidence : (N,) float array
            Cosine of the angle between the chosen beam and the normal.
        """
        to_station = self.origins_m[None, :, :] - aims_m[:, None, :]            # (N, H, 3)
        to_station /= np.linalg.norm(to_station, axis=2, keepdims=True)
        cos = np.einsum("nhk,nk->nh", to_station, normals)
        station = np.argmax(cos, axis=1)
        best = cos[np.arange(len(aims_m)), station]
        station[best < np.cos(np.radians(self.max_incidence_deg))] = -1
        return station, best
