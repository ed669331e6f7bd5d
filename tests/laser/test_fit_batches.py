"""The unclipped candidates of both scan directions are fitted in one Levenberg–Marquardt batch
(:func:`scanrig.laser.stripes._fit_lines`): each window's fit, and its direction's covariance, are
those its direction's batch gives alone, to round-off."""

import numpy as np

from scanrig.laser import stripes
from tests.laser.colour_synth import stripe_frames


def test_one_batch_fits_each_window_as_its_direction_alone_would(monkeypatch):
    on, _, _ = stripe_frames(np.random.default_rng(0))
    calls = []
    fit_lines = stripes._fit_lines

    def recorded(windows, max_width_px):
        calls.append((windows, max_width_px))
        return fit_lines(windows, max_width_px)

    monkeypatch.setattr(stripes, "_fit_lines", recorded)
    stripes.detect_stripe(on, color="red")
    ((windows, max_width_px),) = calls
    assert len(windows) == 2 and min(w.cand.line.size for w in windows) > 50  # texture along rows and columns
    for w, together in zip(windows, fit_lines(windows, max_width_px)):
        (alone,) = fit_lines([w], max_width_px)
        assert np.array_equal(together["line"], alone["line"])
        np.testing.assert_allclose(together["centre"], alone["centre"], rtol=0, atol=1e-9)
        np.testing.assert_allclose(together["sigma_px"], alone["sigma_px"], rtol=1e-8)
