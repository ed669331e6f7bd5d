"""Pixel-integrated Gaussian models and their least-squares fit, vectorised over all candidates.

A pixel integrates the light falling on it, so the model of pixel ``i`` (centre at integer ``i``,
edges at ``i ± 0.5``) of a trace of peak ``A``, centre ``x0`` and Gaussian width ``s`` over a
background ``b`` is

    μ_i = b + A · √(2π) s · [Φ((i + ½ − x0)/s) − Φ((i − ½ − x0)/s)]

(``A`` is the peak of the continuous profile, so a wide trace has pixel values close to ``b + A``).
A spot is the separable product of two such profiles, with widths ``s_u`` and ``s_v``.

The fit is Levenberg–Marquardt with Marquardt's diagonal scaling, run on every candidate at once:
windows are stacked into ``(n, W)`` (stripes) or ``(n, Wv · Wu)`` (spots) arrays and a boolean
mask drops pixels that are saturated, outside the frame or nearer to another candidate. A few
NumPy calls per iteration on the whole stack replace a Python loop over candidates.

Internally the stacks are *candidate-minor*: pixel ``m`` of all candidates is one contiguous row
(``(M, n)`` data, ``(P, M, n)`` Jacobian, ``(P, n)`` parameters), so every elementwise operation
and every sum over a window runs over long contiguous rows instead of many 19-element ones, and
each entry of ``JᵀJ`` is one ``(n,)`` array; the small systems are then solved by a Cholesky
factorisation written out entry by entry over the candidate axis
(:func:`~scanrig.laser.stacked_linalg.damped_solve`), or, for a
batch too small to repay its fixed cost of order P³ NumPy calls, by LAPACK.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.special import erf

from scanrig.laser.stacked_linalg import MATMUL_MAX, damped_solve, gram, spd_inverse

_INV_SQRT2 = 1.0 / np.sqrt(2.0)
_ROOT_HALF_PI = np.sqrt(np.pi / 2.0)
#: Width bounds of the fit, pixels: below 0.3 px a Gaussian is a single pixel and its centre is
#: unobservable; the upper bound is set by the caller from the window.
MIN_WIDTH_PX = 0.3
#: Lower bound of the fitted peak, DN: keeps the model a peak, not a dip.
MIN_PEAK_DN = 1e-6
#: Levenberg–Marquardt damping: start, decrease on success, increase on failure.
_LAMBDA0, _LAMBDA_DOWN, _LAMBDA_UP = 1e-3, 0.3, 10.0
#: Statistical stop rule of :func:`fit_batch`: a fit stops when what is left to gain is at most this,
#: in χ² units (it leaves every parameter within √STOP_CHI2 = 0.1 of its σ of the minimum).
STOP_CHI2 = 1e-2
#: With it, the step is scaled by the inverse of the curvature ratio measured along the last step,
#: within these limits (a secant correction of Gauss–Newton's step length where large residuals
#: make it overshoot or fall short).
_STEP_SCALES = (0.25, 2.0)

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
    x0, s = np.broadcast_arrays(np.ravel(x0).astype(float), np.ravel(s).astype(float))
    out = np.empty((3, x.size, x0.size))
    profile_terms(pixel_edges(x), x0, s, out)
    return out[0].T, out[1].T, out[2].T


def profile_terms(edges: np.ndarray, x0: np.ndarray, s: np.ndarray, out: np.ndarray) -> None:
    """:func:`integrated_profile` candidate-minor: ``edges (W + 1, 1)``, ``x0, s (n,)``; writes
    ``g, dg_dx0, dg_ds`` into ``out[0], out[1], out[2]``, each ``(W, n)``."""
    t = edges - x0
    t *= 1.0 / s  # (W + 1, n): the edges in units of s
    cdf = erf(t * _INV_SQRT2)  # 2 Φ(t) − 1
    e = t * t
    e *= -0.5
    np.exp(e, out=e)  # √(2π) φ(t)
    t *= e  # √(2π) t φ(t)
    area = out[0]
    np.subtract(cdf[1:], cdf[:-1], out=area)
    area *= _ROOT_HALF_PI  # √(2π) [Φ(t1) − Φ(t0)]
    np.subtract(area, t[1:], out=out[2])
    out[2] += t[:-1]
    area *= s  # g
    np.subtract(e[:-1], e[1:], out=out[1])


_EDGE_CACHE: dict[tuple[int, float, float], np.ndarray] = {}


def pixel_edges(x: np.ndarray) -> np.ndarray:
    """Pixel edges ``x − ½`` and ``x[-1] + ½`` of consecutive pixel centres, ``(W + 1, 1)``, cached."""
    key = (x.size, float(x[0]), float(x[-1]))
    edges = _EDGE_CACHE.get(key)
    if edges is None:
        edges = np.append(x - 0.5, x[-1] + 0.5)[:, None]
        edges.flags.writeable = False
        if len(_EDGE_CACHE) < 64:
            _EDGE_CACHE[key] = edges
    return edges


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
    mu, jac = minor_model_1d(x)(np.asarray(p, float).T)
    return mu.T, jac.transpose(2, 1, 0)


def minor_model_1d(x: np.ndarray):
    """:func:`model_1d` for :func:`fit_batch` with ``minor=True``: ``p (4, n)`` -> ``mu (W, n)``,
    ``jac (4, W, n)``."""
    edges = pixel_edges(x)

    def model(p):
        a, x0, s, b = p
        jac = np.empty((4, x.size, a.size))
        profile_terms(edges, x0, s, jac)
        jac[1:3] *= a
        jac[3] = 1.0
        mu = jac[0] * a
        mu += b
        return mu, jac

    return model


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
    mu, jac = minor_model_2d(xu, xv)(np.asarray(p, float).T)
    return mu.T, jac.transpose(2, 1, 0)


def minor_model_2d(xu: np.ndarray, xv: np.ndarray):
    """:func:`model_2d` for :func:`fit_batch` with ``minor=True``: ``p (6, n)`` -> ``mu (Wv·Wu, n)``,
    ``jac (6, Wv·Wu, n)`` (pixel index ``row · Wu + column``)."""
    edges_u, edges_v = pixel_edges(xu), pixel_edges(xv)
    pick_v = [0, 0, 1, 0, 2]  # jac[k] = v-factor[k] × u-factor[k]: g, g, dg/dx0, g, dg/ds of v
    pick_u = [0, 1, 0, 2, 0]  # ... and g, A dg/dx0, A g, A dg/ds, A g of u (the first without A)

    def model(p):
        a, b = p[0], p[5]
        n = a.size
        if edges_u is edges_v:  # one call for both axes: (3, W, 2n), u then v
            both = np.empty((3, xu.size, 2 * n))
            profile_terms(edges_u, p[1:3].reshape(-1), p[3:5].reshape(-1), both)
            prof_u, prof_v = both[:, :, :n], both[:, :, n:]
        else:
            prof_u, prof_v = np.empty((3, xu.size, n)), np.empty((3, xv.size, n))
            profile_terms(edges_u, p[1], p[3], prof_u)
            profile_terms(edges_v, p[2], p[4], prof_v)
        factor_u = np.take(prof_u * a, pick_u, axis=0)  # (5, Wu, n)
        factor_u[0] = prof_u[0]
        jac = np.empty((6, xv.size, xu.size, n))
        np.multiply(np.take(prof_v, pick_v, axis=0)[:, :, None], factor_u[:, None], out=jac[:5])
        jac[5] = 1.0
        jac = jac.reshape(6, -1, n)
        mu = jac[0] * a
        mu += b
        return mu, jac

    return model


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
        Jacobian at the solution, zero on pixels outside the mask (a transposed view of the
        candidate-minor ``(P, M, n)`` array the fit works on); evaluated when first asked for.
    residuals : (n, M) float array, DN
        Data minus model, zero outside the mask (a view of an ``(M, n)`` array); evaluated with
        ``jac``.
    model, y, weights
        The candidate-minor model, data ``(M, n)`` and mask as 0/1 floats (None: every pixel
        fitted) of the fit, which ``jac`` and ``residuals`` are evaluated from.

    Methods
    -------
    minor(index)
        Residuals ``(M, k)`` and Jacobian ``(P, M, k)`` of some candidates, candidate-minor: what
        needs them for a few (a sample, the misfits) does not evaluate all.
    """

    params: np.ndarray
    info_inv: np.ndarray
    chi2_unit: np.ndarray
    dof: np.ndarray
    model: Callable = field(repr=False)
    y: np.ndarray = field(repr=False)
    weights: np.ndarray | None = field(repr=False)

    def minor(self, index: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Residuals ``(M, k)`` (DN) and Jacobian ``(P, M, k)`` at the solution of the candidates
        ``index`` (all when None), zero outside the mask, candidate-minor; new arrays."""
        p, y, w = self.params.T, self.y, self.weights
        if index is not None:
            p, y = p[:, index], y[:, index]
            w = None if w is None else w[:, index]
        return _evaluate(self.model, p, y, w)

    @functools.cached_property
    def _at_solution(self) -> tuple[np.ndarray, np.ndarray]:
        return self.minor()

    @property
    def jac(self) -> np.ndarray:
        return self._at_solution[1].transpose(2, 1, 0)

    @property
    def residuals(self) -> np.ndarray:
        return self._at_solution[0].T


def fit_batch(model, y: np.ndarray, mask: np.ndarray, p0: np.ndarray, lower: np.ndarray,
              upper: np.ndarray, n_iter: int = 12, tol: float = 1e-5, *, minor: bool = False,
              normal=None, noise_var: np.ndarray | None = None, stop_chi2: float = STOP_CHI2,
              misfit_stop: float | None = None) -> FitResult:
    """Levenberg–Marquardt least squares for a stack of independent windows.

    A candidate stops when an accepted step lowers its cost by less than ``tol`` (relative), or,
    given its ``noise_var``, instead as soon as what is left to gain is below ``stop_chi2`` in χ²
    (see the notes), or after ``n_iter`` steps; stopped candidates leave the working set, so the
    usual 2–3 steps cost what they cost and a few hard ones do not slow down the rest.

    Parameters
    ----------
    model : callable
        ``model(p) -> (mu (n, M), jac (n, M, P))`` for any subset of candidates ``p (n, P)``; with
        ``minor``, ``model(p (P, n)) -> (mu (M, n), jac (P, M, n))`` (:func:`minor_model_1d`,
        :func:`minor_model_2d`), which is faster.
    y : (n, M) float array, DN
        Windows, flattened; ``(M, n)`` with ``minor``.
    mask : (n, M) bool array
        Pixels that take part in the fit; ``(M, n)`` with ``minor``.
    p0 : (n, P) float array
        Start values.
    lower, upper : (P,) float arrays
        Box bounds: a parameter on its bound that the cost pushes outwards is held there while the
        others take the step of the reduced system, and steps are clipped to the bounds.
    n_iter : int
        Most iterations.
    tol : float
        Relative cost decrease below which a candidate has converged (without ``noise_var``).
    minor : bool
        Model, data and mask are candidate-minor (see the module notes).
    normal : callable, optional
        With ``minor``: ``normal(p (P, k), y (M, k), w (M, k) or None) -> (Σ r² (k,), JᵀJ (P, P, k)
        (lower triangle), Jᵀr (P, k))``, the weighted cost and normal equations of ``model``, for a
        model whose structure gives them more cheaply than its dense Jacobian (``w`` the mask as 0/1
        floats, None where every pixel is fitted). ``model`` is then evaluated only at the solution.
        It may also set parameters of ``p`` in place before forming them (those that enter the
        model linearly, to their optimum for the others: variable projection); the fit carries
        what it leaves there.
    noise_var : (n,) float array, optional
        Noise variance σ² of each candidate's pixels, units of ``y²``; switches on the statistical
        stop rule and the step-length correction (see the notes).
    stop_chi2 : float
        With ``noise_var``: a candidate stops when what is left to gain is at most
        ``stop_chi2 · σ²``.
    misfit_stop : float, optional
        With ``noise_var``: a candidate whose χ²/dof exceeds ``misfit_stop`` times its
        ``MISFIT_LEVEL`` quantile ``q`` (a window the model does not describe) stops in units of
        its residual variance ``s² = χ²/dof · σ²`` over ``misfit_stop · q`` instead of ``σ²`` (see
        the notes). Default: every candidate in units of ``noise_var``.

    Returns
    -------
    FitResult

    Notes
    -----
    Along a step ``δ`` the cost is ``c(p + tδ) ≈ c(p) − t g + t² κ h`` with ``g = 2 Jᵀr · δ`` and
    ``h = δᵀ JᵀJ δ``: ``κ = 1`` for Gauss–Newton; where large residuals make the true curvature
    differ from ``JᵀJ``'s, ``κ`` is measured along the last step from its actual decrease ``Δc``,
    ``κ = (g − Δc) / h``. The most the line can still gain is ``g² / (4 κ h)``, and a candidate
    stops when that is at most ``stop_chi2 · σ²``, at low damping (where the step is
    Gauss–Newton's and points at the minimum). What is left to gain there is ``δ*ᵀ JᵀJ δ*``, ``δ*``
    the distance to the minimum, and ``δ*_k² ≤ (δ*ᵀ JᵀJ δ*) (JᵀJ)⁻¹_kk`` for every parameter ``k``:
    the stop leaves each parameter within ``√stop_chi2`` of its own standard deviation
    ``σ √((JᵀJ)⁻¹_kk)`` of the minimum. It is decided before the step is taken: no evaluation is
    spent on confirming convergence. The step is scaled by ``1 / κ`` (within ``_STEP_SCALES``), a
    secant correction of its length that turns the slow zig-zag of Gauss–Newton on large residuals
    into a few steps. The relative tolerance is then not used: a step that gains little says only
    that the step was short (after a step that overshot, ``1 / κ`` shortens the next one four-fold),
    not that the minimum is near; on the colour fit's whitened windows (χ²/dof about 20) it stopped
    fits up to 10 χ² short of their minimum, and the 99th percentile of the centres' distance from
    the fully converged ones was 0.11 of their σ instead of 0.06.

    On a window the model does not describe (texture, a printed edge) the residuals are not noise:
    its χ²/dof is tens to hundreds, and Gauss–Newton, whose ``JᵀJ`` leaves out the curvature that
    large residuals add, crawls along the valley where peak, width and background trade off,
    gaining a fraction of a σ² per accepted step at low damping (its steps are accepted, its
    damping falls) until ``n_iter``. With ``misfit_stop`` the stop's unit is the larger of ``σ²``
    and ``s² / (misfit_stop · q)``: unchanged for a window that fits or nearly does, it grows with
    the scatter of one that does not, whose parameters then stop within ``√stop_chi2`` of the σ
    that ``s² / (misfit_stop · q)`` gives them.

    Between iterations a candidate carries only its parameters, cost, damping and normal equations
    ``JᵀJ``, ``Jᵀr`` (``P² + P`` numbers), not its Jacobian and residuals: the working set is
    compacted as candidates leave it without copying ``(P, M, n)`` arrays, and the Jacobian and
    residuals of the result are evaluated once, at the solution (moving them out of the working set
    costs about as much), and only when asked for (:class:`FitResult`); ``(JᵀJ)⁻¹`` is that of the
    carried normal equations.
    """
    if not minor:
        user_model = model

        def model(pt):
            mu, jac = user_model(pt.T)
            return mu.T, jac.transpose(2, 1, 0)

        y, mask = y.T, mask.T
    lower = np.asarray(lower, float)[:, None]
    upper = np.asarray(upper, float)[:, None]
    w = None if mask.all() else mask.astype(np.float64)  # None: every pixel is fitted
    n_par = p0.shape[1]
    dof = mask.sum(axis=0) - n_par
    p = _clip(np.array(np.asarray(p0).T, dtype=float, order="C"), lower, upper)  # (P, n)
    n = p.shape[1]
    evaluate = normal or functools.partial(_evaluate, model, normal=True)
    # the working set: candidates still iterating, their data and state (views until one leaves)
    idx = np.arange(n)
    ya, wa, pa = y, w, p
    cost, hess, grad = evaluate(pa, ya, wa)
    statistical = noise_var is not None
    if statistical:
        stop = stop_chi2 * np.asarray(noise_var, float) * np.ones(n)
        if misfit_stop is not None:  # the cost above which the stop's unit grows with it
            dof_1 = np.maximum(dof, 1)
            scatter = (misfit_stop / stop_chi2) * dof_1 * _misfit_limit(dof_1) * stop
        curvature = np.ones(n)  # along the last step, over Gauss–Newton's (1 until a step measures it)
    lam = np.full(n, _LAMBDA0)
    converged = np.zeros(n, bool)
    # the candidates' final state, written as they leave the working set
    p_out, cost_out, hess_out = np.empty_like(p), np.empty_like(cost), np.empty_like(hess)
    for step_count in range(n_iter + 1):
        # a parameter on its bound that the cost pushes outwards is held there (projected step)
        held = ((pa <= lower) & (grad <= 0.0)) | ((pa >= upper) & (grad >= 0.0))
        step = damped_solve(*(_held(hess, grad, held) if held.any() else (hess, grad)), lam)
        leave = converged | (lam >= 1e10)
        if statistical:  # 1 / curvature within _STEP_SCALES (the longest where it is not positive)
            step *= np.maximum(1.0 / np.maximum(curvature, 1.0 / _STEP_SCALES[1]), _STEP_SCALES[0])
        p_try = _clip(pa + step, lower, upper)
        if statistical:
            # what is left to gain along the step, lin² / (4 curvature quad), with the curvature
            # measured along the last one (see the notes); only at low damping, where the step is
            # Gauss–Newton's
            lin, quad = _step_terms(hess, grad, p_try - pa)
            unit = stop
            if misfit_stop is not None:  # (a zero noise variance keeps its zero unit)
                unit = stop * np.maximum(np.divide(cost, scatter, out=np.ones_like(cost), where=scatter > 0), 1.0)
            leave |= (lam <= _LAMBDA0) & (lin * lin <= 4.0 * unit * curvature * quad)
        if step_count == n_iter:
            leave[:] = True
        if leave.any():
            out = np.flatnonzero(leave)
            done = idx[out]
            p_out[:, done], cost_out[done], hess_out[..., done] = pa[:, out], cost[out], hess[..., out]
            keep = np.flatnonzero(~leave)
            idx, ya, pa, p_try, cost, hess, grad, lam = (
                np.take(a, keep, axis=-1) for a in (idx, ya, pa, p_try, cost, hess, grad, lam))
            wa = None if wa is None else np.take(wa, keep, axis=-1)
            if statistical:
                stop, lin, quad = (np.take(a, keep) for a in (stop, lin, quad))
                if misfit_stop is not None:
                    scatter = np.take(scatter, keep)
        if idx.size == 0:
            break
        cost_try, hess_try, grad_try = evaluate(p_try, ya, wa)
        accepted = cost_try < cost
        # with noise_var the statistical rule replaces the relative tolerance (see the notes)
        converged = np.zeros_like(accepted) if statistical else accepted & (cost - cost_try <= tol * cost)
        if statistical:  # a zero step measures nothing: 1
            curvature = np.divide(lin - (cost - cost_try), quad, out=np.ones_like(quad), where=quad > 0.0)
        lam = np.where(accepted, lam * _LAMBDA_DOWN, lam * _LAMBDA_UP)
        if accepted.all():
            pa, cost, hess, grad = p_try, cost_try, hess_try, grad_try
        else:  # the rejected keep their state: one masked pass per array, no boolean gathers
            for kept, tried in ((pa, p_try), (cost, cost_try), (hess, hess_try), (grad, grad_try)):
                np.copyto(kept, tried, where=accepted)
    return FitResult(p_out.T, spd_inverse(hess_out), cost_out, dof, model, y, w)


def _held(hess: np.ndarray, grad: np.ndarray, held: np.ndarray):
    """Normal equations ``hess (P, P, k)``, ``grad (P, k)`` with the parameters ``held (P, k)``
    fixed: their rows and columns cleared but for the diagonal and their gradient zero, so that
    their step is zero and the others' is that of the reduced system; new arrays."""
    n_par = hess.shape[0]
    free = ~held
    h = np.where(free[:, None] & free[None, :], hess, 0.0)
    h.reshape(n_par * n_par, -1)[:: n_par + 1] = hess.reshape(n_par * n_par, -1)[:: n_par + 1]
    return h, grad * free


def _step_terms(hess: np.ndarray, grad: np.ndarray, step: np.ndarray):
    """``2 Jᵀr · δ`` and ``δᵀ JᵀJ δ`` ``(k,)`` of the steps ``δ (P, k)`` for the normal equations
    ``hess (P, P, k)`` (lower triangle read) and ``grad (P, k)``: the Gauss–Newton model lowers the
    cost by their difference."""
    n_par = step.shape[0]
    # sums over the few parameters as products summed along axis 0, not einsum, whose fixed cost
    # is most of the time here (the same sums in the same order: same values)
    diag_step = hess.reshape(n_par * n_par, -1)[:: n_par + 1] * step
    quad = (diag_step * step).sum(axis=0)
    for i in range(1, n_par):
        quad += 2.0 * (hess[i, :i] * step[:i]).sum(axis=0) * step[i]
    return 2.0 * (grad * step).sum(axis=0), quad


def _clip(p: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``p`` clipped to the bounds, in place (np.clip's Python wrapper costs more)."""
    np.maximum(p, lower, out=p)
    return np.minimum(p, upper, out=p)


def _evaluate(model, p: np.ndarray, y: np.ndarray, w: np.ndarray | None, normal: bool = False):
    """Weighted residuals ``r (M, k)`` and Jacobian ``(P, M, k)`` of the candidate-minor ``model`` at
    ``p (P, k)``, zero where ``w (M, k)`` is (None: every pixel fitted); with ``normal``, instead
    the cost ``Σ r² (k,)`` and the normal equations ``JᵀJ (P, P, k)`` (lower triangle) and
    ``Jᵀr (P, k)``."""
    mu, jac = model(p)
    r = y - mu
    if w is not None:
        jac *= w
        r *= w
    if not normal:
        return r, jac
    return np.einsum("mn,mn->n", r, r), gram(jac), np.einsum("imn,mn->in", jac, r)


#: Significance level above which a window's χ² is taken as model misfit (not noise).
MISFIT_LEVEL = 0.999


def centre_misfit(jac: np.ndarray, info_inv: np.ndarray, residuals: np.ndarray, pixel_var: np.ndarray,
                  dof: np.ndarray, centre: tuple[int, ...], clusters: np.ndarray | None = None) -> np.ndarray:
    """Variance inflation of the centre where the model does not explain the window.

    With the noise model right, χ²/dof of a window scatters around 1 and the covariance is right
    as it is. Where χ² exceeds its ``MISFIT_LEVEL`` quantile the model does not explain the window
    (a halo, texture, a nearby reflection, shot noise beyond the model), but how much that matters
    depends on where: the centre moves with the pixels by ``δx0 = Σ_i a_i δy_i``, ``a`` its row of
    ``(JᵀJ)⁻¹ Jᵀ``, so a misfit at the window's end (a printed edge) hardly moves it and one on the
    flanks does. Such windows get the sandwich ratio ``Σ a_i² r_i² / Σ a_i² v_i`` (residuals
    ``r``, modelled pixel variances ``v``): what the residuals say about the centre's variance over
    what the noise model says (at least 1). Scaling by the whole window's χ²/dof instead overstated
    the σ of stripes beside printed edges three-fold. Where neighbouring pixels' errors are
    correlated (demosaicing, subsampled chroma), ``clusters`` groups them and the numerator is the
    cluster-robust ``Σ_c (Σ_{i∈c} a_i r_i)²``: errors that move together count as they add up.
    Its denominator is then what that sum would be for independent whitened pixels,
    ``Σ a_i² − Σ_c u_cᵀ (JᵀJ)⁻¹ u_c`` with ``u_c = Σ_{i∈c} a_i J_i``: the residuals are orthogonal to
    ``a`` (``Σ a_i r_i = 0``), so the clusters' sums fall short of ``Σ a_i²`` by their leverage,
    which is large where a few clusters carry the centre. With ``clusters`` every window gets the
    ratio, as correlated noise does not show in χ².

    Parameters
    ----------
    jac : (P, M, n) float array
        Candidate-minor Jacobian at the solution (zero on pixels not fitted).
    info_inv : (n, P, P) float array
        ``(JᵀJ)⁻¹``.
    residuals : (M, n) float array
    pixel_var : (M, n) float array
        Modelled variance of each fitted pixel (0 where not fitted), in the units of ``residuals²``.
    dof : (n,) int array
        Degrees of freedom of each fit.
    centre : tuple of int
        Indices of the centre's parameters (one for a stripe, two for a spot); their ratios are
        averaged.
    clusters : (M, n) int array, optional
        Label of each pixel's group of correlated pixels within its window, from 0 (default: every
        pixel its own); for whitened windows only (``pixel_var`` 1 where fitted, 0 elsewhere).

    Returns
    -------
    (n,) float array
        Factor ≥ 1 for the covariance.
    """
    dof = np.maximum(dof, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        chi2 = np.where(pixel_var > 0, residuals**2 / pixel_var, 0.0).sum(axis=0)
    misfit = misfits(chi2, dof) | (clusters is not None)
    factor = np.ones(dof.size)
    if misfit.any():
        a = np.einsum("nkj,jmn->kmn", info_inv[misfit][:, list(centre), :], jac[..., misfit])  # (K, M, m)
        if clusters is None:
            factor[misfit] = lever_misfit(a, residuals[:, misfit], pixel_var[:, misfit])
        else:
            ar = a * residuals[:, misfit]
            expected = np.einsum("kmn,mn->kn", a * a, pixel_var[:, misfit])
            labels = clusters[:, misfit]
            spread = (_cluster_sums(ar, labels) ** 2).sum(axis=-1)
            lever = _cluster_sums(jac[None, :, :, misfit] * a[:, None], labels)  # u_c, (K, P, m, L)
            expected -= np.einsum("kpnl,npq,kqnl->kn", lever, info_inv[misfit], lever)
            factor[misfit] = _sandwich_factor(spread, expected)
    return factor


def lever_misfit(a: np.ndarray, residuals: np.ndarray, pixel_var: np.ndarray) -> np.ndarray:
    """:func:`centre_misfit`'s factor of windows with independent pixels, from the centre's rows
    ``a (K, M, n)`` of ``(JᵀJ)⁻¹ Jᵀ`` (for a model whose structure gives them without its dense
    Jacobian), ``residuals`` and ``pixel_var (M, n)``: ``Σ a_i² r_i² / Σ a_i² v_i``, averaged over
    the K centre parameters, at least 1 (1 where undefined)."""
    ar = a * residuals
    return _sandwich_factor(np.einsum("kmn,kmn->kn", ar, ar), np.einsum("kmn,mn->kn", a * a, pixel_var))


def _sandwich_factor(spread: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """``spread / expected (K, n)`` averaged over K, at least 1 (1 where undefined), ``(n,)``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (spread / expected).mean(axis=0)
    return np.where(np.isfinite(ratio), np.maximum(ratio, 1.0), 1.0)


def _cluster_sums(values: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Sums of ``values (..., M, n)`` over the pixels of each cluster of ``labels (M, n)`` (ints
    from 0, per window), ``(..., n, L)``: one bincount per leading index over (window, cluster) bins."""
    n_labels = int(labels.max()) + 1
    n = labels.shape[1]
    bins = (labels + n_labels * np.arange(n)).ravel()
    flat = values.reshape(-1, labels.size)
    sums = np.stack([np.bincount(bins, weights=row, minlength=n_labels * n) for row in flat])
    return sums.reshape(*values.shape[:-2], n, n_labels)


def misfits(chi2: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """Whether each window's ``chi2 (n,)`` exceeds its ``MISFIT_LEVEL`` quantile for ``dof (n,)``
    (at least 1)."""
    return chi2 / dof > _misfit_limit(dof)


def _misfit_limit(dof: np.ndarray) -> np.ndarray:
    """χ²/dof at the ``MISFIT_LEVEL`` quantile for each of ``dof (n,)`` (ints, at least 1)."""
    table_size = max(64, 1 << (int(dof.max(initial=1)) - 1).bit_length())  # few distinct tables
    return _misfit_limits(table_size)[dof - 1]


@functools.lru_cache(maxsize=16)
def _misfit_limits(max_dof: int) -> np.ndarray:
    """χ²/dof at the ``MISFIT_LEVEL`` quantile for dof = 1 .. ``max_dof`` (chdtri is slow)."""
    from scipy.special import chdtri  # inverse survival function of χ²: no scipy.stats

    dof = np.arange(1, max_dof + 1)
    limits = chdtri(dof, 1.0 - MISFIT_LEVEL) / dof
    limits.flags.writeable = False
    return limits


#: The shot-noise slope is used only when it exceeds this many standard errors.
SHOT_NOISE_SIGNIFICANCE = 3.0
#: About this many candidates, spread over the frame, estimate the frame's shot-noise slope.
_SLOPE_SAMPLE = 256


def parameter_covariance(res: FitResult, noise_sigma: np.ndarray, centre: tuple[int, ...] = (1,),
                         correlation: np.ndarray | None = None, shot_slope: float | None = None) -> np.ndarray:
    """Covariance of the fitted parameters, honest under signal-dependent (shot) noise.

    The pixel variance is modelled as ``σ_c² + k · s_i``: σ_c the local background noise of the
    candidate, ``s_i = A g_i`` the fitted signal above background (both models have the peak first,
    so ``s = A ∂μ/∂A``), and ``k`` (DN per DN) one slope per frame, pooled over the fitted pixels
    of about ``_SLOPE_SAMPLE`` candidates spread over the frame, from the leverage-corrected squared
    residuals: ``r_i² / (1 − h_ii) − σ_c²`` regressed on ``s_i``. ``k`` is used only when it
    exceeds ``SHOT_NOISE_SIGNIFICANCE`` standard errors, so white noise keeps the plain
    ``σ² (JᵀJ)⁻¹``. The least-squares estimate is unweighted;
    under the modelled variance its covariance is the sandwich ``(JᵀJ)⁻¹ Jᵀ V J (JᵀJ)⁻¹``. Finally
    :func:`centre_misfit` inflates fits whose χ² is still significant, by what their residuals
    say about the centre. Noise correlated between neighbouring pixels of a 1-D window (demosaicing,
    JPEG) enters the sandwich as ``V^½ R V^½``, ``R`` the correlation at each pixel lag.

    Parameters
    ----------
    res : FitResult
    noise_sigma : (n,) float array, DN
        Background noise σ at each candidate.
    centre : tuple of int
        Indices of the centre's parameters, for :func:`centre_misfit`.
    correlation : (L,) float array, optional
        Noise correlation between pixels ``0 .. L − 1`` apart along a 1-D window (``correlation[0]
        = 1``; beyond ``L − 1``, 0). Default: white noise.
    shot_slope : float, optional
        Known shot-noise slope ``k``, DN per DN of signal; default: pooled from the residuals.

    Returns
    -------
    (n, P, P) float array
        Covariance of the parameters (units of the parameters). NaN where singular.
    """
    info = res.info_inv  # (n, P, P)
    base_var = noise_sigma**2
    good = np.all(np.isfinite(info), axis=(1, 2))
    usable = np.flatnonzero(good)  # the pooled slope needs only an evenly spread sample of them
    sample = usable[:: max(1, usable.size // _SLOPE_SAMPLE)]
    slope = 0.0 if shot_slope is None else shot_slope
    if shot_slope is None and sample.size:
        rg, jg = res.minor(sample)  # (M, k), (P, M, k)
        if sample.size < MATMUL_MAX:
            jk = jg.transpose(2, 1, 0)  # (k, M, P)
            leverage = ((jk @ info[sample]) * jk).sum(axis=2).T
        else:
            info_t = np.ascontiguousarray(info[sample].transpose(1, 2, 0))  # (P, P, k)
            leverage = np.einsum("jmk,jmk->mk", np.einsum("imk,ijk->jmk", jg, info_t), jg)
        f = (jg[-1] != 0) & (leverage < 0.9)  # fitted: the background derivative is 1 there
        var_sample = base_var[sample]
        x = (jg[0] * res.params[sample, 0])[f]
        t = rg[f] ** 2 / (1.0 - leverage[f]) - (np.zeros(f.shape) + var_sample)[f]
        sxx = float(np.dot(x, x))
        if sxx > 0:
            slope = float(np.dot(x, t)) / sxx
            standard_error = np.sqrt(2.0) * (float(var_sample.sum()) / var_sample.size) / np.sqrt(sxx)
            if slope < SHOT_NOISE_SIGNIFICANCE * standard_error:
                slope = 0.0
    factor = np.ones(len(info))
    if slope > 0.0 or correlation is not None:
        r, jac = res.minor()
        signal = jac[0] * res.params[:, 0]  # both models have the peak first
        pixel_var = np.where(jac[-1] != 0, base_var + slope * np.maximum(signal, 0.0), 0.0)
        cov = info @ _meat(jac, pixel_var, correlation) @ info
        if good.any():
            pick = slice(None) if usable.size == good.size else usable  # views where every fit is usable
            factor[pick] = centre_misfit(jac[..., pick], info[pick], r[:, pick], pixel_var[:, pick], res.dof[pick],
                                         centre)
    else:
        cov = base_var[:, None, None] * info
        # white noise: a window's χ² is its cost over σ², and only the misfits need their residuals
        # (centre_misfit tests them again, on these)
        maybe = usable[misfits(res.chi2_unit[usable] / base_var[usable], np.maximum(res.dof[usable], 1))]
        if maybe.size:
            r, jac = res.minor(maybe)
            factor[maybe] = centre_misfit(jac, info[maybe], r, np.where(jac[-1] != 0, base_var[maybe], 0.0),
                                          res.dof[maybe], centre)
    return cov * factor[:, None, None]


def _meat(jac: np.ndarray, pixel_var: np.ndarray, correlation: np.ndarray | None) -> np.ndarray:
    """``Jᵀ V^½ R V^½ J`` ``(n, P, P)`` of the candidate-minor ``jac (P, M, n)``, pixel variances
    ``(M, n)`` and the correlation ``R`` at pixel lags ``0 .. L − 1`` (None: ``R = I``)."""
    if correlation is None:
        return np.einsum("imn,jmn->nij", jac, jac * pixel_var)
    jw = jac * np.sqrt(pixel_var)
    meat = np.einsum("imn,jmn->nij", jw, jw)
    for lag in range(1, min(len(correlation), jac.shape[1])):  # a few lags, each over all candidates
        cross = np.einsum("imn,jmn->nij", jw[:, :-lag], jw[:, lag:])
        meat += correlation[lag] * (cross + cross.transpose(0, 2, 1))
    return meat

