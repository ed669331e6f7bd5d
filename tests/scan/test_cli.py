"""``scanrig scan`` end to end on the simulator (quarter-size cameras), resume, and bad input."""

from pathlib import Path

import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.reconstruct.points import read_points
from scanrig.scan.store import read_state

SCENE = str(Path(__file__).parent / "data" / "small_sphere.toml")
BALL_CENTRE_M, BALL_RADIUS_M = np.array([0.0, 0.0, 0.06]), 0.06
#: Floor points (z = 0) near the ball's contact point also lie within a few mm of its surface.
FLOOR_CLEARANCE_M = 0.005
ARGS = ["--sim", SCENE, "--sim-scale", "0.25", "--spacing-mm", "12", "--roi-mm=-70,-70,5,70,70,130", "--workers", "1"]


@pytest.fixture(scope="module")
def scanned(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli") / "session"
    assert main(["scan", str(root), *ARGS, "--budget", "40", "--seed", "3"]) == 0
    return root


def test_scan_writes_points_on_the_ball(scanned):
    cloud, comments = read_points(scanned / "points.ply")
    assert "seed: 3" in comments
    state = read_state(scanned)
    assert len(state.frames) == 40 and state.finished == "beam budget spent" and len(state.passes) >= 2
    near = np.abs(np.linalg.norm(cloud.p_world - BALL_CENTRE_M, axis=1) - BALL_RADIUS_M) < 0.01
    on_ball = near & (cloud.p_world[:, 2] > FLOOR_CLEARANCE_M)
    assert on_ball.sum() >= 10
    # the simulator's spot noise propagates into each point's sigma; 5 sigma bounds its distance
    # to the true sphere (tessellated: its facets lie within 0.1 mm of the sphere at this size)
    dist = np.abs(np.linalg.norm(cloud.p_world[on_ball] - BALL_CENTRE_M, axis=1) - BALL_RADIUS_M)
    assert np.all(dist <= 5 * cloud.sigma[on_ball] + 1e-4)


def test_resume_with_a_larger_budget_is_refused(scanned, capsys):
    assert main(["scan", str(scanned), *ARGS, "--budget", "80", "--resume"]) == 2
    assert "--budget 80 differs from the interrupted scan's 40" in capsys.readouterr().err


def test_resume_of_a_finished_scan_keeps_the_points(scanned, tmp_path):
    before = read_points(scanned / "points.ply")[0].p_world
    assert main(["scan", str(scanned), "--sim", SCENE, "--sim-scale", "0.25", "--workers", "1", "--resume"]) == 0
    np.testing.assert_array_equal(read_points(scanned / "points.ply")[0].p_world, before)


@pytest.mark.parametrize("args, message", [
    ([], "give exactly one rig: --sim SCENE, --replay FOLDER or --camera NAME=SOURCE (got none)"),
    (["--sim", "sphere", "--replay", "x"], "give exactly one rig: --sim SCENE, --replay FOLDER or --camera NAME=SOURCE (got ['--sim', '--replay'])"),
    (["--sim", "sphere", "--roi-mm", "1,2,3"], "--roi-mm must be 6 comma-separated numbers, got '1,2,3'"),
    (["--camera", "cam0"], "--camera must be NAME=SOURCE (device index, URL or video file), got 'cam0'"),
    (["--camera", "cam0=0"], "a real rig needs --gcode PORT, --head-mm X,Y,Z and --roi-mm besides --camera"),
])
def test_bad_command_lines(tmp_path, capsys, args, message):
    assert main(["scan", str(tmp_path / "s"), *args]) == 2
    assert message in capsys.readouterr().err


def test_resume_on_another_rig_is_refused(scanned, capsys):
    assert main(["scan", str(scanned), "--sim", SCENE, "--sim-scale", "0.5", "--resume"]) == 2
    assert "resume it with the same rig options" in capsys.readouterr().err


def test_resume_without_a_scan(tmp_path, capsys):
    assert main(["scan", str(tmp_path), "--sim", SCENE, "--resume"]) == 2
    assert "scan/manifest.jsonl: no scan manifest to resume (start the scan without --resume)" in capsys.readouterr().err
