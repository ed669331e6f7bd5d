"""From a camera frame to the laser signal: colour channel, dark frame, region of interest, noise.

The detectors see one ``(H, W)`` *signal* image in DN (digital numbers of the input's bit depth):

- ``grey``: the frame itself (a colour frame is converted to luma);
- ``red`` / ``green`` / ``blue``: that channel minus the mean of the two others, which removes white
  ambient light and grey texture. It is *not* clipped at 0: clipping would turn zero-mean noise
  into a biased half-normal background and bias both the noise estimate and the fit tails;
- minus the laser-off (dark) frame of the same camera, processed the same way, when given.

Noise: :mod:`scanrig.laser.noise` (per cell from the frame, or per pixel from the dark frame).

Clipping. The saturation level is the dtype's maximum, a given level, or (``"auto"``) each
channel's found from the frame (:func:`~scanrig.laser.clip_level.channel_clip_levels`): a webcam's processing can clip a
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

A scene that itself comes near the clip level (white paper under auto exposure):
:mod:`scanrig.laser.bright_scene`.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError, ShapeError
from scanrig.laser.background import BG_CELL, background_cells
from scanrig.laser.bright_scene import (
    hide_clipped_scene,
    scene_level_cells,
    scene_reaches_clip,
    show_cores,
    warn_if_bright,
)
from scanrig.laser.channels import CHANNEL, CLIP_MARGIN, LASER_COLORS
from scanrig.laser.clip_level import channel_clip_levels
from scanrig.laser.colour_check import grey_frames
from scanrig.laser.colour_frames import ColourFrames
from scanrig.laser.exposure import exposure_matched
from scanrig.laser.luma import LumaDifference, luma_difference
from scanrig.laser.noise import (
    CORRELATED_NOISE_MIN,
    NOISE_CELL,
    NoiseModel,
    clutter_cells,
    correlated_noise_factor,
    fit_noise_model,
    high_pass_bands,
    noise_from_bands,
)
from scanrig.laser.pixels import cell_lookup, cells_shape, padded_box_sums

#: Change of the non-laser channels, in noise σ, that shows the laser in a pixel clipped in both
#: the frame and the dark frame.
_CROSSTALK_SIGMAS = 6.0


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
        Local background per ``BG_CELL`` pixel cell
        (see :func:`~scanrig.laser.background.background_cells`).
    noise_model : NoiseModel or None
        Per-pixel noise, when a dark frame was subtracted and the noise was not given; then
        :meth:`noise_at` uses it instead of ``noise``.
    colour : ColourFrames or None
        The raw colour frames, for the fit of clipped traces from all channels
        (:mod:`scanrig.laser.colour_fit`); None for a grey frame or a grey laser.
    seed_floor : (Hc, Wc) float32 array or None
        Per ``BG_CELL`` cell, the least signal, DN, that seeds a search there
        (:func:`~scanrig.laser.peaks.prescan`): half of full scale where the scene itself reaches the
        clip level, so that only a laser core the other channels show seeds there (:func:`prepare_image`),
        0 elsewhere; None in a frame whose scene is not that bright.
    """

    signal: np.ndarray
    saturated: np.ndarray | None
    origin: tuple[int, int]
    noise_sigma: float
    noise: np.ndarray
    background: np.ndarray
    noise_model: NoiseModel | None = None
    colour: ColourFrames | None = None
    seed_floor: np.ndarray | None = None

    def background_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Background level, DN, at integer signal coordinates ``u``, ``v`` (same shape)."""
        return cell_lookup(self.background, BG_CELL, u, v)

    def noise_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Noise standard deviation, DN, at integer signal coordinates ``u``, ``v`` (same shape):
        of the 3 × 3 pixels around each with a noise model, else of the cell."""
        if self.noise_model is not None:
            return self.noise_model.sigma_at(u, v)
        return cell_lookup(self.noise, NOISE_CELL, u, v)

    @functools.cached_property
    def clutter(self) -> np.ndarray:
        """Structured clutter per ``NOISE_CELL`` pixel cell, DN (0 where there is none beyond the
        noise): JPEG blocking and ringing of a colour difference, whose chroma JPEG stores at half
        resolution, which a peak of a stripe must clear as it must clear the noise
        (:func:`~scanrig.laser.noise.clutter_cells`). Measured once per frame, when asked; 0 for a
        grey signal (luma keeps full resolution: its noise estimate sees its structure)."""
        if self.colour is None:
            return np.zeros_like(self.noise)
        return clutter_cells(self.signal, self.noise, self.box_sums if self.box_sums_computed() else None)

    def clutter_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """:attr:`clutter`, DN, at integer signal coordinates ``u``, ``v`` (same shape). A stripe's
        peak is tested against the larger of it and :meth:`noise_at`; the fits' σ is
        :meth:`noise_at` alone."""
        return cell_lookup(self.clutter, NOISE_CELL, u, v)

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

    @functools.cached_property
    def luma(self) -> LumaDifference:
        """:func:`~scanrig.laser.luma.luma_difference` of the colour frame and its laser-off frame,
        computed once per frame when asked (both scan directions use it)."""
        return luma_difference(self.colour)


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
        The frame as read (RGB order for colour), DN. Three equal channels are a grey frame
        (:func:`~scanrig.laser.colour_check.grey_frames`), whatever ``color`` says.
    color : {"grey", "red", "green", "blue"}
        Laser colour.
    dark : array like ``image``, optional
        Laser-off frame of the same camera, subtracted after colour selection.
    roi : (u0, v0, u1, v1) ints, optional
        Region of interest, pixels, end-exclusive. Default: the whole frame.
    saturation_level : float or "auto", optional
        DN at which a pixel is clipped, in every channel. ``"auto"``: each channel's, found from the
        frame and the dark frame (:func:`~scanrig.laser.clip_level.channel_clip_levels`; for a colour
        camera, whose white balance can clip a channel below 255, and 10- to 14-bit data in 16-bit
        files). Default: the dtype's maximum (255 or 65535).
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
    # a grey frame stored as three equal channels is grey: a colour laser's signal there, its
    # channel minus the others, would be 0
    image, dark = grey_frames(image, dark)
    u0, v0, u1, v1 = _check_roi(roi, image.shape)
    image = image[v0:v1, u0:u1]
    dark = None if dark is None else exposure_matched(image, dark[v0:v1, u0:u1])
    full_scale = float(np.iinfo(image.dtype).max)
    if isinstance(saturation_level, str):
        if saturation_level != "auto":
            raise InputError(f"saturation_level must be a number of DN or 'auto', got {saturation_level!r}")
        levels = channel_clip_levels(image, dark, CHANNEL[color] if image.ndim == 3 and color != "grey" else None)
    else:
        if saturation_level is None:
            saturation_level = full_scale
        elif not 0 < saturation_level <= full_scale:
            raise InputError(f"saturation_level must be in (0, {full_scale:g}] for {image.dtype} images, "
                             f"got {saturation_level}")
        levels = np.full(image.shape[2] if image.ndim == 3 else 1, float(saturation_level))
    # the level a clipped pixel of the signal stands for: its channel's, or the brightest channel's (grey)
    saturation_level = float(levels.max() if image.ndim == 2 or color == "grey" else levels[CHANNEL[color]])
    clip_levels = levels * (1.0 - CLIP_MARGIN)
    colour = None
    if image.ndim == 3 and color != "grey":
        signal, raw_laser = _colour_signal(image, dark, CHANNEL[color])
        colour = ColourFrames(image, dark, CHANNEL[color], clip_levels, raw_laser)
        saturated = _clipped(image, color, clip_levels, raw_laser)
    else:
        signal = _signal(image, color)
        if dark is not None:
            signal = np.subtract(signal, _signal(dark, color), dtype=np.float32)
        saturated = _clipped(image, color, clip_levels)
    if saturated is not None:
        saturated = _close_gaps(saturated)
    unknown = scene_at = seed_floor = background = None
    if saturated is not None:
        if image.ndim == 2 and dark is None:  # the signal is the frame, and stays so: its background
            background = scene_level = background_cells(signal)
        else:
            scene_level = scene_level_cells(image if dark is None else dark, color)
        scene_clipped = scene_reaches_clip(scene_level, saturation_level)
        bright = warn_if_bright(scene_clipped, color, saturation_level)
        if signal.dtype == np.float32:
            at = np.flatnonzero(saturated)
            unknown = _clipped_to_full_scale(signal, at, dark, color, clip_levels, saturation_level)
            if bright and colour is not None:  # 0 until a laser's core shows (below)
                scene_at, near, seed_floor = hide_clipped_scene(signal, unknown, saturated, at, scene_clipped, dark,
                                                                colour.laser_channel, saturation_level)
    model = None
    if noise_sigma is None:
        rows, high_pass = high_pass_bands(signal)
        noise_sigma, noise = noise_from_bands(rows, high_pass, signal.shape,
                                               1.0 if color == "grey" or image.ndim == 2 else 0.5, local=True)
        if dark is not None:
            model = fit_noise_model(rows, high_pass, dark, color, saturated)  # unknown pixels are among them
        factor = correlated_noise_factor(signal, rows, noise_sigma)
        if factor > CORRELATED_NOISE_MIN:
            noise_sigma, noise = noise_sigma * factor, noise * np.float32(factor)
            if model is not None:
                model = dataclasses.replace(model, offset=model.offset * factor**2, slope=model.slope * factor**2)
    elif not (np.isfinite(noise_sigma) and noise_sigma > 0):
        raise InputError(f"noise_sigma must be a positive number of DN, got {noise_sigma}")
    else:
        noise = np.full(cells_shape(signal.shape, NOISE_CELL), noise_sigma, np.float32)
    if unknown is not None and colour is not None and unknown.any():
        seen = _crosstalk_changed(colour, unknown, _CROSSTALK_SIGMAS * noise_sigma)
        signal[unknown] = np.where(seen, np.float32(saturation_level), np.float32(0.0))
    if scene_at is not None:
        show_cores(signal, saturated, scene_at, colour, near, scene_level, saturation_level)
    if background is None:
        background = background_cells(signal)
    return LaserImage(signal, saturated, (u0, v0), float(noise_sigma), noise, background, model, colour, seed_floor)


def _close_gaps(clipped: np.ndarray) -> np.ndarray:
    """The clipped mask with one-pixel gaps closed (3 × 3 closing): JPEG ringing drops single
    pixels of a clipped plateau just below the clip level, and the run must stay one run."""
    import cv2

    kernel = np.ones((3, 3), np.uint8)
    return cv2.morphologyEx(clipped.view(np.uint8), cv2.MORPH_CLOSE, kernel).view(bool)


def _clipped_to_full_scale(signal: np.ndarray, at: np.ndarray, dark: np.ndarray | None, color: str,
                           clip_levels: np.ndarray, saturation_level: float) -> np.ndarray | None:
    """Set the clipped pixels of a float32 ``signal`` ``(H, W)`` to full scale, in place, and
    those clipped in the dark frame too (where the laser channel is unknown) to 0; return the mask
    ``(H, W)`` of the latter (None when there are none).

    A white core reads as the brightest part of the trace; after dark subtraction, as what the
    laser added at least: a glint just below the clip level that noise pushes over it in one
    frame is not a spot at full scale.

    Parameters
    ----------
    at : (n,) int array
        Flat indices of the clipped pixels (a boolean mask would be scanned whole each time).
    dark : array or None
        The laser-off frame (cropped like ``signal``).
    clip_levels : (C,) float array
        DN from which a pixel counts as clipped, per channel.
    saturation_level : float
        Full scale of the signal, DN.
    """
    if dark is None:
        np.put(signal, at, saturation_level)
        unknown_at = None
    else:
        # the dark frame's pixels there, as a one-row frame
        dark_at = dark[np.divmod(at, signal.shape[1])][None]
        np.put(signal, at, saturation_level - np.maximum(_signal(dark_at, color)[0].astype(np.float32), 0.0))
        # clipped in the dark frame too (asked only where the frame is clipped)
        dark_clipped = _clipped(dark_at, color, clip_levels)
        unknown_at = None if dark_clipped is None else dark_clipped[0]
    if unknown_at is None:
        return None
    unknown = np.zeros(signal.shape, bool)
    np.put(unknown, at[unknown_at], True)
    np.put(signal, at[unknown_at], 0.0)  # until the other channels say otherwise (prepare_image)
    return unknown


def _crosstalk_changed(colour: ColourFrames, where: np.ndarray, threshold: float) -> np.ndarray:
    """Whether the non-laser channels differ between frame and dark frame by more than
    ``threshold`` DN (sum of absolute changes) at the pixels ``where``: ``(n,)`` bool."""
    others = colour.other_channels
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


def _clipped(image: np.ndarray, color: str, clip_levels: np.ndarray,
             laser_channel: np.ndarray | None = None) -> np.ndarray | None:
    """Pixels ``(H, W)`` whose laser channel (any channel for a grey laser) is at or above its
    clip level ``clip_levels`` ``(C,)``, DN; None when there are none. ``laser_channel``: that
    channel of a colour ``image`` ``(H, W)``, when already extracted."""
    # an integer pixel is at or above a level where it is at or above its ceiling: NumPy compares
    # integers ten times faster than with a float
    levels = np.ceil(clip_levels).astype(image.dtype)
    if image.ndim == 3 and color == "grey":
        clipped = (image >= levels).any(axis=2)
        return clipped if clipped.any() else None
    if image.ndim == 2:
        plane, level = image, levels[0]
    else:
        import cv2

        # the channel extracted by OpenCV first: twice as fast as comparing it in place, strided
        k = CHANNEL[color]
        plane = cv2.extractChannel(np.ascontiguousarray(image), k) if laser_channel is None else laser_channel
        level = levels[k]
    # a frame without clipped pixels (the usual case) is told by its maximum: one SIMD pass, six
    # times faster than the comparison and its test
    return plane >= level if plane.max() >= level else None


def _signal(image: np.ndarray, color: str) -> np.ndarray:
    """Colour selection: the frame (grey), luma (colour frame, grey laser) or channel minus others."""
    import cv2

    if image.ndim == 2:
        return image
    if color == "grey":
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    return _colour_signal(image, None, CHANNEL[color])[0]


#: Bytes of the float32 strip of a colour frame's three channels that :func:`_colour_signal` works
#: on at a time: a strip stays in the core's cache between its two passes.
_STRIP_BYTES = 1 << 20


def _colour_signal(image: np.ndarray, dark: np.ndarray | None, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The signal of a colour laser, and the frame's laser channel.

    The frame (less the dark frame) is made float32 and its channels combined by one OpenCV
    transform, strip by strip of rows (``_STRIP_BYTES``): the float strip is read back from the
    cache, not from memory: on a 1920 × 1080 frame 2.5-3 times as fast as the same two passes over
    the whole frame, or as OpenCV's split channels combined.

    Parameters
    ----------
    image, dark : (H, W, 3) uint8 or uint16 arrays
        The frame and the laser-off frame (or None), DN.
    k : int
        The laser's channel.

    Returns
    -------
    signal : (H, W) float32 array, DN
        Channel ``k`` minus the mean of the two others, minus the same of ``dark``.
    raw_laser : (H, W) array like ``image``, DN
        Channel ``k`` of ``image``, contiguous.
    """
    import cv2

    weights = np.full((1, 3), -0.5)
    weights[0, k] = 1.0
    h, w = image.shape[:2]
    signal = np.empty((h, w), np.float32)
    step = max(1, _STRIP_BYTES // (3 * 4 * w))
    frames = np.empty((step, w, 3), np.float32)
    for top in range(0, h, step):
        rows = slice(top, top + step)
        strip = frames[: min(step, h - top)]
        if dark is None:
            np.copyto(strip, image[rows])
        else:
            cv2.subtract(image[rows], dark[rows], dst=strip, dtype=cv2.CV_32F)
        # the values are half-integers, exact in float32 whatever the order of the sums
        cv2.transform(strip, weights, dst=signal[rows])
    return signal, cv2.extractChannel(np.ascontiguousarray(image), k)
