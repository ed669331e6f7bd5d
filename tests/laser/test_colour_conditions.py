"""The clipped colour fit where a window leaves a channel almost nothing: few unclipped pixels.

A window whose channel keeps fewer than four unclipped pixels (a wide clipped band, a scene near
the clip level) was suspected to overflow or misbehave in the start values of the colour fit
(:func:`scanrig.laser.colour_fit._start`). Two pixels are fitted exactly by the channel's two
levels whatever the profile, so they say nothing about its amplitude: the start takes none.
"""

import warnings

import numpy as np
import pytest

from scanrig.laser import colour_fit
from scanrig.laser.colour_frames import ColourFrames

#: Pixels of the test windows, and the centre of their beam (px from the window's middle).
_HALF, _CENTRE_PX = 9, 0.3
_X = np.arange(-_HALF, _HALF + 1, dtype=float)


def _beam(rng, x, n_lines=4):
    """Lines ``(n, len(x), 3)`` across a red beam (1.2 px) 3000 DN high at ``_CENTRE_PX`` with 7 % / 5 %
    crosstalk over 30 DN, noise 2 DN, not clipped; ``x`` the pixels, px."""
    profile = np.exp(-0.5 * ((x - _CENTRE_PX) / 1.2) ** 2)
    return 30.0 + 3000.0 * profile[None, :, None] * np.array([1.0, 0.07, 0.05]) + rng.normal(0, 2, (n_lines, x.size, 3))


@pytest.mark.parametrize("n_usable", [0, 1, 2, 3])
def test_start_takes_no_profile_from_a_channel_with_two_usable_pixels_or_fewer(n_usable):
    rng = np.random.default_rng(n_usable)
    y = _beam(rng, _X)
    usable = np.ones(y.shape, bool)
    usable[:, n_usable:, 1] = False  # green keeps the first n_usable pixels: its flank's far tail
    trial = np.exp(-0.5 * (_X[None, :] / colour_fit._START_WIDTHS[:, None]) ** 2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow, invalid value or division by zero
        start = colour_fit._start(y, usable, trial, np.full(3, 2.0), 0)
    width, amp, background = start[:, 0], start[:, 1:4], start[:, 4:]
    assert np.isfinite(start).all()
    np.testing.assert_allclose(width, 1.2, rtol=0.25)  # red and blue still place the profile
    green_mean = y[:, :n_usable, 1].mean(axis=1) if n_usable else np.zeros(len(y))
    if n_usable <= 2:
        np.testing.assert_array_equal(amp[:, 1], 0.0)
        np.testing.assert_allclose(background[:, 1], green_mean)
    else:  # three pixels of the tail: finite, but not forced to 0
        assert np.all(np.abs(amp[:, 1]) > 0.0)


@pytest.mark.parametrize("n_unclipped", [0, 1, 2, 3])
def test_clipped_fit_of_windows_clipped_in_every_channel_but_a_few_pixels_stays_quiet(n_unclipped):
    """Every channel clipped over the window but ``n_unclipped`` pixels of one flank: no
    floating-point warning, and what is returned is finite (here every candidate is dropped: a flank's
    tail does not place the beam within the shift limit)."""
    rng = np.random.default_rng(10 + n_unclipped)
    image = np.clip(_beam(rng, np.arange(40.0) - 20, 6), 0, 255)  # the beam at 20.3
    image[:, 11 + n_unclipped : 30] = 255  # the window of a candidate at 20 is 11-29
    frames = ColourFrames(np.rint(image).astype(np.uint8), None, 0, np.full(3, 247.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = colour_fit.fit_clipped(frames, True, np.arange(6), np.full(6, 20), _HALF, 6.0)
    for key in ("centre", "var", "peak", "width_px"):
        assert np.isfinite(out[key]).all()
