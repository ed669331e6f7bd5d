"""``scanrig calibrate`` / ``scanrig relocate`` end to end on rendered sessions, and bad input."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import scanrig
from scanrig.calibration.synthetic import render_board
from scanrig.cli.main import main
from scanrig.geometry.camera import Camera
from scanrig.geometry.transform import RigidTransform
from scanrig.io.session import write_image
from scanrig.targets import chessboard, save_target

TARGET = chessboard((7, 5), 0.03)
SENTINEL = "# an earlier calibration: must survive a failed run\n"


def _cameras():
    base = np.array([620.0, 620.0, 320.0, 240.0, -0.05, 0.02, 0.0, 0.0, 0.0])
    left = Camera("left", "opencv5", base, 640, 480)
    right = Camera("right", "opencv5", base + [5, 5, -4, 3, 0, 0, 0, 0, 0], 640, 480,
                   RigidTransform(Rotation.from_rotvec([0, -0.08, 0]).as_matrix(), np.array([-0.08, 0, 0])))
    return left, right


def _board_poses(n, rng):
    centre = np.array([TARGET.boards[0].size_m[0] / 2, TARGET.boards[0].size_m[1] / 2, 0.0])
    poses = []
    for k in range(n):
        R = Rotation.from_rotvec(np.deg2rad([25 * np.sin(k), 25 * np.cos(1.7 * k), 5 * k])).as_matrix()
        t = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.02, 0.02), 0.55]) - R @ centre
        poses.append(RigidTransform(R, t))
    return poses


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A session with 2 cameras x 5 shots of a 7x5 chessboard, rendered with blur and noise."""
    rng = np.random.default_rng(21)
    root = tmp_path_factory.mktemp("rendered")
    save_target(TARGET, root / "target.toml")
    left, right = _cameras()
    for cam in (left, right):
        (root / "calibration" / cam.name).mkdir(parents=True)
    for k, world_from_board in enumerate(_board_poses(5, rng)):
        for cam in (left, right):
            img = render_board(TARGET.boards[0], cam, cam.cam_from_world @ world_from_board, 0.8, 2.0, rng,
                               supersample=2)
            write_image(root / "calibration" / cam.name / f"{k:02d}.png", img)
    return root


def _copy(src, dst):
    shutil.copytree(src, dst)
    (dst / "rig.toml").write_text(SENTINEL)
    return dst


def test_calibrate_rendered_session(rendered, tmp_path, capsys):
    root = _copy(rendered, tmp_path / "s")
    (root / "rig.toml").unlink()
    assert main(["calibrate", str(root), "--no-cross-validate"]) == 0
    out = capsys.readouterr().out
    assert "RMS" in out and "wrote" in out
    rig, info, meta = scanrig.io.rig_file.load_rig_info(root / "rig.toml")
    left, right = _cameras()
    # 5 views per camera at 0.1 px-level detection noise: focal length within 0.5 %.
    assert rig["left"].params[0] == pytest.approx(left.params[0], rel=5e-3)
    assert rig["right"].params[0] == pytest.approx(right.params[0], rel=5e-3)
    assert info["left"]["n_observations"] > 0 and len(info["left"]["params_std"]) == 9
    baseline = np.linalg.norm(rig["left"].center_world - rig["right"].center_world)
    assert baseline == pytest.approx(np.linalg.norm(right.center_world - left.center_world), abs=1e-3)
    for name in ("summary.txt", "corners.csv", "outliers.csv", "residuals_left.png", "residuals_right.png"):
        assert (root / "calibration_report" / name).is_file()


def test_relocate_cli_updates_rig(rendered, tmp_path, capsys):
    root = tmp_path / "r"
    root.mkdir()
    left, right = _cameras()
    scanrig.save_rig(scanrig.Rig([left, right]), root / "rig.toml")
    moved = right.with_pose(RigidTransform(Rotation.from_rotvec([0.0, 0.01, 0.002]).as_matrix(),
                                           np.array([0.004, 0.0, -0.002])) @ right.cam_from_world)
    rng = np.random.default_rng(3)
    pts = rng.uniform([-0.2, -0.15, 0.4], [0.2, 0.15, 0.8], size=(6, 3))
    uv = moved.project(pts) + rng.normal(scale=0.1, size=(6, 2))
    lines = ["point,x,y,z,u,v"] + [f"p{k},{x},{y},{z},{u},{v}" for k, ((x, y, z), (u, v)) in enumerate(zip(pts, uv))]
    (root / "known_points.csv").write_text("\n".join(lines) + "\n")
    assert main(["relocate", str(root), "--camera", "right", "--points", str(root / "known_points.csv")]) == 0
    out = capsys.readouterr().out
    assert "camera moved: yes" in out
    new = scanrig.load_rig(root / "rig.toml")["right"]
    # Within 5 of the printed sigmas (the acceptance figure is checked in test_relocate.py).
    sigma_mm = [float(v) for v in out.split("new centre sigma [")[1].split("]")[0].split(",")]
    assert np.linalg.norm(new.center_world - moved.center_world) * 1000 < 5 * np.linalg.norm(sigma_mm)
    np.testing.assert_array_equal(new.params, right.params)
    assert main(["relocate", str(root), "--camera", "nope", "--points", str(root / "known_points.csv")]) == 2
    assert "--camera 'nope' is not in" in capsys.readouterr().err


def _fails(root, capsys, pattern):
    assert main(["calibrate", str(root), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert pattern in err, err
    assert (root / "rig.toml").read_text() == SENTINEL


def test_bad_input_image_sizes_differ(rendered, tmp_path, capsys):
    root = _copy(rendered, tmp_path / "s")
    img = np.full((240, 320), 255, np.uint8)
    write_image(root / "calibration" / "left" / "03.png", img)
    _fails(root, capsys, "03.png: image is 320x240 but 00.png of camera 'left' is 640x480")


def test_bad_input_target_never_seen(rendered, tmp_path, capsys):
    root = _copy(rendered, tmp_path / "s")
    for path in (root / "calibration" / "right").iterdir():
        write_image(path, np.full((480, 640), 200, np.uint8))
    _fails(root, capsys, "camera 'right': the target was never found in its calibration images")


def test_bad_input_too_few_views(rendered, tmp_path, capsys):
    root = _copy(rendered, tmp_path / "s")
    for path in sorted((root / "calibration" / "right").iterdir())[1:]:
        path.unlink()
    _fails(root, capsys, "camera 'right': the target was found in 1 usable view(s); at least 2 are needed")


def test_bad_input_target_missing_field(rendered, tmp_path, capsys):
    root = _copy(rendered, tmp_path / "s")
    (root / "target.toml").write_text('kind = "chessboard"\ninner_corners = [7, 5]\n')
    _fails(root, capsys, "target.toml: target (kind = 'chessboard'): missing field 'square_m'")


def test_bad_input_disconnected_cameras(rendered, tmp_path, capsys):
    root = _copy(rendered, tmp_path / "s")
    # left keeps shots 00-02, right keeps 03-04 renamed so that no stem is shared
    for k in (3, 4):
        (root / "calibration" / "left" / f"{k:02d}.png").unlink()
    for k in (0, 1, 2):
        (root / "calibration" / "right" / f"{k:02d}.png").unlink()
    _fails(root, capsys, "camera graph is disconnected: cameras ['right'] share no shot")
