"""Cramér–Rao bound of a laser trace's centre under additive white Gaussian noise.

For pixel values ``y_i = μ_i(θ) + n_i``, ``n_i ~ N(0, σ²)``, the Fisher information is
``F = JᵀJ / σ²`` with ``J_ik = ∂μ_i/∂θ_k``; the variance of any unbiased estimator of ``θ_k`` is at
least ``(F⁻¹)_kk``. Rounding to integers adds 1/12 DN² to σ² (a good approximation once σ is
above about 0.5 DN). The bound with all parameters unknown (peak, width, background) is the one
a detector faces; the *position-only* bound (``1 / F_x0x0``) assumes the others are known and is
never larger.
"""

from __future__ import annotations

import numpy as np

from scanrig.laser.fit import model_1d, model_2d
from scanrig.laser.noise import QUANTIZATION_SIGMA


def effective_noise(noise_sigma: float, quantized: bool = True) -> float:
    """Noise σ, DN, including rounding to integers when ``quantized``."""
    return float(np.hypot(noise_sigma, QUANTIZATION_SIGMA)) if quantized else float(noise_sigma)


def crb_stripe(peak: float, width_px, offset_px, noise_sigma: float, background: float = 0.0,
               half_window: int = 20, position_only: bool = False) -> np.ndarray:
    """Cramér–Rao bound (standard deviation, pixels) of a stripe profile's centre.

    Parameters
    ----------
    peak : float, DN
        Peak of the continuous Gaussian profile above background.
    width_px : float or array, pixels
        Gaussian σ of the profile.
    offset_px : float or array, pixels
        Centre relative to a pixel centre (broadcast against ``width_px``).
    noise_sigma : float, DN
        Total noise σ (use :func:`effective_noise` for quantised data).
    background : float, DN
        Background level (does not change the bound; kept for a complete parameter vector).
    half_window : int
        The profile is observed on ``±half_window`` pixels, wide enough to hold all its information.
    position_only : bool
        Bound for the centre with peak, width and background known.

    Returns
    -------
    array, pixels
        Bound on the centre's standard deviation, broadcast shape of ``width_px`` and ``offset_px``.
    """
    width, offset = np.broadcast_arrays(np.asarray(width_px, float), np.asarray(offset_px, float))
    p = np.stack([np.full(width.size, peak), offset.ravel(), width.ravel(),
                  np.full(width.size, background)], axis=1)
    x = np.arange(-half_window, half_window + 1, dtype=float)
    _, jac = model_1d(x, p)
    return _centre_bound(jac, noise_sigma, position_only).reshape(width.shape)


def crb_spot(peak: float, width_px, offset_u_px, offset_v_px, noise_sigma: float,
             half_window: int = 12, position_only: bool = False) -> np.ndarray:
    """Cramér–Rao bound (standard deviation, pixels) of a round spot's centre along ``u``.

    Parameters
    ----------
    peak : float, DN
        Peak of the continuous Gaussian above background.
    width_px : float or array, pixels
        Gaussian σ (same along ``u`` and ``v``; the fit does not know that).
    offset_u_px, offset_v_px : float or array, pixels
        Centre relative to a pixel centre.
    noise_sigma : float, DN
        Total noise σ.
    half_window : int
        Observed window ``±half_window`` pixels in both directions.
    position_only : bool
        Bound for ``u0`` with every other parameter known.

    Returns
    -------
    array, pixels
        Bound on the standard deviation of ``u0``.
    """
    width, ou, ov = np.broadcast_arrays(*(np.asarray(a, float) for a in (width_px, offset_u_px, offset_v_px)))
    n = width.size
    p = np.stack([np.full(n, peak), ou.ravel(), ov.ravel(), width.ravel(), width.ravel(),
                  np.zeros(n)], axis=1)
    x = np.arange(-half_window, half_window + 1, dtype=float)
    _, jac = model_2d(x, x, p)
    return _centre_bound(jac, noise_sigma, position_only).reshape(width.shape)


def _centre_bound(jac: np.ndarray, noise_sigma: float, position_only: bool):
    """Bound on the standard deviation of parameter 1 (the centre along u or the line)."""
    fisher = np.einsum("nmi,nmj->nij", jac, jac) / noise_sigma**2
    k = 1
    if position_only:
        return 1.0 / np.sqrt(fisher[:, k, k])
    return np.sqrt(np.linalg.inv(fisher)[:, k, k])
