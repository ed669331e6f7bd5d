"""The vectorised Levenberg–Marquardt of ``laser.fit`` against a slow reference solver.

``fit_batch`` stops a candidate when an accepted step lowers its cost by less than ``tol``
(relative). Near the minimum the cost is quadratic, ``c(p) − c* = δᵀ JᵀJ δ``, so a cost within
``ε c*`` of the minimum puts parameter ``k`` within ``sqrt(ε c* (JᵀJ)⁻¹_kk)`` of it. With a linear
convergence rate ρ (large residuals: the colour fit converges at ρ ≈ 0.6) the cost left after the
last step is at most ``tol c ρ / (1 − ρ)``; ``SLACK`` = 9 allows ρ up to 0.9. The reference is
``scipy.optimize.least_squares`` on each window alone, converged to machine precision.
"""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import least_squares

from scanrig.laser.colour_fit import _model_1d as colour_model_1d
from scanrig.laser.colour_fit import _projection_1d as colour_projection_1d
from scanrig.laser.fit import MIN_PEAK_DN, MIN_WIDTH_PX, fit_batch, minor_model_1d

from .synth import integrated

TOL = 1e-5  # fit_batch's default relative cost tolerance
SLACK = 9.0  # cost excess over tol · cost allowed by a convergence rate up to 0.9 (see the module notes)
#: Enough iterations for the slowest clipped colour window to meet the convergence test.
ITERATIONS_TO_CONVERGE = 200


def _reference(model, y, mask, p0, lower, upper):
    """Each window fitted alone by scipy's trust-region reflective solver, to machine precision."""
    out = np.empty_like(p0)
    for j in range(p0.shape[0]):
        def residual(q, j=j):
            mu, _ = model(q[:, None])
            return (y[:, j] - mu[:, 0])[mask[:, j]]

        def jacobian(q, j=j):
            _, jac = model(q[:, None])
            return -jac[:, mask[:, j], 0].T

        out[j] = least_squares(residual, np.clip(p0[j], lower, upper), jac=jacobian, bounds=(lower, upper), xtol=1e-15, ftol=1e-15,
                               gtol=1e-15, max_nfev=2000).x
    return out


def _within_tolerance(res, reference, residual_cost, k):
    """Parameter ``k`` of the fast fit within the bound of the module notes of the reference."""
    bound = np.sqrt(SLACK * TOL * residual_cost * res.info_inv[:, k, k])
    return np.abs(res.params[:, k] - reference[:, k]) <= bound + 1e-12


@pytest.mark.parametrize("n", [5, 40])  # LAPACK below the unrolled threshold, unrolled above
def test_stripe_fit_matches_the_reference_solver(n):
    """Noisy pixel-integrated profiles with masked pixels (a clipped core, a neighbour's pixels)."""
    rng = np.random.default_rng(31)
    half = 9
    x = np.arange(-half, half + 1.0)
    centre, width = rng.uniform(-0.5, 0.5, n), rng.uniform(0.7, 2.5, n)
    peak, background = rng.uniform(20, 250, n), rng.uniform(0, 30, n)
    y = background + peak * integrated(x[:, None], centre, width) + rng.normal(0, 2.0, (x.size, n))
    mask = rng.uniform(size=y.shape) > 0.1
    mask[half, : n // 3] = False  # clipped centre pixel
    p0 = np.stack([peak * 0.7, centre + 0.4, width * 1.3, background + 5.0], axis=1)
    lower = np.array([MIN_PEAK_DN, -half, MIN_WIDTH_PX, -np.inf])
    upper = np.array([np.inf, half, 3.0, np.inf])
    model = minor_model_1d(x)
    res = fit_batch(model, y, mask, p0, lower, upper, minor=True)
    reference = _reference(model, y, mask, p0, lower, upper)
    mu, _ = model(reference.T)
    reference_cost = np.sum(np.where(mask, y - mu, 0.0) ** 2, axis=0)
    assert np.all(res.chi2_unit <= reference_cost * (1 + SLACK * TOL))
    for k in range(4):
        assert _within_tolerance(res, reference, reference_cost, k).all()


def _counting(normal, counts: list):
    """``normal`` that appends the number of windows of each evaluation to ``counts``."""
    def counted(p, y, w):
        counts.append(p.shape[1])
        return normal(p, y, w)
    return counted


def test_colour_fit_by_variable_projection_matches_the_reference_solver():
    """Clipped red stripes with crosstalk into green and blue and a halo the model lacks (large
    residuals, the slow case). The fit over the centre and width alone, each channel's amplitude
    and background solved for them at every evaluation (variable projection through fit_batch's
    ``normal``, :func:`scanrig.laser.colour_fit._projection_1d`), stops by its convergence test at the
    minimum of the full model (the reference iterates all eight parameters) to within the
    tolerance, and in fewer evaluations than fit_batch iterating all eight through the dense
    Jacobian. Windows whose laser amplitude ends on its bound are left out of the comparison."""
    rng = np.random.default_rng(32)
    n, half, clip = 40, 12, 255.0
    x = np.arange(-half, half + 1.0)
    noise = np.array([3.0, 2.0, 2.5])
    centre, width = rng.uniform(-1.0, 1.0, n), rng.uniform(1.0, 1.5, n)
    peak = rng.uniform(400, 2000, n)  # the laser 1.5-8 times past full scale in red
    # 30 % of the light in a 3-px halo, as on the rendered colour set (tests/laser/colour_synth.py)
    beam = 0.7 * integrated(x[:, None], centre, width) + 0.3 * integrated(x[:, None], centre, np.hypot(width, 3.0))
    share, level = np.array([1.0, 0.07, 0.05]), np.array([150.0, 140.0, 130.0])
    y = level[:, None, None] + share[:, None, None] * peak * beam + rng.normal(0, 1, (3, x.size, n)) * noise[:, None, None]
    y_minor = (y / noise[:, None, None]).reshape(-1, n)
    mask = (y < clip).reshape(-1, n)
    p0 = np.concatenate([np.stack([centre + 0.3, width * 1.2]), share[:, None] * peak * 0.8,
                         np.repeat(level[:, None] + 3.0, n, axis=1)]).T
    lower = np.r_[-half, MIN_WIDTH_PX, MIN_PEAK_DN, -100 * clip, -100 * clip, np.full(3, -np.inf)]
    upper = np.r_[half, half / 2, np.full(3, 100 * clip), np.full(3, np.inf)]
    model = colour_model_1d(x, noise)
    normal, complete = colour_projection_1d(x, noise, (lower, upper))
    evaluations = {"dense": [], "projected": []}

    def counted_model(p):
        evaluations["dense"].append(p.shape[1])
        return model(p)

    fit_batch(counted_model, y_minor, mask, p0, lower, upper, n_iter=ITERATIONS_TO_CONVERGE, minor=True)
    zeroed, w = y_minor * mask, mask.astype(float)
    reduced = fit_batch(None, zeroed, mask, p0[:, :2], lower[:2], upper[:2], n_iter=ITERATIONS_TO_CONVERGE,
                        minor=True, normal=_counting(normal, evaluations["projected"]))
    params, info_inv = complete(reduced.params.T, zeroed, w)
    res = SimpleNamespace(params=params.T, info_inv=info_inv, chi2_unit=reduced.chi2_unit, dof=reduced.dof - 6)
    assert np.median(res.chi2_unit / res.dof) > 3.0  # the halo leaves large residuals, as intended
    inside = (res.params[:, 2] > lower[2]) & (res.params[:, 2] < upper[2])
    assert inside.sum() >= 0.9 * n
    reference = _reference(model, y_minor, mask, p0, lower, upper)
    mu, _ = model(reference.T)
    reference_cost = np.sum(np.where(mask, y_minor - mu, 0.0) ** 2, axis=0)
    assert np.all(res.chi2_unit[inside] <= reference_cost[inside] * (1 + SLACK * TOL))
    for k in range(2):  # centre and width
        assert _within_tolerance(res, reference, reference_cost, k)[inside].all()
    assert sum(evaluations["projected"]) < sum(evaluations["dense"])
