"""A bent calibration board: read from the scene file, rendered bent, its truth recorded."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from scanrig.errors import FileFormatError
from scanrig.sim.calibration_shots import default_target, write_calibration
from scanrig.sim.scene_file import load_scene_file

from .conftest import plane_scene, small_rig
from .test_targets_render import (
    CORNER_RMS_TOL_PX,
    corner_rms_px,
    tilted_chessboard_corners,
)

#: Injected bend (c_x, c_y), metres: large enough that the flat board's corners miss by several
#: times the corner tolerance in the view below.
FLEX_M = (0.003, 0.001)

SCENE = """
name = "bent"
[calibration]
board_flex_m = {value}
[materials.white]
kind = "matte"
[[objects]]
name = "floor"
shape = "plane"
size_m = [1.0, 1.0]
material = "white"
"""


def test_scene_file_reads_board_flex(tmp_path: Path):
    path = tmp_path / "bent.toml"
    path.write_text(SCENE.format(value="[0.003, 0.001]"))
    assert load_scene_file(path).board_flex_m == FLEX_M
    path.write_text(SCENE.format(value="[0.003]"))
    with pytest.raises(FileFormatError) as exc:
        load_scene_file(path)
    assert str(exc.value) == (f"{path}: [calibration]: board_flex_m must be two numbers (c_x, c_y) in metres, "
                              "got [0.003]")


@pytest.mark.slow
def test_bent_board_is_rendered_bent():
    """Chessboard corners found in the render lie at the projections of the bent board's corners."""
    cam, pose, corners = tilted_chessboard_corners(replace(plane_scene(), board_flex_m=FLEX_M))
    target = default_target("chessboard")
    bent = target.points_target + target.flex_directions(target.point_ids) @ np.array(FLEX_M)
    rms = {name: corner_rms_px(corners, cam.project(pose.apply(points)))
           for name, points in (("bent", bent), ("flat", target.points_target))}
    print(f"corner RMS against the bent board {rms['bent']:.4f} px, against the flat one {rms['flat']:.4f} px")
    assert rms["bent"] < CORNER_RMS_TOL_PX
    assert rms["flat"] > 3 * CORNER_RMS_TOL_PX


@pytest.mark.slow
def test_board_flex_truth_is_written(tmp_path: Path):
    room = replace(plane_scene(), board_flex_m=FLEX_M)
    (tmp_path / "truth").mkdir()
    write_calibration(tmp_path, room, small_rig(), 1, "charuco", np.random.default_rng(3), workers=1)
    assert (tmp_path / "truth" / "board_flex.csv").read_text() == "c_x_m,c_y_m\n0.003,0.001\n"
    assert "flex" not in (tmp_path / "target.toml").read_text()
