"""Real camera images (not laser images): the detectors run, stay in the frame and stay honest."""

import numpy as np
import pytest

import scanrig
from scanrig.io.session import read_image
from scanrig.laser.overlay import render_overlay
from tests.data_paths import real_data


@pytest.fixture(scope="module")
def image():
    return read_image(real_data("opencv-stereo-9x6") / "left01.jpg")


@pytest.mark.parametrize("detect", [scanrig.detect_spots, scanrig.detect_stripe])
def test_candidates_on_a_real_frame_are_well_formed(image, detect):
    t = detect(image)
    h, w = image.shape[:2]
    u, v, sigma = t["u"].to_numpy(), t["v"].to_numpy(), t["sigma_px"].to_numpy()
    assert len(t) > 0  # the frame has specular highlights and bright texture
    assert np.all((u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5))
    assert np.all(np.isfinite(sigma) & (sigma > 0))
    assert np.all(t["snr"].to_numpy() > 0) and np.all(t["width_px"].to_numpy() > 0)
    ranks = t["rank"].to_numpy()
    assert ranks.min() == 0


def test_overlay_marks_the_detections_on_the_frame(image):
    t = scanrig.detect_spots(image)
    rgb = render_overlay(image, t)
    assert rgb.shape == image.shape[:2] + (3,) and rgb.dtype == np.uint8
    best = t.filter(np.asarray(t["rank"].to_numpy() == 0))
    u, v = int(round(best["u"][0].as_py())), int(round(best["v"][0].as_py()))
    assert tuple(rgb[v, u]) == (0, 255, 0)
