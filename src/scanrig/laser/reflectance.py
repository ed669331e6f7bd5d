"""A step in the surface's reflectance under the beam: a printed edge multiplies trace and background.

The light leaving a grey surface is its reflectance ``ρ`` times the light falling on it, ambient
and laser alike, and black ink is grey, so a printed edge across a fit window scales every
channel's background and the laser's profile by the same ``ρ_i``. The colour model
``μ_ci = b_c + a_c · g_i`` (:mod:`scanrig.laser.colour_fit`) cannot follow that: its background is
one level per channel, and the profile it fits is skewed towards the brighter side. Here any such
model is multiplied by a blurred step common to the channels,

    μ_ci = ρ_i · (b_c + a_c · g_i),    ρ_i = exp(d · Φ((x_i − e) / w)),

``Φ`` the standard normal CDF at the pixel's centre, ``d`` the step in log-reflectance (black ink
on white paper: about −2.6), ``e`` the edge's position, px, and ``w`` its blur (optics,
demosaicing and compression), fixed at ``EDGE_WIDTH_PX``. The channels away from the beam (and the
weak crosstalk copies of the profile everywhere) pin the step; the laser channel's flanks then give
the centre.

The two extra parameters are fitted only where the plain model is known to be wrong, and kept only
where the data support them: the F test of :func:`step_is_significant`.
"""

from __future__ import annotations

import numpy as np
from scipy.special import fdtri, ndtr

#: Parameters appended to the plain model's.
PARAMS = ("log_step", "edge")
#: Bound of the log-reflectance step either way (a factor of 400).
MAX_LOG_STEP = 6.0
#: The edge's blur, px: a pixel-sharp printed edge after Bayer demosaicing and compression (on the
#: rendered colour set, fitting it instead, 0.3-3 px, gave the same accuracy for 10 % more time).
EDGE_WIDTH_PX = 1.0
#: The step model is kept where its F statistic over the plain model exceeds this quantile.
STEP_LEVEL = 0.999
_INV_ROOT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


def with_step(model, x: np.ndarray, n_channels: int):
    """The model ``model`` times a reflectance step common to its channels.

    Parameters
    ----------
    model : callable
        Candidate-minor model ``p (P, n) -> mu (C W, n), jac (P, C W, n)`` (channel-major pixels,
        whitened or not: the step scales both alike).
    x : (W,) float array
        Pixel centres along the line, px from the window's middle.
    n_channels : int
        Channels ``C`` of the model.

    Returns
    -------
    callable
        ``p (P + 2, n) -> mu (C W, n), jac (P + 2, C W, n)``, the last two parameters
        :data:`PARAMS`.
    """
    xc = x[:, None]

    def stepped(p):
        n_plain, n = p.shape[0] - 2, p.shape[1]
        mu0, jac0 = model(p[:n_plain])
        d, e = p[n_plain], p[n_plain + 1]
        t = (xc - e) * (1.0 / EDGE_WIDTH_PX)  # (W, n)
        cdf = ndtr(t)
        rho = np.exp(d * cdf)  # (W, n), the same on every channel
        dlog = np.empty((2, 1) + t.shape)  # ∂ log ρ / ∂(d, e)
        dlog[0, 0] = cdf
        dlog[1, 0] = d * (-_INV_ROOT_2PI / EDGE_WIDTH_PX) * np.exp(-0.5 * t * t)
        mu = mu0.reshape(n_channels, -1, n) * rho  # (C, W, n)
        jac = np.empty((n_plain + 2,) + mu.shape)
        np.multiply(jac0.reshape(n_plain, n_channels, -1, n), rho, out=jac[:n_plain])
        np.multiply(dlog, mu, out=jac[n_plain:])
        return mu.reshape(-1, n), jac.reshape(n_plain + 2, -1, n)

    return stepped


def reflectance_at(x: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Reflectance ``ρ`` relative to the left side at ``x (n,)`` px for the fitted ``step (n, 2)``
    (:data:`PARAMS`)."""
    return np.exp(step[:, 0] * ndtr((x - step[:, 1]) / EDGE_WIDTH_PX))


def step_bounds(half: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of :data:`PARAMS` for a window of ``± half`` pixels."""
    return np.array([-MAX_LOG_STEP, -half]), np.array([MAX_LOG_STEP, half])


def step_start(y: np.ndarray, mu: np.ndarray, usable: np.ndarray, noise: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Start values of the step from the plain model's fit: the split of the window that best
    separates the data's log-ratio to that fit into two levels.

    Each usable pixel well above the noise in both data and model gives ``log(y / μ)``, weighted
    by ``(μ / σ)²`` (its inverse variance); the channels are pooled at each position, and of the
    ``W − 1`` splits between neighbouring pixels the one with the largest weighted between-levels
    sum of squares is taken.

    Parameters
    ----------
    y, mu : (n, W, C) arrays
        Data and the plain model's fit, DN.
    usable : (n, W, C) bool array
    noise : (C,) array
        Each channel's noise σ, DN.
    x : (W,) float array
        Pixel centres, px.

    Returns
    -------
    (n, 3) array
        ``log_left`` (the left level's log-ratio: the plain model's per-channel parameters are
        scaled by its exponential), then start values of :data:`PARAMS`.
    """
    floor = 3.0 * noise
    good = usable & (y > floor) & (mu > floor)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(good, np.log(np.where(good, y / mu, 1.0)), 0.0)
    weight = np.where(good, (mu / noise) ** 2, 0.0)
    s_w = weight.sum(axis=2)  # (n, W)
    s_wl = (weight * ratio).sum(axis=2)
    left_w, left_wl = np.cumsum(s_w, axis=1)[:, :-1], np.cumsum(s_wl, axis=1)[:, :-1]  # split after pixel k
    right_w, right_wl = s_w.sum(axis=1, keepdims=True) - left_w, s_wl.sum(axis=1, keepdims=True) - left_wl
    with np.errstate(divide="ignore", invalid="ignore"):
        mean_l, mean_r = left_wl / left_w, right_wl / right_w
        score = np.where((left_w > 0) & (right_w > 0), (mean_r - mean_l) ** 2 * left_w * right_w / (left_w + right_w),
                         -1.0)
    k = np.argmax(score, axis=1)
    pick = np.arange(y.shape[0])
    level_l, level_r = np.nan_to_num(mean_l[pick, k]), np.nan_to_num(mean_r[pick, k])
    log_step = np.clip(level_r - level_l, -MAX_LOG_STEP, MAX_LOG_STEP)
    return np.stack([level_l, log_step, x[k] + 0.5], axis=1)


def step_is_significant(chi2_plain: np.ndarray, chi2_step: np.ndarray, dof_step: np.ndarray) -> np.ndarray:
    """Whether the step model explains the window significantly better than the plain one.

    The F test of nested least-squares models, ``F = ((χ²_plain − χ²_step) / k) / (χ²_step / dof)``
    (``k`` = 2, the step's parameters) against its ``STEP_LEVEL`` quantile: the residual variance of the step model is the scale, so a
    model misfit common to both (a halo, compression) does not count as evidence for a step.

    Parameters
    ----------
    chi2_plain, chi2_step : (n,) float arrays
        Weighted sums of squared residuals of the two fits on the same pixels.
    dof_step : (n,) int array
        Degrees of freedom of the step model's fit.

    Returns
    -------
    (n,) bool array
    """
    dof = np.maximum(dof_step, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = (chi2_plain - chi2_step) / len(PARAMS) / (chi2_step / dof)
    return (dof_step > 0) & (f > fdtri(len(PARAMS), dof, STEP_LEVEL))
