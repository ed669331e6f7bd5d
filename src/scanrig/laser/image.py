"""From a camera frame to the laser signal: colour channel, dark frame, region of interest, noise.

The detectors see one ``(H, W)`` *signal* image in DN (digital numbers of the input's bit depth):

- ``grey``: the frame itself (a colour frame is converted to luma);
- ``red`` / ``green`` / ``blue``: that channel minus the mean of the two others, which removes white
  ambient light and grey texture. It is *not* clipped at 0: clipping would turn zero-mean noise
  into a biased half-normal background and bias both the noise estimate and the fit tails;
- minus the laser-off (dark) frame of the same camera, processed the same way, when given.

Pixels whose laser channel sits at the saturation level are flagged; the fit excludes them (the
unclipped tails still fix the centre) and candidate finding sees them at full scale, so a white
saturated core with coloured fringes is one trace, not two fringes.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError, ShapeError

LASER_COLORS = ("grey", "red", "green", "blue")
_CHANNEL = {"red": 0, "green": 1, "blue": 2}
#: Rows between the 3-row bands sampled for the noise estimate.
_NOISE_BAND_STEP = 32
#: ... but at least this many bands (bands touch, every 3 rows, in frames under 48 rows).
_MIN_NOISE_BANDS = 16
#: Background cells are ``BG_CELL`` pixels square, sampled every ``_BG_STRIDE`` pixels.
BG_CELL = 16
_BG_STRIDE = 4
#: Noise cells are ``NOISE_CELL`` pixels square.
NOISE_CELL = 64
#: In the local noise estimate, high-pass values beyond this many global σ are clipped, so that the
#: laser trace itself inflates its cell only a little (and the 5 × 5 cell median removes the rest).
_NOISE_CLIP = 3.0
#: MAD -> standard deviation for Gaussian noise.
_MAD_TO_SIGMA = 1.4826
#: Standard deviation of rounding to integers, DN.
QUANTIZATION_SIGMA = 1.0 / np.sqrt(12.0)


@dataclass(frozen=True)
class LaserImage:
    """The laser signal of one frame, ready for the detectors.

    Attributes
    ----------
    signal : (H, W) uint8, uint16 or float32 array, DN
        Laser signal inside the region of interest. Integer when no conversion was needed (grey
        input without dark frame), so that candidate finding runs on the raw bytes.
    saturated : (H, W) bool array or None
        Pixels whose laser channel is at ``saturation_level``; None when there are none.
    origin : (int, int)
        ``(u0, v0)`` of the region of interest in the full frame; add it to signal coordinates.
    noise_sigma : float
        Robust estimate of the per-pixel noise standard deviation of the whole ``signal``, DN,
        including quantisation.
    noise : (Hn, Wn) float32 array, DN
        Local noise standard deviation per ``NOISE_CELL`` pixel cell (see :func:`estimate_noise`):
        shot noise makes bright parts of the scene noisier than dark ones.
    background : (Hc, Wc) float32 array, DN
        Local background per ``BG_CELL`` pixel cell (see :func:`background_cells`).
    """

    signal: np.ndarray
    saturated: np.ndarray | None
    origin: tuple[int, int]
    noise_sigma: float
    noise: np.ndarray
    background: np.ndarray

    def background_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Background level, DN, at integer signal coordinates ``u``, ``v`` (same shape)."""
        return _cell_lookup(self.background, BG_CELL, u, v)

    def noise_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Noise standard deviation, DN, at integer signal coordinates ``u``, ``v`` (same shape)."""
        return _cell_lookup(self.noise, NOISE_CELL, u, v)


def _cell_lookup(cells: np.ndarray, cell: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    hc, wc = cells.shape
    return cells[np.minimum(v // cell, hc - 1), np.minimum(u // cell, wc - 1)]


def prepare_image(
    image: np.ndarray,
    color: str = "grey",
    dark: np.ndarray | None = None,
    roi: tuple[int, int, int, int] | None = None,
    saturation_level: float | None = None,
    noise_sigma: float | None = None,
) -> LaserImage:
    """Laser signal, saturation mask, background and noise of one frame.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 or uint16 array
        The frame as read (RGB order for colour), DN.
    color : {"grey", "red", "green", "blue"}
        Laser colour.
    dark : array like ``image``, optional
        Laser-off frame of the same camera, subtracted after colour selection.
    roi : (u0, v0, u1, v1) ints, optional
        Region of interest, pixels, end-exclusive. Default: the whole frame.
    saturation_level : float, optional
        DN at which a pixel is clipped. Default: the dtype's maximum (255 or 65535); set it for a
        12-bit camera stored in 16-bit files.
    noise_sigma : float, optional
        Known noise standard deviation of the signal, DN; estimated from the frame when omitted.

    Returns
    -------
    LaserImage

    Raises
    ------
    ShapeError
        If ``image`` or ``dark`` has the wrong dtype or shape, or is empty.
    InputError
        If ``color``, ``roi``, ``saturation_level`` or ``noise_sigma`` is invalid.
    """
    check_frame(image, "image")
    if color not in LASER_COLORS:
        raise InputError(f"color must be one of {LASER_COLORS}, got {color!r}")
    if dark is not None:
        check_frame(dark, "dark")
        if dark.shape != image.shape or dark.dtype != image.dtype:
            raise ShapeError(f"dark must match image ({image.shape} {image.dtype}), "
                             f"got {dark.shape} {dark.dtype}")
    u0, v0, u1, v1 = _check_roi(roi, image.shape)
    image = image[v0:v1, u0:u1]
    dark = None if dark is None else dark[v0:v1, u0:u1]
    full_scale = float(np.iinfo(image.dtype).max)
    if saturation_level is None:
        saturation_level = full_scale
    elif not 0 < saturation_level <= full_scale:
        raise InputError(f"saturation_level must be in (0, {full_scale:g}] for {image.dtype} images, "
                         f"got {saturation_level}")

    channel = _laser_channel(image, color)
    saturated = None
    if channel.max() >= saturation_level:
        saturated = channel >= saturation_level
    signal = _signal(image, color)
    if dark is not None:
        signal = signal.astype(np.float32) - _signal(dark, color).astype(np.float32)
    if saturated is not None and signal.dtype == np.float32:
        signal[saturated] = saturation_level  # a white core reads as the brightest part of the trace
    if noise_sigma is None:
        noise_sigma, noise = estimate_noise(signal, 1.0 if color == "grey" or image.ndim == 2 else 0.5,
                                            local=True)
    elif not (np.isfinite(noise_sigma) and noise_sigma > 0):
        raise InputError(f"noise_sigma must be a positive number of DN, got {noise_sigma}")
    else:
        noise = np.full(_cells_shape(signal.shape, NOISE_CELL), noise_sigma, np.float32)
    return LaserImage(signal, saturated, (u0, v0), float(noise_sigma), noise, background_cells(signal))


def check_frame(image, name: str) -> None:
    """Raise :class:`ShapeError` unless ``image`` is a non-empty 8/16-bit ``(H, W)`` or ``(H, W, 3)`` array."""
    if not isinstance(image, np.ndarray):
        raise ShapeError(f"{name} must be a numpy array, got {type(image).__name__}")
    if image.dtype not in (np.uint8, np.uint16):
        raise ShapeError(f"{name} must be an 8- or 16-bit image (uint8 or uint16), got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise ShapeError(f"{name} must have shape (H, W) or (H, W, 3), got {image.shape}")
    if image.shape[0] < 3 or image.shape[1] < 3:
        raise ShapeError(f"{name} is empty or smaller than 3x3 pixels: shape {image.shape}")


def _check_roi(roi, shape) -> tuple[int, int, int, int]:
    h, w = shape[:2]
    if roi is None:
        return 0, 0, w, h
    try:
        u0, v0, u1, v1 = (int(x) for x in roi)
    except (TypeError, ValueError):
        raise InputError(f"roi must be four integers (u0, v0, u1, v1), got {roi!r}") from None
    if not (0 <= u0 and u0 + 3 <= u1 <= w and 0 <= v0 and v0 + 3 <= v1 <= h):
        raise InputError(f"roi (u0, v0, u1, v1) = {roi!r} must lie inside the {w}x{h} frame "
                         f"and be at least 3x3 pixels")
    return u0, v0, u1, v1


def _laser_channel(image: np.ndarray, color: str) -> np.ndarray:
    """The raw channel that carries the laser (the whole image when grey)."""
    if image.ndim == 2:
        return image
    if color == "grey":
        return image.max(axis=2)
    return image[:, :, _CHANNEL[color]]


def _signal(image: np.ndarray, color: str) -> np.ndarray:
    """Colour selection: the frame (grey), luma (colour frame, grey laser) or channel minus others."""
    if image.ndim == 2:
        return image
    if color == "grey":
        import cv2

        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    k = _CHANNEL[color]
    others = [c for c in range(3) if c != k]
    f = image.astype(np.float32)
    return f[:, :, k] - 0.5 * (f[:, :, others[0]] + f[:, :, others[1]])


def estimate_noise(signal: np.ndarray, step: float = 1.0, local: bool = False):
    """Robust noise standard deviation of an image, DN: for the whole frame and, optionally, per cell.

    Both come from the high-pass ``h = 9·x − (3×3 box sum)`` on 3-row bands every
    ``_NOISE_BAND_STEP`` rows; for white noise of variance σ² it has variance 72 σ².

    - Whole frame: the median of ``|h|``. Edges of texture and the laser trace occupy few pixels and
      do not move it. ``h`` of integer (half-integer) data is integer (half-integer), so the median
      is taken from the histogram with linear interpolation inside the median's bin (the grouped
      median): a plain median of 8-bit data would jump in steps of several per cent.
    - Per ``NOISE_CELL``-pixel cell (shot noise makes bright parts noisier): the mean of ``|h|``
      clipped at ``c = _NOISE_CLIP`` frame σ, divided by its expectation for unit Gaussian noise,
      √72 · [√(2/π)(1 − e^(−c²/2)) + 2c(1 − Φ(c))]; then a 5 × 5 median over cells (a stripe
      straddling two columns of cells contaminates 10 of 25). A cell holds about 120 samples, so
      a cell scatters by about 7 % before the median and about 3 % after.

    Both are floored at the quantisation noise 1/√12 DN (an all-dark frame has zero measured noise).

    Parameters
    ----------
    signal : (H, W) array, DN
    step : float
        Spacing of the signal's values: 1 for integer data (also after dark subtraction), 0.5 after
        colour differencing.
    local : bool
        Also return the per-cell map.

    Returns
    -------
    sigma : float
        σ, DN. Reliable for σ above about 1 DN; below, rounding is not noise-like and the estimate
        runs low (pass a measured ``noise_sigma`` to the detectors instead).
    cells : (ceil(H/cell), ceil(W/cell)) float32 array, DN
        Only when ``local``.
    """
    rows, high_pass = _high_pass_bands(signal)
    magnitude = np.abs(high_pass)  # integer for integer data: exact, and a cheap histogram
    if magnitude.dtype.kind == "i" and step == 1.0:
        bins = magnitude.ravel()
    else:
        bins = np.rint(magnitude / step).astype(np.int64).ravel()
    counts = np.cumsum(np.bincount(bins))
    half = 0.5 * counts[-1]
    k = int(np.searchsorted(counts, half))
    below_k = counts[k - 1] if k else 0
    median_abs = step * (k - 0.5 + (half - below_k) / (counts[k] - below_k))
    if k == 0:  # more than half exactly zero: the bin [0, ½) holds them
        median_abs = step * 0.5 * half / counts[0]
    sigma = max(float(_MAD_TO_SIGMA * median_abs / np.sqrt(72.0)), QUANTIZATION_SIGMA)
    if not local:
        return sigma
    return sigma, _noise_cells(rows, magnitude, signal.shape, sigma)


def _noise_cells(rows: np.ndarray, magnitude: np.ndarray, shape, sigma: float) -> np.ndarray:
    """Per-cell noise from the band rows and ``|h|`` (see :func:`estimate_noise`)."""
    import cv2

    clip = np.float32(_NOISE_CLIP * np.sqrt(72.0) * sigma)
    mag = np.minimum(magnitude.astype(np.float32, copy=False), clip)
    hc, wc = _cells_shape(shape, NOISE_CELL)
    # mean of columns 1 .. W-2 of each band per cell column: zero-padded sums over counts
    n_bands, n_cols = mag.shape
    padded = np.zeros((n_bands, wc * NOISE_CELL), np.float32)
    padded[:, 1 : 1 + n_cols] = mag
    per_band = padded.reshape(n_bands, wc, NOISE_CELL).sum(axis=2)
    edges = np.clip(np.arange(wc + 1) * NOISE_CELL, 1, 1 + n_cols)
    with np.errstate(invalid="ignore", divide="ignore"):  # a cell without columns: NaN, as a mean
        np.true_divide(per_band, np.diff(edges), out=per_band, casting="unsafe")
    # bands in order of rows, so each cell row's bands are consecutive: summed in that order
    row_cells = rows // NOISE_CELL
    counts = np.bincount(row_cells, minlength=hc)
    sums = np.zeros((hc, wc))
    filled = np.flatnonzero(counts)
    first_band = np.cumsum(counts)[filled] - counts[filled]
    sums[filled] = np.add.reduceat(per_band.astype(np.float64), first_band, axis=0)
    counts = counts[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        cells = np.where(counts > 0, sums / counts / _expected_clipped_abs(), sigma).astype(np.float32)
    if min(hc, wc) >= 3:
        cells = cv2.medianBlur(cells, 5)
    return np.maximum(cells, np.float32(QUANTIZATION_SIGMA))


@functools.lru_cache(maxsize=1)
def _expected_clipped_abs() -> float:
    """E min(|h|, c √72) for unit Gaussian noise (h of variance 72), c = ``_NOISE_CLIP``."""
    from scipy.special import erfc

    c = _NOISE_CLIP
    return float(np.sqrt(72.0) * (np.sqrt(2 / np.pi) * (1 - np.exp(-c * c / 2)) + c * erfc(c / np.sqrt(2))))


def _high_pass_bands(signal: np.ndarray):
    """``9·x − (3×3 box sum)`` on 3-row bands every ``_NOISE_BAND_STEP`` rows (closer in small frames).

    Returns
    -------
    rows : (nb,) int array
        Centre row of each band.
    high_pass : (nb, W - 2) array, DN
        Columns 1 .. W-2; int16 (8-bit data), int32 (16-bit) or float32 (exact in each).
    """
    step = min(max(signal.shape[0] // _MIN_NOISE_BANDS, 3), _NOISE_BAND_STEP)  # small frames: denser
    starts = np.arange(1, signal.shape[0] - 1, step)
    work = {np.dtype(np.uint8): np.int16, np.dtype(np.uint16): np.int32}.get(signal.dtype, np.float32)
    above, centre, below = (signal[starts + d].astype(work) for d in (-1, 0, 1))
    col3 = above + centre + below
    return starts, 9 * centre[:, 1:-1] - (col3[:, :-2] + col3[:, 1:-1] + col3[:, 2:])


def _cells_shape(shape, cell: int) -> tuple[int, int]:
    return -(-shape[0] // cell), -(-shape[1] // cell)


def background_cells(signal: np.ndarray) -> np.ndarray:
    """Local background, DN, per ``BG_CELL``-pixel cell: shape (ceil(H/cell), ceil(W/cell)).

    Cell means of every ``_BG_STRIDE``-th pixel, then a 5 × 5 median over cells, which ignores
    structures (the trace) narrower than about two cells while following shading and texture.
    """
    import cv2

    hc, wc = _cells_shape(signal.shape, BG_CELL)
    sub = np.ascontiguousarray(signal[::_BG_STRIDE, ::_BG_STRIDE], dtype=np.float32)
    means = cv2.resize(sub, (wc, hc), interpolation=cv2.INTER_AREA)
    return cv2.medianBlur(means, 5) if min(hc, wc) >= 3 else np.full_like(means, np.median(means))
