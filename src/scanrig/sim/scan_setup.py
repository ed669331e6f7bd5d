"""The setup of a scan of a simulated scene: its cameras, laser stations and region of interest.

``scanrig scan --sim`` and ``scanrig demo`` scan a scene from the same layout, defined here once:
the scene's default rig (optionally scaled), the laser at the scene's head position plus side
stations on a ring around the scene centre at the head's distance, and a cubic region of interest
around the centre.

>>> from scanrig.sim import load_scene
>>> from scanrig.sim.scan_setup import laser_stations
>>> laser_stations(load_scene("default")).shape
(5, 3)
"""

from __future__ import annotations

import numpy as np

from scanrig.geometry import Rig
from scanrig.sim.rigs import default_rig
from scanrig.sim.scene import Scene

#: Side laser stations: azimuths (degrees, from +x towards +y) around the scene centre.
SIDE_AZIMUTHS_DEG = (0.0, 90.0, 180.0, 270.0)
#: Elevation of the side stations above the scene centre, degrees.
SIDE_ELEVATION_DEG = 25.0
#: Colour channel in which the simulated (650 nm) laser shows.
LASER_COLOR = "red"


def scene_rig(scene: Scene, n_cameras: int, image_scale: float = 1.0) -> Rig:
    """The scene's default rig with image size and focal length scaled by ``image_scale``.

    Parameters
    ----------
    scene : Scene
    n_cameras : int
        Cameras of the rig (1 to 8).
    image_scale : float
        Factor on width, height and focal length (1 = the scene's own cameras).

    Returns
    -------
    Rig
        The true cameras, aimed at ``scene.center_m``.
    """
    return default_rig(n_cameras, scene.center_m, scene.rig.scaled(image_scale))


def laser_stations(scene: Scene, azimuths_deg=SIDE_AZIMUTHS_DEG,
                   elevation_deg: float = SIDE_ELEVATION_DEG) -> np.ndarray:
    """Positioner locations of a scan: the scene's laser head, then the side stations.

    Parameters
    ----------
    scene : Scene
    azimuths_deg : sequence of float
        Azimuths of the side stations around ``scene.center_m``, degrees.
    elevation_deg : float
        Elevation of the side stations, degrees; they are as far from the centre as the head.

    Returns
    -------
    (1 + len(azimuths_deg), 3) float array
        Station positions, world frame, metres; row 0 is ``scene.laser.head_m``.
    """
    centre = np.asarray(scene.center_m, dtype=np.float64)
    head = np.asarray(scene.laser.head_m, dtype=np.float64)
    reach, el = np.linalg.norm(head - centre), np.radians(elevation_deg)
    sides = [centre + reach * np.array([np.cos(a) * np.cos(el), np.sin(a) * np.cos(el), np.sin(el)])
             for a in np.radians(azimuths_deg)]
    return np.array([head, *sides])


def scene_roi(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned region of interest: the cube of half-side ``scene.radius_m`` around the centre.

    Returns
    -------
    roi_min_m, roi_max_m : (3,) float arrays
        Corners, world frame, metres.
    """
    centre = np.asarray(scene.center_m, dtype=np.float64)
    return centre - scene.radius_m, centre + scene.radius_m
