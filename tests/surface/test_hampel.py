"""Hampel tanh psi/rho/weights and the robust noise scale."""

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.surface.hampel import (HampelConstants, check_q, hampel_psi, hampel_rho, hampel_weight,
                                    refined_scale, robust_scale, trimmed_consistency, trimmed_scale,
                                    truncated_consistency)

A, B, BETA = 1.634, 4.0, 0.915  # sigma = 1
FD_STEP = 1e-6
FD_TOL = 1e-6  # central differences of a smooth float64 function at step 1e-6: error ~ h^2 + eps/h


def test_psi_is_the_derivative_of_rho():
    r = np.concatenate([np.linspace(-6, 6, 2001)])
    r = r[np.min(np.abs(np.abs(r)[:, None] - [A, B]), axis=1) > 10 * FD_STEP]  # away from the kinks
    numeric = (hampel_rho(r + FD_STEP, A, B, BETA) - hampel_rho(r - FD_STEP, A, B, BETA)) / (2 * FD_STEP)
    np.testing.assert_allclose(numeric, hampel_psi(r, A, B, BETA), atol=FD_TOL)


def test_psi_shape_and_weights():
    r = np.array([-5.0, -4.0, -2.0, -1.0, 0.0, 1.0, 3.0, 4.5])
    psi = hampel_psi(r, A, B, BETA)
    assert np.all(psi[np.abs(r) > B] == 0.0)
    np.testing.assert_array_equal(psi[np.abs(r) <= A], r[np.abs(r) <= A])
    w = hampel_weight(r, A, B, BETA)
    nz = r != 0
    np.testing.assert_allclose(w[nz], psi[nz] / r[nz])
    assert np.all((w >= 0) & (w <= 1))
    # rho is constant beyond b: gross errors add a bounded, fixed loss
    assert hampel_rho(np.array([5.0]), A, B, BETA) == hampel_rho(np.array([50.0]), A, B, BETA)


@pytest.mark.parametrize("q, kappa", [(0.05, 0.759), (0.10, 0.623), (0.20, 0.438), (0.30, 0.310), (0.50, 0.143)])
def test_trimmed_consistency_matches_reference_table(q, kappa):
    assert trimmed_consistency(q) == pytest.approx(kappa, abs=5e-4)  # the table has 3 decimals


def test_truncated_consistency_limits():
    assert truncated_consistency(8.0) == pytest.approx(1.0, abs=1e-12)
    rng = np.random.default_rng(20261123)
    x = rng.normal(size=400_000)
    inside = x[np.abs(x) <= 1.5]
    # Monte-Carlo mean of x^2 on the truncated set: relative SE ~ 1/sqrt(n) ~ 0.2 %
    assert np.mean(inside**2) == pytest.approx(truncated_consistency(1.5), rel=0.01)


@pytest.mark.parametrize("eps, q", [(0.0, 0.25), (0.2, 0.25), (0.4, 0.5)])
def test_robust_scale_recovers_sigma_under_gross_one_sided_errors(eps, q):
    rng = np.random.default_rng(7)
    n, sigma = 5000, 0.01
    r = rng.normal(0, sigma, n)
    bad = rng.random(n) < eps
    r[bad] = rng.uniform(6 * sigma, 0.3, bad.sum())
    est, upper = robust_scale(r, q, rng=rng)
    # SE of a Gaussian scale from ~3000-5000 points is ~1.3 %; 5 % is about 4 SE
    assert est == pytest.approx(sigma, rel=0.05)
    assert est < upper < 1.1 * est  # bootstrap 95 % bound: about 1.65 SE above


def test_refined_scale_removes_the_trimmed_overestimate_below_the_breakdown_point():
    # 36 % two-sided gross errors at q = 0.5: the trimmed half holds inliers beyond the central
    # half of the Gaussian, so the q-trimmed scale over-estimates sigma by ~1.6x. Refined inside
    # 2.5 scales it is left with the gross errors inside the cut (~5 % of the points, mean
    # square ~(2.75 sigma)^2 / 3), which raise it by ~8 %.
    rng = np.random.default_rng(11)
    r = rng.normal(0, 1.0, 5000)
    bad = rng.random(r.size) < 0.36
    r[bad] = rng.uniform(-20, 20, bad.sum())
    assert trimmed_scale(r, 0.5) > 1.4
    sigma, good = refined_scale(r, 0.5, cut=2.5)
    assert 1.0 < sigma < 1.15
    assert np.all(good <= (2.5 * 1.2) ** 2) and good.size > 0.6 * r.size  # the last step's set
    assert sigma == pytest.approx(np.sqrt(good.mean() / truncated_consistency(2.5)))


@pytest.mark.parametrize("bad", [0.0, -0.1, 0.51, float("nan"), "x"])
def test_q_outside_range_is_rejected(bad):
    with pytest.raises(InputError, match="q"):
        check_q(bad)


def test_constants_validated():
    with pytest.raises(InputError):
        HampelConstants(p=5.0, r=4.0)
