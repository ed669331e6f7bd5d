"""A laser-off frame taken at another exposure than its laser-on frame (:mod:`scanrig.laser.exposure`)."""

from __future__ import annotations

import re
import warnings

import cv2
import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.io.session import read_image, write_image
from scanrig.laser.exposure import GAIN_TOLERANCE, exposure_gains, exposure_matched, mismatched, row_gains
from scanrig.laser.session_detect import exposure_mismatches
from scanrig.laser.stripes import detect_stripe
from tests.data_paths import real_data
from tests.laser.colour_synth import exposed, stripe_frames

#: Rows this far from the frame's top and bottom are left out of the shares (as in the benchmark).
EDGE_ROWS = 8
#: The rendered frames' gains are found to 0.27 % (seed 0, gains 0.7-1.5 on the laser-off frame).
GAIN_RTOL = 0.005
#: A share may lose this much to the exposure mismatch: two rows in 464 on each of the three
#: seeds (measured: at most one; before the laser-off frame was matched, 0.058 at x 0.8).
SHARE_MARGIN = 0.005


@pytest.fixture(scope="module")
def rendered():
    """Three rendered red stripes on printed paper: ``[(on, off, true centre per row)]``."""
    return [stripe_frames(np.random.default_rng(seed)) for seed in range(3)]


def test_each_channels_gain_is_found(rendered):
    """A white-balance change: each channel of the laser-off frame at its own exposure."""
    on, off, _ = rendered[0]
    gains = np.array([0.8, 0.9, 1.25])
    np.testing.assert_allclose(exposure_gains(on, exposed(off, gains)), 1.0 / gains, rtol=GAIN_RTOL)


def test_frames_at_one_exposure_are_left_as_they_are(rendered):
    on, off, _ = rendered[0]
    assert not mismatched(exposure_gains(on, off)).any()
    assert exposure_matched(on, off) is off


def test_the_matched_frame_keeps_its_clipped_pixels_and_dtype():
    rng = np.random.default_rng(0)
    on = rng.integers(8000, 40000, (256, 256)).astype(np.uint16)
    off = np.rint(on * 1.25).astype(np.uint16)
    off[:8] = 65535
    matched = exposure_matched(on, off)
    assert matched.dtype == np.uint16 and matched is not off
    assert np.all(matched[:8] == 65535)
    np.testing.assert_allclose(matched[8:], on[8:], atol=2.0)
    assert off[8:].max() > on.max()  # the input is not written


def test_a_frame_without_usable_pixels_takes_no_gain():
    """A black laser-off frame (or one whose every pixel is clipped) says nothing about exposure."""
    on = np.full((64, 64, 3), 120, np.uint8)
    for off in (np.zeros_like(on), np.full_like(on, 255)):
        np.testing.assert_array_equal(exposure_gains(on, off), 1.0)
        assert exposure_matched(on, off) is off


@pytest.mark.parametrize("gain", [0.8, 1.25])
def test_a_laser_off_frame_at_another_exposure_finds_the_stripe(rendered, gain):
    """Rank 0 within 0.5 px of the truth on as many rows as with the laser-off frame taken at the
    laser-on frame's exposure (0.9935, 0.9957, 0.9828 on seeds 0-2; before the laser-off frame was
    matched 0.961, 0.946, 0.920 at x 0.8 and 0.987, 0.953, 0.942 at x 1.25)."""

    def share(dark_gain):
        return share_within_half_a_pixel([(on, exposed(off, dark_gain), truth) for on, off, truth in rendered])

    assert share(gain) >= share(1.0) - SHARE_MARGIN


def share_within_half_a_pixel(frames) -> float:
    """Share of the rows (but ``EDGE_ROWS`` at either end) whose rank-0 centre lies within 0.5 px of
    the truth, over ``frames``: ``[(laser-on frame, laser-off frame, true centre per row)]``."""
    within = []
    for on, off, truth in frames:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            table = detect_stripe(on, color="red", dark=off)
        u, v, line, rank = (table[k].to_numpy() for k in ("u", "v", "line", "rank"))
        best = (rank == 0) & (v == line)
        centre = np.full(on.shape[0], np.nan)
        centre[line[best]] = u[best]
        within.append(np.abs(centre - truth)[EDGE_ROWS:-EDGE_ROWS] < 0.5)
    return np.mean(np.concatenate(within))


def _session(root, on, dark):
    """A one-camera session: ``scan/cam0/f0.png`` and its laser-off frame ``scan/cam0/dark.png``."""
    folder = root / "scan" / "cam0"
    folder.mkdir(parents=True)
    write_image(folder / "f0.png", on)
    write_image(folder / "dark.png", dark)
    return folder


def test_detect_names_a_camera_whose_laser_off_frame_is_at_another_exposure(tmp_path, rendered, capsys):
    on, off, _ = rendered[0]
    folder = _session(tmp_path, on, exposed(off, (0.8, 0.8, 1.0)))
    assert main(["detect", str(tmp_path), "--mode", "stripe", "--color", "red"]) == 0
    warnings_shown = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert warnings_shown == [
        f"warning: cam0: the laser-off frame {folder / 'dark.png'} is 0.80 times as bright as {folder / 'f0.png'} "
        "(red 0.80, green 0.80, blue 1.00): scaled to the frame's before it is subtracted; automatic exposure or "
        "white balance is on, set both by hand to take the two frames alike"]


def test_detect_names_a_camera_whose_frames_show_flicker_bands(tmp_path, rendered, capsys):
    """±20 % bands: the laser-off frame is 1/1.2 to 1/0.8 times as bright from row to row."""
    on, off, _ = rendered[0]
    folder = _session(tmp_path, on, exposed(off, flicker(on.shape[0])))
    assert main(["detect", str(tmp_path), "--mode", "stripe", "--color", "red"]) == 0
    shown = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert len(shown) == 1  # bands alone: not named as an exposure change as well
    match = re.fullmatch(
        rf"warning: cam0: the laser-off frame {re.escape(str(folder / 'dark.png'))} is (\S+) to (\S+) times as bright "
        rf"as {re.escape(str(folder / 'f0.png'))} from row to row \(flicker bands of a rolling shutter under "
        r"mains-powered light\): scaled row by row before it is subtracted; light the scene with a steady lamp, or "
        r"set the exposure time to whole periods of the flicker \(10 ms under 50 Hz mains, 8.3 ms under 60 Hz\)",
        shown[0])
    assert match is not None, shown[0]
    low, high = (float(x) for x in match.groups())
    assert low == pytest.approx(0.8, abs=0.02) and high == pytest.approx(1.2, abs=0.02)


def test_a_laser_off_frame_at_the_frames_exposure_is_not_named(tmp_path, rendered):
    on, off, _ = rendered[0]
    _session(tmp_path, on, off)
    assert exposure_mismatches(tmp_path) == []


def flicker(rows: int, amplitude: float = 0.2, period_rows: float = 300.0) -> np.ndarray:
    """A rolling shutter's flicker bands: each row's gain ``1 + amplitude sin(2π row / period)``,
    ``(rows, 1, 1)`` (for :func:`exposed`)."""
    return (1.0 + amplitude * np.sin(2.0 * np.pi * np.arange(rows) / period_rows + 0.7))[:, None, None]


@pytest.mark.parametrize("which", ["laser-off", "laser-on"])
def test_row_gains_follow_flicker_bands(rendered, which):
    """±20 % bands over 300 rows on one frame of the pair: each row's gain found within the
    tolerance of the whole-frame match at the 90th percentile (measured 0.44 % and 0.48 %; 1.6 % and
    1.9 % at most, at the frame's top, beyond the first band's centre)."""
    on, off, _ = rendered[0]
    bands = flicker(on.shape[0])
    if which == "laser-off":
        on_frame, off_frame, truth = on, exposed(off, bands), 1.0 / bands[:, 0, 0]
    else:
        on_frame, off_frame, truth = exposed(on, bands), off, bands[:, 0, 0]
    found = row_gains(on_frame, off_frame)
    assert found is not None and found.shape == (on.shape[0], 3)
    assert np.percentile(np.abs(found / truth[:, None] - 1.0), 90) <= GAIN_TOLERANCE


def test_row_gains_of_a_grey_frame_follow_flicker_bands(rendered):
    """A grey camera has no other channel to tell the laser's light from the lamp's: its bands
    alone, the running median keeping the stripe out (measured: 0.47-0.51 % at the 90th percentile
    on seeds 0-2)."""
    on, off = (cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in rendered[0][:2])
    assert row_gains(on, off) is None
    bands = flicker(on.shape[0])[:, :, 0]
    found = row_gains(on, exposed(off, bands))
    assert found is not None and found.shape == (on.shape[0], 1)
    assert np.percentile(np.abs(found * bands - 1.0), 90) <= GAIN_TOLERANCE


def test_a_frame_matched_row_by_row_keeps_its_clipped_pixels_and_dtype():
    rng = np.random.default_rng(1)
    on = rng.integers(8000, 40000, (480, 320)).astype(np.uint16)
    bands = flicker(on.shape[0])[:, :, 0]
    off = np.rint(on / bands).astype(np.uint16)
    off[:, :4] = 65535
    matched = exposure_matched(on, off)
    assert matched.dtype == np.uint16 and np.all(matched[:, :4] == 65535)
    assert np.percentile(np.abs(matched[:, 4:] / on[:, 4:] - 1.0), 90) <= GAIN_TOLERANCE


def test_frames_without_flicker_take_no_row_gains(rendered):
    """Frames at one exposure, at two exposures, or with the stripe across the rows (a horizontal
    laser line lights most of a band) show no bands."""
    for on, off, _ in rendered:
        for dark in (off, exposed(off, 0.8)):
            assert row_gains(on, dark) is None
        across = [np.ascontiguousarray(f.transpose(1, 0, 2)) for f in (on, off)]
        assert row_gains(*across) is None


def test_real_frames_take_no_row_gains():
    """The Ciclop webcam's pairs (the bust, the board's two patterns) show no bands of their own."""
    folder = real_data("ciclop-laser-stripes")
    pairs = [("laser_on_object/laser.png", "laser_on_object/laser_background.png"),
             ("laser_on_pattern/laser-0-255-255-8.png", "laser_on_pattern/laser-background-0-255-255-8.png"),
             ("laser_on_pattern/laser-0-255-255-8-x.png", "laser_on_pattern/laser-background-0-255-255-8-x.png")]
    for on_name, off_name in pairs:
        on, off = read_image(folder / on_name), read_image(folder / off_name)
        assert row_gains(on, off) is None, on_name


#: A share may lose this much to flicker bands on the laser-on frame: they scale the laser's light
#: too, and with it what clips (measured 0.0072; the whole laser-on frame at x 0.8 or x 1.25, matched,
#: loses 0.008-0.019 in the benchmark).
BANDS_ON_LASER_MARGIN = 0.01


@pytest.mark.parametrize("which", ["laser-off", "laser-on"])
def test_flicker_bands_on_one_frame_keep_the_stripe(rendered, which):
    """Rank 0 within 0.5 px of the truth on as many rows as without the bands (±20 % over 300
    rows, seeds 0-2: measured 0.9914 on the laser-off frame and 0.9835 on the laser-on frame,
    0.9907 without bands; before the laser-off frame was matched row by row 0.9677 and 0.9497)."""

    def banded(on, off, truth):
        bands = flicker(on.shape[0])
        return (on, exposed(off, bands), truth) if which == "laser-off" else (exposed(on, bands), off, truth)

    with_bands = share_within_half_a_pixel([banded(*frames) for frames in rendered])
    assert with_bands >= share_within_half_a_pixel(rendered) - (SHARE_MARGIN if which == "laser-off"
                                                               else BANDS_ON_LASER_MARGIN)
