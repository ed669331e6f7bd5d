"""Shiny parts produce secondary reflections in truth and in the images; matte parts do not."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.sim import primitives
from scanrig.sim.laser import BeamPose, trace_laser
from scanrig.sim.materials import Material
from scanrig.sim.render import CameraView
from scanrig.sim.scene import SceneObject, place

from .conftest import plane_scene, small_rig

#: The secondary spot must stand out from the per-pixel noise of the background under it by
#: this many standard deviations (shot + read noise of the sensor model).
VISIBLE_SIGMAS = 5.0

STEEL = Material("steel", "metal", albedo=0.08, specular=0.7, roughness_rad=0.005)   # polished
GREY = Material("grey", "matte", albedo=0.5)


def _plate_scene(material):
    # a vertical plate facing -y, behind the floor area the cameras look at
    plate = SceneObject("plate", place(primitives.plane((0.15, 0.15)), (0.0, 0.05, 0.12), (90.0, 0.0, 0.0)), material)
    return plane_scene(extra=(plate,))


def _trace(scene):
    head = np.asarray(scene.laser.head_m)
    d = np.array([0.0, 0.05, 0.12]) - head
    return trace_laser(BeamPose(head, d / np.linalg.norm(d)), scene.laser, scene)


def test_shiny_plate_sends_a_visible_secondary_spot_to_the_floor():
    scene = _plate_scene(STEEL)
    trace = _trace(scene)
    assert trace.truth_kind == ["primary", "secondary"]
    primary, secondary = trace.truth_points
    assert abs(primary[1] - 0.05) < 1e-9                     # on the plate
    assert abs(secondary[2]) < 1e-9                           # on the floor
    cam = small_rig(1, center=(0.0, 0.0, 0.05)).cameras[0]
    view = CameraView(cam, scene)
    laser_only = view.clean_frame_e(trace) - view.background_e
    u, v = np.rint(cam.project(secondary[None])[0]).astype(int)
    noise_e = np.sqrt(view.background_e[v, u] + view.sensor.read_noise_e**2)
    assert laser_only[v - 2:v + 3, u - 2:u + 3].max() > VISIBLE_SIGMAS * noise_e


def test_matte_plate_has_no_secondary():
    scene = _plate_scene(GREY)
    trace = _trace(scene)
    assert trace.truth_kind == ["primary"]
    shiny_trace = _trace(_plate_scene(STEEL))
    cam = small_rig(1, center=(0.0, 0.0, 0.05)).cameras[0]
    view = CameraView(cam, scene)
    laser_only = view.clean_frame_e(trace) - view.background_e
    u, v = np.rint(cam.project(shiny_trace.truth_points[1:])[0]).astype(int)
    assert laser_only[v - 2:v + 3, u - 2:u + 3].max() == 0.0


@pytest.mark.parametrize("material, expect", [(STEEL, True), (GREY, False)])
def test_stripe_secondaries_follow_material(material, expect):
    scene = _plate_scene(material)
    head = np.asarray(scene.laser.head_m)
    d = np.array([0.0, 0.05, 0.12]) - head
    d /= np.linalg.norm(d)
    fan = np.cross(np.cross(d, [0.0, 0.0, 1.0]), d)
    trace = trace_laser(BeamPose(head, d, fan / np.linalg.norm(fan)), scene.laser, scene)
    kinds = np.array(trace.truth_kind)
    assert (kinds == "primary").sum() > 100
    assert ((kinds == "secondary").sum() > 10) == expect
