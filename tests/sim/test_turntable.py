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
from scanrig.geometry import Rig
from scanrig.io.session import read_image
from scanrig.sim.calibration_shots import CALIBRATION_SUPERSAMPLING, calibration_sensor, write_calibration
from scanrig.sim.library import load_scene
from scanrig.sim.light_plane_shots import sheet_plane
from scanrig.sim.turntable import LASER_FILL, turntable_rig, write_laser_on_calibration_poses

#: Frames of the test scan (one every 90 degrees: a wrong object-frame mapping moves points by cm).
N_FRAMES = 4
#: Fewest points per frame: the object spans ~200 of the 480 image rows at half scale.
MIN_POINTS_PER_FRAME = 150
#: Half the cube's edge, metres (scanrig.sim.calibration_shots.default_target("cube")).
CUBE_HALF_EDGE_M = 0.1
#: Pixels brighter than this share of the stripe's peak are taken as the stripe: they lie within
#: about one PSF sigma (0.6 px) of its centre line plus the sheet's half-thickness (~0.4 px).
STRIPE_SHARE = 0.5
#: Their rays meet the true sheet within ~1.5 px of the centre line: at 0.3-0.4 m with fx 725 px a
#: pixel is 0.4-0.55 mm, stretched by 1/sin(30 deg) along the sheet: 1.5 px is at most 1.7 mm.
STRIPE_ON_CUBE_M = 1.7e-3
#: Fewest such pixels: the sheet crosses the cube from top to bottom (~200 px at half scale), half of
#: it on white paper (the rest on black squares and markers, too dark to pass STRIPE_SHARE).
MIN_STRIPE_PIXELS = 60
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
    normal, offset = sheet_plane(rig.laser)
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
    # the object moves: no laser-off frame for the camera, one per frame instead, that frame
    # without the laser (their difference is noise but on the stripe)
    assert not list((session / "scan" / "cam0").glob("dark.*"))
    frames = sorted((session / "scan" / "cam0").glob("*.png"))
    assert [p.name for p in sorted((session / "scan" / "cam0" / "dark").glob("*.png"))] == [p.name for p in frames]
    laser = read_image(frames[0]).astype(float) - read_image(session / "scan" / "cam0" / "dark" / frames[0].name)
    assert np.mean(np.abs(laser) > 3) < 0.01  # the dim room's noise: 0-1 DN on 99 % of the pixels
    assert laser.max() > 30  # the stripe: 86 DN
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


def test_light_plane_shot_shows_the_true_sheet_on_the_cube(tmp_path):
    """Shot 000 (the cube at the world origin, on the axis) with the laser on: the stripe's pixels are
    where the true sheet cuts the cube, and the stripe peaks LASER_FILL of the full well above paper."""
    scene = load_scene(_half_scale_scene(tmp_path))
    rig = turntable_rig(scene)
    rng = np.random.default_rng(12)
    (tmp_path / "truth").mkdir()
    shots = write_calibration(tmp_path, scene, Rig([rig.camera]), 1, "cube", rng, workers=1)
    assert list(shots) == ["000"] and np.array_equal(shots["000"].as_matrix(), np.eye(4))
    write_laser_on_calibration_poses(tmp_path, scene, rig, shots, rng, workers=1)
    off = read_image(tmp_path / "calibration" / "cam0" / "000.png").astype(float)
    on = read_image(tmp_path / "light_plane" / "cam0" / "000.png").astype(float)
    sensor = calibration_sensor(scene)
    assert sensor.supersampling == CALIBRATION_SUPERSAMPLING
    laser_dn = on - off
    full_scale_dn = sensor.full_well_e / sensor.gain_e_per_dn
    # the peak pixel: LASER_FILL of the full well, less what pixel integration spreads to its neighbours
    assert 0.5 * LASER_FILL * full_scale_dn < laser_dn.max() <= (LASER_FILL + 0.05) * full_scale_dn
    v, u = np.nonzero(laser_dn > STRIPE_SHARE * laser_dn.max())
    centers, dirs = rig.camera.rays(np.c_[u, v].astype(float))
    normal, offset = sheet_plane(rig.laser)
    p = centers + ((offset - centers @ normal) / (dirs @ normal))[:, None] * dirs
    on_cube = np.abs(np.abs(p).max(axis=1) - CUBE_HALF_EDGE_M)
    assert len(p) >= MIN_STRIPE_PIXELS and on_cube.max() < STRIPE_ON_CUBE_M


def test_light_plane_shots_option_is_for_the_arc_rig(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "s"), "--rig", "turntable", "--light-plane-shots", "4"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "error: --light-plane-shots is for --rig arc; --rig turntable photographs every calibration pose of the "
        "cube with the laser on as well (light_plane/cam0/<shot>)"]


def test_colour_scene_is_refused(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "s"), "--rig", "turntable", "--scene", "colour_stripe"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "error: scene 'colour_stripe' has a colour camera; turntable sessions render grey cameras only"]
    assert not (tmp_path / "s").exists()
