"""The luma difference of a colour frame and its laser-off frame: its noise correlation along the
lines, and whether the camera's colours leave the laser in it."""

import numpy as np
import pytest

from scanrig.laser.image import prepare_image
from scanrig.laser.luma import MAX_LAG_PX, autocovariance, luma_difference

from .synth import integrated, quantize


def test_autocovariance_recovers_a_moving_average():
    """Noise ``e_i + a e_(i+1)`` has variance ``(1 + a²) s²`` and correlation ``a / (1 + a²)`` at
    lag 1, none beyond; a bright trace in a few lines is left out."""
    rng = np.random.default_rng(5)
    a, s = 0.6, 2.0
    e = rng.normal(0.0, s, (200, 641))
    lines = 50.0 + e[:, :-1] + a * e[:, 1:]
    lines[::10, 300:305] += 400.0  # a trace: far beyond 5 robust σ
    _, _, cov = autocovariance(lines, np.zeros_like(lines))
    rho = cov / cov[0]
    standard_error = 1.0 / np.sqrt(lines.size)  # of a correlation from this many pairs (about)
    assert cov[0] == pytest.approx((1 + a * a) * s * s, rel=0.05)  # the outlier gate clips a few per mille
    assert rho[1] == pytest.approx(a / (1 + a * a), abs=6 * standard_error)
    np.testing.assert_allclose(rho[2 : MAX_LAG_PX + 1], 0.0, atol=6 * standard_error)


def _frames(crosstalk_rgb, seed=3):
    """Grey paper at 120 DN and the same with a vertical red beam (peak 100 DN in red) that adds
    ``crosstalk_rgb`` times its red to each channel; independent noise of 2 DN in each frame."""
    rng = np.random.default_rng(seed)
    h, w = 96, 128
    beam = integrated(np.arange(w, dtype=float)[None, :], 64.3, 1.5) * np.ones((h, 1))
    added = 100.0 * beam[:, :, None] * np.asarray(crosstalk_rgb)
    off = quantize(120.0 + rng.normal(0.0, 2.0, (h, w, 3)))
    on = quantize(120.0 + added + rng.normal(0.0, 2.0, (h, w, 3)))
    return on, off


@pytest.mark.parametrize("crosstalk, carries", [((1.0, 0.07, 0.05), True),  # green and blue see some red
                                                ((1.0, -0.4, -0.3), False)])  # a colour matrix subtracts it
def test_luma_is_used_only_where_the_colours_leave_the_laser_in_it(crosstalk, carries):
    on, off = _frames(crosstalk)
    luma = luma_difference(prepare_image(on, "red", off).colour)
    expected = np.dot([0.299, 0.587, 0.114], crosstalk)  # luma per DN of red the beam adds
    assert luma.laser_share == pytest.approx(expected, abs=0.03)  # rounding of 8-bit luma on a 100-DN beam
    assert luma.carries_laser(0) is carries


def test_noise_of_the_luma_difference_is_that_of_two_frames():
    """Luma of independent channels of σ = 2 DN has σ √(Σ w²) · 2; the difference of two frames
    √2 times that (plus the rounding of both lumas)."""
    on, off = _frames((1.0, 0.07, 0.05))
    luma = luma_difference(prepare_image(on, "red", off).colour)
    expected = np.sqrt(2 * (np.sum(np.square([0.299, 0.587, 0.114])) * 4.0 + 1.0 / 12.0))
    assert float(luma.sigma_at(np.array([10]), np.array([10]))[0]) == pytest.approx(expected, rel=0.1)
    assert abs(luma.correlation(True)[1]) < 0.05  # white noise: no correlation along rows
