"""`scanrig calibrate SESSION --light-plane` on a rendered single-camera session with a known sheet."""

import shutil
import tomllib

import cv2
import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.reconstruct.light_plane import load_light_plane
from tests.reconstruct import light_plane_synth as synth

#: The task's accuracy for >= 6 poses at 0.3-0.6 m.
NORMAL_TOL_DEG = 0.05
OFFSET_TOL_M = 5e-5
#: A single seed's normalised error beyond 4 has probability < 1e-4 for an honest sigma.
MAX_NORMALISED = 4.0
#: Files a light-plane calibration writes; none may exist after a failed run.
OUTPUTS = ("rig.toml", "light_plane.toml", "calibration_report")


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """8 poses of the chessboard, an 800 x 640 camera with f = 600 px, rendered once (~2 s)."""
    out = tmp_path_factory.mktemp("lp") / "s"
    out.mkdir()
    return synth.rendered_session(out, 8)


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


@pytest.mark.slow
def test_light_plane_end_to_end(session, tmp_path, capsys):
    root = _copy(session, tmp_path / "s")
    cv2.imwrite(str(root / "light_plane" / "cam0" / "zz_blank.png"), np.full((640, 800), 20, np.uint8))
    # lp05 without its laser-off twin: its pose comes from PnP in the laser-on image itself
    (root / "calibration" / "cam0" / "lp05.png").unlink()
    assert main(["calibrate", str(root), "--light-plane", "--no-cross-validate"]) == 0
    out = capsys.readouterr().out
    assert "light plane of cam0 (world frame of rig.toml)" in out
    assert f"skipped: {root / 'light_plane' / 'cam0' / 'zz_blank.png'}: the target was not found, skipped" in out
    assert "  images   8 used, 1 skipped" in out
    assert "warning" not in out.split("light plane of cam0")[1]
    plane, camera = load_light_plane(root / "light_plane.toml")
    assert camera == "cam0"
    truth = synth.true_plane_in_rig_world(root)
    angle_deg, offset_m = synth.angle_and_offset_error(plane, *truth)
    assert angle_deg < NORMAL_TOL_DEG and abs(offset_m) < OFFSET_TOL_M
    # one seed: each error within 4 of its sigmas (the spread over seeds is the benchmark's)
    assert np.all(np.abs(synth.normalised_errors(plane, *truth)) < MAX_NORMALISED)
    doc = tomllib.loads((root / "light_plane.toml").read_text())
    assert doc["offset_sigma_m"] == pytest.approx(plane.offset_sigma_m(), rel=1e-12)
    assert doc["n_poses"] == 8 and doc["laser_color"] == "grey"
    report = root / "calibration_report"
    assert (report / "light_plane_cam0.png").stat().st_size > 0
    assert (report / "light_plane_summary.txt").read_text().startswith("light plane of cam0")
    for stem in [f"lp{i:02d}" for i in range(8)]:
        assert f"  {stem} " in out


def _fails(root, capsys, args, message):
    assert main(["calibrate", str(root), "--light-plane", "--no-cross-validate", "--no-plots", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {message}"]
    assert not any((root / name).exists() for name in OUTPUTS)


@pytest.mark.slow
def test_light_plane_bad_input(session, tmp_path, capsys):
    root = _copy(session, tmp_path / "a")
    _fails(root, capsys, ["--color", "purple"], "--color must be one of ['grey', 'red', 'green', 'blue'], got 'purple'")
    (root / "session.toml").write_text('laser_color = "purple"\n')
    _fails(root, capsys, [], f"laser_color in {root / 'session.toml'} must be one of ['grey', 'red', 'green', "
                             f"'blue'], got 'purple'")
    (root / "session.toml").unlink()
    folder = root / "light_plane" / "cam0"
    shutil.copy(folder / "lp00.png", folder / "lp00.jpg")
    _fails(root, capsys, [], f"{folder / 'lp00.png'}: two images share the stem 'lp00' (also lp00.jpg)")
    (folder / "lp00.jpg").unlink()
    # one pose with the stripe, one without (its laser-off image in place of the laser-on one)
    for path in sorted(folder.iterdir())[2:]:
        path.unlink()
    shutil.copy(root / "calibration" / "cam0" / "lp01.png", folder / "lp01.png")
    _fails(root, capsys, [], f"{folder}: the stripe on the target was found in 1 usable pose(s); at least 2 are "
                             f"needed (6 or more at different distances and tilts); {folder / 'lp01.png'}: no laser "
                             f"stripe on the target (0 points), skipped")
    (folder / "lp01.png").unlink()
    # the same pose three times (no laser-off twins: each located in its own image)
    for stem in ("x1", "x2"):
        shutil.copy(folder / "lp00.png", folder / f"{stem}.png")
    _fails(root, capsys, [], "the stripe points of all 3 poses lie along one line (the target in one plane at "
                             "every pose?): move the target to other distances and tilts between shots")
    # no stripe: the laser-off images in place of the laser-on ones
    root = _copy(session, tmp_path / "b")
    for path in (root / "light_plane" / "cam0").iterdir():
        shutil.copy(root / "calibration" / "cam0" / path.name, path)
    _fails(root, capsys, [], f"{root / 'light_plane' / 'cam0'}: no laser stripe found on the target in any of 8 "
                             f"image(s) with laser colour 'grey'")
    shutil.rmtree(root / "light_plane")
    _fails(root, capsys, [], f"{root / 'light_plane'}: no light-plane images (light_plane/<camera>/<shot>.png: the "
                             f"target with the laser stripe across it)")


@pytest.mark.slow
def test_light_plane_wrong_colour_names_the_right_one(session, tmp_path, capsys):
    """A red laser: the stripe only in the red channel; --color green finds nothing and says red."""
    root = _copy(session, tmp_path / "c")
    for path in (root / "light_plane" / "cam0").iterdir():
        on = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        off_path = root / "calibration" / "cam0" / path.name
        off = cv2.imread(str(off_path), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(path), np.dstack([off, off, on]))  # BGR on disk: the stripe in red
        cv2.imwrite(str(off_path), np.dstack([off, off, off]))
    folder = root / "light_plane" / "cam0"
    _fails(root, capsys, ["--color", "green"],
           f"{folder}: no laser stripe found on the target in any of 8 image(s) with laser colour 'green'; the "
           f"images show a red stripe: use --color red (or laser_color = 'red' in session.toml)")
    assert main(["calibrate", str(root), "--light-plane", "--color", "red", "--no-cross-validate", "--no-plots"]) == 0
    assert "laser_color = \"red\"" in (root / "light_plane.toml").read_text()


@pytest.mark.slow
def test_a_colour_camera_whose_white_balance_clips_red_below_255(tmp_path, capsys):
    """The colour scene's red laser, its red channel times 0.85 after the sensor clipped, stored
    as JPEG: each pose's stripe is fitted with red clipped where the image shows it (about 218 DN),
    not as a peak at its flat top (0.012 deg and 0.036 mm measured; 0.048 deg and 0.201 mm with
    red taken to clip at 255)."""
    import dataclasses

    from scanrig.sim.library import load_scene

    scene = load_scene("colour_stripe")
    scene = dataclasses.replace(scene, colour=dataclasses.replace(scene.colour, white_balance=(0.85, 1.0, 1.0)))
    root = synth.rendered_session(tmp_path, 8, scene=scene)
    assert main(["calibrate", str(root), "--light-plane", "--color", "red", "--no-cross-validate", "--no-plots"]) == 0
    plane, _ = load_light_plane(root / "light_plane.toml")
    angle_deg, offset_m = synth.angle_and_offset_error(plane, *synth.true_plane_in_rig_world(root))
    assert angle_deg < NORMAL_TOL_DEG and abs(offset_m) < OFFSET_TOL_M


def _bright_line(image, rows, u_centre, peak):
    """Add a Gaussian line (sigma 1 px) centred at column ``u_centre`` on ``rows``."""
    u = np.arange(image.shape[1])
    profile = peak * np.exp(-0.5 * (u - u_centre) ** 2)
    out = image.astype(np.float64)
    out[rows] += profile
    return np.clip(out, 0, 255).astype(np.uint8)


@pytest.mark.slow
def test_light_plane_ignores_ten_percent_junk(session, tmp_path, capsys):
    """Brighter lines beside the stripe on 10 % of its rows (on the board, off the sheet) and on
    rows above the board (off the target): the plane moves by less than its sigma."""
    from scanrig import detect_stripe
    from scanrig.io.session import read_image

    clean = _copy(session, tmp_path / "clean")
    dirty = _copy(session, tmp_path / "dirty")
    for path in sorted((dirty / "light_plane" / "cam0").iterdir()):
        image = read_image(path)
        table = detect_stripe(image, dark=read_image(dirty / "calibration" / "cam0" / path.name))
        stripe = table.filter(np.asarray(table.column("rank")) == 0)
        v, u = np.asarray(stripe.column("v")), np.asarray(stripe.column("u"))
        rows = np.unique(np.rint(v).astype(int))
        rows = rows[len(rows) // 2: len(rows) // 2 + len(rows) // 10]  # 10 % of the stripe's rows
        image = _bright_line(image, rows, np.median(u) + 40, 200.0)  # on the board, off the sheet
        above = np.arange(max(int(v.min()) - 40, 0), int(v.min()) - 5)
        image = _bright_line(image, above, np.median(u), 200.0)       # off the board
        cv2.imwrite(str(path), image)
    planes = []
    for root in (clean, dirty):
        assert main(["calibrate", str(root), "--light-plane", "--no-cross-validate", "--no-plots"]) == 0
        planes.append(load_light_plane(root / "light_plane.toml")[0])
    capsys.readouterr()
    ref, moved = planes
    c = ref.centroid[None]
    assert abs(moved.distance(c)[0]) < ref.offset_sigma(c)[0]
    assert np.all(np.abs(ref.axes @ moved.normal) < ref.tilt_sigma_rad())


def test_several_cameras_write_one_file_each(tmp_path):
    from scanrig.cli.calibrate import _write_light_planes
    from scanrig.reconstruct.light_plane_fit import calibrate_light_plane

    rng = np.random.default_rng(9)
    planes, pixels, _ = synth.observation(rng)
    fit = calibrate_light_plane(synth.camera(), planes, pixels, rng)
    (tmp_path / "calibration_report").mkdir()
    summaries = _write_light_planes(tmp_path, [("cam0", fit, []), ("cam2", fit, [])], "red", 3, "scanrig calibrate",
                                    plots=False)
    assert [s.splitlines()[-1] for s in summaries] == [f"wrote {tmp_path / 'light_plane_cam0.toml'}",
                                                       f"wrote {tmp_path / 'light_plane_cam2.toml'}"]
    assert load_light_plane(tmp_path / "light_plane_cam2.toml")[1] == "cam2"
    assert not (tmp_path / "light_plane.toml").exists()
    text = (tmp_path / "calibration_report" / "light_plane_summary.txt").read_text()
    assert text.count("light plane of ") == 2
