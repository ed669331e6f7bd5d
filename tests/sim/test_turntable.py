"""The simulated single-camera turntable scan, from the CLI: simulate, detect, reconstruct, evaluate."""

import re
from importlib import resources

import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.io.object_poses import read_object_poses
from scanrig.reconstruct.evaluate import load_truth_surface
from scanrig.reconstruct.light_plane import load_light_plane
from scanrig.reconstruct.points import read_points
from scanrig.sim.library import load_scene
from scanrig.sim.turntable import turntable_rig

#: Frames of the test scan (one every 90 degrees: a wrong object-frame mapping moves points by cm).
N_FRAMES = 4
#: Fewest points per frame: the object spans ~200 of the 480 image rows at half scale.
MIN_POINTS_PER_FRAME = 150
#: Largest distance to the true surface in predicted sigmas: with ~1200 points, a 4-sigma excess
#: has a probability of ~0.1 under honest Gaussian sigmas.
MAX_DISTANCE_SIGMAS = 4.0


def _half_scale_scene(tmp_path):
    """The built-in turntable scene with a 640 x 480 camera (focal length halved too)."""
    text = (resources.files("scanrig.sim") / "scenes" / "turntable.toml").read_text()
    for key, full, half in (("width", "1280", "640"), ("height", "960", "480"), ("fx_px", "1450.0", "725.0")):
        assert f"\n{key} = {full}\n" in text
        text = text.replace(f"\n{key} = {full}\n", f"\n{key} = {half}\n")
    path = tmp_path / "turntable_small.toml"
    path.write_text(text)
    return path


def test_rig_geometry_matches_the_scene():
    scene = load_scene("turntable")
    rig = turntable_rig(scene)
    centre = np.asarray(scene.center_m)
    np.testing.assert_allclose(np.linalg.norm(rig.camera.center_world - centre), scene.rig.distance_m, rtol=1e-12)
    normal, offset = rig.light_plane()
    # the sheet contains the turntable axis, so the object's profile is a meridian
    assert abs(normal @ centre - offset) < 1e-12 and abs(normal @ rig.axis_direction) < 1e-12
    quarter = rig.world_from_object(np.pi / 2)
    np.testing.assert_allclose(quarter.apply(centre + [[0.1, 0.0, 0.0]]), [centre + [0.0, 0.1, 0.0]], atol=1e-15)


@pytest.mark.slow
def test_turntable_scan_from_the_cli_matches_the_true_surface(tmp_path, capsys):
    session = tmp_path / "tt"
    scene = _half_scale_scene(tmp_path)
    assert main(["simulate", str(session), "--rig", "turntable", "--scene", str(scene), "--frames", str(N_FRAMES),
                 "--no-calibration", "--seed", "3", "--workers", "1"]) == 0
    assert not list((session / "scan" / "cam0").glob("dark.*"))  # the object moves: no laser-off frame
    assert len(read_object_poses(session / "scan" / "object_poses.csv")) == N_FRAMES
    assert load_light_plane(session / "truth" / "light_plane.toml")[1] == "cam0"
    assert main(["detect", str(session), "--k-detect", "15"]) == 0
    assert main(["reconstruct", str(session), "--rig", str(session / "truth" / "rig.toml"),
                 "--light-plane", str(session / "truth" / "light_plane.toml")]) == 0
    assert main(["evaluate", str(session / "points.ply"), "--truth", str(session / "truth")]) == 0
    assert re.search(r"\d+ points: RMS [0-9.]+ mm", capsys.readouterr().out)
    cloud, _ = read_points(session / "points.ply")
    distance = load_truth_surface(session / "truth")(cloud.p_world)
    assert np.bincount(cloud.frame, minlength=N_FRAMES).min() >= MIN_POINTS_PER_FRAME
    # the predicted sigma (detector's sigma with the 0.1 px floor) bounds the error of the true rig and plane
    assert np.sqrt(np.mean(distance**2)) <= np.median(cloud.sigma)
    assert np.all(distance <= MAX_DISTANCE_SIGMAS * cloud.sigma)


def test_unknown_rig_is_one_error_line(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "s"), "--rig", "gantry"]) == 2
    assert capsys.readouterr().err.splitlines() == ["error: --rig must be 'arc' or 'turntable', got 'gantry'"]


def test_a_flat_calibration_target_is_refused_before_rendering(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "s"), "--rig", "turntable", "--scene", "turntable",
                 "--target", "chessboard"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "error: a turntable session is calibrated with the cube standing on the turntable for shot 000 (the world "
        "frame); target kind 'chessboard' cannot stand there in view, use 'cube'"]
    assert not (tmp_path / "s").exists()
