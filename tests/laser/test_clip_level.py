"""The clip level of each channel, found from the frame (scanrig.laser.clip_level.channel_clip_levels)."""

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.laser.clip_level import channel_clip_levels
from scanrig.laser.image import CLIP_MARGIN, prepare_image
from scanrig.sim.colour import jpeg_round_trip
from tests.laser.colour_synth import stripe_frames

SHAPE = (240, 320)
#: Scene level and noise of the synthetic frames, DN.
BACKGROUND_DN = 40.0
NOISE_DN = 2.0
#: A webcam whose red channel clips here (its processing maps full scale below 255), DN.
WEBCAM_RED_CLIP = 180


def stripe_frame(peak_dn: float, seed: int, red_clip: int = 255) -> np.ndarray:
    """A red line laser (vertical, Gaussian σ 2 px, ``peak_dn`` above the scene in red, 8 % of it in
    green and blue) on a noisy grey scene, red clipped at ``red_clip``: ``(H, W, 3)`` uint8."""
    rng = np.random.default_rng(seed)
    u = np.arange(SHAPE[1])
    centre = 150.0 + 0.05 * np.arange(SHAPE[0])[:, None]  # slightly tilted: sub-pixel phases
    profile = np.exp(-0.5 * ((u - centre) / 2.0) ** 2)
    gains = np.array([1.0, 0.08, 0.08])
    frame = BACKGROUND_DN + peak_dn * profile[:, :, None] * gains + rng.normal(0.0, NOISE_DN, SHAPE + (3,))
    frame = np.clip(np.rint(frame), 0, 255)
    frame[:, :, 0] = np.minimum(frame[:, :, 0], red_clip)
    return frame.astype(np.uint8)


def test_a_channel_clipped_at_180_is_found_clipped_at_180():
    frame = stripe_frame(peak_dn=600.0, seed=1, red_clip=WEBCAM_RED_CLIP)
    np.testing.assert_array_equal(channel_clip_levels(frame), [WEBCAM_RED_CLIP, 255, 255])


def test_a_frame_that_never_clips_gets_the_dtype_maximum():
    frame = stripe_frame(peak_dn=120.0, seed=2)  # the laser's top, 160 DN, is noisy, not a pile
    np.testing.assert_array_equal(channel_clip_levels(frame), [255, 255, 255])
    deep = frame.astype(np.uint16) * 16
    np.testing.assert_array_equal(channel_clip_levels(deep), [65535, 65535, 65535])


def test_a_large_flat_area_at_the_top_of_the_histogram_is_not_clipping():
    """A noise-free rendered frame: a flat patch at 120 DN, the brightest thing in the frame,
    ends in a step down to the scene (clipping is entered from high values)."""
    frame = np.full(SHAPE, 40, np.uint8)
    frame[60:180, 80:240] = 120
    np.testing.assert_array_equal(channel_clip_levels(frame), [255])


def test_a_flat_area_crossed_by_a_brighter_trace_is_not_clipping():
    """Flat paper at 164 DN (a third of the frame) with a thin bright trace across it: few pixels
    lie above the paper, but they border it from above, which a clipped run never does."""
    frame = np.full(SHAPE, 30, np.uint8)
    frame[:, 100:200] = 164
    frame[:, 149:152] = 200
    frame[:, 150] = 230 + np.arange(SHAPE[0]) % 10  # its peak varies along it (sub-pixel phase)
    np.testing.assert_array_equal(channel_clip_levels(frame), [255])


def test_a_noisy_flat_area_at_the_top_is_not_clipping():
    rng = np.random.default_rng(3)
    frame = np.clip(np.rint(rng.normal(120.0, NOISE_DN, SHAPE)), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(channel_clip_levels(frame), [255])


def test_the_dark_frame_counts_too():
    """A frame whose red plateau is too small to count alone is found clipped with its laser-off
    frame, where a bright area clips at the same level."""
    on = stripe_frame(peak_dn=600.0, seed=4, red_clip=WEBCAM_RED_CLIP)[:, 140:165]
    off = stripe_frame(peak_dn=0.0, seed=5)[:, 140:165]
    # a bright part of the scene, brighter upwards, clipped where it passes the level
    ramp_dn = np.clip(300.0 * (1.0 - np.arange(SHAPE[0]) / 150.0), 0.0, None)[:, None]
    off[:, :, 0] = np.minimum(off[:, :, 0] + ramp_dn, WEBCAM_RED_CLIP)
    assert channel_clip_levels(off)[0] == WEBCAM_RED_CLIP
    np.testing.assert_array_equal(channel_clip_levels(on, off), [WEBCAM_RED_CLIP, 255, 255])


@pytest.mark.parametrize("quality", [95, 80, 60])
def test_a_plateau_that_jpeg_spread_is_found_from_the_lasers_peaks(quality):
    """JPEG scatters the plateau clipped at 180 DN over some 15 values: no value piles up, and only
    the laser's channel, whose lines' peaks top out in one band, finds it again (at the plateau's
    lower quartile, a few DN under the clip)."""
    frame = jpeg_round_trip(stripe_frame(peak_dn=600.0, seed=12, red_clip=WEBCAM_RED_CLIP), quality)
    dark = jpeg_round_trip(stripe_frame(peak_dn=0.0, seed=13), quality)
    assert channel_clip_levels(frame)[0] == 255
    for off in (None, dark):
        levels = channel_clip_levels(frame, off, laser_channel=0)
        assert WEBCAM_RED_CLIP - 8 <= levels[0] <= WEBCAM_RED_CLIP
        np.testing.assert_array_equal(levels[1:], [255, 255])


def test_peaks_clipped_at_full_scale_keep_the_dtype_maximum():
    """Over-exposed red stripes on printed paper, clipped at 255 and stored as JPEG: the lines' maxima
    reach 255, so no band below it is the clip."""
    on, off, _ = stripe_frames(np.random.default_rng(0))
    np.testing.assert_array_equal(channel_clip_levels(on, off, laser_channel=0), [255, 255, 255])


def test_a_frame_without_the_laser_has_no_peaks_to_read():
    """The laser-off frame of printed paper as JPEG: the paper between dots tops many lines at one
    level, but it covers most of the frame, as a laser's plateau never does."""
    _, off, _ = stripe_frames(np.random.default_rng(1))
    np.testing.assert_array_equal(channel_clip_levels(off, laser_channel=0), [255, 255, 255])


def test_the_peaks_are_read_in_8_bit_frames_only():
    """JPEG stores 8 bits: a 16-bit frame's clip piles up on one value, or is its top."""
    frame = jpeg_round_trip(stripe_frame(peak_dn=600.0, seed=14, red_clip=WEBCAM_RED_CLIP), 80)
    assert channel_clip_levels(frame, laser_channel=0)[0] < 255
    assert channel_clip_levels(frame.astype(np.uint16) * 257, laser_channel=0)[0] == 65535


@pytest.mark.parametrize("use_dark", [False, True])
def test_prepare_image_flags_the_plateau_of_a_channel_clipped_below_full_scale(use_dark):
    frame = stripe_frame(peak_dn=600.0, seed=6, red_clip=WEBCAM_RED_CLIP)
    dark = stripe_frame(peak_dn=0.0, seed=7) if use_dark else None
    li = prepare_image(frame, color="red", dark=dark, saturation_level="auto")
    np.testing.assert_allclose(li.colour.clip_level, np.array([WEBCAM_RED_CLIP, 255, 255]) * (1 - CLIP_MARGIN))
    plateau = frame[:, :, 0] == WEBCAM_RED_CLIP
    assert plateau.sum() > 5 * SHAPE[0]
    assert li.saturated is not None and li.saturated[plateau].all()
    # the clipped core reads as the clip level (less the dark's red difference) in the signal
    assert li.signal[plateau].min() >= WEBCAM_RED_CLIP - (BACKGROUND_DN + 6 * NOISE_DN)


def test_a_given_saturation_level_applies_to_every_channel():
    frame = stripe_frame(peak_dn=600.0, seed=8, red_clip=WEBCAM_RED_CLIP)
    li = prepare_image(frame, color="red", saturation_level=250)
    np.testing.assert_allclose(li.colour.clip_level, np.full(3, 250 * (1 - CLIP_MARGIN)))
    assert li.saturated is None  # red never reaches 242.5 DN


def test_by_default_the_clip_level_is_the_dtype_maximum():
    frame = stripe_frame(peak_dn=600.0, seed=9, red_clip=WEBCAM_RED_CLIP)
    li = prepare_image(frame, color="red")
    np.testing.assert_allclose(li.colour.clip_level, np.full(3, 255 * (1 - CLIP_MARGIN)))
    assert li.saturated is None


def test_a_grey_laser_is_clipped_where_any_channel_is():
    frame = stripe_frame(peak_dn=600.0, seed=10, red_clip=WEBCAM_RED_CLIP)
    li = prepare_image(frame, color="grey", saturation_level="auto")
    assert li.saturated is not None and li.saturated[frame[:, :, 0] == WEBCAM_RED_CLIP].all()


def test_an_unknown_saturation_level_word_is_refused():
    frame = stripe_frame(peak_dn=600.0, seed=11)
    with pytest.raises(InputError, match="saturation_level must be a number of DN or 'auto', got 'max'"):
        prepare_image(frame, color="red", saturation_level="max")
