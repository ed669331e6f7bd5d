"""The simulated survey files let ``relocate`` recover a moved camera's true pose."""

import numpy as np

from scanrig.calibration.relocate import read_known_points, relocate_camera
from scanrig.geometry import RigidTransform
from scanrig.sim import primitives
from scanrig.sim.materials import Material
from scanrig.sim.scene import SceneObject, place
from scanrig.sim.survey import MARK_SIGMA_PX, write_survey

from .conftest import plane_scene, small_rig


def _scene():
    ball = SceneObject("ball", place(primitives.sphere(0.08), (0.0, 0.0, 0.08)), Material("grey", "matte", albedo=0.5))
    return plane_scene(extra=(ball,))


def test_survey_relocates_a_moved_camera_to_its_true_pose(tmp_path, rng):
    scene, rig = _scene(), small_rig(3)
    paths = write_survey(tmp_path, scene, rig, rng)
    assert [p.name for p in paths] == [f"{name}.csv" for name in rig.names]

    true_cam = rig.cameras[1]
    names, p_world, uv = read_known_points(tmp_path / "survey" / f"{true_cam.name}.csv")
    assert len(names) >= 12                        # most grid lines of sight hit the plane or the ball
    assert np.ptp(p_world[:, 2]) > 0.02            # not all on the floor: the pose is well conditioned
    residual_px = np.linalg.norm(true_cam.project(p_world) - uv, axis=1)
    assert np.sqrt(np.mean(residual_px ** 2)) < 4 * MARK_SIGMA_PX

    moved = true_cam.with_pose(RigidTransform.from_rvec_tvec([0.02, -0.01, 0.015], [0.01, 0.0, -0.005])
                               @ true_cam.cam_from_world)
    result = relocate_camera(moved, p_world, uv)
    error_m = np.abs(result.camera.center_world - true_cam.center_world)
    assert result.moved
    assert np.all(error_m < 5 * result.center_std_m), (error_m, result.center_std_m)
