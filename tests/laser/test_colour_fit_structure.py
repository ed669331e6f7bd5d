"""Shortcuts of the colour fit that its model's structure allows, checked against the general path.

The plain stripe fit takes the misfit inflation of its centre's variance from the centre's row of
``(JᵀJ)⁻¹ Jᵀ`` built from the profile (:func:`scanrig.laser.colour_fit._lever_1d`) instead of the
dense Jacobian (:func:`scanrig.laser.fit.centre_misfit`), and its start width from a parabola
through the trial widths' χ² (:func:`scanrig.laser.colour_fit._refined_width`).
"""

import numpy as np

from scanrig.laser import colour_fit, fit, stripes

from .colour_synth import stripe_frames


def _plain_fit_arguments(monkeypatch, seed):
    """The arguments of the plain colour fit of the rendered frame of ``seed`` (no laser-off frame)."""
    calls = []
    fit = colour_fit._fit

    def spy(*args, **options):
        calls.append((args, options))
        return fit(*args, **options)

    monkeypatch.setattr(colour_fit, "_fit", spy)
    on, _, _ = stripe_frames(np.random.default_rng(seed))
    stripes.detect_stripe(on, color="red")
    monkeypatch.undo()
    return calls[0]


def test_the_lever_from_the_profile_inflates_as_the_dense_jacobian_does(monkeypatch):
    args, options = _plain_fit_arguments(monkeypatch, 3)
    assert options.get("lever") is not None  # the plain fit takes the shortcut
    _, with_lever = colour_fit._fit(*args, **options)
    _, dense = colour_fit._fit(*args, **{k: v for k, v in options.items() if k != "lever"})
    inflated = dense[:, 0, 0] > colour_fit._fit(*args, **options)[0].info_inv[:, 0, 0] * 1.01
    assert inflated.mean() > 0.5  # the rendered windows misfit: most are inflated
    np.testing.assert_allclose(with_lever[:, 0, 0], dense[:, 0, 0], rtol=1e-9, equal_nan=True)


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


def test_the_structured_solve_matches_the_general_one_with_and_without_held_parameters(monkeypatch):
    args, options = _plain_fit_arguments(monkeypatch, 3)
    y, usable, noise, model, p0, lower, upper, n_axes, normal = args
    n, m = y.shape[:2]
    y_minor = np.ascontiguousarray(y.transpose(2, 1, 0).reshape(-1, n)) / np.repeat(noise, m)[:, None]
    mask = np.ascontiguousarray(usable.transpose(2, 1, 0).reshape(-1, n)).astype(float)
    _, hess, grad = normal(np.ascontiguousarray(p0.T), y_minor, mask)
    lam = np.random.default_rng(0).uniform(1e-4, 1e2, n)
    held = np.zeros(grad.shape, bool)
    held[1, ::3] = held[2, ::5] = held[7, ::7] = True  # a width, a laser amplitude, a background
    for h, g in ((hess, grad), fit._held(hess, grad, held)):
        general = fit._damped_solve(h, g, lam)
        structured = fit._damped_solve(h, g, lam, colour_fit._solve_1d)
        assert np.all(np.isfinite(general))
        np.testing.assert_allclose(structured, general, rtol=1e-8, atol=1e-10 * np.abs(general).max())


def test_the_structured_solve_gives_nan_where_the_system_is_not_positive_definite():
    rng = np.random.default_rng(1)
    jac = rng.normal(size=(8, 40, 2))
    jac[[3, 4, 6, 7]] = 0.0  # only the first channel has levels: no channel meets another's
    hess = np.einsum("imn,jmn->ijn", jac, jac)
    hess[1, 1, 1] = -1.0  # the second is indefinite
    grad = rng.normal(size=(8, 2))
    diag = hess.reshape(64, 2)[::9] + 1e-9
    step = colour_fit._solve_1d(hess, grad, diag)
    assert np.all(np.isfinite(step[:, 0])) and np.all(np.isnan(step[:2, 1]))
