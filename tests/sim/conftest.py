"""Small scenes and rigs shared by the simulator tests (small images keep the tests fast)."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.geometry import Camera, Rig
from scanrig.sim import primitives
from scanrig.sim.laser import LaserSpec
from scanrig.sim.materials import Material
from scanrig.sim.rigs import RigSpec, default_rig, look_at
from scanrig.sim.scene import Lighting, Scene, SceneObject, place
from scanrig.sim.sensor import Sensor

#: A lens with strong barrel distortion (about 60 px at the image corners of 1280x1024, fx 2200).
STRONG_DIST = (-0.35, 0.12, 1e-3, -8e-4, -0.01)


def small_rig(n: int = 2, center=(0.0, 0.0, 0.0), distance_m: float = 0.7) -> Rig:
    spec = RigSpec(distance_m=distance_m, width=320, height=256, fx_px=500.0, spacing_deg=40.0)
    return default_rig(n, center, spec)


def strong_camera(eye=(0.0, -0.55, 0.45), target=(0.0, 0.0, 0.0)) -> Camera:
    params = np.array([2200.0, 2195.0, 641.3, 509.8, *STRONG_DIST])
    return Camera("strong", "opencv5", params, 1280, 1024, look_at(eye, target))


def plane_scene(material: Material | None = None, size_m: float = 1.0, sensor: Sensor | None = None,
                extra: tuple = ()) -> Scene:
    material = material or Material("white", "matte", albedo=0.8)
    objects = (SceneObject("plane", place(primitives.plane((size_m, size_m))), material), *extra)
    return Scene("test-plane", objects, lighting=Lighting(ambient_W_m2=40.0, lamp_W_m2=0.0),
                 center_m=(0.0, 0.0, 0.0), radius_m=0.1, laser=LaserSpec(head_m=(0.15, -0.4, 0.6)),
                 sensor=sensor or Sensor())


@pytest.fixture
def rng():
    return np.random.default_rng(20261123)
