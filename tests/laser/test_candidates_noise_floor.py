"""The frame's lowest noise, with which candidate finding rejects early, bounds every looked-up noise."""

import numpy as np
import pytest

from scanrig.laser.image import prepare_image
from scanrig.laser.noise import NoiseModel

from .synth import stripe_image


@pytest.mark.parametrize("with_dark", [False, True])
def test_noise_floor_is_the_lowest_noise_of_the_frame(with_dark):
    rng = np.random.default_rng(31)
    shape = (96, 130)
    # a shaded background (5 to 120 DN): the cells and the per-pixel model vary over the frame
    shading = np.linspace(5.0, 120.0, shape[1])[None, :]
    img = stripe_image(shape, lambda lines: 60.3 + 0.2 * lines, rng, 100.0, 1.5, 0.0, 2.0)
    scene = np.clip(img + shading + rng.normal(0.0, 1.0, shape), 0, 255).round().astype(np.uint8)
    dark = np.clip(shading + rng.normal(0.0, 1.0, shape), 0, 255).round().astype(np.uint8) if with_dark else None
    li = prepare_image(scene, dark=dark)
    assert (li.noise_model is not None) == with_dark
    v, u = np.mgrid[: shape[0], : shape[1]]
    noise = li.noise_at(u.ravel(), v.ravel())
    floor = li.noise_floor()
    assert floor <= noise.min()
    if with_dark:  # the model's σ at level 0; the darkest pixels (5 DN) lie a little above it
        assert noise.min() <= floor * (1 + li.noise_model.slope * 10.0 / floor**2)
    else:  # the cells' own minimum
        assert floor == noise.min()


@pytest.mark.parametrize("channels", [1, 3])
def test_noise_model_sigma_matches_a_plain_loop_up_to_the_edges(channels):
    rng = np.random.default_rng(32)
    shape = (9, 11) if channels == 1 else (9, 11, 3)
    dark = rng.integers(0, 256, size=shape).astype(np.uint8)
    weights = None if channels == 1 else (1.0, 0.25, 0.25)
    model = NoiseModel(dark, weights, offset=0.8, slope=0.05)
    v, u = (a.ravel() for a in np.mgrid[:9, :11])

    def plain(uk, vk):
        level = [float(np.dot(dark[min(max(vk + i, 0), 8), min(max(uk + j, 0), 10)],
                              weights if weights is not None else 1.0))
                 for i in (-1, 0, 1) for j in (-1, 0, 1)]
        return np.sqrt(max(0.8 + 0.05 * np.mean(level), 1.0 / 12.0))

    expected = np.array([plain(uk, vk) for uk, vk in zip(u, v)])
    np.testing.assert_allclose(model.sigma_at(u, v), expected, rtol=1e-6)  # float32
    np.testing.assert_array_equal(model.sigma_at(u.reshape(9, 11), v.reshape(9, 11)).shape, (9, 11))
