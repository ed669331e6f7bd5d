"""Pixel-integrated Gaussian models and their least-squares fit, vectorised over all candidates.

A pixel integrates the light falling on it, so the model of pixel ``i`` (centre at integer ``i``,
edges at ``i ± 0.5``) of a trace of peak ``A``, centre ``x0`` and Gaussian width ``s`` over a
background ``b`` is

    μ_i = b + A · √(2π) s · [Φ((i + ½ − x0)/s) − Φ((i − ½ − x0)/s)]

(``A`` is the peak of the continuous profile, so a wide trace has pixel values close to ``b + A``).
A spot is the separable product of two such profiles, with widths ``s_u`` and ``s_v``.

The fit is Levenberg–Marquardt with Marquardt's diagonal scaling, run for a fixed number of
iterations on every candidate at once: windows are stacked into ``(n, W)`` (stripes) or
``(n, Wv, Wu)`` (spots) arrays and a boolean mask drops pixels that are saturated, outside the
frame or nearer to another candidate. A few NumPy calls per iteration on the whole stack replace
a Python loop over candidates; the windows are small, so this is far below the frame's read time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import erf

_SQRT2 = np.sqrt(2.0)
#: Width bounds of the fit, pixels: below 0.3 px a Gaussian is a single pixel and its centre is
#: unobservable; the upper bound is set by the caller from the window.
MIN_WIDTH_PX = 0.3
#: Lower bound of the fitted peak, DN: keeps the model a peak, not a dip.
MIN_PEAK_DN = 1e-6
#: Levenberg–Marquardt damping: start, decrease on success, increase on failure.
_LAMBDA0, _LAMBDA_DOWN, _LAMBDA_UP = 1e-3, 0.3, 10.0

#: Parameter order of the 1-D model.
PARAMS_1D = ("peak", "x0", "width", "background")
#: Parameter order of the 2-D model.
PARAMS_2D = ("peak", "u0", "v0", "width_u", "width_v", "background")


def integrated_profile(x: np.ndarray, x0: np.ndarray, s: np.ndarray):
    """Unit-peak pixel-integrated Gaussian and its derivatives with respect to ``x0`` and ``s``.

    Parameters
    ----------
    x : (W,) float array, pixels
        Consecutive pixel centres (``x[k+1] = x[k] + 1``), so that neighbouring pixels share an
        edge and erf is evaluated once per edge.
    x0, s : (n, 1) float arrays, pixels
        Centre and Gaussian width.

    Returns
    -------
    g, dg_dx0, dg_ds : (n, W) arrays
        ``g = √(2π) s [Φ(t1) − Φ(t0)]`` with ``t1,0 = (x ± ½ − x0)/s``; ``g → 1`` at the centre
        of a wide profile.
    """
    edges = np.append(x - 0.5, x[-1] + 0.5)[None, :]
    t = (edges - x0) / s
    root_2pi_cdf = np.sqrt(np.pi / 2.0) * erf(t / _SQRT2)  # √(2π) Φ(t) up to a constant
    e = np.exp(-0.5 * t * t)  # √(2π) φ(t)
    te = t * e
    root_2pi_area = root_2pi_cdf[:, 1:] - root_2pi_cdf[:, :-1]
    g = s * root_2pi_area
    dg_dx0 = e[:, :-1] - e[:, 1:]
    dg_ds = root_2pi_area - te[:, 1:] + te[:, :-1]
    return g, dg_dx0, dg_ds


def model_1d(x: np.ndarray, p: np.ndarray):
    """Stripe profile model and Jacobian.

    Parameters
    ----------
    x : (W,) float array, pixels
        Pixel offsets in the window.
    p : (n, 4) float array
        ``peak (DN), x0 (px), width (px), background (DN)`` per candidate.

    Returns
    -------
    mu : (n, W) array, DN
    jac : (n, W, 4) array
    """
    a, x0, s, b = (p[:, i : i + 1] for i in range(4))
    g, gx, gs = integrated_profile(x, x0, s)
    mu = b + a * g
    jac = np.stack([g, a * gx, a * gs, np.ones_like(g)], axis=-1)
    return mu, jac


def model_2d(xu: np.ndarray, xv: np.ndarray, p: np.ndarray):
    """Separable spot model and Jacobian.

    Parameters
    ----------
    xu : (Wu,) float array, pixels
        Column offsets in the window.
    xv : (Wv,) float array, pixels
        Row offsets in the window.
    p : (n, 6) float array
        ``peak (DN), u0, v0 (px), width_u, width_v (px), background (DN)``.

    Returns
    -------
    mu : (n, Wv * Wu) array, DN
    jac : (n, Wv * Wu, 6) array
    """
    a, u0, v0, su, sv, b = (p[:, i : i + 1] for i in range(6))
    gu, gu_x, gu_s = (t[:, None, :] for t in integrated_profile(xu, u0, su))
    gv, gv_x, gv_s = (t[:, :, None] for t in integrated_profile(xv, v0, sv))
    a = a[:, :, None]
    n = p.shape[0]
    jac = np.empty((n, xv.size, xu.size, 6))
    jac[..., 0] = gu * gv
    jac[..., 1] = (a * gu_x) * gv
    jac[..., 2] = (a * gu) * gv_x
    jac[..., 3] = (a * gu_s) * gv
    jac[..., 4] = (a * gu) * gv_s
    jac[..., 5] = 1.0
    mu = b[:, :, None] + a * jac[..., 0]
    return mu.reshape(n, -1), jac.reshape(n, -1, 6)


@dataclass(frozen=True)
class FitResult:
    """Result of a batch fit.

    Attributes
    ----------
    params : (n, P) float array
        Fitted parameters (order ``PARAMS_1D`` or ``PARAMS_2D``).
    info_inv : (n, P, P) float array
        Inverse of ``JᵀJ`` over the fitted pixels: the covariance for unit noise variance (multiply
        by σ² in DN²). NaN where singular.
    chi2_unit : (n,) float array
        Sum of squared residuals, DN² (divide by σ² for χ²).
    dof : (n,) int array
        Fitted pixels minus parameters.
    jac : (n, M, P) float array
        Jacobian at the solution, zero on pixels outside the mask.
    residuals : (n, M) float array, DN
        Data minus model, zero outside the mask.
    """

    params: np.ndarray
    info_inv: np.ndarray
    chi2_unit: np.ndarray
    dof: np.ndarray
    jac: np.ndarray
    residuals: np.ndarray


def fit_batch(model, y: np.ndarray, mask: np.ndarray, p0: np.ndarray, lower: np.ndarray,
              upper: np.ndarray, n_iter: int = 12, tol: float = 1e-5) -> FitResult:
    """Levenberg–Marquardt least squares for a stack of independent windows.

    Each candidate iterates until an accepted step lowers its cost by less than ``tol`` (relative)
    or ``n_iter`` is reached; converged candidates leave the working set, so the usual 3–5
    iterations cost what they cost and a few hard ones do not slow down the rest.

    Parameters
    ----------
    model : callable
        ``model(p) -> (mu (n, M), jac (n, M, P))`` for any subset of candidates ``p (n, P)``.
    y : (n, M) float array, DN
        Windows, flattened.
    mask : (n, M) bool array
        Pixels that take part in the fit.
    p0 : (n, P) float array
        Start values.
    lower, upper : (P,) float arrays
        Box bounds; steps are clipped to them.
    n_iter : int
        Most iterations.
    tol : float
        Relative cost decrease below which a candidate has converged.

    Returns
    -------
    FitResult
    """
    w = mask.astype(np.float64)
    n, n_par = p0.shape
    diag_idx = np.arange(n_par)
    p = np.clip(p0, lower, upper)
    mu, jac = model(p)
    jac *= w[:, :, None]
    r = (y - mu) * w
    cost = np.einsum("nm,nm->n", r, r)
    lam = np.full(n, _LAMBDA0)
    active = np.arange(n)
    for _ in range(n_iter):
        if active.size == 0:
            break
        every = active.size == n  # no copies while every candidate still iterates
        ja, ra = (jac, r) if every else (jac[active], r[active])
        ya, wa, ca, la = (y, w, cost, lam) if every else (y[active], w[active], cost[active], lam[active])
        jt = ja.transpose(0, 2, 1)
        hess = jt @ ja
        grad = (jt @ ra[:, :, None])[:, :, 0]
        diag = hess[:, diag_idx, diag_idx]
        hess[:, diag_idx, diag_idx] += la[:, None] * diag + 1e-12 * diag.max(axis=1, keepdims=True) + 1e-300
        step = np.linalg.solve(hess, grad[:, :, None])[:, :, 0]
        p_try = np.clip(p[active] + step, lower, upper)
        mu_try, jac_try = model(p_try)
        jac_try *= wa[:, :, None]
        r_try = (ya - mu_try) * wa
        cost_try = np.einsum("nm,nm->n", r_try, r_try)
        better = cost_try < ca
        converged = better & (ca - cost_try <= tol * ca)
        if every and better.all():
            p, jac, r, cost = p_try, jac_try, r_try, cost_try
        else:
            idx = active[better]
            p[idx] = p_try[better]
            jac[idx] = jac_try[better]
            r[idx] = r_try[better]
            cost[idx] = cost_try[better]
        lam[active] = np.where(better, la * _LAMBDA_DOWN, la * _LAMBDA_UP)
        active = active[~converged & (lam[active] < 1e10)]
    jt = jac.transpose(0, 2, 1)
    hess = jt @ jac
    info_inv = np.full_like(hess, np.nan)
    diag = hess[:, diag_idx, diag_idx]
    # determinant of the correlation matrix: scale-free test for a (near-)singular information
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = np.linalg.det(hess) / np.prod(diag, axis=1) > 1e-12
    if ok.any():
        info_inv[ok] = np.linalg.inv(hess[ok])
    dof = mask.sum(axis=1) - n_par
    return FitResult(p, info_inv, cost, dof, jac, r)


#: Significance level above which a window's χ² is taken as model misfit (not noise).
MISFIT_LEVEL = 0.999


def misfit_scale(chi2_unit: np.ndarray, dof: np.ndarray, noise_sigma: float) -> np.ndarray:
    """Variance inflation of each fit: χ²/dof when the misfit is significant, else 1.

    With white noise of the estimated σ, χ²/dof scatters around 1 and the covariance
    ``σ² (JᵀJ)⁻¹`` is already right; scaling every fit by its own χ²/dof would only add noise to
    the reported sigma. Where χ² exceeds its 99.9 % quantile the model does not explain the window
    (shot noise on a bright trace, texture, a nearby reflection) and the covariance is inflated by
    χ²/dof.

    Parameters
    ----------
    chi2_unit : (n,) float array, DN²
        Sums of squared residuals.
    dof : (n,) int array
        Degrees of freedom.
    noise_sigma : float, DN

    Returns
    -------
    (n,) float array
        Factor ≥ 1 for the covariance.
    """
    from scipy.special import chdtri  # inverse survival function of χ²: fast, no scipy.stats

    dof = np.maximum(dof, 1)
    reduced = chi2_unit / noise_sigma**2 / dof
    return np.where(reduced > chdtri(dof, 1.0 - MISFIT_LEVEL) / dof, reduced, 1.0)


#: The shot-noise slope is used only when it exceeds this many standard errors.
SHOT_NOISE_SIGNIFICANCE = 3.0
#: About this many candidates, spread over the frame, estimate the frame's shot-noise slope.
_SLOPE_SAMPLE = 256


def parameter_covariance(res: FitResult, noise_sigma: np.ndarray) -> np.ndarray:
    """Covariance of the fitted parameters, honest under signal-dependent (shot) noise.

    The pixel variance is modelled as ``σ_c² + k · s_i``: σ_c the local background noise of the
    candidate, ``s_i = A g_i`` the fitted signal above background (both models have the peak first,
    so ``s = A ∂μ/∂A``), and ``k`` (DN per DN) one slope per frame, pooled over the fitted pixels
    of about ``_SLOPE_SAMPLE`` candidates spread over the frame, from the leverage-corrected squared
    residuals: ``r_i² / (1 − h_ii) − σ_c²`` regressed on ``s_i``. ``k`` is used only when it
    exceeds ``SHOT_NOISE_SIGNIFICANCE`` standard errors, so white noise keeps the plain
    ``σ² (JᵀJ)⁻¹``. The least-squares estimate is unweighted;
    under the modelled variance its covariance is the sandwich ``(JᵀJ)⁻¹ Jᵀ V J (JᵀJ)⁻¹``. Finally
    :func:`misfit_scale` inflates fits whose normalised χ² is still significant.

    Parameters
    ----------
    res : FitResult
    noise_sigma : (n,) float array, DN
        Background noise σ at each candidate.

    Returns
    -------
    (n, P, P) float array
        Covariance of the parameters (units of the parameters). NaN where singular.
    """
    jac, r, info = res.jac, res.residuals, res.info_inv
    fitted = jac[:, :, -1] != 0  # the background derivative is 1 on every fitted pixel
    base_var = (noise_sigma**2)[:, None]
    signal = res.params[:, :1] * jac[:, :, 0]
    good = np.all(np.isfinite(info), axis=(1, 2))
    usable = np.flatnonzero(good)  # the pooled slope needs only an evenly spread sample of them
    good[:] = False
    good[usable[:: max(1, usable.size // _SLOPE_SAMPLE)]] = True
    slope = 0.0
    if good.any():
        jg = jac[good]
        leverage = ((jg @ info[good]) * jg).sum(axis=2)
        f = fitted[good] & (leverage < 0.9)
        x = signal[good][f]
        t = r[good][f] ** 2 / (1.0 - leverage[f]) - np.broadcast_to(base_var[good], f.shape)[f]
        sxx = float(np.dot(x, x))
        if sxx > 0:
            slope = float(np.dot(x, t)) / sxx
            standard_error = np.sqrt(2.0) * float(np.mean(base_var[good])) / np.sqrt(sxx)
            if slope < SHOT_NOISE_SIGNIFICANCE * standard_error:
                slope = 0.0
    pixel_var = np.where(fitted, base_var + slope * np.maximum(signal, 0.0), 0.0)
    if slope > 0.0:
        meat = jac.transpose(0, 2, 1) @ (jac * pixel_var[:, :, None])
        cov = info @ meat @ info
    else:
        cov = base_var[:, :, None] * info
    with np.errstate(divide="ignore", invalid="ignore"):
        chi2_normalised = np.where(fitted, r**2 / pixel_var, 0.0).sum(axis=1)
    return cov * misfit_scale(chi2_normalised, res.dof, 1.0)[:, None, None]
