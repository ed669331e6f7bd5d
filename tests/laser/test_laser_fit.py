"""Pixel-integrated Gaussian model, its Jacobian, the batch fit and the Cramér–Rao bound."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanrig.laser.crb import crb_spot, crb_stripe, effective_noise
from scanrig.laser.fit import (
    fit_batch,
    integrated_profile,
    model_1d,
    model_2d,
    parameter_covariance,
)

from .synth import integrated, profiles

# Central differences with step 1e-6 on O(1..100) functions: truncation ~1e-12, rounding ~1e-8.
FD_STEP = 1e-6
FD_TOL = 1e-6


@settings(max_examples=50, deadline=None)
@given(x0=st.floats(-3, 3), s=st.floats(0.3, 4.0))
def test_integrated_profile_sums_to_gaussian_area(x0, s):
    # the pixel integrals telescope to the whole integral √(2π)·s when the window holds the profile
    x = np.arange(-40, 41, dtype=float)
    g, _, _ = integrated_profile(x, np.array([[x0]]), np.array([[s]]))
    assert g.sum() == pytest.approx(np.sqrt(2 * np.pi) * s, rel=1e-12)


@pytest.mark.parametrize("model, p", [
    (lambda p: model_1d(np.arange(-6.0, 7.0), p), np.array([[150.0, 0.31, 1.7, 12.0], [40.0, -0.8, 0.6, 3.0]])),
    (lambda p: model_2d(np.arange(-5.0, 6.0), np.arange(-4.0, 5.0), p),
     np.array([[150.0, 0.31, -0.2, 1.7, 1.1, 12.0], [40.0, -0.8, 0.45, 0.6, 2.2, 3.0]])),
])
def test_jacobian_matches_finite_differences(model, p):
    _, jac = model(p)
    for k in range(p.shape[1]):
        dp = np.zeros_like(p)
        dp[:, k] = FD_STEP
        numeric = (model(p + dp)[0] - model(p - dp)[0]) / (2 * FD_STEP)
        np.testing.assert_allclose(jac[:, :, k], numeric, atol=FD_TOL * np.abs(p[:, :1]).max())


def test_fit_recovers_noise_free_parameters_exactly():
    x = np.arange(-8.0, 9.0)
    truth = np.array([[180.0, 0.37, 1.3, 10.0], [90.0, -0.45, 2.4, 3.0], [200.0, 0.0, 0.8, 0.0]])
    y, _ = model_1d(x, truth)
    p0 = truth * np.array([0.8, 0.0, 1.3, 1.1])
    res = fit_batch(lambda p: model_1d(x, p), y, np.ones(y.shape, bool), p0,
                    np.array([1e-3, -8, 0.3, -np.inf]), np.array([np.inf, 8, 4, np.inf]))
    np.testing.assert_allclose(res.params, truth, atol=1e-6)


def test_jacobian_and_residuals_at_the_solution_match_the_model_there():
    """The result's Jacobian and residuals, evaluated when asked for, are the model's at the fitted
    parameters (zero on masked pixels), and those of a subset are its columns."""
    rng = np.random.default_rng(7)
    x = np.arange(-6.0, 7.0)
    n = 40
    truth = np.column_stack([rng.uniform(50, 200, n), rng.uniform(-0.5, 0.5, n), rng.uniform(0.8, 2.0, n),
                             rng.uniform(0, 20, n)])
    y = model_1d(x, truth)[0] + rng.normal(0, 2.0, (n, x.size))
    mask = rng.random(y.shape) > 0.1
    res = fit_batch(lambda p: model_1d(x, p), y, mask, truth, np.array([1e-3, -6, 0.3, -np.inf]),
                    np.array([np.inf, 6, 4, np.inf]))
    mu, jac = model_1d(x, res.params)
    np.testing.assert_allclose(res.residuals, np.where(mask, y - mu, 0.0), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(res.jac, np.where(mask[:, :, None], jac, 0.0), rtol=1e-12, atol=1e-9)
    some = np.array([3, 17, 29])
    r, j = res.minor(some)  # candidate-minor
    np.testing.assert_array_equal(r, res.residuals[some].T)
    np.testing.assert_array_equal(j, res.jac[some].transpose(2, 1, 0))


def test_crb_equals_monte_carlo_spread_of_the_fit():
    """The fit of 4000 noisy profiles scatters as the bound says (within sampling error)."""
    rng = np.random.default_rng(201)
    sigma, noise, n = 1.5, 2.0, 4000
    y, true_x = profiles(rng, n, sigma, noise=noise, dtype=np.uint16)
    half = 15
    x = np.arange(-half, half + 1, dtype=float)
    p0 = np.stack([np.full(n, 150.0), np.zeros(n), np.full(n, 1.0), np.full(n, 8.0)], axis=1)
    res = fit_batch(lambda p: model_1d(x, p), y.astype(float), np.ones(y.shape, bool), p0,
                    np.array([1e-3, -half, 0.3, -np.inf]), np.array([np.inf, half, 4, np.inf]))
    err = res.params[:, 1] + half - true_x
    bound = crb_stripe(180.0, sigma, true_x - half, effective_noise(noise), half_window=half)
    rel_sampling_error = 4.0 / np.sqrt(2 * n)  # 4 standard errors of an RMS from n samples
    assert np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(bound**2)) == pytest.approx(1.0, abs=rel_sampling_error)


def test_position_only_bound_is_never_above_the_full_bound():
    offsets = np.linspace(-0.5, 0.5, 11)
    for s in (0.8, 1.5, 2.5):
        full = crb_stripe(180.0, s, offsets, 2.0)
        known = crb_stripe(180.0, s, offsets, 2.0, position_only=True)
        assert np.all(known <= full * (1 + 1e-12))
        spot_known = crb_spot(180.0, s, offsets, 0.0, 2.0, position_only=True)
        assert np.all(spot_known <= crb_spot(180.0, s, offsets, 0.0, 2.0) * (1 + 1e-12))


def test_covariance_with_correlated_noise_matches_the_scatter():
    """Noise correlated between neighbouring pixels (moving average ``e_i + a e_(i+1)``, as
    demosaicing leaves it): with its correlation along the window the reported σ matches the
    centres' scatter; taken as white it understates it."""
    rng = np.random.default_rng(17)
    n, half, a, noise = 4000, 9, 0.8, 1.5
    x = np.arange(-half, half + 1, dtype=float)
    true_x = rng.uniform(-0.5, 0.5, n)
    white = rng.normal(0.0, noise / np.hypot(1.0, a), (n, x.size + 1))
    y = 10.0 + 60.0 * integrated(x[None, :], true_x[:, None], 1.4) + white[:, :-1] + a * white[:, 1:]
    p0 = np.stack([np.full(n, 60.0), np.zeros(n), np.full(n, 1.0), np.full(n, 10.0)], axis=1)
    res = fit_batch(lambda p: model_1d(x, p), y, np.ones(y.shape, bool), p0,
                    np.array([1e-3, -half, 0.3, -np.inf]), np.array([np.inf, half, 4, np.inf]))
    err = res.params[:, 1] - true_x
    correlation = np.array([1.0, a / (1.0 + a * a)])
    sigma = np.full(n, noise)
    spread_correlated = 1.4826 * np.median(np.abs(err / np.sqrt(parameter_covariance(res, sigma, correlation=correlation)[:, 1, 1])))
    spread_white = 1.4826 * np.median(np.abs(err / np.sqrt(parameter_covariance(res, sigma)[:, 1, 1])))
    sampling_error = 4 * 1.17 / np.sqrt(n)  # 4 standard errors of a MAD-based spread from n samples
    assert spread_correlated == pytest.approx(1.0, abs=sampling_error)
    assert spread_white > 1.0 + 3 * sampling_error
