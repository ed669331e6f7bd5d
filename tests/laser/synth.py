"""Synthetic laser frames for tests and benchmarks: pixel-integrated Gaussians, noise, rounding.

Independent of ``scanrig.laser.fit`` on purpose (the truth must not share code with the
estimator): pixel integration uses ``scipy.special.ndtr`` differences directly.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr


def integrated(x: np.ndarray, centre, sigma) -> np.ndarray:
    """Unit-peak Gaussian of width ``sigma`` integrated over pixels centred at ``x``."""
    return np.sqrt(2 * np.pi) * sigma * (ndtr((x + 0.5 - centre) / sigma) - ndtr((x - 0.5 - centre) / sigma))


def quantize(values: np.ndarray, dtype=np.uint8) -> np.ndarray:
    """Round and clip to an integer image type (saturation included)."""
    top = np.iinfo(dtype).max
    return np.clip(np.rint(values), 0, top).astype(dtype)


def profiles(rng, n: int, sigma: float, amplitude=180.0, background=10.0, noise=2.0, half=15,
             dtype=np.uint8):
    """``n`` stripe profiles with true centres uniform in ±0.5 px around pixel ``half``.

    Returns
    -------
    y : (n, 2 * half + 1) integer array
    true_x : (n,) float, pixel coordinate of the centre
    """
    x = np.arange(2 * half + 1, dtype=float)
    true_x = half + rng.uniform(-0.5, 0.5, n)
    mu = background + amplitude * integrated(x[None, :], true_x[:, None], sigma)
    return quantize(mu + rng.normal(0.0, noise, mu.shape), dtype), true_x


def spot_image(shape, spots, rng, background=10.0, noise=2.0, dtype=np.uint8) -> np.ndarray:
    """A frame with Gaussian spots.

    Parameters
    ----------
    shape : (H, W)
    spots : sequence of (u, v, amplitude, sigma_u, sigma_v)
    """
    h, w = shape
    img = np.full(shape, float(background))
    for u, v, a, su, sv in spots:
        r = int(np.ceil(6 * max(su, sv))) + 1
        v0, v1 = max(int(v) - r, 0), min(int(v) + r + 1, h)
        u0, u1 = max(int(u) - r, 0), min(int(u) + r + 1, w)
        gv = integrated(np.arange(v0, v1, dtype=float), v, sv)
        gu = integrated(np.arange(u0, u1, dtype=float), u, su)
        img[v0:v1, u0:u1] += a * gv[:, None] * gu[None, :]
    if noise:
        img += rng.normal(0.0, noise, shape)
    return quantize(img, dtype)


def stripe_image(shape, centre_of_line, rng, amplitude=180.0, sigma=1.5, background=10.0, noise=2.0,
                 dtype=np.uint8, along="rows") -> np.ndarray:
    """A frame with a stripe crossing every row (``along="rows"``) or every column.

    ``centre_of_line(line_index_array) -> centre`` gives the true sub-pixel centre on each line,
    so the stripe may be straight, tilted or curved; the profile along a line is a pixel-integrated
    Gaussian of width ``sigma`` (the width along the scan line, not across the stripe).
    """
    h, w = shape
    n_lines, n_pos = (h, w) if along == "rows" else (w, h)
    lines = np.arange(n_lines, dtype=float)
    centres = np.asarray(centre_of_line(lines), float)
    prof = amplitude * integrated(np.arange(n_pos, dtype=float)[None, :], centres[:, None], sigma)
    img = background + (prof if along == "rows" else prof.T)
    if noise:
        img = img + rng.normal(0.0, noise, shape)
    return quantize(img, dtype)
