"""Passive-stereo baseline: a textured plane seen by a side-by-side pair comes back flat."""

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.geometry import Camera
from scanrig.reconstruct.stereo import stereo_pair_points
from tests.reconstruct.synth import look_at

#: SGBM's sub-pixel disparities are good to ~0.25 px; at 1 m with f = 800 px and B = 0.12 m that
#: is 0.25 · Z² / (f B) ≈ 2.6 mm of depth.
DEPTH_SIGMA_M = 2.6e-3
#: SGBM fills the band seen by one camera only (image borders) with wrong matches: a few percent.
MIN_FRACTION_WITHIN_3_SIGMA = 0.9


def _render_plane(cam, texture, half_m=0.6):
    """Image of the textured plane z = 0 (texture over [-half_m, half_m]²) seen by ``cam``."""
    import cv2

    v, u = np.mgrid[0:cam.height, 0:cam.width]
    centers, dirs = cam.rays(np.c_[u.ravel(), v.ravel()].astype(float))
    t = -centers[:, 2] / dirs[:, 2]
    xy = centers[:, :2] + t[:, None] * dirs[:, :2]
    scale = (texture.shape[1] - 1) / (2 * half_m)
    mx = ((xy[:, 0] + half_m) * scale).reshape(cam.height, cam.width).astype(np.float32)
    my = ((xy[:, 1] + half_m) * scale).reshape(cam.height, cam.width).astype(np.float32)
    return cv2.remap(texture, mx, my, cv2.INTER_LINEAR)


def test_textured_plane_is_recovered():
    import cv2

    rng = np.random.default_rng(81)
    texture = cv2.resize(rng.uniform(0, 255, (160, 160)).astype(np.float32), (1600, 1600),
                         interpolation=cv2.INTER_CUBIC)
    texture = np.clip(texture, 0, 255).astype(np.uint8)
    params = [800.0, 800.0, 319.5, 239.5]
    target = np.array([0.0, 0.0, 0.0])
    cam_a = Camera("a", "pinhole", params, 640, 480, look_at(np.array([-0.06, -0.8, 0.6]), target))
    cam_b = Camera("b", "pinhole", params, 640, 480, look_at(np.array([0.06, -0.8, 0.6]), target))
    p = stereo_pair_points(cam_a, cam_b, _render_plane(cam_a, texture), _render_plane(cam_b, texture),
                           depth_range_m=(0.7, 1.4))
    assert len(p) > 0.3 * 640 * 480
    assert np.median(np.abs(p[:, 2])) < DEPTH_SIGMA_M
    assert np.mean(np.abs(p[:, 2]) < 3 * DEPTH_SIGMA_M) > MIN_FRACTION_WITHIN_3_SIGMA
    # the swapped call gives the same cloud
    p_swapped = stereo_pair_points(cam_b, cam_a, _render_plane(cam_b, texture), _render_plane(cam_a, texture),
                                   depth_range_m=(0.7, 1.4))
    assert len(p_swapped) == len(p)


def test_stereo_bad_input():
    params = [800.0, 800.0, 319.5, 239.5]
    cam_a = Camera("a", "pinhole", params, 640, 480, look_at(np.array([-0.06, -0.8, 0.6])))
    cam_b = Camera("b", "pinhole", params, 640, 480, look_at(np.array([0.06, -0.8, 0.6])))
    with pytest.raises(InputError, match="image for camera 'a' is 10x10, the camera is 640x480"):
        stereo_pair_points(cam_a, cam_b, np.zeros((10, 10), np.uint8), np.zeros((480, 640), np.uint8))
    far = Camera("b", "pinhole", params, 640, 480, look_at(np.array([0.9, -0.5, 0.6])))
    img = np.zeros((480, 640), np.uint8)
    with pytest.raises(InputError, match="the baseline is too wide for semi-global matching"):
        stereo_pair_points(cam_a, far, img, img, depth_range_m=(0.3, 3.0))
