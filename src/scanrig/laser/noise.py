"""The noise of a laser signal: per cell from the frame itself, or per pixel from the laser-off frame.

Without a dark frame the noise is measured per ``NOISE_CELL``-pixel cell (see
:func:`estimate_noise`). With one, it is modelled per pixel (:class:`NoiseModel`): the difference
of two exposures of the same scene has the shot noise of *its level*, which a cell measured over
mostly dark pixels underestimates by far at a bright pixel (a glint of room light on polished
metal, the edge of a lit part). A cell-based threshold there let the dark frame's own noise,
the same in every frame, pass as a faint spot at the same pixel frame after frame. Demosaicing
and JPEG correlate the noise over a few pixels, which the box sums and fits see in full
(:func:`correlated_noise_factor`). JPEG's blocking and ringing in a colour difference are a floor
of their own for detection, not noise for the fits (:func:`clutter_cells`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from scanrig.geometry.uncertainty import MAD_TO_SIGMA
from scanrig.laser.pixels import cells_shape, pixel_blocks

#: Rows between the 3-row bands sampled for the noise estimate.
_NOISE_BAND_STEP = 32
#: ... but at least this many bands (bands touch, every 3 rows, in frames under 48 rows).
_MIN_NOISE_BANDS = 16
#: Noise cells are ``NOISE_CELL`` pixels square.
NOISE_CELL = 64
#: In the local noise estimate, high-pass values beyond this many global σ are clipped, so that the
#: laser trace itself inflates its cell only a little (and the 5 × 5 cell median removes the rest).
_NOISE_CLIP = 3.0
#: Standard deviation of rounding to integers, DN.
QUANTIZATION_SIGMA = 1.0 / np.sqrt(12.0)
#: The photon-transfer fit of :func:`fit_noise_model`: clipped, reweighted iterations, the clip in
#: σ of the current model, and at most this many high-pass samples (every band, or every k-th).
_PTC_ITERATIONS = 3
_PTC_CLIP = 4.0
_PTC_MAX_SAMPLES = 12_000
_PTC_MIN_SAMPLES = 50
#: ... whose slope is raised by this many of its standard errors (see :func:`fit_noise_model`).
_PTC_SLOPE_MARGIN = 2.0
#: Below this :func:`correlated_noise_factor` is taken as white noise (texture and traces raise the
#: factor of a white-noise frame by a few per cent).
CORRELATED_NOISE_MIN = 1.25
#: Squared weights of the channels in the signal of a colour frame: red minus the mean of the
#: others, and OpenCV's RGB -> grey luma.
_CHANNEL_WEIGHTS2 = {"red": (1.0, 0.25, 0.25), "green": (0.25, 1.0, 0.25), "blue": (0.25, 0.25, 1.0),
                     "grey": (0.299**2, 0.587**2, 0.114**2)}


@dataclass(frozen=True)
class NoiseModel:
    """Per-pixel noise of a dark-subtracted signal: variance ``offset + slope · L``, DN².

    A pixel at raw level ``L`` DN (above an unknown black level) has variance ``a + L / g``: read
    noise and rounding, plus shot noise with ``g`` electrons per DN. Where the laser is off, frame
    and dark are at the dark's level, so their difference has ``2a + 2L/g``: linear in the dark's
    level, whatever the gain and black level (they are measured, see :func:`fit_noise_model`).
    The laser's own shot noise is left to the fit (:func:`scanrig.laser.fit.parameter_covariance`).
    For a colour signal, ``L`` is the channels' levels weighted by their squared coefficients.

    Attributes
    ----------
    dark : (H, W) or (H, W, 3) uint8 or uint16 array
        The raw laser-off frame inside the region of interest.
    weights : (3,) tuple of float or None
        Squared channel coefficients of the signal; None for a one-channel frame.
    offset : float
        Variance at level 0, DN² (may be negative: the black level is not at 0).
    slope : float
        Variance per DN of level, DN (twice the inverse gain).
    """

    dark: np.ndarray
    weights: tuple[float, float, float] | None
    offset: float
    slope: float

    def sigma_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Noise σ, DN, at integer signal coordinates: the root of the mean variance of the 3 × 3
        pixels around each (the box sum of the detectors has 9 times that variance)."""
        shape = np.shape(u)
        blocks = pixel_blocks(self.dark, np.ravel(v) - 1, np.ravel(u) - 1, 3, 3)
        weights = np.ones(1, np.float32) if self.weights is None else np.asarray(self.weights, np.float32)
        # the weighted sum over the 3 × 3 pixels (and channels) as one product per block: NumPy's
        # reductions over such short axes are ten times slower (exact for a coloured laser's weights,
        # in any order); NumPy's own loop, not BLAS (see weighted_line)
        level = np.einsum("nk,k->n", blocks.reshape(blocks.shape[0], 9 * weights.size).astype(np.float32),
                          np.tile(weights, 9))
        var = self.offset + self.slope * (level / 9)
        return np.sqrt(np.maximum(var, QUANTIZATION_SIGMA**2)).astype(np.float32).reshape(shape)

    @property
    def floor(self) -> float:
        """The lowest σ :meth:`sigma_at` returns (at level 0: the slope is never negative), DN."""
        return float(np.sqrt(np.maximum(np.float32(self.offset), np.float32(QUANTIZATION_SIGMA**2))))


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
    rows, high_pass = high_pass_bands(signal)
    return noise_from_bands(rows, high_pass, signal.shape, step, local)


def effective_noise(signal: np.ndarray) -> float:
    """Noise σ of an image for fits over a few pixels, DN: :func:`estimate_noise`, scaled by
    :func:`correlated_noise_factor` where the noise is correlated over a few pixels.

    ``signal`` is an ``(H, W)`` array, or anything with its ``shape`` and ``dtype`` that returns
    its rows for ``signal[rows]`` (``rows (n,)`` ints): only the bands of
    :func:`high_pass_bands` are read."""
    rows, high_pass = high_pass_bands(signal)
    sigma = noise_from_bands(rows, high_pass, signal.shape, 1.0, local=False)
    factor = correlated_noise_factor(signal, rows, sigma)
    return sigma * factor if factor > CORRELATED_NOISE_MIN else sigma


def correlated_noise_factor(signal: np.ndarray, rows: np.ndarray, sigma: float) -> float:
    """How much larger the noise of a 3 × 3 box sum is than white pixel noise of σ would make it (≥ 1).

    Demosaicing, JPEG and a camera's own denoising leave noise that is correlated over a few
    pixels: the pixel-scale high-pass of :func:`estimate_noise` sees little of it, but the box
    sums of the detectors, and the fitted centres, see all of it. On the 3-row bands at ``rows``,
    ``h = B(x) − (B(x − 3) + B(x + 3)) / 2`` of the box sums ``B`` (three boxes without shared
    pixels) has variance 13.5 σ² for white noise; the ratio of its robust σ (MAD, which the few
    pixels of a trace or an edge hardly move) to that is the factor. On white noise it is 1 to
    within a few per cent; on demosaiced JPEG colour-difference signals it is 2-4.

    Parameters
    ----------
    signal : (H, W) array, DN
    rows : (nb,) int array
        Centre rows of the bands (from :func:`high_pass_bands`).
    sigma : float
        White-noise σ of the pixels, DN.

    Returns
    -------
    float
    """
    if signal.shape[1] < 12:
        return 1.0
    rows = rows[::2]  # every other band: a few ten thousand samples are plenty for a median
    work = np.int32 if signal.dtype.kind == "u" else np.float32  # exact and fast for integer data
    col3 = signal[rows - 1].astype(work) + signal[rows] + signal[rows + 1]
    box = col3[:, :-2] + col3[:, 1:-1] + col3[:, 2:]
    twice_h = np.abs(2 * box[:, 3:-3] - box[:, :-6] - box[:, 6:]).ravel()
    scale = 2.0  # to h
    if work is np.float32:
        # the signals of prepare_image are multiples of ½ DN: their 4 h are integers
        quadruple = 2 * twice_h
        if np.array_equal(quadruple, np.rint(quadruple)):
            twice_h, scale = quadruple.astype(np.int32), 4.0
    median = _middle_value(twice_h) / scale
    return max(1.0, MAD_TO_SIGMA * median / (np.sqrt(13.5) * sigma))


#: Largest value whose histogram :func:`_middle_value` counts (larger: a selection).
_HISTOGRAM_MAX = 1 << 16


def _middle_value(values: np.ndarray) -> float:
    """The ``size // 2``-th smallest of ``values`` (``(n,)``), as ``np.partition`` finds it.

    Non-negative integers up to ``_HISTOGRAM_MAX`` are counted in a histogram: the flat areas of a
    JPEG frame make most of them equal, and a selection among so many ties is ten times slower.
    """
    middle = values.size // 2
    if values.dtype.kind in "iu" and values.size and 0 <= values.min() and values.max() <= _HISTOGRAM_MAX:
        return float(np.searchsorted(np.cumsum(np.bincount(values)), middle, side="right"))
    return float(np.partition(values, middle)[middle])


def noise_from_bands(rows: np.ndarray, high_pass: np.ndarray, shape, step: float, local: bool):
    """:func:`estimate_noise` from the high-pass bands."""
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
    sigma = max(float(MAD_TO_SIGMA * median_abs / np.sqrt(72.0)), QUANTIZATION_SIGMA)
    if not local:
        return sigma
    return sigma, _noise_cells(rows, magnitude, shape, sigma)


def fit_noise_model(rows: np.ndarray, high_pass: np.ndarray, dark: np.ndarray, color: str,
                    invalid: np.ndarray | None = None) -> NoiseModel | None:
    """Photon transfer from one frame: the per-pixel noise of ``frame − dark`` against the dark's level.

    The high-pass ``h = 9·x − (3×3 box sum)`` of the difference (see :func:`estimate_noise`) has
    variance ``64 v(centre) + Σ v(8 neighbours)``, about ``72 · v(L)`` for the variance
    ``v(L) = offset + slope · L`` of :class:`NoiseModel`, ``L`` the local level of the dark frame.
    ``L`` is taken on the ring of 16 pixels around the 3 × 3: a level that includes the dark's own
    noise in ``h`` (its 3 × 3 mean) would sort the samples by that noise, and on a flat 8-bit
    background, where the level is a few integers, the bright samples would be those of bright
    noise. ``h² / 72`` is regressed on ``L`` sample by sample, weighted by ``1 / v²`` (the variance
    of a variance estimate), ordinary least squares first, then ``_PTC_ITERATIONS`` times with
    ``h²`` clipped at ``_PTC_CLIP`` σ of the current model and the clipped mean's expectation
    divided out: the laser trace, a few samples far above their level's noise, hardly moves it,
    and a few bright samples (one glint in a dark scene) still weigh in by their leverage, which
    bins of equal count would average away. The mean square is right for any distribution
    (rounding makes 8-bit noise far from Gaussian), unlike the mean of ``|h|``. A negative slope is
    set to 0.

    Parameters
    ----------
    rows : (nb,) int array
        Centre rows of the high-pass bands of the signal.
    high_pass : (nb, W - 2) array, DN
        The high-pass of the dark-subtracted signal on those bands.
    dark : (H, W) or (H, W, 3) uint8 or uint16 array
        The raw laser-off frame (same region as the signal).
    color : str
        Laser colour (it fixes the channel weights of a colour frame).
    invalid : (H, W) bool array, optional
        Pixels to leave out (saturated in the frame or the dark): samples whose 3 × 3 holds one.

    Returns
    -------
    NoiseModel or None
        None when fewer than ``_PTC_MIN_SAMPLES`` samples are usable (a frame of a few rows).
    """
    stride = -(-high_pass.size // _PTC_MAX_SAMPLES)  # every band up to _PTC_MAX_SAMPLES samples
    rows, high_pass = rows[::stride], high_pass[::stride]
    weights = None if dark.ndim == 2 else _CHANNEL_WEIGHTS2[color]
    h = dark.shape[0]
    level = dark[np.clip(rows[:, None] + np.arange(-2, 3), 0, h - 1)].astype(np.float32)  # (nb, 5, W[, 3])
    if weights is not None:
        level = level @ np.asarray(weights, np.float32)
    col5 = level.sum(axis=1)
    col3 = col5 - level[:, 0] - level[:, 4]
    box3 = col3[:, 1:-3] + col3[:, 2:-2] + col3[:, 3:-1]
    box5 = col5[:, :-4] + col5[:, 1:-3] + col5[:, 2:-2] + col5[:, 3:-1] + col5[:, 4:]
    x = ((box5 - box3) / 16.0).astype(np.float64)  # the ring around each 3 x 3, columns 2 .. W-3
    y = np.square(high_pass[:, 1:-1], dtype=np.float64) / 72.0
    if invalid is not None:
        bad = invalid[rows - 1] | invalid[rows] | invalid[rows + 1]
        bad = (bad[:, 1:-3] | bad[:, 2:-2] | bad[:, 3:-1])
        x, y = x[~bad], y[~bad]
    x, y = x.ravel(), y.ravel()
    if x.size < _PTC_MIN_SAMPLES:
        return None
    line = weighted_line(x, y, np.ones_like(x))
    floor = QUANTIZATION_SIGMA**2
    for _ in range(_PTC_ITERATIONS):
        var = np.maximum(line[0] + line[1] * (x - line[2]), floor)
        clipped = np.minimum(y, _PTC_CLIP**2 * var) / _clipped_square()
        line = weighted_line(x, clipped, 1.0 / var**2)
    value, slope, pivot, spread = line
    # Few bright samples (one glint in a dark frame) leave the slope uncertain: take its upper
    # bound, so that the threshold errs on the side of no false candidates where it is unsure.
    # h²/72 has variance 2 v², and the weights are 1/v²: var(slope) = 2 / Σ w (x − x̄)².
    slope += _PTC_SLOPE_MARGIN * np.sqrt(2.0 / spread) if spread > 0 else 0.0
    return NoiseModel(dark, weights, float(value - slope * pivot), float(slope))


def weighted_line(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[float, float, float, float]:
    """Weighted least-squares line ``y ≈ value + slope · (x − pivot)``, ``pivot`` the weighted mean
    of ``x`` and ``slope ≥ 0``: returns ``(value, slope, pivot, Σ w (x − pivot)²)``.

    The sums of products are NumPy's own loops, not BLAS's ``dot``: a multi-threaded BLAS spends
    some ten milliseconds per call on these ten thousand values when the cores are busy (the sums
    take microseconds), four calls per frame with a laser-off frame."""

    def dot(a, b):
        return float(np.einsum("i,i->", a, b))

    w_sum = float(w.sum())
    pivot = dot(w, x) / w_sum
    value = dot(w, y) / w_sum
    wdx = w * (x - pivot)
    spread = dot(wdx, x - pivot)
    slope = max(dot(wdx, y) / spread, 0.0) if spread > 0 else 0.0
    return value, slope, pivot, spread


@functools.lru_cache(maxsize=1)
def _clipped_square() -> float:
    """E min(z², c²) for a unit Gaussian z, c = ``_PTC_CLIP``."""
    from scipy.special import erf, erfc

    c = _PTC_CLIP
    return float(erf(c / np.sqrt(2)) - c * np.sqrt(2 / np.pi) * np.exp(-c * c / 2) + c * c * erfc(c / np.sqrt(2)))


def _noise_cells(rows: np.ndarray, magnitude: np.ndarray, shape, sigma: float) -> np.ndarray:
    """Per-cell noise from the band rows and ``|h|`` (see :func:`estimate_noise`)."""
    import cv2

    clip = np.float32(_NOISE_CLIP * np.sqrt(72.0) * sigma)
    mag = np.minimum(magnitude.astype(np.float32, copy=False), clip)
    hc, wc = cells_shape(shape, NOISE_CELL)
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


#: Rows between the rows of box sums sampled for the clutter (:func:`clutter_cells`).
_CLUTTER_ROW_STEP = 8
#: Pixels searched on each side of a local maximum for its prominence: the stripes' default reach
#: (3 × ``max_width_px`` + 1 at 3 px).
CLUTTER_REACH_PX = 10
#: Quantile of a cell's prominences taken as its clutter level.
_CLUTTER_QUANTILE = 0.9
#: That quantile for white Gaussian noise, in σ of the box sum, as :func:`clutter_cells` takes it
#: (the histogram's bins and the low rank over cells included): measured so that six 1280 × 1024
#: frames of unit-σ noise give a median cell of 1.00 DN (``tests/laser/test_clutter.py`` checks it).
_CLUTTER_WHITE = 2.63
#: Prominences above this many times the frame's quantile are signal, not clutter, and left out:
#: a laser crossing a cell is its most prominent structure.
_CLUTTER_CLIP = 4.0
#: Below this many noise σ the clutter is taken as noise (on white noise it scatters about 1).
CLUTTER_MIN = 1.25
#: Fewest maxima for a cell's own quantile.
_CLUTTER_MIN_MAXIMA = 8
#: Most bins of the cells' histograms of prominence (see :func:`clutter_cells`).
_CLUTTER_BINS = 128


def clutter_cells(signal: np.ndarray, noise: np.ndarray, box_sums: np.ndarray | None = None) -> np.ndarray:
    """Structured clutter per ``NOISE_CELL``-pixel cell, in noise-equivalent σ of a pixel, DN.

    JPEG stores colour at half resolution in 8 × 8 blocks: on flat paper, where quantisation leaves
    almost no pixel-scale noise (and :func:`estimate_noise` its floor), a colour difference holds
    blocking and ringing bumps of a few DN, which rise above both flanks like a faint stripe. The
    floor a stripe's peak must clear there is this structure, not the noise. It is measured as the
    detectors see it: on every ``_CLUTTER_ROW_STEP``-th row, the prominence of each local maximum of
    the 3 × 3 box sums along the row (its box sum minus the higher of the lowest within
    ``CLUTTER_REACH_PX`` on either side, as :func:`~scanrig.laser.peaks.line_prominence`), those
    above ``_CLUTTER_CLIP`` times the frame's ``_CLUTTER_QUANTILE`` quantile left out (signal). Per
    cell (of at least ``_CLUTTER_MIN_MAXIMA`` maxima, else 0), their ``_CLUTTER_QUANTILE`` quantile
    is divided by that quantile for white noise of σ 1 (``_CLUTTER_WHITE`` box-sum σ of 3 DN each),
    and the ``_CLUTTER_RANK``-th lowest of the 5 × 5 cells around is taken: a laser raises the
    cells it crosses (its own peaks, and the ringing JPEG leaves beside it), and two lasers close
    together cross half of a 5 × 5 neighbourhood. On white noise the result is the noise σ within
    a few per cent; cells where it is below ``CLUTTER_MIN`` times their ``noise`` are set to 0 (no
    clutter beyond the noise).

    Parameters
    ----------
    signal : (H, W) array, DN
    noise : (ceil(H/cell), ceil(W/cell)) float32 array, DN
        The noise cells (:func:`estimate_noise`).
    box_sums : (H + 2, W + 2) array, optional
        :func:`~scanrig.laser.pixels.padded_box_sums` of ``signal``, when computed: their rows are
        read instead of summed again.

    Returns
    -------
    (ceil(H/cell), ceil(W/cell)) float32 array, DN
        0 where there is no clutter beyond the noise, and in frames too small to measure it.
    """
    import cv2
    from scipy.ndimage import rank_filter

    hc, wc = noise.shape
    reach = CLUTTER_REACH_PX
    h, w = signal.shape
    if w < 2 * reach + 5 or h < 3:
        return np.zeros_like(noise)
    rows = np.arange(1, h - 1, _CLUTTER_ROW_STEP)
    if box_sums is None:
        work = {np.dtype(np.uint8): np.int16, np.dtype(np.uint16): np.int32}.get(signal.dtype, np.float32)  # exact
        col3 = signal[rows - 1].astype(work) + signal[rows] + signal[rows + 1]
        box = (col3[:, :-2] + col3[:, 1:-1] + col3[:, 2:]).astype(np.float32)  # columns 1 .. W-2
    else:  # the same exact sums (the ring holds rows and columns -1 and W)
        box = box_sums[rows + 1, 2:-2].astype(np.float32, copy=False)
    n = box.shape[1]
    centre = box[:, reach : n - reach]  # columns reach + 1 .. W - reach - 2
    is_max = (centre >= box[:, reach - 1 : n - reach - 1]) & (centre > box[:, reach + 1 : n - reach + 1])
    lowest = cv2.erode(box, np.ones((1, reach), np.uint8), anchor=(0, 0))  # of x .. x + reach - 1
    base = np.maximum(lowest[:, : n - 2 * reach], lowest[:, reach + 1 : n - reach + 1])
    at = np.flatnonzero(is_max)  # flat: several times faster than the 2-D nonzero
    band, col = np.divmod(at, is_max.shape[1])
    if band.size == 0:
        return np.zeros_like(noise)
    prominence = np.maximum(centre.ravel()[at] - base.ravel()[at], 0.0).astype(np.float64)
    clip = _CLUTTER_CLIP * np.quantile(prominence, _CLUTTER_QUANTILE)
    cell = rows[band] // NOISE_CELL * wc + (col + reach + 1) // NOISE_CELL
    clutter = prominence <= clip
    prominence, cell = prominence[clutter], cell[clutter]
    # each cell's quantile from its histogram, to within a bin of 1/_CLUTTER_BINS of the clip level
    # (a sort of the maxima costs ten times more)
    width = clip / _CLUTTER_BINS if clip > 0 else 1.0
    bins = (prominence / width).astype(np.int64)
    n_bins = int(bins.max()) + 1
    cumulative = np.cumsum(np.bincount(cell * n_bins + bins, minlength=hc * wc * n_bins).reshape(hc * wc, n_bins),
                           axis=1)
    counts = cumulative[:, -1]
    rank = np.floor(_CLUTTER_QUANTILE * (counts - 1))
    level = np.where(counts >= _CLUTTER_MIN_MAXIMA, (cumulative <= rank[:, None]).sum(axis=1) * width, 0.0)
    level = level.astype(np.float32)
    # the _CLUTTER_RANK-th lowest of each 5 × 5 neighbourhood, the edge cells repeated beyond the map
    cells = rank_filter(level.reshape(hc, wc) / np.float32(3.0 * _CLUTTER_WHITE), rank=_CLUTTER_RANK,
                        size=_CLUTTER_SPAN, mode="nearest")
    return np.where(cells >= CLUTTER_MIN * noise, cells, np.float32(0.0))


#: Side of the neighbourhood of cells over which the clutter is taken, and the rank taken there
#: (0 the lowest; see :func:`clutter_cells`).
_CLUTTER_SPAN = 5
_CLUTTER_RANK = 6


def high_pass_bands(signal: np.ndarray):
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
