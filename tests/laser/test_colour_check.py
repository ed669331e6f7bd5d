"""Frames whose colour is not what the laser colour assumes (scanrig.laser.colour_check)."""

import numpy as np
import pytest

from scanrig.laser.colour_check import FEWER_FACTOR, colour_advice, colour_shown, equal_channels, grey_frames


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


@pytest.mark.parametrize("grey", [lambda f: f, lambda f: f[:, :, 0]], ids=["three equal channels", "2-D"])
def test_grey_frames_show_no_colour_and_are_not_detected_again(grey):
    found_with, asked = _light({"red": 0.0, "green": 0.0, "blue": 100.0})
    assert colour_shown(grey(_grey_in_colour()), "red", found_with, 1.0) is None and asked == []


def test_the_advice_names_the_option_and_the_session_key():
    assert colour_advice("blue") == "use --color blue (or laser_color = 'blue' in session.toml)"
