"""The statistical stop rule, the step-length correction and the held bounds of ``fit_batch``.

With the pixels' noise variance σ² given, a fit stops once what is left to gain is at most
``STOP_CHI2 · σ²``, which leaves every parameter within ``√STOP_CHI2`` of its own standard deviation
of the minimum (the notes of :func:`scanrig.laser.fit.fit_batch`). The tests compare with the same
windows fitted to convergence (relative cost decrease 1e-14, 300 iterations), on small residuals
(the grey stripes) and on large ones (a halo the model lacks, where Gauss–Newton zig-zags); with
``misfit_stop``, on windows the model does not describe (a printed edge beside a weak peak).
"""

import numpy as np
import pytest
from scipy.special import ndtr

from scanrig.laser import stripes
from scanrig.laser.fit import MIN_PEAK_DN, MIN_WIDTH_PX, STOP_CHI2, _misfit_limit, fit_batch, minor_model_1d

from .synth import integrated

HALF = 9
X = np.arange(-HALF, HALF + 1.0)
NOISE = 2.0  # DN
MAX_WIDTH_PX = 3.0
LOWER = np.array([MIN_PEAK_DN, -HALF, MIN_WIDTH_PX, -np.inf])
UPPER = np.array([np.inf, HALF, MAX_WIDTH_PX, np.inf])
#: The stop rule's bound on a parameter's distance from the minimum, in its standard deviations.
BOUND_SIGMAS = np.sqrt(STOP_CHI2)


def _windows(rng, n, halo=0.0):
    """Noisy stripe profiles ``(W, n)`` (peak 40-250 DN over 0-30 DN, width 0.8-2.5 px, centre
    within ±0.5 px) and their backgrounds ``(n,)``; with ``halo``, that share of the light is spread
    3 px wider, which the model lacks."""
    centre, width = rng.uniform(-0.5, 0.5, n), rng.uniform(0.8, 2.5, n)
    peak, background = rng.uniform(40, 250, n), rng.uniform(0, 30, n)
    beam = (1 - halo) * integrated(X[:, None], centre, width) + halo * integrated(X[:, None], centre, np.hypot(width, 3.0))
    return background + peak * beam + rng.normal(0, NOISE, (X.size, n)), background


def _counted(model, counter):
    """``model`` that adds the number of candidates of each evaluation to ``counter``."""
    def wrapped(p):
        counter.append(p.shape[1])
        return model(p)
    return wrapped


def _fits(y, p0, **options):
    """The statistical fit, the fully converged one, and model evaluations per candidate of each."""
    n = y.shape[1]
    mask = np.ones(y.shape, bool)
    model = minor_model_1d(X)
    quick_calls, converged_calls = [], []
    quick = fit_batch(_counted(model, quick_calls), y, mask, p0, LOWER, UPPER, minor=True,
                      noise_var=np.full(n, NOISE**2), **options)
    converged = fit_batch(_counted(model, converged_calls), y, mask, p0, LOWER, UPPER, n_iter=300, tol=1e-14,
                          minor=True)
    return quick, converged, sum(quick_calls) / n, sum(converged_calls) / n


def test_statistical_stop_leaves_every_parameter_within_its_bound_and_saves_evaluations():
    """Small residuals, the start of the stripe detector: each parameter within √STOP_CHI2 of its σ
    of the converged fit, in fewer model evaluations than the relative rule takes."""
    rng = np.random.default_rng(41)
    n = 400
    y, _ = _windows(rng, n)
    p0 = stripes._start(y, np.full(n, 15.0), HALF, MAX_WIDTH_PX, None)
    quick, converged, evaluations, _ = _fits(y, p0)
    sigma = NOISE * np.sqrt(np.diagonal(converged.info_inv, axis1=1, axis2=2))  # (n, 4)
    distance = np.abs(quick.params - converged.params) / sigma
    assert distance.max() <= BOUND_SIGMAS
    relative_calls = []
    fit_batch(_counted(minor_model_1d(X), relative_calls), y, np.ones(y.shape, bool), p0, LOWER, UPPER, minor=True)
    assert evaluations < sum(relative_calls) / n - 1.0  # at least one evaluation fewer per candidate


def test_the_detectors_start_leaves_one_step_to_most_fits():
    """From the stripe detector's start, with the background known (as the frame's background map
    gives it), one step satisfies the stop rule for most windows: 13-19 % take a second (seeds
    41-45), where from the Gaussian through the three central pixels alone 54-59 % did."""
    rng = np.random.default_rng(41)
    n = 400
    y, background = _windows(rng, n)
    calls = []
    fit_batch(_counted(minor_model_1d(X), calls), y, np.ones(y.shape, bool),
              stripes._start(y, background, HALF, MAX_WIDTH_PX, None), LOWER, UPPER, minor=True,
              noise_var=np.full(n, NOISE**2))
    assert calls[0] == n and sum(calls[2:]) <= 0.3 * n


def test_large_residuals_do_not_stop_the_fit_early():
    """A 30 % halo the model lacks: χ²/dof well above 1 and Gauss–Newton's curvature wrong, which
    the rule measures along each step; the centre still ends within its bound of the minimum, in a
    few steps."""
    rng = np.random.default_rng(42)
    n = 300
    y, _ = _windows(rng, n, halo=0.3)
    p0 = stripes._start(y, np.full(n, 15.0), HALF, MAX_WIDTH_PX, None)
    quick, converged, evaluations, _ = _fits(y, p0, n_iter=60)
    assert np.median(converged.chi2_unit / converged.dof) > 2 * NOISE**2  # large residuals, as intended
    sigma_x0 = NOISE * np.sqrt(converged.info_inv[:, 1, 1])
    assert np.all(np.abs(quick.params[:, 1] - converged.params[:, 1]) <= BOUND_SIGMAS * sigma_x0)
    assert evaluations < 6.0


def _statistical(y, p0, **options):
    """The statistical fit of windows ``y`` from ``p0`` and its model evaluations per candidate."""
    calls = []
    res = fit_batch(_counted(minor_model_1d(X), calls), y, np.ones(y.shape, bool), p0, LOWER, UPPER, minor=True,
                    noise_var=np.full(y.shape[1], NOISE**2), **options)
    return res, sum(calls) / y.shape[1]


def test_misfit_stop_shortens_windows_the_model_does_not_describe_and_spares_the_others():
    """A printed edge (60-200 DN, 2-6 px off) beside each peak: χ²/dof in the hundreds, where the
    stop in units of σ² crawls on. In units of the windows' own scatter they take at least one model
    evaluation fewer, and their centres stay within twice the rule's bound (each fit within it of
    the minimum) of the fits stopped in units of σ², in the σ the scatter gives them. Windows the
    model describes are fitted exactly as without ``misfit_stop``."""
    rng = np.random.default_rng(44)
    n = 300
    y, _ = _windows(rng, n)
    y += rng.uniform(60, 200, n) * ndtr((X[:, None] - rng.uniform(2, 6, n) * rng.choice([-1, 1], n)) / 0.7)
    p0 = stripes._start(y, np.full(n, 15.0), HALF, MAX_WIDTH_PX, None)
    plain, plain_evaluations = _statistical(y, p0)
    quick, evaluations = _statistical(y, p0, misfit_stop=stripes.HOPELESS_MISFIT)
    scatter = plain.chi2_unit / plain.dof
    assert np.median(scatter) > 100 * NOISE**2  # the model does not describe them, as intended
    unit = np.maximum(NOISE**2, scatter / (stripes.HOPELESS_MISFIT * _misfit_limit(plain.dof)))
    distance = np.abs(quick.params[:, 1] - plain.params[:, 1]) / np.sqrt(unit * plain.info_inv[:, 1, 1])
    assert np.percentile(distance, 99) <= 2 * BOUND_SIGMAS
    assert evaluations <= plain_evaluations - 1.0
    y, _ = _windows(rng, n)
    p0 = stripes._start(y, np.full(n, 15.0), HALF, MAX_WIDTH_PX, None)
    np.testing.assert_array_equal(_statistical(y, p0, misfit_stop=stripes.HOPELESS_MISFIT)[0].params,
                                  _statistical(y, p0)[0].params)


def test_a_parameter_pushed_against_its_bound_is_held_and_the_others_converge():
    """Profiles wider than the largest width fitted: the width rests on its bound, and the fit
    reaches the bounded minimum (peak, centre and background of the reduced problem)."""
    rng = np.random.default_rng(43)
    n = 100
    centre = rng.uniform(-0.5, 0.5, n)
    y = 10.0 + 150.0 * integrated(X[:, None], centre, 4.5) + rng.normal(0, NOISE, (X.size, n))
    p0 = stripes._start(y, np.full(n, 10.0), HALF, MAX_WIDTH_PX, None)
    quick, converged, _, _ = _fits(y, p0)
    assert np.all(quick.params[:, 2] == MAX_WIDTH_PX)
    # the bounded minimum: the gradient of the free parameters is zero there
    mu, jac = minor_model_1d(X)(quick.params.T)
    gradient = np.einsum("imn,mn->ni", jac, y - mu)  # (n, 4), Jᵀr
    scale = NOISE * np.sqrt(np.einsum("mn,mn->n", jac[1], jac[1]))  # of the centre's
    assert np.all(np.abs(gradient[:, 1]) <= BOUND_SIGMAS * scale)
    assert np.all(gradient[:, 2] >= 0.0)  # the cost would fall beyond the bound: it is held
    np.testing.assert_allclose(quick.params[:, 1], converged.params[:, 1], atol=0.05)


@pytest.mark.parametrize("width", [0.5, 0.8, 1.5, 2.5])
def test_log_parabola_start_is_close_to_the_truth(width):
    """Noise-free profiles: the start's centre within 0.05 px and width within 10 % (the three-point
    Gaussian through the samples of a pixel-integrated profile)."""
    n = 50
    centre = np.linspace(-0.5, 0.5, n)
    y = 12.0 + 180.0 * integrated(X[:, None], centre, width)
    start = stripes._start(y, np.full(n, 12.0), HALF, MAX_WIDTH_PX, None)
    np.testing.assert_allclose(start[:, 1], centre, atol=0.05)
    np.testing.assert_allclose(start[:, 2], width, rtol=0.1)
    np.testing.assert_allclose(start[:, 0], 180.0, rtol=0.1)
