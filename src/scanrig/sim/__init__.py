"""The virtual world: scenes, materials, a physically based renderer, a virtual rig, ground truth.

The pipeline never imports this package: it writes the same session folders a real rig writes
and keeps its ground truth apart, under ``truth/``.

>>> import numpy as np
>>> from scanrig.sim import simulate_session
>>> simulate_session("session", scene="default", n_cameras=3, mode="spot", n_frames=20,
...                  rng=np.random.default_rng(0))                     # doctest: +SKIP
"""

from scanrig.sim.laser import BeamPose, LaserSpec, raster_poses, trace_laser
from scanrig.sim.library import load_scene, scene_names
from scanrig.sim.materials import Material
from scanrig.sim.render import CameraView
from scanrig.sim.rigs import RigSpec, default_rig, look_at
from scanrig.sim.scene import Lighting, Scene, SceneObject
from scanrig.sim.sensor import Sensor
from scanrig.sim.session_writer import simulate_session
from scanrig.sim.virtual_rig import VirtualRig

__all__ = [
    "BeamPose", "CameraView", "LaserSpec", "Lighting", "Material", "RigSpec", "Scene", "SceneObject", "Sensor",
    "VirtualRig", "default_rig", "load_scene", "look_at", "raster_poses", "scene_names", "simulate_session",
    "trace_laser",
]
