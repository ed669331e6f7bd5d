"""A scene: objects with materials, room lighting, and the setup that looks at it.

World frame: metres, z up. Object meshes are stored in world coordinates, split at sharp edges
so that interpolated normals are smooth only across curved tessellations.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import trimesh

from scanrig.errors import InputError
from scanrig.sim.colour import ColourResponse, check_sensor
from scanrig.sim.laser import LaserSpec
from scanrig.sim.materials import Material
from scanrig.sim.raycast import RayCaster
from scanrig.sim.rigs import RigSpec
from scanrig.sim.sensor import Sensor


@dataclass(frozen=True)
class SceneObject:
    """One rigid object.

    Parameters
    ----------
    name : str
    mesh : trimesh.Trimesh
        Triangles in world coordinates, metres.
    material : Material
    """

    name: str
    mesh: trimesh.Trimesh
    material: Material


@dataclass(frozen=True)
class Lighting:
    """Room light (in the camera's spectral band, after any laser-line filter).

    Parameters
    ----------
    ambient_W_m2 : float
        Uniform irradiance from all directions, W/m².
    lamp_W_m2 : float
        Irradiance of a distant lamp on a surface facing it, W/m² (casts shadows).
    lamp_direction : (3,) float
        Direction the lamp's light travels (normalised on construction).
    """

    ambient_W_m2: float = 40.0
    lamp_W_m2: float = 60.0
    lamp_direction: tuple = (0.3, 0.5, -1.0)

    def __post_init__(self):
        if self.ambient_W_m2 < 0 or self.lamp_W_m2 < 0:
            raise InputError("lighting ambient_W_m2 and lamp_W_m2 must be >= 0")
        d = np.asarray(self.lamp_direction, dtype=np.float64)
        if d.shape != (3,) or not np.linalg.norm(d) > 0:
            raise InputError(f"lighting lamp_direction must be a non-zero 3-vector, got {self.lamp_direction!r}")
        object.__setattr__(self, "lamp_direction", tuple(d / np.linalg.norm(d)))


@dataclass(frozen=True)
class Scene:
    """Everything the simulator needs to render a session.

    Parameters
    ----------
    name : str
    objects : list of SceneObject
    lighting : Lighting
    center_m : (3,) float
        Centre of the region of interest (cameras aim here; the laser raster covers it).
    radius_m : float
        Radius of the region of interest, metres.
    rig : RigSpec
        How the default cameras are placed.
    laser : LaserSpec
        Laser head position and optics.
    sensor : Sensor
        Exposure and noise of every camera.
    colour : ColourResponse or None
        How colour cameras see the laser and the room light (:mod:`scanrig.sim.colour`); None for
        grey cameras.
    board_flex_m : (2,) float
        Flex terms ``(c_x, c_y)`` (metres) bending every board of the calibration target
        (:func:`scanrig.targets.target.flex_shape`); (0, 0) for flat boards.
    """

    name: str
    objects: tuple
    lighting: Lighting = field(default_factory=Lighting)
    center_m: tuple = (0.0, 0.0, 0.1)
    radius_m: float = 0.25
    rig: RigSpec = field(default_factory=RigSpec)
    laser: LaserSpec = field(default_factory=LaserSpec)
    sensor: Sensor = field(default_factory=Sensor)
    colour: ColourResponse | None = None
    board_flex_m: tuple = (0.0, 0.0)

    def __post_init__(self):
        if not self.objects:
            raise InputError(f"scene {self.name!r} has no objects")
        names = [o.name for o in self.objects]
        if len(set(names)) != len(names):
            raise InputError(f"scene {self.name!r}: object names must be unique, got {names}")
        object.__setattr__(self, "objects", tuple(self.objects))
        if self.colour is not None:
            check_sensor(self.colour, self.sensor)

    @cached_property
    def raycaster(self) -> RayCaster:
        """Embree scene over all objects (built on first use)."""
        return RayCaster([o.mesh for o in self.objects])

    @property
    def materials(self) -> list[Material]:
        """Material of each object, in object order."""
        return [o.material for o in self.objects]


def place(mesh: trimesh.Trimesh, position_m=(0.0, 0.0, 0.0), rotation_deg=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """Rotate (extrinsic x, y, z Euler angles, degrees) then translate a mesh; split sharp edges.

    Returns
    -------
    trimesh.Trimesh
        A new mesh in world coordinates.
    """
    from scipy.spatial.transform import Rotation

    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", rotation_deg, degrees=True).as_matrix()
    m[:3, 3] = position_m
    out = mesh.copy()
    out.apply_transform(m)
    return out.smooth_shaded
