"""16-bit frames of 10-, 12- and 14-bit cameras: clipped at the top of their data
(scanrig.laser.clip_level.channel_clip_levels)."""

import warnings

import numpy as np
import pytest

from scanrig.laser.clip_level import channel_clip_levels
from scanrig.laser.image import prepare_image


def sensor_frame(top: int, seed: int = 3) -> np.ndarray:
    """A 16-bit colour frame of a camera whose data end at ``top`` DN: a scene at 30 % of it with
    noise, and a small red spot (3 x 3 pixels, too few for a pile of clipped values) at ``top``."""
    rng = np.random.default_rng(seed)
    frame = np.clip(np.rint(rng.normal(0.3 * top, 0.01 * top, (60, 80, 3))), 0, top).astype(np.uint16)
    frame[20:23, 40:43, 0] = top
    return frame


@pytest.mark.parametrize("bits", [10, 12, 14])
def test_a_frame_that_reaches_the_top_of_its_bit_depth_is_clipped_there(bits):
    top = 2**bits - 1
    np.testing.assert_array_equal(channel_clip_levels(sensor_frame(top)), [top] * 3)
    li = prepare_image(sensor_frame(top), color="red", saturation_level="auto")
    assert li.saturated is not None and np.array_equal(np.argwhere(li.saturated)[[0, -1]], [[20, 40], [22, 42]])


def test_a_frame_below_the_top_keeps_the_dtype_maximum():
    """Values up to 4094 or 4096: not a 12-bit camera's top, so nothing says where it clips."""
    for top in (4094, 4096):
        np.testing.assert_array_equal(channel_clip_levels(sensor_frame(top)), [65535] * 3)


def test_the_dark_frame_counts_for_the_top():
    """The frame stays below 4095; its laser-off frame reaches it (a glint): 12-bit data."""
    frame = sensor_frame(4095)
    frame[20:23, 40:43, 0] = 4000
    dark = sensor_frame(4095, seed=4)
    np.testing.assert_array_equal(channel_clip_levels(frame), [65535] * 3)
    np.testing.assert_array_equal(channel_clip_levels(frame, dark), [4095] * 3)


def test_8_bit_frames_are_unchanged():
    frame = sensor_frame(255)
    assert frame.max() == 255
    np.testing.assert_array_equal(channel_clip_levels(frame.astype(np.uint8)), [255] * 3)


def test_a_flat_channel_is_not_clipped():
    """A channel at one value everywhere (a colour frame's unused channels, rendered): a pile
    without a rim, not a clip level (and no warning about the median of no pixels)."""
    frame = sensor_frame(255).astype(np.uint8)
    frame[:, :, 1:] = 40
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(channel_clip_levels(frame), [255] * 3)
