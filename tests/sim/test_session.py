"""End to end: session folder, truth files, determinism, the CLI and the virtual rig."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.io.rig_file import load_rig
from scanrig.io.session import Session, read_image
from scanrig.sim import VirtualRig, load_scene, raster_poses, simulate_session

#: A spot's brightest pixel lies within this distance of the projected true hit: the spot is
#: symmetric and its noise-free peak is within 0.5 px of the centre; shot noise on a peak of a
#: few hundred electrons can move the argmax by one more pixel.
PEAK_TOL_PX = 1.5

SMALL_SCENE = """
name = "small-plane"
center_m = [0.0, 0.0, 0.0]
radius_m = 0.08

[rig]
width = 320
height = 256
fx_px = 500.0
distance_m = 0.7
spacing_deg = 40.0

[laser]
head_m = [0.15, -0.4, 0.6]
waist_m = 1e-3
power_W = 1e-3
stripe_power_W = 0.05

[materials.paint]
kind = "matte"
albedo = 0.7
texture_amplitude = 0.2

[[objects]]
name = "plane"
shape = "plane"
size_m = [0.8, 0.8]
material = "paint"
"""


@pytest.fixture
def scene_file(tmp_path) -> Path:
    path = tmp_path / "small.toml"
    path.write_text(SMALL_SCENE)
    return path


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_gives_identical_files_whatever_the_worker_count(tmp_path, scene_file):
    runs = []
    for name, workers in (("a", 2), ("b", 1)):
        out = simulate_session(tmp_path / name, scene=scene_file, n_cameras=2, mode="spot", n_frames=4,
                               rng=np.random.default_rng(11), with_calibration=False, workers=workers)
        runs.append(_files(out))
    assert runs[0] == runs[1]
    other = simulate_session(tmp_path / "c", scene=scene_file, n_cameras=2, mode="spot", n_frames=4,
                             rng=np.random.default_rng(12), with_calibration=False, workers=2)
    assert _files(other)["scan/cam0/00000.png"] != runs[0]["scan/cam0/00000.png"]


def test_session_layout_and_truth(tmp_path, scene_file):
    simulate_session(tmp_path / "a", scene=scene_file, n_cameras=2, mode="spot", n_frames=6,
                     rng=np.random.default_rng(11), with_calibration=True, n_shots=1, target_kind="chessboard",
                     workers=2, provenance={"seed": 11})
    root = tmp_path / "a"
    session = Session(root)
    assert session.camera_names("scan") == ["cam0", "cam1"]
    assert len(session.frames("scan")) == 6 and session.dark_path("cam0") is not None
    assert len(session.frames("calibration")) == 1 and (root / "target.toml").is_file()
    for name in ("rig.toml", "frames.csv", "laser.csv", "target_poses.csv", "scene.toml", "meshes/plane.ply"):
        assert (root / "truth" / name).is_file(), name
    rig = load_rig(root / "truth" / "rig.toml")
    with open(root / "truth" / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["frame"] for r in rows] == list(session.frames("scan"))      # one primary hit per frame
    assert {r["kind"] for r in rows} == {"primary"}
    dark = read_image(session.dark_path("cam0")).astype(np.float64)
    for row in rows:
        img = read_image(session.frames("scan")[row["frame"]]["cam0"]).astype(np.float64)
        peak = np.unravel_index(np.argmax(img - dark), img.shape)[::-1]
        q = rig["cam0"].project([[float(row["x"]), float(row["y"]), float(row["z"])]])[0]
        assert np.hypot(*(peak - q)) < PEAK_TOL_PX, (row, peak, q)


def test_stripe_session(tmp_path, scene_file):
    out = simulate_session(tmp_path / "s", scene=scene_file, n_cameras=1, mode="stripe", n_frames=2,
                           rng=np.random.default_rng(2), with_calibration=False, workers=1)
    with open(out / "truth" / "laser.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and all(r["fan_x"] != "" for r in rows)
    img = read_image(out / "scan" / "cam0" / "00000.png").astype(np.float64)
    dark = read_image(out / "scan" / "cam0" / "dark.png").astype(np.float64)
    # a stripe crosses the image: many rows hold a bright laser pixel
    assert ((img - dark).max(axis=1) > 10).sum() > 40


def test_cli_simulate(tmp_path, scene_file, capsys):
    out = tmp_path / "cli"
    status = main(["simulate", str(out), "--scene", str(scene_file), "--cameras", "1", "--frames", "2",
                   "--no-calibration", "--seed", "4", "--workers", "1"])
    assert status == 0
    assert (out / "scan" / "cam0" / "00001.png").is_file()
    assert "seed = 4" in (out / "session.toml").read_text()


def test_cli_bad_mode_exits_2(tmp_path, scene_file, capsys):
    status = main(["simulate", str(tmp_path / "x"), "--scene", str(scene_file), "--mode", "sweep"])
    assert status == 2
    assert "--mode must be 'spot' or 'stripe', got 'sweep'" in capsys.readouterr().err


def test_virtual_rig_records_truth(scene_file):
    scene = load_scene(scene_file)
    from scanrig.sim import default_rig

    rig = default_rig(2, scene.center_m, scene.rig)
    vr = VirtualRig(scene, rig, np.random.default_rng(5))
    assert vr.names == ["cam0", "cam1"]
    pose = raster_poses(scene.laser, scene.center_m, scene.radius_m, 1, "spot")[0]
    vr.set_laser(False)
    dark = vr.grab()
    vr.move_to(pose)
    vr.set_laser(True)
    lit = vr.grab()
    assert set(lit) == {"cam0", "cam1"} and lit["cam0"].shape == (256, 320)
    assert vr.truth[0].beam is None and len(vr.truth[0].points) == 0
    (p,) = vr.truth[1].points
    q = rig["cam0"].project(p[None])[0]
    diff = lit["cam0"].astype(float) - dark["cam0"].astype(float)
    peak = np.unravel_index(np.argmax(diff), diff.shape)[::-1]
    assert np.hypot(*(peak - q)) < PEAK_TOL_PX


def test_virtual_rig_frames_do_not_depend_on_the_background_workers(scene_file):
    scene = load_scene(scene_file)
    from scanrig.sim import default_rig

    rig = default_rig(2, scene.center_m, scene.rig)
    pose = raster_poses(scene.laser, scene.center_m, scene.radius_m, 1, "stripe")[0]
    frames = []
    for workers in (1, 2):
        vr = VirtualRig(scene, rig, np.random.default_rng(5), workers=workers)
        vr.move_to(pose)
        vr.set_laser(True)
        frames.append(vr.grab())
    assert all(np.array_equal(frames[0][name], frames[1][name]) for name in rig.names)
