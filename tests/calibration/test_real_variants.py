"""Calibration on the real chessboard sets (tests/data/opencv-stereo-9x6, mrpt-stereo-9x6) as other
rigs deliver them: down-scaled, re-saved as JPEG, 16-bit, grey or colour; a folder with an image
without the board, or with an unreadable file."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from scanrig.calibration.detect import detect_target
from scanrig.calibration.pipeline import calibrate, detect_session
from scanrig.cli.main import main
from scanrig.io.session import Session, read_image
from scanrig.targets import chessboard, load_target
from tests.data_paths import real_data

OPENCV = real_data("opencv-stereo-9x6")
#: Views of the left camera calibrated (of 13): each detection takes 0.35-0.6 s.
VIEWS = 8
MRPT = real_data("mrpt-stereo-9x6")
TARGET_TOML = 'kind = "chessboard"\ninner_corners = [9, 6]\nsquare_m = 0.025\n'
#: The same board (both sets' 9 x 6 inner corners) for single images.
BOARD = chessboard((9, 6), 0.025)
#: JPEG q80 re-encoding of the views moves fx, fy, cx, cy by at most 0.034 of their sigma
#: (measured: 0.020, 0.022, 0.019, 0.005 px against sigmas 0.53-0.67 px) and the RMS by 0.07 %.
JPEG_SIGMAS = 0.1
JPEG_RMS_REL = 0.01
#: Views rotated 90 degrees give the rotated intrinsics to this, px (measured: 1.3e-9 px).
ROTATED_PX = 1e-6


def left_session(root: Path, change=None, suffix: str = ".png", quality: int | None = None,
                 views: int = VIEWS) -> Path:
    """``root``, a session of ``target.toml`` and ``calibration/left/NN<suffix>``: the first ``views``
    left views of opencv-stereo-9x6 (640 x 480 grey JPEG), as symlinks, or through ``change`` (an
    array function) written as ``suffix`` at JPEG ``quality``."""
    folder = root / "calibration" / "left"
    folder.mkdir(parents=True)
    for src in sorted(OPENCV.glob("left*.jpg"))[:views]:
        name = src.stem.removeprefix("left")
        if change is None:
            (folder / src.name.removeprefix("left")).symlink_to(src)
        else:
            params = [] if quality is None else [cv2.IMWRITE_JPEG_QUALITY, quality]
            assert cv2.imwrite(str(folder / f"{name}{suffix}"), change(read_image(src)), params)
    (root / "target.toml").write_text(TARGET_TOML)
    return root


def solve(root: Path):
    """Detect and calibrate (opencv5, no cross-validation): ``(fx, fy, cx, cy)``, their sigmas, the
    RMS in px and the images without the board."""
    target = load_target(root / "target.toml")
    obs, not_found = detect_session(Session(root), target)
    result = calibrate(obs, target, "opencv5", cross_validate=False)
    return (result.rig["left"].params[:4], np.asarray(result.uncertainty.params_std["left"][:4]),
            result.bundle.rms_px(), not_found)


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    """The first ``VIEWS`` left views as shipped: fx fy cx cy = 534.018 534.195 341.984 235.145 px,
    sigmas 0.577 0.669 0.561 0.530 px, RMS 0.1612 px (all 13 views: 533.553 533.681 342.158 234.182,
    sigmas 0.36-0.42 px)."""
    return solve(left_session(tmp_path_factory.mktemp("left")))


def test_the_baseline_finds_every_board(baseline):
    assert baseline[3] == [] and baseline[2] < 0.2


def test_half_scale_halves_the_intrinsics(tmp_path, baseline):
    """Down-scaled 0.5 (INTER_AREA): fx, fy halve and the principal point maps as pixel centres do
    (``c -> (c + 0.5) / 2 - 0.5``, docs/conventions.md), each within 1 sigma of the two solves
    combined. Measured: 0.051, 0.066, 0.001, 0.022 px on fx, fy, cx, cy against 0.41, 0.47, 0.40,
    0.37 px; RMS 0.0804 px (half of 0.1612: 0.0806)."""
    half, sigma_half, rms_half, not_found = solve(left_session(
        tmp_path, lambda a: cv2.resize(a, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)))
    full, sigma_full, rms_full, _ = baseline
    assert not_found == []
    expected = np.r_[full[:2] / 2, (full[2:] + 0.5) / 2 - 0.5]
    assert np.all(np.abs(half - expected) <= np.hypot(sigma_half, sigma_full / 2))
    assert rms_half == pytest.approx(rms_full / 2, rel=0.02)


def test_jpeg_q80_keeps_the_intrinsics(tmp_path, baseline):
    params, _, rms, not_found = solve(left_session(tmp_path, lambda a: a, ".jpg", 80))
    full, sigma, rms_full, _ = baseline
    assert not_found == []
    assert np.all(np.abs(params - full) <= JPEG_SIGMAS * sigma)
    assert rms == pytest.approx(rms_full, rel=JPEG_RMS_REL)


@pytest.mark.parametrize("name", ["left01.jpg", "left07.jpg", "left14.jpg"])
def test_16_bit_and_colour_copies_of_grey_views_give_the_same_corners(name):
    """The grey views as 16-bit (x 257) and as three equal channels: the very same corners."""
    grey = read_image(OPENCV / name)
    expected = detect_target(grey, BOARD)
    assert len(expected.uv) == 54
    for copy in (grey.astype(np.uint16) * 257, cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)):
        found = detect_target(copy, BOARD)
        np.testing.assert_array_equal(found.point_ids, expected.point_ids)
        np.testing.assert_array_equal(found.uv, expected.uv)


#: The MRPT colour views made 16-bit (x 257) move corners by at most 0.0033 px (measured, 8 views):
#: their grey is scaled by the image's own maximum, not by 257.
MRPT_16_BIT_PX = 0.005


@pytest.mark.parametrize("name", ["0_left.jpg", "1_right.jpg"])
def test_colour_views_as_grey_and_16_bit(name):
    """MRPT's colour views (1024 x 768): made grey by cv2.cvtColor, the very same corners; 16-bit,
    within ``MRPT_16_BIT_PX``."""
    colour = read_image(MRPT / name)
    expected = detect_target(colour, BOARD)
    assert len(expected.uv) == 54
    np.testing.assert_array_equal(detect_target(cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY), BOARD).uv, expected.uv)
    np.testing.assert_allclose(detect_target(colour.astype(np.uint16) * 257, BOARD).uv, expected.uv,
                               rtol=0, atol=MRPT_16_BIT_PX)


def test_a_view_without_the_board_is_named_and_skipped(tmp_path):
    """A real 640 x 480 view without a chessboard (the Ciclop bust, laser off, made grey) among 6
    views: the calibration is written from the 6, and the summary names the view."""
    folder = left_session(tmp_path, views=6) / "calibration" / "left"
    bust = read_image(real_data("ciclop-laser-stripes") / "laser_on_object" / "laser_background.png")
    assert cv2.imwrite(str(folder / "15.jpg"), cv2.cvtColor(bust, cv2.COLOR_RGB2GRAY)[300:780, 100:740])
    assert main(["calibrate", str(tmp_path), "--no-plots", "--no-cross-validate"]) == 0
    summary = (tmp_path / "calibration_report" / "summary.txt").read_text()
    assert "target not found in 1 image(s): left/15" in summary
    assert "324 points in 6 views" in summary


def _truncated(path: Path) -> None:
    data = (OPENCV / "left05.jpg").read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _text(path: Path) -> None:
    path.write_text("not an image\n")


def _empty(path: Path) -> None:
    path.write_bytes(b"")


@pytest.mark.parametrize("corrupt, reason", [(_truncated, "cannot decode image"), (_text, "cannot decode image"),
                                             (_empty, "image file is empty")], ids=["truncated", "text", "empty"])
def test_an_unreadable_view_is_a_one_line_error_naming_it(tmp_path, capsys, corrupt, reason):
    """One unreadable file among the views: exit 2, one ``error:`` line naming the file, nothing written."""
    folder = left_session(tmp_path, views=2) / "calibration" / "left"
    corrupt(folder / "15.jpg")
    assert main(["calibrate", str(tmp_path), "--no-plots", "--no-cross-validate"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith(f"error: {folder / '15.jpg'}: {reason}")
    assert not (tmp_path / "rig.toml").exists()


@pytest.mark.parametrize("suffix", [".bmp", ".pgm", ".tif"])
def test_views_in_other_lossless_formats_give_the_same_calibration(tmp_path, baseline, suffix):
    """The views as BMP, PGM or TIFF (as machine-vision cameras' tools save them): the very pixels of
    the shipped JPEGs, so the very calibration."""
    params, sigma, rms, not_found = solve(left_session(tmp_path, lambda a: a, suffix))
    assert not_found == []
    np.testing.assert_array_equal(params, baseline[0])
    np.testing.assert_array_equal(sigma, baseline[1])


def test_views_in_a_format_it_does_not_read_are_named(tmp_path, capsys):
    """A camera raw file among the views: one error line naming it and the formats read, exit 2;
    not a view silently left out."""
    root = left_session(tmp_path, views=2)
    raw = root / "calibration" / "left" / "03.nef"
    raw.write_bytes(b"MM\x00* a camera raw file")
    assert main(["calibrate", str(root), "--no-plots", "--no-cross-validate"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith(f"error: {raw}: ")
    assert ".png" in errors[0] and not (root / "rig.toml").exists()


def test_light_plane_views_in_a_format_it_does_not_read_are_named(tmp_path, capsys):
    """A camera raw light-plane view: named, exit 2; not a folder said to hold no light-plane images."""
    root = left_session(tmp_path, views=2)
    (root / "light_plane" / "left").mkdir(parents=True)
    raw = root / "light_plane" / "left" / "01.dng"
    raw.write_bytes(b"II*\x00 a camera raw file")
    assert main(["calibrate", str(root), "--no-plots", "--no-cross-validate", "--light-plane", "--color", "red"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith(f"error: {raw}: ") and ".png" in errors[0]


def test_rotated_views_rotate_the_intrinsics(tmp_path, baseline):
    """Views rotated 90 degrees clockwise (as the Ciclop stores its webcam's frames): fx and fy swap,
    ``cx' = (H - 1) - cy`` and ``cy' = cx`` (pixel centres), sigmas likewise, the same RMS: the
    detection and the solve are the same up to the rotation (sigmas and RMS to 2e-11)."""
    params, sigma, rms, not_found = solve(left_session(tmp_path, lambda a: np.ascontiguousarray(np.rot90(a, -1))))
    (fx, fy, cx, cy), (sfx, sfy, scx, scy), rms_full, _ = baseline
    assert not_found == []
    np.testing.assert_allclose(params, [fy, fx, 479 - cy, cx], rtol=0, atol=ROTATED_PX)
    np.testing.assert_allclose(sigma, [sfy, sfx, scy, scx], rtol=1e-6)
    assert rms == pytest.approx(rms_full, rel=1e-6)
