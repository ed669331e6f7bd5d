"""``scanrig calibrate`` on the real Ciclop scanner's images (tests/data/ciclop-laser-stripes): light plane, intrinsics first."""

from __future__ import annotations

from pathlib import Path

import pytest

from scanrig.cli.main import main
from tests.data_paths import real_data

CICLOP = real_data("ciclop-laser-stripes")
#: Hand-held views of the scanner's 11 x 6 chessboard (13 mm squares, Horus's default) calibrated.
VIEWS = 4


def ciclop_session(root: Path) -> Path:
    """A one-camera session: ``VIEWS`` calibration views, the board on the turntable (``pattern.png``)
    as shot 100 with its laser-on image ``light_plane/cam0/100.png``, and a laser-on image
    ``101.png`` whose board is too dark to be found (the upstream notebook finds none in it either)."""
    calibration, light_plane = root / "calibration" / "cam0", root / "light_plane" / "cam0"
    calibration.mkdir(parents=True)
    light_plane.mkdir(parents=True)
    for k in range(VIEWS):
        (calibration / f"{k:03d}.jpg").symlink_to(CICLOP / "camera_calibration" / f"frame{k}.jpg")
    pattern = CICLOP / "laser_on_pattern"
    (calibration / "100.png").symlink_to(pattern / "pattern.png")
    (light_plane / "100.png").symlink_to(pattern / "laser-0-255-255-8-x.png")
    (light_plane / "101.png").symlink_to(pattern / "laser-0-255-255-8.png")
    (root / "target.toml").write_text('kind = "chessboard"\ninner_corners = [11, 6]\nsquare_m = 0.013\n')
    (root / "session.toml").write_text('cameras = ["cam0"]\nlaser_mode = "stripe"\nlaser_color = "red"\n')
    return root


def test_too_few_light_plane_poses_names_the_images_left_out_and_writes_nothing(tmp_path, capsys):
    root = ciclop_session(tmp_path)
    before = sorted(p.name for p in root.iterdir())
    code = main(["calibrate", str(root), "--light-plane", "--no-cross-validate", "--no-plots"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1
    assert "found in 1 usable pose(s); at least 2 are needed" in err[0]
    assert f"{root / 'light_plane' / 'cam0' / '101.png'}: the target was not found, skipped" in err[0]
    # pattern.png, the board's own exposure, is no laser-off frame for the dim laser shot
    assert (f"{root / 'calibration' / 'cam0' / '100.png'}: brighter than its laser-on image 100.png (median 129 "
            f"against 0 DN), another exposure: used for the target's pose only, not subtracted") in err[0]
    assert sorted(p.name for p in root.iterdir()) == before


@pytest.mark.parametrize("color", ["green", "blue"])
def test_a_wrong_laser_colour_is_named_though_it_finds_centres_on_the_board(tmp_path, capsys, color):
    """The red laser's board: green and blue still find a centre on hundreds of scan lines (noise and
    print), but far less light than red."""
    root = ciclop_session(tmp_path)
    before = sorted(p.name for p in root.iterdir())
    assert main(["calibrate", str(root), "--light-plane", "--color", color, "--no-cross-validate", "--no-plots"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"error: {root / 'light_plane' / 'cam0'}: 100.png shows little {color} laser light on "
                             f"the target; the images show a red stripe: use --color red (or laser_color = 'red' in "
                             f"session.toml)")
    assert sorted(p.name for p in root.iterdir()) == before


def test_a_red_laser_asked_for_as_grey_is_named(tmp_path, capsys):
    """No laser colour (grey, the image's luma): the board's print is fitted at full weight (the
    right-hand laser's points scatter 16.7 mm about the maker's plane as grey, 0.06 mm as red), so
    the lines say which colour the stripe is."""
    root = ciclop_session(tmp_path)
    (root / "session.toml").write_text('cameras = ["cam0"]\nlaser_mode = "stripe"\n')
    assert main(["calibrate", str(root), "--light-plane", "--no-cross-validate", "--no-plots"]) == 2
    assert ("; 100.png: the stripe is red, detected as grey on the image's luma: use --color red (or laser_color = "
            "'red' in session.toml)") in capsys.readouterr().err


def test_intrinsics_left_open_by_their_own_folder_say_to_add_views_there(tmp_path, capsys):
    """Three Ciclop views in calibration_intrinsic/cam0/ do not fix the intrinsics: the advice is
    to add views there, not to calibrate them separately (which that folder already is)."""
    for stage, frames in (("calibration_intrinsic", range(3)), ("calibration", range(3, 3 + VIEWS))):
        (tmp_path / stage / "cam0").mkdir(parents=True)
        for k in frames:
            (tmp_path / stage / "cam0" / f"{k:03d}.jpg").symlink_to(CICLOP / "camera_calibration" / f"frame{k}.jpg")
    (tmp_path / "target.toml").write_text('kind = "chessboard"\ninner_corners = [11, 6]\nsquare_m = 0.013\n')
    assert main(["calibrate", str(tmp_path), "--no-cross-validate", "--no-plots"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if "intrinsics not determined" in line]
    assert len(lines) == 1
    assert lines[0].startswith("WARNING: calibration_intrinsic/cam0 (calibrated alone): cam0: intrinsics not determined")
    assert lines[0].endswith("add views to calibration_intrinsic/cam0/ (the board filling the image, tilted differently "
                             "each time); the rig holds them fixed as they are (--refine-intrinsics: only to these sigmas)")
