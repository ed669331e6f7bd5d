"""A camera calibrated alone from views that leave its focal length open is refused, not held fixed.

Four real chessboard frames of one caliscope webcam (tests/data/caliscope-4cam-charuco, BSD-2-Clause)
fit fx 213 ± 123 px where the lens's is about 904 px; three Ciclop views (CC BY-SA 4.0) fix it to
±1.6 px of 1430 and still calibrate.
"""

from __future__ import annotations

from pathlib import Path

from scanrig.cli.main import main
from tests.data_paths import real_data

CALISCOPE_FRAMES = [real_data("caliscope-4cam-charuco") / "chessboard_intrinsic" / f"cam_0_frame_{k}.jpg"
                    for k in (100, 200, 300, 1070)]
CICLOP_VIEWS = real_data("ciclop-laser-stripes") / "camera_calibration"


def _session(root: Path, intrinsic: list[Path], rig: list[Path], inner_corners: tuple[int, int]) -> Path:
    """A one-camera session with ``intrinsic`` views in calibration_intrinsic/cam0/ and ``rig`` views in calibration/cam0/."""
    for stage, frames in (("calibration_intrinsic", intrinsic), ("calibration", rig)):
        (root / stage / "cam0").mkdir(parents=True)
        for k, frame in enumerate(frames):
            (root / stage / "cam0" / f"{k:03d}{frame.suffix}").symlink_to(frame)
    (root / "target.toml").write_text(f'kind = "chessboard"\ninner_corners = [{inner_corners[0]}, {inner_corners[1]}]\n'
                                      f'square_m = 0.025\n')
    return root


def test_views_that_leave_the_focal_length_open_are_refused_and_nothing_is_written(tmp_path, capsys):
    root = _session(tmp_path, CALISCOPE_FRAMES, CALISCOPE_FRAMES, (9, 6))
    before = sorted(p.name for p in root.iterdir())
    assert main(["calibrate", str(root), "--no-cross-validate", "--no-plots"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"error: {root / 'calibration_intrinsic' / 'cam0'}: 4 views leave the focal length open (fx ")
    assert err[0].endswith("1 sigma): add views (the board filling the image, tilted differently each time)")
    assert sorted(p.name for p in root.iterdir()) == before


def test_views_that_fix_the_focal_length_calibrate(tmp_path):
    views = sorted(CICLOP_VIEWS.glob("frame*.jpg"))
    root = _session(tmp_path, views[:3], views[3:7], (11, 6))
    assert main(["calibrate", str(root), "--no-cross-validate", "--no-plots"]) == 0
    assert (root / "rig.toml").is_file()
