"""Real stereo images put into a session the way a user first might: checked before any detection."""

from __future__ import annotations

from pathlib import Path

import pytest

from scanrig.calibration.session_calibration import check_shared_stems
from scanrig.cli.main import main
from scanrig.errors import FileFormatError
from tests.data_paths import real_data

OPENCV = real_data("opencv-stereo-9x6")


def test_camera_folders_without_a_shared_stem_are_named_before_detecting(tmp_path, capsys):
    """OpenCV's pairs copied under their own names (left01.jpg, right01.jpg): no shot in common."""
    for side in ("left", "right"):
        (tmp_path / "calibration" / side).mkdir(parents=True)
        for img in sorted(OPENCV.glob(f"{side}*.jpg")):
            (tmp_path / "calibration" / side / img.name).symlink_to(img)
    (tmp_path / "target.toml").write_text('kind = "chessboard"\ninner_corners = [9, 6]\nsquare_m = 0.025\n')
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["calibrate", str(tmp_path), "--no-plots"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1
    assert ("camera graph is disconnected: cameras ['right'] share no shot with cameras ['left'], not one image "
            "stem (right01.jpg in right, left01.jpg in left)") in err[0]
    assert "detecting target" not in captured.out + captured.err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_only_the_cameras_sharing_no_stem_are_named():
    paths = {cam: {stem: Path(f"{cam}/{stem}.png") for stem in stems}
             for cam, stems in (("cam0", ["000", "001"]), ("cam1", ["001", "002"]), ("cam2", ["c2_000"]))}
    with pytest.raises(FileFormatError, match=r"cameras \['cam2'\] share no shot with cameras \['cam0', 'cam1'\]"):
        check_shared_stems(Path("calibration"), paths)
    check_shared_stems(Path("calibration"), {"cam0": paths["cam0"], "cam1": paths["cam1"]})
    check_shared_stems(Path("calibration"), {"cam2": paths["cam2"]})
