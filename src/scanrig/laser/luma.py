"""Unclipped traces of a colour frame with a laser-off frame: the luma difference and its noise.

The signal of a coloured laser, the laser channel minus the mean of the two others, is in JPEG's
YCbCr purely colour difference (``R − (G + B)/2 = 1.76 Cr − 0.71 Cb``): stored at half resolution
(4:2:0) and quantised coarsely, it smears and shifts a beam 2-3 px wide (measured on the rendered
colour set, ``benchmarks/bench_colour_stripes.py``, the beam on printed ink: median error 0.13 px,
the same in every noise draw; from luma 0.06 px). Luma keeps full resolution. Laser-on minus laser-off luma removes the lit scene as the
colour difference does, so with a laser-off frame the unclipped candidates are fitted on it;
without one, luma keeps the scene's texture and the colour difference is fitted instead.

Demosaicing and JPEG correlate the noise of neighbouring pixels (on the rendered set the
correlation along a row is about 0.5 at one pixel and 0.15 at two), which a white-noise covariance
ignores and a box-sum factor (:func:`scanrig.laser.noise.correlated_noise_factor`, which also
counts the correlation across lines) overstates for a fit along one line (σ 1.7 times too large).
The fit's covariance uses the noise's autocovariance along the scan line instead
(:func:`scanrig.laser.fit.parameter_covariance`), measured once per frame on rows (and columns) of
the luma difference away from bright pixels.

Some cameras' colour matrices subtract a red laser from green and blue (a webcam of the Ciclop
frames: green falls by 50 DN where red rises by 130); their luma holds a weak, distorted copy of
the beam, and the colour difference is fitted there (:attr:`LumaDifference.laser_share`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.geometry.uncertainty import MAD_TO_SIGMA
from scanrig.laser.colour_frames import ColourFrames
from scanrig.laser.noise import QUANTIZATION_SIGMA, weighted_line

#: Largest lag of the noise autocovariance, pixels: an 8-pixel JPEG block.
MAX_LAG_PX = 8
#: About this many pixels, on lines spread evenly over the frame, estimate the noise along rows
#: and as many along columns (the correlation to within about 0.005).
_NOISE_SAMPLES = 40_000
#: Pixels further than this many robust σ from their line's median (the laser, glints, edges the
#: two exposures' JPEG treated differently) are left out of the autocovariance.
_OUTLIER_SIGMAS = 5.0
#: The laser "added" to its channel where the difference exceeds this many robust σ.
_LASER_SIGMAS = 10.0
#: Luma weights of R, G, B (ITU-R BT.601, as JPEG and OpenCV).
LUMA_WEIGHTS = np.array([0.299, 0.587, 0.114])


@dataclass(frozen=True)
class LumaDifference:
    """Luma of a colour frame minus that of its laser-off frame, and its noise.

    The noise variance of a pixel is ``offset + slope · Y_dark`` (read noise, and the shot noise of
    both exposures of the lit scene, ``Y_dark`` the laser-off frame's luma there), measured as the
    lag-0 autocovariance against the level; its correlation with the pixels ``1 .. MAX_LAG_PX``
    along a row or a column, pooled over levels.

    Attributes
    ----------
    plane : (H, W) float32 array, DN
        ``Y(frame) − Y(dark)``, ``Y`` by :data:`LUMA_WEIGHTS`.
    dark_level : (H, W) array of the frame's dtype, DN
        ``Y(dark)``, rounded.
    offset, slope : float
        Noise variance at level 0 (DN²) and per DN of level (DN).
    correlation_rows, correlation_columns : (MAX_LAG_PX + 1,) float arrays
        Noise correlation at lags ``0 .. MAX_LAG_PX`` along rows and along columns.
    laser_share : float
        Median luma added per DN the laser added to its own channel, where it added more than
        ``_LASER_SIGMAS`` robust σ unclipped (NaN where it did nowhere). At or above the channel's
        own luma weight green and blue rose with the laser (crosstalk); below it the camera's colour
        matrix subtracted the laser from them.
    """

    plane: np.ndarray
    dark_level: np.ndarray
    offset: float
    slope: float
    correlation_rows: np.ndarray
    correlation_columns: np.ndarray
    laser_share: float

    def sigma_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Noise σ, DN, at integer pixels ``u, v``."""
        var = self.offset + self.slope * self.dark_level[v, u].astype(np.float64)
        return np.sqrt(np.maximum(var, 2.0 * QUANTIZATION_SIGMA**2))

    def shot_slope(self, laser_channel: int) -> float:
        """Shot-noise variance of the laser's own light per DN of luma signal, DN.

        A channel's variance grows by ``ΔL / g`` with ``ΔL`` DN of light, ``g`` electrons per DN.
        The laser, seen in its own channel ``k`` (crosstalk of a few per cent neglected), adds the
        luma signal ``s = w_k ΔL`` and the variance ``w_k² ΔL / g = w_k s / g``. A grey lit scene at
        luma ``Y`` adds ``2 Σ w_c² Y / g`` (both exposures): the measured ``slope``, so
        ``1 / g = slope / (2 Σ w_c²)``.
        """
        return float(LUMA_WEIGHTS[laser_channel] * self.slope / (2.0 * np.sum(LUMA_WEIGHTS**2)))

    def carries_laser(self, laser_channel: int) -> bool:
        """Whether the luma difference holds the laser at least as strongly as its own channel's
        luma weight (see ``laser_share``)."""
        return bool(self.laser_share >= LUMA_WEIGHTS[laser_channel])

    def correlation(self, rows: bool) -> np.ndarray:
        """Noise correlation at lags ``0 .. MAX_LAG_PX`` along rows (else columns)."""
        return self.correlation_rows if rows else self.correlation_columns


def luma_difference(colour: ColourFrames) -> LumaDifference:
    """The :class:`LumaDifference` of a colour frame with its laser-off frame (``colour.dark`` set)."""
    import cv2

    def luma(frame):
        return cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY)

    dark = luma(colour.dark)
    plane = cv2.subtract(luma(colour.image), dark, dtype=cv2.CV_32F)
    h, w = plane.shape
    rows = slice(None, None, max(1, h * w // _NOISE_SAMPLES))  # every k-th row: about _NOISE_SAMPLES pixels
    cols = slice(None, None, max(1, h * w // _NOISE_SAMPLES))
    d_rows, level_rows, cov_rows = autocovariance(plane[rows], dark[rows])
    d_cols, level_cols, cov_cols = autocovariance(plane[:, cols].T, dark[:, cols].T)
    offset, slope = _variance_line(np.concatenate([d_rows, d_cols]), np.concatenate([level_rows, level_cols]))
    return LumaDifference(plane, dark, offset, slope, cov_rows / cov_rows[0], cov_cols / cov_cols[0],
                          _laser_share(colour, rows, plane[rows]))


def _laser_share(colour: ColourFrames, rows: slice, luma_lines: np.ndarray) -> float:
    """:attr:`LumaDifference.laser_share` on the rows ``rows`` (their luma difference given)."""
    k = colour.laser_channel
    on, off = colour.image[rows, :, k], colour.dark[rows, :, k]
    added = on.astype(np.float32) - off
    sigma = MAD_TO_SIGMA * np.median(np.abs(added - np.median(added)))
    lit = ((added > _LASER_SIGMAS * max(float(sigma), QUANTIZATION_SIGMA)) & (on < colour.clip_level[k])
           & (off < colour.clip_level[k]))
    return float(np.median(luma_lines[lit] / added[lit])) if lit.any() else float("nan")


def autocovariance(lines: np.ndarray, level: np.ndarray):
    """Noise autocovariance along the lines (axis 1) of ``lines (k, n)``, DN², lags ``0 .. MAX_LAG_PX``.

    Each line's median is subtracted; pixels beyond ``_OUTLIER_SIGMAS`` robust σ of it and their
    neighbours up to ``MAX_LAG_PX`` along the line (a trace's flanks), and pairs holding one, are
    left out.

    Returns
    -------
    square, at_level : (m,) float arrays
        The squared deviations of the pixels kept (DN²) and the level ``level (k, n)`` there (DN).
    autocov : (MAX_LAG_PX + 1,) float array, DN²
    """
    import cv2

    d = lines - np.median(lines, axis=1, keepdims=True)
    sigma = MAD_TO_SIGMA * np.median(np.abs(d))
    valid = np.abs(d) <= _OUTLIER_SIGMAS * max(sigma, QUANTIZATION_SIGMA)
    # ... and their neighbours up to MAX_LAG_PX along the line: a trace's flanks are not noise
    valid = cv2.erode(valid.view(np.uint8), np.ones((1, 2 * MAX_LAG_PX + 1), np.uint8),
                      borderType=cv2.BORDER_REPLICATE).view(bool)
    d = np.where(valid, d, 0.0).astype(np.float64)
    out = np.empty(MAX_LAG_PX + 1)
    for lag in range(MAX_LAG_PX + 1):  # a few lags, each over the whole sample
        end = d.shape[1] - lag
        pairs = np.count_nonzero(valid[:, :end] & valid[:, lag:])
        out[lag] = np.einsum("ij,ij->", d[:, :end], d[:, lag:]) / max(pairs, 1)
    out[0] = max(out[0], 2.0 * QUANTIZATION_SIGMA**2)
    return d[valid] ** 2, level[valid].astype(np.float64), out


def _variance_line(square: np.ndarray, level: np.ndarray) -> tuple[float, float]:
    """Least-squares ``square ≈ offset + slope · level`` with ``slope ≥ 0`` (in NumPy's own sums:
    see :func:`~scanrig.laser.noise.weighted_line`)."""
    value, slope, pivot, _ = weighted_line(level, square, np.ones_like(level))
    return value - slope * pivot, slope
