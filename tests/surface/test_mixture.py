"""The local mixture's inlier posterior: formula, clean data, one-sided bias, neighbours, bad input."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings as hypothesis_settings, strategies as st
from scipy.stats import norm

from scanrig.errors import InputError
from scanrig.surface.filter import filter_points
from scanrig.surface.hampel import hampel_weight
from scanrig.surface.mixture import chart_neighbours, inlier_posterior
from scanrig.surface.fit_settings import FitSettings

from .conftest import FAST, SIGMA

R, WINDOW = 4.0, 1.5


def _all_neighbours(n):
    """One chart whose every point has all ``n`` points as neighbours: (1, n, n)."""
    return np.broadcast_to(np.arange(n), (1, n, n)).copy()


def test_posterior_is_the_mixture_formula():
    # 80 inliers near 0, 20 outliers at -5 sigma (inside the window (-6, -4]), 5 at +7 (beyond it)
    s = np.concatenate([np.linspace(-3, 3, 80), np.full(20, -5.0), np.full(5, 7.0)])[None]
    post = inlier_posterior(s, _all_neighbours(s.shape[1]), R, WINDOW)
    f_in = 80 / 105
    density_low = 20 / (105 * (WINDOW - 1) * R)
    inlier = f_in * norm.pdf(s[0])
    expected = np.where(s[0] < 0, inlier / (inlier + density_low), 1.0)  # nothing in (4, 6]
    np.testing.assert_allclose(post[0], expected, rtol=1e-12)


@hypothesis_settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-R, R), min_size=2, max_size=40))
def test_posterior_is_one_without_outliers_beyond_the_band(values):
    s = np.array(values)[None]
    np.testing.assert_array_equal(inlier_posterior(s, _all_neighbours(s.shape[1]), R, WINDOW), 1.0)


def test_one_sided_outliers_lower_only_their_side():
    rng = np.random.default_rng(0)
    s = np.concatenate([rng.normal(0, 1, 300), -rng.uniform(0, 8, 100)])[None]
    post = inlier_posterior(s, _all_neighbours(s.shape[1]), R, WINDOW)[0]
    assert np.all(post[s[0] >= 0] == 1.0)
    assert np.all(post[s[0] < 0] < 1.0)
    # monotone in |s| on the contaminated side
    neg = np.flatnonzero(s[0] < 0)
    order = neg[np.argsort(-s[0, neg])]
    assert np.all(np.diff(post[order]) <= 1e-15)


def test_posterior_weights_remove_most_of_a_one_sided_bias():
    # Residuals at the true surface: Gaussian inliers, 30 % outliers spread evenly over
    # [-8, 0] sigma (edge ghosts). The Hampel weights keep the in-band ones and their weighted
    # mean sinks by ~0.2 sigma (standard error 0.008 at this size); with the posterior the
    # remaining bias comes from the model's approximations (f_in counts the in-band outliers).
    rng = np.random.default_rng(1)
    n = 20000
    uv = rng.uniform(-1, 1, (1, n, 2))
    bad = rng.random(n) < 0.3
    s = np.where(bad, -rng.uniform(0, 8, n), rng.normal(0, 1, n))
    post = inlier_posterior(s[None], chart_neighbours(uv, np.ones((1, n), bool), 100), R, WINDOW)[0]
    w = hampel_weight(s, 1.634, R, 0.915)
    bias_hampel = np.sum(w * s) / np.sum(w)
    bias_mixture = np.sum(w * post * s) / np.sum(w * post)
    assert bias_hampel < -0.15
    assert abs(bias_mixture) < 0.25 * abs(bias_hampel)


def test_neighbours_are_the_nearest_valid_points():
    rng = np.random.default_rng(2)
    uv = rng.uniform(-1, 1, (2, 30, 2))
    valid = np.ones((2, 30), bool)
    valid[1, 5:] = False  # a chart of 5 points padded to 30
    nb = chart_neighbours(uv, valid, 8)
    d = np.linalg.norm(uv[0, :, None] - uv[0, None], axis=-1)
    np.testing.assert_array_equal(np.sort(nb[0], axis=1), np.sort(np.argsort(d, axis=1)[:, :8], axis=1))
    assert np.all(nb[0, :, 0] == np.arange(30))  # each point is its own nearest
    np.testing.assert_array_equal(np.sort(nb[1, :5, :5], axis=1), np.tile(np.arange(5), (5, 1)))
    assert np.all(nb[1, :5, 5:] == -1) and np.all(nb[1, 5:] == -1)
    # padding neighbours and NaN residuals are not counted
    s = np.where(valid, rng.normal(0, 1, (2, 30)), np.nan)
    post = inlier_posterior(s, nb, R, WINDOW)
    assert np.all(post[valid] == 1.0) and np.all(np.isnan(post[~valid]))


def test_fit_with_the_mixture_sinks_less_into_one_sided_ghosts():
    # A plane with a strip where 30 % of the points are ghosts pulled down evenly by 0-8 sigma:
    # the strip's inliers are the measure. Mean error over the strip: a few hundredths of
    # sigma of noise (about 200 points), the ghosts' pull ~0.2 sigma.
    rng = np.random.default_rng(3)
    g = np.linspace(-1, 1, 40)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    truth = 0.3 * x - 0.2 * y
    z = truth + rng.normal(0, SIGMA, x.size)
    strip = np.abs(x) < 0.25
    ghost = strip & (rng.random(x.size) < 0.3)
    z[ghost] = truth[ghost] - rng.uniform(0, 8 * SIGMA, ghost.sum())
    points = np.column_stack([x, y, z])
    bias = {}
    for k in (0, 100):
        settings = dataclasses.replace(FAST, mixture_neighbours=k)
        res = filter_points(points, rng=np.random.default_rng(0), q=0.3, settings=settings)
        d = res.denoised
        err = d[:, 2] - (0.3 * d[:, 0] - 0.2 * d[:, 1])
        bias[k] = np.mean(err[strip & ~ghost]) / SIGMA
    assert bias[0] < -0.1
    assert abs(bias[100]) < 0.6 * abs(bias[0])


@pytest.mark.parametrize("kwargs, message", [
    (dict(mixture_window=1.0), "mixture_window must be > 1, got 1.0"),
    (dict(mixture_neighbours=-1), "start_epochs, warmup_epochs and mixture_neighbours must be >= 0, got 60, 50, -1"),
])
def test_bad_mixture_settings_are_rejected(kwargs, message):
    with pytest.raises(InputError, match=message):
        FitSettings(**kwargs)


def test_bad_posterior_arguments_are_rejected():
    s = np.zeros((1, 3))
    with pytest.raises(InputError, match="window must be > 1, got 0.5"):
        inlier_posterior(s, _all_neighbours(3), R, 0.5)
    with pytest.raises(InputError, match="r must be > 0, got 0.0"):
        inlier_posterior(s, _all_neighbours(3), 0.0, WINDOW)
    with pytest.raises(InputError, match="k \\(neighbours per point\\) must be >= 1, got 0"):
        chart_neighbours(np.zeros((1, 3, 2)), np.ones((1, 3), bool), 0)
