"""Hampel's hyperbolic-tangent influence function, its loss, and the robust noise scale.

The influence function is the one of Chen & Jain's robust back-propagation, with residual
``r = z - zhat`` and cut-offs ``a < b`` (metres) and slope ``beta`` (1/metre)::

    psi(r) = r                                   |r| <= a
           = a tanh(beta (b - |r|)) sgn(r)       a < |r| <= b
           = 0                                   |r| > b

Its integral ``rho`` (the loss that back-propagation minimises) has a closed form, see
:func:`hampel_rho`. ``psi``, ``rho`` and the IRLS weight are written once and take numpy arrays or
torch tensors alike (the training loop of :mod:`scanrig.surface.robust_fit` passes tensors, and
autograd runs through them); torch is never imported for numpy input. The cut-offs follow the noise scale: ``a = p sigma``, ``b = r sigma``,
``beta = gamma / sigma`` with ``(p, r, gamma)`` from the Hampel-Rousseeuw-Ronchetti optimal
tanh estimator (``r = 4, k = 4.5``: ``p = 1.634, gamma = 0.915``, 95.6 % Gaussian efficiency).

The noise scale is a trimmed scale with breakdown point ``q`` (the tolerated fraction of bad
data), made consistent for Gaussian inliers, and bounded above by a residual-bootstrap
percentile (:func:`robust_scale`).

Notes
-----
Formulas and constants: ``/shared/reference/robust-filtering.md`` sections 1.2-1.5 and
``docs/surface-filter.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

from scanrig.errors import InputError

_TINY = 1e-30  # divisor floor of psi(r) / r; smaller residuals lie inside ``a`` and have weight 1


@dataclass(frozen=True)
class HampelConstants:
    """Cut-offs of the tanh estimator in units of the noise scale sigma.

    Attributes
    ----------
    p : float
        End of the quadratic part: ``a = p * sigma``.
    r : float
        Rejection point: ``b = r * sigma``; residuals beyond it have zero influence.
    gamma : float
        Redescent slope: ``beta = gamma / sigma``.
    """

    p: float = 1.634
    r: float = 4.0
    gamma: float = 0.915

    def __post_init__(self):
        if not (0.0 < self.p < self.r) or self.gamma <= 0.0:
            raise InputError(f"Hampel constants need 0 < p < r and gamma > 0, got {self}")


def check_q(q: float) -> float:
    """Return the tolerated bad-data fraction ``q`` as a float in ``(0, 0.5]`` or raise."""
    try:
        q = float(q)
    except (TypeError, ValueError):
        raise InputError(f"q must be a number in (0, 0.5], got {q!r}") from None
    if not (0.0 < q <= 0.5):
        raise InputError(f"q (tolerated fraction of bad data) must be in (0, 0.5], got {q}")
    return q


def hampel_psi(r, a, b, beta):
    """Influence function psi(r) of Chen & Jain's Hampel tanh loss.

    Parameters
    ----------
    r : (...) float array or torch tensor
        Residuals ``z - zhat`` in metres.
    a, b : float, array or tensor broadcastable to ``r``
        Cut-offs in metres, ``0 < a < b``.
    beta : float, array or tensor broadcastable to ``r``
        Redescent slope in 1/metre.

    Returns
    -------
    (...) float array, or tensor for a tensor ``r``
        psi(r) in metres.
    """
    xp, r = _namespace(r)
    ar = xp.abs(r)
    mid = a * xp.tanh(beta * (b - ar)) * xp.sign(r)
    return xp.where(ar <= a, r, xp.where(ar <= b, mid, 0.0))


def hampel_rho(r, a, b, beta):
    """Loss rho(r) = integral of psi from 0 to r (closed form), in square metres.

    ``rho = r^2/2`` for ``|r| <= a``; ``a^2/2 + (a/beta) ln(cosh(beta (b-a)) / cosh(beta (b-|r|)))``
    for ``a < |r| <= b``; constant beyond ``b``. Parameters as in :func:`hampel_psi`.
    """
    xp, r = _namespace(r)
    ar = xp.abs(r)
    tail = 0.5 * a**2 + (a / beta) * (_logcosh(beta * (b - a)) - _logcosh(beta * (b - ar.clip(max=b))))
    return xp.where(ar <= a, 0.5 * r**2, tail)


def hampel_weight(r, a, b, beta):
    """IRLS weight ``psi(r) / r`` in [0, 1]: 1 inside ``a``, 0 beyond ``b``. Parameters as in :func:`hampel_psi`."""
    xp, r = _namespace(r)
    ar = xp.abs(r)
    mid = a * xp.tanh(beta * (b - ar)) / ar.clip(min=_TINY)  # r = 0 takes the first branch (weight 1)
    return xp.where(ar <= a, 1.0, xp.where(ar <= b, mid, 0.0))


def _namespace(r):
    """``(module, r)``: torch and ``r`` for a torch tensor, else numpy and ``r`` as a float array.

    The formulas above use only functions both modules name alike (``abs``, ``tanh``, ``sign``,
    ``where``, the ``clip`` method), so each is written once for both.
    """
    if type(r).__module__.startswith("torch"):
        import torch

        return torch, r
    return np, np.asarray(r, dtype=float)


def _logcosh(x):
    """Numerically stable ln cosh(x) = |x| + ln(1 + exp(-2|x|)) - ln 2, of an array or a tensor."""
    xp, x = _namespace(x)
    x = xp.abs(x)
    softplus = np.log1p(np.exp(-2.0 * x)) if xp is np else xp.nn.functional.softplus(-2.0 * x)
    return x + softplus - math.log(2.0)


def _gauss_pdf(x):
    """Standard normal density."""
    return np.exp(-0.5 * x * x) / np.sqrt(2.0 * np.pi)


def trimmed_consistency(q: float) -> float:
    """Consistency factor kappa_q of the q-trimmed mean square for Gaussian residuals.

    ``E[r^2 | |r| <= c_q] = kappa_q sigma^2`` with ``c_q = Phi^-1(1 - q/2)``, so
    ``kappa_q = 1 - 2 c_q phi(c_q) / (1 - q)``.
    """
    q = check_q(q)
    c = ndtri(1.0 - q / 2.0)
    return float(1.0 - 2.0 * c * _gauss_pdf(c) / (1.0 - q))


def trimmed_scale(residuals: np.ndarray, q: float) -> float:
    """Noise scale from the ``ceil((1-q) n)`` smallest absolute residuals (breakdown point q).

    Parameters
    ----------
    residuals : (n,) float array
        Residuals in metres.
    q : float
        Breakdown point: the fraction of residuals left out, in (0, 0.5].

    Returns
    -------
    float
        ``sqrt(sum_{i<=h} r_(i)^2 / (h kappa_q))`` in metres.
    """
    good = _trimmed_squares(residuals, q)
    return float(np.sqrt(good.mean() / trimmed_consistency(q)))


def _trimmed_squares(residuals: np.ndarray, q: float) -> np.ndarray:
    """The ``ceil((1-q) n)`` smallest squared residuals of a finite, non-empty vector."""
    q = check_q(q)
    r2 = np.square(np.asarray(residuals, dtype=float).ravel())
    if r2.size == 0 or not np.all(np.isfinite(r2)):
        raise InputError("residuals must be a non-empty finite vector")
    h = int(np.ceil((1.0 - q) * r2.size))
    return np.partition(r2, h - 1)[:h]


def truncated_consistency(c: float) -> float:
    """Consistency factor of the mean square of Gaussian residuals truncated at ``|r| <= c sigma``.

    ``E[r^2 | |r| <= c sigma] = kappa(c) sigma^2`` with ``kappa(c) = 1 - 2 c phi(c) / (2 Phi(c) - 1)``.
    """
    return float(1.0 - 2.0 * c * _gauss_pdf(c) / (2.0 * ndtr(c) - 1.0))


def robust_scale(residuals: np.ndarray, q: float, *, rng: np.random.Generator, cut: float = 4.0,
                 n_refine: int = 3, n_boot: int = 200, alpha: float = 0.05) -> tuple[float, float]:
    """Noise scale with breakdown point ``q`` and its bootstrap upper confidence bound.

    1. Start from the q-trimmed scale (:func:`trimmed_scale`); it tolerates a fraction ``q`` of
       arbitrary residuals but over-estimates sigma when fewer than ``q`` are bad.
    2. Refine ``n_refine`` times on the residuals inside ``cut`` times the current scale, with
       the truncated-Gaussian consistency factor (:func:`truncated_consistency`); this removes the
       over-estimate once the bad data lie beyond the cut.
    3. Bootstrap the final "good" set (resample with replacement ``n_boot`` times, recompute the
       scale at the same truncation) and return its ``1 - alpha`` percentile as the upper bound.

    Parameters
    ----------
    residuals : (n,) float array
        Residuals in metres (held-out residuals when the model is flexible).
    q : float
        Tolerated fraction of bad data, in (0, 0.5].
    rng : numpy.random.Generator
        Source of the bootstrap indices.
    cut : float
        Truncation point in units of the scale (the Hampel rejection point ``r``).
    n_refine : int
        Refinement steps.
    n_boot : int
        Bootstrap resamples.
    alpha : float
        One-sided level of the upper bound.

    Returns
    -------
    sigma : float
        Scale estimate in metres.
    sigma_upper : float
        Bootstrap ``1 - alpha`` upper bound in metres.
    """
    sigma, good = refined_scale(residuals, q, cut=cut, n_refine=n_refine)
    idx = rng.integers(0, good.size, size=(n_boot, good.size))
    boot = np.sqrt(good[idx].mean(axis=1) / truncated_consistency(cut))
    return sigma, float(np.quantile(boot, 1.0 - alpha))


def refined_scale(residuals: np.ndarray, q: float, *, cut: float = 4.0, n_refine: int = 3) -> tuple[float, np.ndarray]:
    """Steps 1 and 2 of :func:`robust_scale`: the q-trimmed scale refined inside ``cut`` scales.

    Returns
    -------
    sigma : float
        Scale estimate in metres.
    good : (m,) float array
        Squared residuals of the last refinement's "good" set (all of them if none was made).
    """
    r2 = np.square(np.asarray(residuals, dtype=float).ravel())
    sigma = trimmed_scale(np.sqrt(r2), q)
    kappa = truncated_consistency(cut)
    good = r2
    for _ in range(n_refine):
        inside = r2[r2 <= (cut * sigma) ** 2]
        if inside.size == 0 or sigma == 0.0:
            break
        good = inside
        sigma = float(np.sqrt(good.mean() / kappa))
    return sigma, good
