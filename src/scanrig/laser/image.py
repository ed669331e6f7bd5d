"""From a camera frame to the laser signal: colour channel, dark frame, region of interest, noise.

The detectors see one ``(H, W)`` *signal* image in DN (digital numbers of the input's bit depth):

- ``grey``: the frame itself (a colour frame is converted to luma);
- ``red`` / ``green`` / ``blue``: that channel minus the mean of the two others, which removes white
  ambient light and grey texture. It is *not* clipped at 0: clipping would turn zero-mean noise
  into a biased half-normal background and bias both the noise estimate and the fit tails;
- minus the laser-off (dark) frame of the same camera, processed the same way, when given.

Noise. Without a dark frame the noise is measured per ``NOISE_CELL``-pixel cell (see
:func:`estimate_noise`). With one, it is modelled per pixel (:class:`NoiseModel`): the difference
of two exposures of the same scene has the shot noise of *its level*, which a cell measured over
mostly dark pixels underestimates by far at a bright pixel (a glint of room light on polished
metal, the edge of a lit part). A cell-based threshold there let the dark frame's own noise,
the same in every frame, pass as a faint spot at the same pixel frame after frame.

Clipping. The saturation level is the dtype's maximum, a given level, or (``"auto"``) each
channel's found from the frame (:func:`channel_clip_levels`): a webcam's processing can clip a
channel well below the dtype's maximum. Pixels whose laser channel is within ``CLIP_MARGIN`` of
the saturation level are flagged
(JPEG and demosaicing spread a clipped plateau a few DN below the clip, so an exact test misses
most of it); the fit excludes them (the unclipped flanks, and in a colour frame the other
channels' crosstalk, still fix the centre: :mod:`scanrig.laser.colour_fit`) and candidate finding
sees them at full scale, so a white saturated core with coloured fringes is one trace, not two
fringes. After dark subtraction "full scale" is the clip level minus the dark's signal (what the
laser added at least). A pixel clipped in the dark frame too carries no difference in the laser
channel: it is unknown, not zero. In a colour frame the other channels tell whether the laser is
there (a red beam changes green and blue by its crosstalk; a glint of room light, clipped in both
frames, changes nothing), so such a pixel reads full scale where they changed by more than
``_CROSSTALK_SIGMAS`` of their noise, else 0.
"""

from __future__ import annotations

import dataclasses
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
MAD_TO_SIGMA = 1.4826
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
#: A pixel within this fraction of the saturation level counts as clipped.
CLIP_MARGIN = 0.03
#: A channel clips below the dtype's maximum at a value ``L`` (see :func:`channel_clip_levels`) that
#: holds at least ``_PILE_MIN_SHARE`` of the pixels (and ``_PILE_MIN_PIXELS``), ``_PILE_RATIO``
#: times as many as any of the ``_PILE_BELOW`` values under it (gain can leave every third value
#: empty, so not only the next one), at most ``_ABOVE_SHARE`` of its count above it, and whose
#: plateau's neighbouring pixels have a median below ``L`` but at least ``_RIM_FRACTION`` of the
#: way up from the channel's median to ``L``.
_PILE_MIN_SHARE = 1e-4
_PILE_MIN_PIXELS = 16
_PILE_RATIO = 5.0
_PILE_BELOW = 4
_ABOVE_SHARE = 0.01
_RIM_FRACTION = 0.5
#: Change of the non-laser channels, in noise σ, that shows the laser in a pixel clipped in both
#: the frame and the dark frame.
_CROSSTALK_SIGMAS = 6.0
#: Below this :func:`correlated_noise_factor` is taken as white noise (texture and traces raise the
#: factor of a white-noise frame by a few per cent).
_CORRELATED_NOISE_MIN = 1.25
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
        level = pixel_blocks(self.dark, np.ravel(v) - 1, np.ravel(u) - 1, 3, 3).astype(np.float32)
        if self.weights is not None:
            level = level @ np.asarray(self.weights, np.float32)
        var = self.offset + self.slope * level.mean(axis=(-2, -1))
        return np.sqrt(np.maximum(var, QUANTIZATION_SIGMA**2)).astype(np.float32).reshape(shape)

    @property
    def floor(self) -> float:
        """The lowest σ :meth:`sigma_at` returns (at level 0: the slope is never negative), DN."""
        return float(np.sqrt(np.maximum(np.float32(self.offset), np.float32(QUANTIZATION_SIGMA**2))))


@dataclass(frozen=True, eq=False)
class ColourFrames:
    """The raw colour frame (and dark frame) inside the region of interest.

    Attributes
    ----------
    image, dark : (H, W, 3) uint8 or uint16 arrays
        RGB; ``dark`` is None without a laser-off frame.
    laser_channel : int
        Index of the laser's colour (0 red, 1 green, 2 blue).
    clip_level : (3,) float array
        DN from which a pixel counts as clipped, per channel (its saturation level less ``CLIP_MARGIN``).
    """

    image: np.ndarray
    dark: np.ndarray | None
    laser_channel: int
    clip_level: np.ndarray

    @functools.cached_property
    def laser_plane(self) -> np.ndarray:
        """The laser channel, minus the dark frame's, ``(H, W)``, DN: float32, or without a dark
        frame the raw channel (integers: exact, and fast in the filters)."""
        return self._difference(self.laser_channel)

    @functools.cached_property
    def laser_box_sums(self) -> np.ndarray:
        """:func:`padded_box_sums` of :attr:`laser_plane`, for the prominence of many candidates
        along rows and columns."""
        return padded_box_sums(self.laser_plane)

    @functools.cached_property
    def laser_noise(self) -> float:
        """Noise σ of :attr:`laser_plane`, DN (:func:`effective_noise`)."""
        return effective_noise(self.laser_plane)

    @functools.cached_property
    def channel_noise(self) -> np.ndarray:
        """Noise σ ``(3,)`` of each raw channel (of frame − dark with a dark frame), DN
        (:func:`effective_noise`): measured once per frame, for every fit of its clipped traces."""
        return np.array([self.laser_noise if c == self.laser_channel else effective_noise(self._difference(c))
                         for c in range(3)])

    def _difference(self, c: int) -> np.ndarray:
        """Channel ``c`` minus the dark frame's, like :attr:`laser_plane`, DN."""
        import cv2

        if self.dark is None:
            return self.image[:, :, c]
        # OpenCV on the extracted planes: twice as fast as NumPy on the strided channels
        return cv2.subtract(cv2.extractChannel(self.image, c), cv2.extractChannel(self.dark, c), dtype=cv2.CV_32F)


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
        shot noise makes bright parts of the scene noisier than dark ones. The pre-scan uses it.
    background : (Hc, Wc) float32 array, DN
        Local background per ``BG_CELL`` pixel cell (see :func:`background_cells`).
    noise_model : NoiseModel or None
        Per-pixel noise, when a dark frame was subtracted and the noise was not given; then
        :meth:`noise_at` uses it instead of ``noise``.
    colour : ColourFrames or None
        The raw colour frames, for the fit of clipped traces from all channels
        (:mod:`scanrig.laser.colour_fit`); None for a grey frame or a grey laser.
    """

    signal: np.ndarray
    saturated: np.ndarray | None
    origin: tuple[int, int]
    noise_sigma: float
    noise: np.ndarray
    background: np.ndarray
    noise_model: NoiseModel | None = None
    colour: ColourFrames | None = None

    def background_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Background level, DN, at integer signal coordinates ``u``, ``v`` (same shape)."""
        return _cell_lookup(self.background, BG_CELL, u, v)

    def noise_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Noise standard deviation, DN, at integer signal coordinates ``u``, ``v`` (same shape):
        of the 3 × 3 pixels around each with a noise model, else of the cell."""
        if self.noise_model is not None:
            return self.noise_model.sigma_at(u, v)
        return _cell_lookup(self.noise, NOISE_CELL, u, v)

    def noise_floor(self) -> float:
        """The lowest :meth:`noise_at` anywhere in the frame, DN: a test that needs more than a few
        noise σ rejects with it what cannot pass before the noise is looked up."""
        return self.noise_model.floor if self.noise_model is not None else float(self.noise.min())

    @functools.cached_property
    def box_sums(self) -> np.ndarray:
        """:func:`padded_box_sums` of :attr:`signal`, computed once per frame for the candidate
        search along rows and columns and their prominence."""
        return padded_box_sums(self.signal)

    def box_sums_computed(self) -> bool:
        """Whether :attr:`box_sums` has been computed (by a search of the whole frame)."""
        return "box_sums" in self.__dict__


def pixel_blocks(a: np.ndarray, top: np.ndarray, left: np.ndarray, height: int, width: int) -> np.ndarray:
    """The blocks ``a[top + i, left + j]``, ``i < height``, ``j < width``, of an image, its edge
    repeated beyond it.

    Blocks inside the image are copied whole from a sliding-window view, without an index per
    value (three times faster), except from a transposed view, whose rows are strided (there the
    index per value is as fast).

    Parameters
    ----------
    a : (H, W) or (H, W, C) array
    top, left : (n,) int arrays
        Block corners, pixels; blocks may reach beyond the image.
    height, width : int
        Block size, pixels.

    Returns
    -------
    (n, height, width) or (n, height, width, C) array of ``a``'s dtype
    """
    n_rows, n_cols = a.shape[:2]
    inside = (top >= 0) & (top + height <= n_rows) & (left >= 0) & (left + width <= n_cols)
    inside &= a.strides[1] <= a.strides[0]
    if top.size and inside.all():
        return np.ascontiguousarray(_windows(a, top, left, height, width))
    out = np.empty((top.size, height, width) + a.shape[2:], a.dtype)
    whole = np.flatnonzero(inside)
    if whole.size:  # (never in an image smaller than a block)
        out[whole] = _windows(a, top[whole], left[whole], height, width)
    edge = np.flatnonzero(~inside)
    rows = np.clip(top[edge, None] + np.arange(height), 0, n_rows - 1)
    cols = np.clip(left[edge, None] + np.arange(width), 0, n_cols - 1)
    out[edge] = a[rows[:, :, None], cols[:, None, :]]
    return out


def _windows(a, top, left, height, width) -> np.ndarray:
    """:func:`pixel_blocks` lying inside ``a``, from its sliding-window view (channels last)."""
    from numpy.lib.stride_tricks import sliding_window_view

    return np.moveaxis(sliding_window_view(a, (height, width), axis=(0, 1))[top, left], (-2, -1), (1, 2))


def padded_box_sums(signal: np.ndarray) -> np.ndarray:
    """3 × 3 box sums of an image, DN, with one ring beyond its edges.

    Parameters
    ----------
    signal : (H, W) array, DN

    Returns
    -------
    (H + 2, W + 2) uint16 (8-bit image) or float32 array
        The sums centred on rows −1 .. H and columns −1 .. W, the image's edge pixels repeated
        beyond it. Exact: nine bytes sum to at most 2295, and the signals of
        :func:`prepare_image` are multiples of ½ DN far below 2**23. Half the bytes for 8-bit
        data make the filters over them twice as fast.
    """
    import cv2

    h, w = signal.shape
    depth, dtype = (cv2.CV_16U, np.uint16) if signal.dtype == np.uint8 else (cv2.CV_32F, np.float32)
    out = np.empty((h + 2, w + 2), dtype)
    cv2.boxFilter(np.ascontiguousarray(signal), depth, (3, 3), dst=out[1:-1, 1:-1], normalize=False,
                  borderType=cv2.BORDER_REPLICATE)
    # the ring: the sums there hold the edge row (column) three times, and its neighbours
    for ring, edge in ((out[0], signal[0]), (out[-1], signal[-1]), (out[:, 0], signal[:, 0]),
                       (out[:, -1], signal[:, -1])):
        e = np.concatenate([edge[:1], edge[:1], edge, edge[-1:], edge[-1:]]).astype(np.float32)
        ring[:] = 3 * (e[:-2] + e[1:-1] + e[2:])
    return out


def _cell_lookup(cells: np.ndarray, cell: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The values of ``cells`` at pixels ``u``, ``v`` (same shape); ``cell`` is a power of two,
    so the cell index is a shift (integer division is several times slower)."""
    hc, wc = cells.shape
    shift = cell.bit_length() - 1
    flat = np.minimum(np.right_shift(v, shift), hc - 1) * wc + np.minimum(np.right_shift(u, shift), wc - 1)
    return np.ascontiguousarray(cells).ravel().take(flat)


def prepare_image(
    image: np.ndarray,
    color: str = "grey",
    dark: np.ndarray | None = None,
    roi: tuple[int, int, int, int] | None = None,
    saturation_level: float | str | None = None,
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
    saturation_level : float or "auto", optional
        DN at which a pixel is clipped, in every channel; set it for a 12-bit camera stored in
        16-bit files. ``"auto"``: each channel's, found from the frame and the dark frame
        (:func:`channel_clip_levels`; for webcams that clip below 255). Default: the dtype's
        maximum (255 or 65535).
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
    if isinstance(saturation_level, str):
        if saturation_level != "auto":
            raise InputError(f"saturation_level must be a number of DN or 'auto', got {saturation_level!r}")
        levels = channel_clip_levels(image, dark)
    else:
        if saturation_level is None:
            saturation_level = full_scale
        elif not 0 < saturation_level <= full_scale:
            raise InputError(f"saturation_level must be in (0, {full_scale:g}] for {image.dtype} images, "
                             f"got {saturation_level}")
        levels = np.full(image.shape[2] if image.ndim == 3 else 1, float(saturation_level))
    # the level a clipped pixel of the signal stands for: its channel's, or the brightest channel's (grey)
    saturation_level = float(levels.max() if image.ndim == 2 or color == "grey" else levels[_CHANNEL[color]])
    clip_levels = levels * (1.0 - CLIP_MARGIN)
    saturated = _clipped(image, color, clip_levels)
    if saturated is not None:
        saturated = _close_gaps(saturated)
    signal = _signal(image, color)
    if dark is not None:
        dark_signal = np.asarray(_signal(dark, color), np.float32)  # a copy only of integer frames
        signal = np.subtract(signal, dark_signal, dtype=np.float32)
    dark_saturated = None
    if saturated is not None and signal.dtype == np.float32:
        # A white core reads as the brightest part of the trace; after dark subtraction, as what
        # the laser added at least: a glint just below the clip level that noise pushes over it
        # in one frame is not a spot at full scale.
        signal[saturated] = (saturation_level if dark is None
                             else saturation_level - np.maximum(dark_signal[saturated], 0.0))
        if dark is not None:
            dark_clipped = _clipped(dark, color, clip_levels)
            if dark_clipped is not None:
                dark_saturated = saturated & dark_clipped
                signal[dark_saturated] = 0.0  # until the other channels say otherwise (below)
    colour = None
    if image.ndim == 3 and color != "grey":
        colour = ColourFrames(image, dark, _CHANNEL[color], clip_levels)
    model = None
    if noise_sigma is None:
        rows, high_pass = _high_pass_bands(signal)
        noise_sigma, noise = _noise_from_bands(rows, high_pass, signal.shape,
                                               1.0 if color == "grey" or image.ndim == 2 else 0.5, local=True)
        if dark is not None:
            invalid = saturated
            if dark_saturated is not None:
                invalid = dark_saturated if invalid is None else invalid | dark_saturated
            model = fit_noise_model(rows, high_pass, dark, color, invalid)
        factor = correlated_noise_factor(signal, rows, noise_sigma)
        if factor > _CORRELATED_NOISE_MIN:
            noise_sigma, noise = noise_sigma * factor, noise * np.float32(factor)
            if model is not None:
                model = dataclasses.replace(model, offset=model.offset * factor**2, slope=model.slope * factor**2)
    elif not (np.isfinite(noise_sigma) and noise_sigma > 0):
        raise InputError(f"noise_sigma must be a positive number of DN, got {noise_sigma}")
    else:
        noise = np.full(_cells_shape(signal.shape, NOISE_CELL), noise_sigma, np.float32)
    if dark_saturated is not None and colour is not None and dark_saturated.any():
        seen = _crosstalk_changed(colour, dark_saturated, _CROSSTALK_SIGMAS * noise_sigma)
        signal[dark_saturated] = np.where(seen, np.float32(saturation_level), np.float32(0.0))
    return LaserImage(signal, saturated, (u0, v0), float(noise_sigma), noise, background_cells(signal), model,
                      colour)


def _close_gaps(clipped: np.ndarray) -> np.ndarray:
    """The clipped mask with one-pixel gaps closed (3 × 3 closing): JPEG ringing drops single
    pixels of a clipped plateau just below the clip level, and the run must stay one run."""
    import cv2

    kernel = np.ones((3, 3), np.uint8)
    return cv2.morphologyEx(clipped.view(np.uint8), cv2.MORPH_CLOSE, kernel).view(bool)


def _crosstalk_changed(colour: ColourFrames, where: np.ndarray, threshold: float) -> np.ndarray:
    """Whether the non-laser channels differ between frame and dark frame by more than
    ``threshold`` DN (sum of absolute changes) at the pixels ``where``: ``(n,)`` bool."""
    others = [c for c in range(3) if c != colour.laser_channel]
    on = colour.image[where][:, others].astype(np.float32)
    off = colour.dark[where][:, others].astype(np.float32)
    return np.abs(on - off).sum(axis=1) > threshold


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


def _clipped(image: np.ndarray, color: str, clip_levels: np.ndarray) -> np.ndarray | None:
    """Pixels ``(H, W)`` whose laser channel (any channel for a grey laser) is at or above its
    clip level ``clip_levels`` ``(C,)``, DN; None when there are none."""
    if image.ndim == 2:
        clipped = image >= clip_levels[0]
    elif color == "grey":
        clipped = (image >= clip_levels).any(axis=2)
    else:
        clipped = image[:, :, _CHANNEL[color]] >= clip_levels[_CHANNEL[color]]
    return clipped if clipped.any() else None


def channel_clip_levels(image: np.ndarray, dark: np.ndarray | None = None) -> np.ndarray:
    """The level, DN, at which each channel of a camera clips, found from its frames.

    Webcams often clip a channel below the dtype's maximum (their processing maps the sensor's
    full scale to a lower value), and the clipped pixels then pile up at that one value. A value
    ``L`` of a channel's histogram (frame and dark frame together) is its clip level when

    - it holds many pixels (``_PILE_MIN_SHARE`` of them, at least ``_PILE_MIN_PIXELS``), at least
      ``_PILE_RATIO`` times as many as each of the ``_PILE_BELOW`` values under it: noise spreads
      an unclipped flat area over several values, clipping stacks it on one;
    - few pixels lie above it (``_ABOVE_SHARE`` of its count): it is the top of the channel's range;
    - the pixels next to the plateau are bright too, but below it (their median is below ``L``
      and at least ``_RIM_FRACTION`` of the way up from the channel's median to ``L``): the light
      continues past the clip, so its run is entered from high values, whereas a flat printed or
      rendered area ends in a step down to the scene, or up to a brighter trace crossing it.

    The highest such value is the level; the dtype's maximum when there is none.

    Parameters
    ----------
    image : (H, W) or (H, W, C) uint8 or uint16 array
        The frame, DN.
    dark : array like ``image``, optional
        The laser-off frame of the same camera settings.

    Returns
    -------
    (C,) float array
        Clip level of each channel, DN (``C = 1`` for an ``(H, W)`` frame).
    """
    import cv2

    full_scale = int(np.iinfo(image.dtype).max)
    frames = [np.ascontiguousarray(f if f.ndim == 3 else f[:, :, None]) for f in (image, dark) if f is not None]
    levels = np.full(frames[0].shape[2], float(full_scale))
    for c in range(levels.size):
        # OpenCV's histogram of the interleaved frame: several times faster than np.bincount of a plane
        counts = sum(cv2.calcHist([f], [c], None, [full_scale + 1], [0, full_scale + 1]).ravel() for f in frames)
        counts = counts.astype(np.int64)
        above = counts.sum() - np.cumsum(counts)
        below = np.lib.stride_tricks.sliding_window_view(np.r_[np.zeros(_PILE_BELOW, counts.dtype), counts[:-1]],
                                                         _PILE_BELOW).max(axis=1)
        pile = ((counts >= max(_PILE_MIN_PIXELS, _PILE_MIN_SHARE * counts.sum()))
                & (counts >= _PILE_RATIO * below) & (above <= _ABOVE_SHARE * counts))
        pile[full_scale] = False  # the dtype's maximum is the default anyway
        median = int(np.searchsorted(np.cumsum(counts), 0.5 * counts.sum()))
        for level in np.flatnonzero(pile)[::-1]:
            rim = []
            for f in frames:
                plateau = (f[:, :, c] == level).view(np.uint8)
                ring = cv2.dilate(plateau, np.ones((3, 3), np.uint8)) > plateau
                rim.append(f[:, :, c][ring])
            if median + _RIM_FRACTION * (level - median) <= np.median(np.concatenate(rim)) < level:
                levels[c] = float(level)
                break
    return levels


def _signal(image: np.ndarray, color: str) -> np.ndarray:
    """Colour selection: the frame (grey), luma (colour frame, grey laser) or channel minus others."""
    import cv2

    if image.ndim == 2:
        return image
    if color == "grey":
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    k = _CHANNEL[color]
    others = [c for c in range(3) if c != k]
    # OpenCV on the split planes: one pass each, no float copy of the three channels (the values
    # are half-integers, exact in float32 whatever the order of the sums)
    planes = cv2.split(np.ascontiguousarray(image))
    half_others = cv2.addWeighted(planes[others[0]], 0.5, planes[others[1]], 0.5, 0.0, dtype=cv2.CV_32F)
    return cv2.subtract(planes[k], half_others, dtype=cv2.CV_32F)


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
    return _noise_from_bands(rows, high_pass, signal.shape, step, local)


def effective_noise(signal: np.ndarray) -> float:
    """Noise σ of an image for fits over a few pixels, DN: :func:`estimate_noise`, scaled by
    :func:`correlated_noise_factor` where the noise is correlated over a few pixels."""
    rows, high_pass = _high_pass_bands(signal)
    sigma = _noise_from_bands(rows, high_pass, signal.shape, 1.0, local=False)
    factor = correlated_noise_factor(signal, rows, sigma)
    return sigma * factor if factor > _CORRELATED_NOISE_MIN else sigma


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
        Centre rows of the bands (from :func:`_high_pass_bands`).
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
    median = float(np.partition(twice_h, twice_h.size // 2)[twice_h.size // 2]) / 2.0
    return max(1.0, MAD_TO_SIGMA * median / (np.sqrt(13.5) * sigma))


def _noise_from_bands(rows: np.ndarray, high_pass: np.ndarray, shape, step: float, local: bool):
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
    line = _weighted_line(x, y, np.ones_like(x))
    floor = QUANTIZATION_SIGMA**2
    for _ in range(_PTC_ITERATIONS):
        var = np.maximum(line[0] + line[1] * (x - line[2]), floor)
        clipped = np.minimum(y, _PTC_CLIP**2 * var) / _clipped_square()
        line = _weighted_line(x, clipped, 1.0 / var**2)
    value, slope, pivot, spread = line
    # Few bright samples (one glint in a dark frame) leave the slope uncertain: take its upper
    # bound, so that the threshold errs on the side of no false candidates where it is unsure.
    # h²/72 has variance 2 v², and the weights are 1/v²: var(slope) = 2 / Σ w (x − x̄)².
    slope += _PTC_SLOPE_MARGIN * np.sqrt(2.0 / spread) if spread > 0 else 0.0
    return NoiseModel(dark, weights, float(value - slope * pivot), float(slope))


def _weighted_line(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[float, float, float, float]:
    """Weighted least-squares line ``y ≈ value + slope · (x − pivot)``, ``pivot`` the weighted mean
    of ``x`` and ``slope ≥ 0``: returns ``(value, slope, pivot, Σ w (x − pivot)²)``."""
    w_sum = float(w.sum())
    pivot = float(np.dot(w, x)) / w_sum
    value = float(np.dot(w, y)) / w_sum
    wdx = w * (x - pivot)
    spread = float(np.dot(wdx, x - pivot))
    slope = max(float(np.dot(wdx, y)) / spread, 0.0) if spread > 0 else 0.0
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
