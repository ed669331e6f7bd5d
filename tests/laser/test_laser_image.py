"""Laser signal preparation: colour, dark frame, ROI, noise estimate, bad input."""

import numpy as np
import pytest

from scanrig.errors import InputError, ShapeError
from scanrig.laser import image as image_module
from scanrig.laser.image import prepare_image
from scanrig.laser.noise import QUANTIZATION_SIGMA, estimate_noise

from .synth import quantize, spot_image

# The noise estimate uses ~20 000 high-pass samples; the MAD's relative standard error is about
# 1.17/sqrt(n) < 1 %, and rounding makes the high-pass slightly non-Gaussian (about +2 % at 2 DN).
NOISE_REL_TOL = 0.05


@pytest.mark.parametrize("noise", [1.5, 2.0, 5.0, 20.0])
def test_noise_estimate_matches_injected_noise(noise):
    rng = np.random.default_rng(101)
    img = spot_image((512, 640), [(100.0, 100.0, 180.0, 1.5, 1.5)], rng, noise=noise, dtype=np.uint16,
                     background=200.0)
    expected = np.hypot(noise, QUANTIZATION_SIGMA)
    assert estimate_noise(img) == pytest.approx(expected, rel=NOISE_REL_TOL)


def test_all_dark_frame_has_quantisation_floor():
    assert estimate_noise(np.zeros((64, 64), np.uint8)) == pytest.approx(QUANTIZATION_SIGMA)


def test_red_minus_other_channels_removes_white_light():
    rng = np.random.default_rng(102)
    grey = rng.integers(0, 150, (40, 50))
    rgb = np.stack([grey + 30, grey, grey], axis=-1).astype(np.uint8)
    li = prepare_image(rgb, "red", noise_sigma=1.0)
    np.testing.assert_array_equal(li.signal, np.full((40, 50), 30.0, np.float32))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("with_dark", [False, True])
@pytest.mark.parametrize("strip_rows", [None, 7])
def test_colour_signal_and_laser_plane_are_the_plain_differences(dtype, with_dark, strip_rows, monkeypatch):
    """The same values in one strip of rows or in several, the last one short (26 rows of 7)."""
    if strip_rows is not None:
        monkeypatch.setattr(image_module, "_STRIP_BYTES", strip_rows * 3 * 4 * 34)
    rng = np.random.default_rng(104)
    high = int(0.9 * np.iinfo(dtype).max)  # nothing clipped
    img = rng.integers(0, high, (30, 40, 3)).astype(dtype)
    dark = rng.integers(0, high, (30, 40, 3)).astype(dtype) if with_dark else None
    roi = (3, 2, 37, 28)
    li = prepare_image(img, "green", dark, roi=roi, noise_sigma=1.0)
    inside = np.s_[roi[1]:roi[3], roi[0]:roi[2]]
    on = img[inside].astype(np.float64)
    off = dark[inside].astype(np.float64) if with_dark else np.zeros_like(on)
    expected = (on[..., 1] - off[..., 1]) - 0.5 * (on[..., 0] - off[..., 0] + on[..., 2] - off[..., 2])
    assert li.saturated is None and li.signal.dtype == np.float32
    np.testing.assert_array_equal(li.signal, expected)  # half-integers: exact in float32
    plane = li.colour.laser_plane
    assert plane.dtype == (np.float32 if with_dark else dtype)
    np.testing.assert_array_equal(plane, on[..., 1] - off[..., 1])


def test_dark_frame_is_subtracted_and_roi_offsets_reported():
    rng = np.random.default_rng(103)
    img = rng.integers(20, 200, (60, 80)).astype(np.uint8)
    # a dark level of its own (a scaled copy of the frame would be the frame at another exposure,
    # test_exposure.py)
    dark = rng.integers(0, 20, img.shape).astype(np.uint8)
    li = prepare_image(img, dark=dark, roi=(10, 5, 70, 50), noise_sigma=1.0)
    assert li.origin == (10, 5)
    np.testing.assert_array_equal(li.signal, img[5:50, 10:70].astype(np.float32) - dark[5:50, 10:70])


def test_saturated_pixels_are_flagged_at_the_dtype_maximum():
    img = np.full((32, 32), 10, np.uint16)
    img[10, 12] = 65535
    li = prepare_image(img, noise_sigma=1.0)
    assert li.saturated.sum() == 1 and li.saturated[10, 12]
    assert prepare_image(quantize(img / 300.0), noise_sigma=1.0).saturated is None


@pytest.mark.parametrize("image, message", [
    (np.zeros((10, 10), np.float32), "image must be an 8- or 16-bit image .* got float32"),
    (np.zeros((10, 10), np.int32), "image must be an 8- or 16-bit image .* got int32"),
    (np.zeros((0, 10), np.uint8), r"image is empty or smaller than 3x3 pixels: shape \(0, 10\)"),
    (np.zeros((10, 10, 4), np.uint8), r"image must have shape \(H, W\) or \(H, W, 3\), got \(10, 10, 4\)"),
    ([[1, 2], [3, 4]], "image must be a numpy array, got list"),
])
def test_bad_images_are_rejected_with_the_reason(image, message):
    with pytest.raises(ShapeError, match=message):
        prepare_image(image)


def test_bad_options_are_rejected():
    img = np.zeros((20, 30), np.uint8)
    with pytest.raises(InputError, match="color must be one of .* got 'purple'"):
        prepare_image(img, "purple")
    with pytest.raises(InputError, match=r"roi \(u0, v0, u1, v1\) = \(0, 0, 40, 10\) must lie inside the 30x20 frame"):
        prepare_image(img, roi=(0, 0, 40, 10))
    with pytest.raises(ShapeError, match=r"dark must match image \(\(20, 30\) uint8\), got \(20, 31\) uint8"):
        prepare_image(img, dark=np.zeros((20, 31), np.uint8))
    with pytest.raises(InputError, match="noise_sigma must be a positive number of DN, got -1"):
        prepare_image(img, noise_sigma=-1)
