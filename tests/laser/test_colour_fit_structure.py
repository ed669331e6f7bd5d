"""Shortcuts of the colour fit that its model's structure allows, checked against the general path.

The plain stripe fit iterates over the centre and width alone, each channel's levels solved for
them (variable projection, :func:`scanrig.laser.colour_fit._projection_1d`): its normal equations
are those of the full model with the levels eliminated, and the full model's ``(JᵀJ)⁻¹`` it reports
at the solution is the dense Jacobian's. It takes the misfit inflation of its centre's variance from
the centre's row of ``(JᵀJ)⁻¹ Jᵀ`` built from the profile (:func:`scanrig.laser.colour_fit._lever_1d`)
instead of the dense Jacobian (:func:`scanrig.laser.fit.centre_misfit`), and its start width from a
parabola through the trial widths' χ² (:func:`scanrig.laser.colour_fit._refined_width`).
"""

import numpy as np

from scanrig.laser import colour_fit, fit
from scanrig.laser.stacked_linalg import spd_inverse

from .colour_fit_calls import plain_fit_arguments


def _dense(res, mask):
    """The full model's dense Jacobian ``(8, 3 W, n)``, residuals ``(3 W, n)`` and ``(JᵀJ)⁻¹ (n, 8, 8)``
    at the fit's parameters (whitened pixels)."""
    residuals, jac = res.minor()
    return jac, residuals, spd_inverse(np.einsum("imn,jmn->ijn", jac, jac * mask))


def test_the_projected_fit_reports_the_dense_covariance_and_inflates_as_the_dense_jacobian_does(monkeypatch):
    y, usable, noise, x, p0, lower, upper = plain_fit_arguments(monkeypatch, 3)
    res, var = colour_fit._fit_projected(y, usable, noise, x, p0, lower, upper)
    mask = colour_fit._minor(y, usable, noise)[1].astype(float)
    jac, residuals, info_inv = _dense(res, mask)
    good = np.all(np.isfinite(info_inv), axis=(1, 2))
    assert good.mean() > 0.95
    np.testing.assert_allclose(res.info_inv[good], info_inv[good], rtol=1e-6, atol=1e-9 * np.abs(info_inv[good]).max())
    inflation = fit.centre_misfit(jac[..., good], info_inv[good], residuals[:, good], mask[:, good], res.dof[good],
                                  (0,))
    assert (inflation > 1.01).mean() > 0.5  # the rendered windows misfit: most are inflated
    np.testing.assert_allclose(var[good], info_inv[good, 0, 0] * inflation, rtol=1e-6)


def test_the_projected_normal_equations_are_the_full_models_with_the_levels_eliminated(monkeypatch):
    y, usable, noise, x, p0, lower, upper = plain_fit_arguments(monkeypatch, 3)
    y_minor, mask = colour_fit._minor(y, usable, noise)
    y_minor *= mask
    w = mask.astype(float)
    normal, complete = colour_fit._projection_1d(x, noise, (lower, upper))
    p = np.ascontiguousarray(p0[:, :2].T)  # the start: off the minimum, the levels solved for it
    cost, hess, grad = normal(p, y_minor, w)
    params, _ = complete(p, y_minor, w)
    mu, jac = colour_fit._model_1d(x, noise)(params)
    r = (y_minor - mu) * w
    full = np.einsum("imn,jmn->ijn", jac, jac * w)  # the dense JᵀJ, (8, 8, n)
    full_grad = np.einsum("imn,mn->in", jac, r)
    inside = np.all((params[2:] > lower[2:, None]) & (params[2:] < upper[2:, None]), axis=0)  # levels off bounds
    solvable = np.all(np.isfinite(hess), axis=(0, 1))
    use = inside & solvable
    assert use.mean() > 0.95
    np.testing.assert_allclose(cost, np.sum(r * r, axis=0), rtol=1e-8)
    # the levels are at their optimum: their gradient vanishes (relative to the data's), and the
    # profile's is the full model's
    scale = np.sqrt(np.sum(jac[2:] ** 2 * w, axis=1) * np.sum(y_minor**2, axis=0))  # (6, n)
    assert np.all(np.abs(full_grad[2:, use]) <= 1e-9 * scale[:, use])
    np.testing.assert_allclose(grad[:, use], full_grad[:2, use], rtol=1e-6, atol=1e-9 * np.abs(full_grad[:2]).max())
    # the Schur complement of the levels' block
    h = full.transpose(2, 0, 1)[use]
    schur = h[:, :2, :2] - h[:, :2, 2:] @ np.linalg.solve(h[:, 2:, 2:], h[:, 2:, :2])
    ours = hess.transpose(2, 0, 1)[use]
    np.testing.assert_allclose(ours, schur, rtol=1e-6, atol=1e-9 * np.abs(schur).max())


def test_the_refined_width_is_the_vertex_of_a_parabola_in_log_width():
    rng = np.random.default_rng(0)
    log_w = np.log(colour_fit._START_WIDTHS)
    true = np.exp(rng.uniform(log_w[1], log_w[-2], 50))  # (n,), inside the trial widths
    chi2 = 3.0 * (log_w[None, :] - np.log(true)[:, None]) ** 2 + rng.uniform(10, 20, (50, 1))
    width = colour_fit._refined_width(chi2, np.argmin(chi2, axis=1))
    np.testing.assert_allclose(width, true, rtol=1e-9)


def test_the_refined_width_keeps_a_trial_width_at_the_ends_and_where_the_chi2_is_flat():
    k = colour_fit._START_WIDTHS.size
    chi2 = np.array([np.arange(k, dtype=float),  # best: the narrowest
                     -np.arange(k, dtype=float),  # best: the widest
                     np.full(k, 7.0)])  # flat: no vertex
    best = np.array([0, k - 1, 3])
    width = colour_fit._refined_width(chi2, best)
    np.testing.assert_array_equal(width, colour_fit._START_WIDTHS[best])
