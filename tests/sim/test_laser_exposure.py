"""Laser power from a wanted over-exposure: the rendered peak on white paper facing the beam."""

from __future__ import annotations

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.geometry import Camera
from scanrig.sim import primitives
from scanrig.sim.laser import BeamPose, LaserSpec, trace_laser
from scanrig.sim.laser_exposure import nominal_peak_e_per_W, overexposed_laser
from scanrig.sim.materials import Material
from scanrig.sim.render import CameraView
from scanrig.sim.rigs import RigSpec, look_at
from scanrig.sim.scene import Lighting, Scene, SceneObject, place
from scanrig.sim.sensor import Sensor

#: The nominal peak treats the pixel's box as a Gaussian of variance 1/12 px² (0.4 % off for a
#: 0.3 px beam under a 0.6 px PSF) and the renderer samples the profile 4 × 4 times per pixel:
#: the rendered peak agrees within 1 % (measured: 0.1 to 0.2 %).
PEAK_REL_TOL = 0.01
HEAD_M = (0.0, -0.6, 0.8)      # 1 m from the centre; the paper's normal points at it (36.87° about x)


def _facing_paper_view(laser: LaserSpec) -> tuple[CameraView, Scene]:
    white = Material("paper", "matte", albedo=1.0)
    paper = SceneObject("paper", place(primitives.plane((0.4, 0.4)), rotation_deg=(np.degrees(np.arcsin(0.6)), 0, 0)),
                        white)
    scene = Scene("paper", (paper,), lighting=Lighting(ambient_W_m2=0.0, lamp_W_m2=0.0), center_m=(0.0, 0.0, 0.0),
                  laser=laser, sensor=Sensor())
    # the camera at the laser head sees the beam's cross-section as the nominal peak assumes
    cam = Camera("head", "opencv5", np.array([2200.0, 2200.0, 50.0, 50.0, 0, 0, 0, 0, 0]), 101, 101,
                 look_at(HEAD_M, (0.0, 0.0, 0.0)))
    return CameraView(cam, scene), scene


@pytest.mark.parametrize("mode", ["spot", "stripe"])
@pytest.mark.parametrize("waist_m", [2.5e-4, 1e-3])
def test_rendered_peak_is_the_wanted_overexposure(mode, waist_m):
    rig = RigSpec(distance_m=1.0, fx_px=2200.0)
    laser = overexposed_laser(LaserSpec(head_m=HEAD_M, waist_m=waist_m), Sensor(), rig, (0.0, 0.0, 0.0), 8.0)
    view, scene = _facing_paper_view(laser)
    head = np.asarray(HEAD_M)
    pose = BeamPose(head, -head / np.linalg.norm(head), np.array([1.0, 0.0, 0.0]) if mode == "stripe" else None)
    window = view.laser_window(trace_laser(pose, laser, scene))
    assert window.electrons.max() / scene.sensor.full_well_e == pytest.approx(8.0, rel=PEAK_REL_TOL)


def test_power_scales_with_the_overexposure():
    rig, sensor, laser = RigSpec(), Sensor(), LaserSpec()
    high = overexposed_laser(laser, sensor, rig, (0.0, 0.0, 0.1), 10.0)
    low = overexposed_laser(laser, sensor, rig, (0.0, 0.0, 0.1), 1.0)
    assert high.stripe_power_W == pytest.approx(10 * low.stripe_power_W, rel=1e-12)
    assert high.power_W * nominal_peak_e_per_W(laser, sensor, rig, (0.0, 0.0, 0.1), "spot") == pytest.approx(
        10 * sensor.full_well_e, rel=1e-12)


def test_bad_overexposure():
    with pytest.raises(InputError) as err:
        overexposed_laser(LaserSpec(), Sensor(), RigSpec(), (0.0, 0.0, 0.1), -1.0)
    assert str(err.value) == "laser_overexposure must be a positive number, got -1.0"
