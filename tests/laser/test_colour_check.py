"""Frames whose colour is not what the laser colour assumes (scanrig.laser.colour_check)."""

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.laser.colour_check import (
    FEWER_FACTOR,
    LEAST_STRIPE_LINES,
    colour_advice,
    colour_shown,
    dips_more_than_rises,
    equal_channels,
    grey_frames,
    laser_light,
    one_colour,
)
from scanrig.laser.image import prepare_image
from scanrig.laser.spots import detect_spots
from scanrig.laser.stripes import detect_stripe


def _grey_in_colour(seed: int = 0, shape=(100, 70)) -> np.ndarray:
    """A noisy grey frame stored as three equal channels, ``(H, W, 3)`` uint8."""
    plane = np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)
    return np.repeat(plane[:, :, None], 3, axis=2)


def test_three_equal_channels_are_equal():
    assert equal_channels(_grey_in_colour())
    assert equal_channels(_grey_in_colour().astype(np.uint16) * 16)


def test_a_difference_between_the_sampled_rows_is_found():
    """Rows 0, 32 and 64 are compared first; a colour pixel on row 33 is found by the full comparison."""
    image = _grey_in_colour()
    image[33, 5, 2] ^= 1
    assert not equal_channels(image)
    image[33, 5, 2] ^= 1
    image[64, 69, 1] ^= 1  # on a sampled row
    assert not equal_channels(image)


def test_a_two_dimensional_frame_has_no_channels_to_compare():
    assert not equal_channels(_grey_in_colour()[:, :, 0])


def test_grey_frames_take_channel_zero_of_both_frames():
    image, dark = _grey_in_colour(1), _grey_in_colour(2)
    grey, grey_dark = grey_frames(image, dark)
    assert grey.shape == grey_dark.shape == (100, 70) and grey.flags.c_contiguous
    np.testing.assert_array_equal(grey, image[:, :, 0])
    np.testing.assert_array_equal(grey_dark, dark[:, :, 0])
    assert grey_frames(image)[1] is None


def test_grey_frames_leave_colour_frames_as_they_are():
    """A colour laser-off frame keeps the pair in colour: one signal for both."""
    image, dark = _grey_in_colour(1), _grey_in_colour(2)
    dark[50, 3, 0] ^= 1
    assert all(a is b for a, b in zip(grey_frames(image, dark), (image, dark)))
    colour = image.copy()
    colour[0, 0, 2] ^= 1
    assert grey_frames(colour)[0] is colour


def _light(found: dict):
    """``found_with`` from a ``colour -> light`` table, recording the colours asked."""
    asked = []

    def found_with(colour):
        asked.append(colour)
        return found[colour]

    return found_with, asked


def test_the_colour_that_finds_far_more_is_named():
    found_with, asked = _light({"red": 10.0, "green": 5.0, "blue": 10.0 * FEWER_FACTOR + 1})
    assert colour_shown(_grey_in_colour() + np.array([0, 0, 1], np.uint8), "red", found_with, least=1.0) == "blue"
    assert sorted(asked) == ["blue", "green", "red"]


def test_a_colour_that_finds_not_far_more_or_too_little_is_not_named():
    colour = _grey_in_colour() + np.array([0, 0, 1], np.uint8)
    assert colour_shown(colour, "red", _light({"red": 10.0, "green": 0.0, "blue": 10.0 * FEWER_FACTOR})[0], 1.0) is None
    assert colour_shown(colour, "red", _light({"red": 0.0, "green": 0.0, "blue": 19.0})[0], least=20.0) is None
    assert colour_shown(colour, "red", _light({"red": 0.0, "green": 0.0, "blue": 0.0})[0], least=0.0) is None


def test_a_grey_laser_is_compared_with_the_three_colours():
    found_with, _ = _light({"grey": 1.0, "red": 50.0, "green": 0.0, "blue": 0.0})
    assert colour_shown(_grey_in_colour() + np.array([1, 0, 0], np.uint8), "grey", found_with, 1.0) == "red"


def test_a_laser_one_colour_finds_far_more_of_than_each_other_is_that_colour():
    """A laser asked for as grey: grey (luma) finds as much as red, but the colours among themselves
    tell; a white laser (every colour finds it) has none."""
    colour = _grey_in_colour() + np.array([1, 0, 0], np.uint8)
    found_with, asked = _light({"grey": 60.0, "red": 50.0, "green": 0.0, "blue": 50.0 / FEWER_FACTOR - 1})
    assert colour_shown(colour, "grey", found_with, 0.0) is None
    assert one_colour(colour, found_with) == "red"
    assert one_colour(colour, _light({"red": 50.0, "green": 50.0 / FEWER_FACTOR, "blue": 0.0})[0]) is None
    found_with, asked = _light({"red": 50.0, "green": 0.0, "blue": 0.0})
    assert one_colour(_grey_in_colour(), found_with) is None and asked == []


@pytest.mark.parametrize("grey", [lambda f: f, lambda f: f[:, :, 0]], ids=["three equal channels", "2-D"])
def test_grey_frames_show_no_colour_and_are_not_detected_again(grey):
    found_with, asked = _light({"red": 0.0, "green": 0.0, "blue": 100.0})
    assert colour_shown(grey(_grey_in_colour()), "red", found_with, 1.0) is None and asked == []


def test_the_advice_names_the_option_and_the_session_key():
    assert colour_advice("blue") == "use --color blue (or laser_color = 'blue' in session.toml)"


# --- the library detectors' own check (check_laser_colour) ------------------------------------


def _swapped(frame: np.ndarray) -> np.ndarray:
    """RGB stored as BGR: a red laser in the blue channel."""
    return np.ascontiguousarray(frame[:, :, ::-1])


@pytest.fixture(scope="module")
def rendered_stripes():
    """An over-exposed red stripe on printed paper (480 x 640) and its laser-off frame."""
    from tests.laser.colour_synth import stripe_frames

    return stripe_frames(np.random.default_rng(0))[:2]


@pytest.fixture(scope="module")
def rendered_spots():
    """A grid of over-exposed red spots on printed paper (480 x 640) and its laser-off frame."""
    from tests.laser.colour_synth import spot_frames

    return spot_frames(np.random.default_rng(0))[:2]


def test_laser_light_counts_bright_rank_0_candidates_on_enough_lines():
    import pyarrow as pa

    lines = LEAST_STRIPE_LINES
    table = pa.table({"rank": np.r_[np.zeros(lines), np.ones(lines)].astype(np.int32),
                      "peak": np.r_[np.full(lines - 1, 200.0), 50.0, np.full(lines, 300.0)]})
    assert laser_light(table, stripes=True) == 200.0 * (lines - 1) + 50.0
    assert laser_light(table, stripes=True, least_peak=100.0) == 0.0  # bright on one line too few
    assert laser_light(table, stripes=False, least_peak=100.0) == 200.0 * (lines - 1) + 300.0 * lines


@pytest.mark.parametrize("dark", [False, True], ids=["no dark", "dark"])
def test_a_laser_of_another_colour_dips_more_than_it_rises(rendered_stripes, dark):
    """Red minus the others of a red stripe rises; of the stripe in the blue channel it dips (by
    the box sums of every eighth row and column)."""
    on, off = rendered_stripes
    off = off if dark else None
    assert not dips_more_than_rises(prepare_image(on, "red", off), 6.0)
    assert dips_more_than_rises(prepare_image(_swapped(on), "red", None if off is None else _swapped(off)), 6.0)


@pytest.mark.parametrize(("detect", "dark"), [(detect_stripe, False), (detect_stripe, True), (detect_spots, True)],
                         ids=["stripes, no dark", "stripes, dark", "spots, dark"])
def test_the_detectors_name_the_colour_the_frame_shows(rendered_stripes, rendered_spots, detect, dark):
    """Red asked of frames whose red laser is in the blue channel: an error that names the
    argument, what was asked and the channel that shows the laser; the right colour's frames
    give their candidates. (The spots without their laser-off frame are not checked: there red
    minus the others dips at the spots about as much as it rises on the printed dots' edges.)"""
    on, off = rendered_stripes if detect is detect_stripe else rendered_spots
    off = off if dark else None
    assert len(detect(on, color="red", dark=off)) > 0
    swapped = {"image": _swapped(on), "dark": None if off is None else _swapped(off)}
    with pytest.raises(InputError, match=r"^color='red': no red laser in this frame; its blue channel shows one "
                                         r"\(\d+ DN of laser light\): use color='blue' \(red and blue are swapped "
                                         r"where RGB data were stored as BGR\)$"):
        detect(swapped["image"], color="red", dark=swapped["dark"])
    detect(swapped["image"], color="red", dark=swapped["dark"], check_color=False)  # not checked: no error


def test_the_detections_colour_shown_asks_for_are_not_checked(rendered_stripes):
    """colour_shown detects the frame in every other colour (as ``scanrig detect`` does): those
    wrong colours are its question, not an error."""
    on, off = rendered_stripes
    assert colour_shown(on, "red", lambda colour: len(detect_stripe(on, color=colour, dark=off)), 0.0) is None
    with pytest.raises(InputError, match="its red channel shows one"):
        detect_stripe(on, color="blue", dark=off)


def test_grey_frames_are_not_checked(rendered_stripes):
    """A grey frame (its luma) with a colour laser asked: no other colour to compare."""
    import cv2

    on, off = (cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in rendered_stripes)
    assert len(detect_stripe(on, color="green", dark=off)) > 0
