"""Frames whose colour is not what the laser colour assumes: grey frames stored as colour, and
frames whose laser shows in another channel (red and blue swapped, a wrong ``laser_color``).

A colour laser's signal is its channel minus the mean of the two others
(:mod:`scanrig.laser.image`): in a grey frame stored as three equal channels it is 0 everywhere,
and with red and blue swapped the stripe is negative. Neither is an error the detectors can see
on their own, so they are checked here: :func:`grey_frames` turns equal channels into the grey
frame they are, :func:`colour_shown` names the colour that finds far more laser than the one
asked for, and :func:`check_laser_colour` raises when it does, for the library's detectors. That
takes a detection in every other colour, so it runs only where the requested colour found no
bright laser and either its signal dips below its background more than it rises above it
(:func:`dips_more_than_rises`), as a laser of another colour makes it do, or its clipped
candidates are the white core of another colour's beam (:func:`clipped_candidates`).
"""

from __future__ import annotations

import contextvars
import functools
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from scanrig.errors import InputError
from scanrig.laser.background import BG_CELL
from scanrig.laser.pixels import cell_lookup

#: The colours a colour frame's laser may have (one channel each).
CHANNEL_COLOURS = ("red", "green", "blue")
#: Another colour must find at least this many times the light (or pixels) of the requested one to
#: be named. Measured on the real Ciclop frames (rank-0 peaks summed over the scan lines): the
#: right colour finds 3.5-180 times what the best other one does (bust, pattern, with and without
#: the laser-off frame), so with red and blue swapped the asked-for colour finds 3.5-180 times less.
FEWER_FACTOR = 3.0
#: Every this-many-th row is compared first; the whole frame only when those rows are equal.
_SAMPLE_ROW_STEP = 32
#: A colour finds a stripe only with a rank-0 candidate on at least this many scan lines (spots:
#: one candidate): fewer are texture.
LEAST_STRIPE_LINES = 20
#: A candidate counts as laser light for :func:`check_laser_colour` only with a fitted peak of at
#: least this fraction of the clip level. Measured on the real Ciclop frames (8-bit): the red
#: laser's rank-0 peaks reach it on 548-716 scan lines (bust, pattern, with and without the
#: laser-off frame); on the frames without the laser (the scene's warm colours and printed
#: texture) no colour's do on more than 2 lines (14 at 0.35, 59 at 0.25).
BRIGHT_FRACTION = 0.5
#: A stripe detection with candidates that bright on at least this fraction of the frame's scan
#: lines (of its smaller side) is not questioned. Where a laser of another colour turns white in
#: its core, every colour finds that part of it (:mod:`scanrig.laser.clipped_runs`): on the Ciclop
#: board with the laser-off frame, green or blue found bright candidates on 30-95 of the 960 rows,
#: where red finds 548-565.
TRUSTED_LINES_FRACTION = 1.0 / 8.0
#: :func:`dips_more_than_rises` reads the 3 x 3 box sums of every this-many-th row and column (the
#: same decision as every 8th or 16th on the Ciclop and rendered frames, 150 frame and colour
#: pairs: 34 x 60 lines of a 1920 x 1080 frame).
_DIP_LINE_STEP = 32
#: :func:`clipped_candidates` follows a clipped run at most this far from a candidate's pixel, px: a
#: red beam 8 times past full scale clips red over 8-10 px across the rendered stripe, and green
#: over the middle 1-3 of them.
CORE_REACH_PX = 16
#: True while :func:`colour_shown` asks its ``found_with`` for other colours: the detections made
#: there are comparisons, not checked themselves (:func:`check_laser_colour`).
_COMPARING = contextvars.ContextVar("comparing_colours", default=False)


def equal_channels(image: np.ndarray) -> bool:
    """Whether a frame's three channels are equal everywhere (a grey frame stored as colour).

    Rows ``0, _SAMPLE_ROW_STEP, 2 _SAMPLE_ROW_STEP, ...`` are compared first, so that a colour
    frame costs a thirty-second of a full comparison; only when they are equal is the whole frame.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The frame, DN.

    Returns
    -------
    bool
        False for an ``(H, W)`` frame (it has no channels to compare).
    """
    if image.ndim != 3:
        return False
    return all(_same_channels(rows) for rows in (image[::_SAMPLE_ROW_STEP], image))


def _same_channels(image: np.ndarray) -> bool:
    """Channel 0 equals channels 1 and 2 at every pixel of ``image`` ``(H, W, 3)``."""
    return bool(np.array_equal(image[:, :, 0], image[:, :, 1]) and np.array_equal(image[:, :, 0], image[:, :, 2]))


def grey_frames(image: np.ndarray, dark: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """A frame and its laser-off frame as grey ``(H, W)`` when their channels are equal.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The frame, DN.
    dark : array like ``image``, optional
        Its laser-off frame.

    Returns
    -------
    image, dark : arrays
        Channel 0 of each (contiguous) when both have three equal channels (or ``dark`` is None),
        else the inputs unchanged.
    """
    if not equal_channels(image) or (dark is not None and not equal_channels(dark)):
        return image, dark
    return tuple(None if f is None else np.ascontiguousarray(f[:, :, 0]) for f in (image, dark))


def colour_shown(image: np.ndarray, color: str, found_with: Callable[[str], float], least: float) -> str | None:
    """The laser colour a frame shows when it is not the requested one.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The frame, DN.
    color : {"grey", "red", "green", "blue"}
        The requested laser colour.
    found_with : callable
        ``found_with(colour) -> float``: how much laser the detector finds in ``image`` with that
        colour (pixels on the target, DN summed over the traces, ...; larger is more). Called only
        for a colour frame, once per colour.
    least : float
        Another colour is named only when it finds at least this much.

    Returns
    -------
    str or None
        The colour among red, green and blue (``color`` left out) that finds the most, when that
        is at least ``least`` and more than ``FEWER_FACTOR`` times what ``color`` finds; None for a
        grey frame (2-D or three equal channels, where every colour is the same signal) or when
        no colour does.
    """
    if image.ndim != 3 or equal_channels(image):
        return None
    comparing = _COMPARING.set(True)
    try:
        others = {other: found_with(other) for other in CHANNEL_COLOURS if other != color}
        best = max(others, key=others.get)
        if others[best] < least or others[best] <= FEWER_FACTOR * found_with(color):
            return None
    finally:
        _COMPARING.reset(comparing)
    return best


def one_colour(image: np.ndarray, found_with: Callable[[str], float]) -> str | None:
    """The colour of a colour frame's laser when one colour finds far more of it than the others.

    A laser asked for as grey is detected on the frame's luma, which holds every channel: a red
    laser's stripe shows there too, but with the scene's texture at full weight and the colour
    channels' crosstalk unused (the Ciclop bust with its laser-off frame: rank 0 on the stripe on
    90 % of rows as grey, 99 % as red). :func:`colour_shown` cannot tell where grey finds more
    than a third of the laser colour's light (the rendered red stripe at half full scale on
    printed paper, with its laser-off frame: 0.39 of it); the colours among themselves can (there
    red finds 115 times green's and blue's).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The frame, DN.
    found_with : callable
        As for :func:`colour_shown`; called for red, green and blue once each.

    Returns
    -------
    str or None
        The colour that finds more than ``FEWER_FACTOR`` times the light of each of the two others;
        None for a grey frame, or when none does (a white laser).
    """
    if image.ndim != 3 or equal_channels(image):
        return None
    comparing = _COMPARING.set(True)
    try:
        found = {colour: found_with(colour) for colour in CHANNEL_COLOURS}
    finally:
        _COMPARING.reset(comparing)
    best = max(found, key=found.get)
    far_more = all(found[best] > FEWER_FACTOR * light for colour, light in found.items() if colour != best)
    return best if far_more else None


def colour_advice(colour: str) -> str:
    """How to ask for ``colour``: ``"use --color red (or laser_color = 'red' in session.toml)"``."""
    return f"use --color {colour} (or laser_color = {colour!r} in session.toml)"


def laser_light(table, stripes: bool, least_peak: float = 0.0, clipped: np.ndarray | None = None) -> float:
    """The laser light a detection found, DN: the fitted peaks of at least ``least_peak`` (or
    ``clipped``) of its rank-0 candidates summed (stripes: one stripe crosses a scan line once; 0
    where such candidates lie on fewer than ``LEAST_STRIPE_LINES`` lines), or of all its
    candidates (spots: a frame may hold several).

    Parameters
    ----------
    table : pyarrow.Table
        One frame's detections (``traces.parquet`` columns), ``n`` rows.
    stripes : bool
        Stripe candidates (else spots).
    least_peak : float
        Candidates with a lower fitted peak are not counted, DN...
    clipped : (n,) bool array, optional
        ... unless set here: light past full scale, whose fitted peak is only a lower bound
        (:attr:`ClippedCandidates.own`).
    """
    peak = _bright_peaks(table, stripes, least_peak, clipped)
    return float(peak.sum()) if _enough(peak.size, stripes) else 0.0


def _enough(n_counted: int, stripes: bool) -> bool:
    """Whether ``n_counted`` rank-0 stripe candidates (spot candidates) make a laser: on at least
    ``LEAST_STRIPE_LINES`` scan lines, or one spot."""
    return n_counted >= (LEAST_STRIPE_LINES if stripes else 1)


def _bright_peaks(table, stripes: bool, least_peak: float, clipped: np.ndarray | None = None) -> np.ndarray:
    """The fitted peaks of the rank-0 candidates (stripes) or of all candidates (spots) of
    ``table`` with at least ``least_peak`` DN or set in ``clipped`` ``(n,)`` bool, ``(m,)``."""
    peak = table["peak"].to_numpy()
    counted = peak >= least_peak
    if clipped is not None:
        counted |= clipped
    return peak[counted & _line_candidates(table, stripes)]


def _line_candidates(table, stripes: bool) -> np.ndarray:
    """The candidates that may be laser light, ``(n,)`` bool: rank 0 (stripes: one stripe crosses a
    scan line once), or all (spots)."""
    return table["rank"].to_numpy() == 0 if stripes else np.ones(len(table), bool)


def checked_detection(detect: Callable, color: str, stripes: bool, k_detect: float, check: bool = True):
    """The detections of ``detect(color)``, checked (:func:`check_laser_colour`) when ``check``.

    Parameters
    ----------
    detect : callable
        ``detect(colour) -> (pyarrow.Table, LaserImage)``: one frame's detections in a colour and
        its signal.
    color : str
        The requested laser colour.
    stripes : bool
        Stripe detections (else spots).
    k_detect : float
        The detection threshold, in noise σ of the 3 x 3 box sum.
    check : bool

    Returns
    -------
    pyarrow.Table
        The detections in ``color``.
    """
    table, li = detect(color)
    if check:
        check_laser_colour(li, color, table, detect, stripes, k_detect)
    return table


class LaserColourError(InputError):
    """A colour frame's laser shows in another channel than the requested colour's
    (:func:`check_laser_colour`): ``shown`` is that colour, ``times`` how many times the requested
    colour's laser light it finds (``inf`` where that colour finds none)."""

    def __init__(self, message: str, shown: str, times: float):
        super().__init__(message)
        self.shown = shown
        self.times = times


def check_laser_colour(li, color: str, table, detect_with: Callable, stripes: bool, k_detect: float) -> None:
    """Raise when a colour frame's laser shows in another channel than ``color``'s.

    Laser light counts only from candidates whose peak reaches ``BRIGHT_FRACTION`` of the clip
    level (:func:`laser_light`): a scene of warm colours without the laser shows as much red
    texture as a red laser, but no candidate that bright. A detection that found such light (on
    ``TRUSTED_LINES_FRACTION`` of the frame's scan lines at least, for stripes) is taken as it is:
    the usual case, in which nothing more is computed. Otherwise, where the signal dips below its
    background more than it rises above it (:func:`dips_more_than_rises`), as a laser of another
    colour makes it do, or where ``color``'s clipped candidates are the white core of another
    colour's beam (:func:`clipped_candidates`, on ``LEAST_STRIPE_LINES`` scan lines or one spot),
    every other colour is detected and one that finds more than ``FEWER_FACTOR`` times the light of
    ``color`` is named (:func:`colour_shown`). In that comparison a candidate on light past full
    scale in its own colour (:attr:`ClippedCandidates.own`) counts whatever its fitted peak, a
    lower bound there: the rendered red stripe at 1 x full scale rises 85 DN above its paper (a
    third of the clip level) while red clips on 401 of its 480 rows; the Ciclop's frames without
    the laser clip on none. Not checked: grey frames and grey lasers, and detections made for
    :func:`colour_shown` itself.

    Parameters
    ----------
    li : LaserImage
        The frame's signal in ``color`` (:func:`~scanrig.laser.image.prepare_image`).
    color : str
        The requested laser colour.
    table : pyarrow.Table
        The detections in ``color``.
    detect_with : callable
        ``detect_with(colour) -> (pyarrow.Table, LaserImage)``: the frame's detections in another
        colour and its signal.
    stripes : bool
        Stripe detections (else spots).
    k_detect : float
        The detection threshold, in noise σ of the 3 x 3 box sum.

    Raises
    ------
    LaserColourError
        ``"color='red': no red laser in this frame; its blue channel shows one (103454 DN of laser
        light): use color='blue' (red and blue are swapped where RGB data were stored as BGR)"``;
        the part in brackets only for red and blue.
    """
    if li.colour is None or _COMPARING.get():
        return
    least_peak = BRIGHT_FRACTION * float(li.colour.clip_level.max())
    bright = _bright_peaks(table, stripes, least_peak).size
    if bright >= (TRUSTED_LINES_FRACTION * min(li.signal.shape) if stripes else 1):
        return
    clipped = clipped_candidates(li, table)
    if not (_enough(np.count_nonzero(clipped.cores & _line_candidates(table, stripes)), stripes)
            or dips_more_than_rises(li, k_detect)):
        return

    @functools.cache
    def light(colour: str) -> float:
        other, other_li = detect_with(colour)
        return laser_light(other, stripes, least_peak, clipped_candidates(other_li, other).own)

    found = laser_light(table, stripes, least_peak, clipped.own)
    best = colour_shown(li.colour.image, color, lambda colour: found if colour == color else light(colour), 0.0)
    if best is not None:
        what = (f"no {color} laser in this frame" if found == 0 else
                f"{color} finds {light(best) / found:.0f} times less laser light than {best} in this frame")
        swapped = (" (red and blue are swapped where RGB data were stored as BGR)"
                   if {color, best} == {"red", "blue"} else "")
        raise LaserColourError(f"color={color!r}: {what}; its {best} channel shows one ({light(best):.0f} DN of "
                               f"laser light): use color={best!r}{swapped}", best,
                               light(best) / found if found else float("inf"))


class ClippedCandidates(NamedTuple):
    """Which candidates of one colour sit on a clipped run of its channel (:func:`clipped_candidates`).

    Attributes
    ----------
    own : (n,) bool array
        Its channel is clipped at the candidate's pixel over a run across the beam that reaches
        beyond every other channel's clipped there, on both sides: light past full scale in this
        colour.
    cores : (n,) bool array
        Its channel is clipped at the candidate's pixel, inside a clipped run of another channel
        that reaches further on both sides: the white core of that colour's beam.
    """

    own: np.ndarray
    cores: np.ndarray


def clipped_candidates(li, table) -> ClippedCandidates:
    """Tell the white core of another colour's beam from light past full scale in the signal's colour.

    A beam so bright that the other channels' crosstalk clips in its core clips its own channel
    over a band wider on both sides: on the rendered red stripe 8 times past full scale, red
    clips over 8-10 px of a row, green over the middle 1-3 (247, 173, 188 beside 255, 255, 251).
    So a candidate on a clipped run of its colour's channel that lies strictly inside a clipped
    run of another channel is that channel's light, and one whose run reaches beyond those of
    all other channels clipped there is its own; runs that end alike (white light) are neither.
    The runs are followed in the raw frame along the row and the column through the candidate's
    pixel (``CORE_REACH_PX`` at most each way), across the beam: where the candidate's channel's
    run is the shorter. Only the candidates flagged ``saturated`` are read (none in most
    frames), and neither set holds one where the scene itself reaches the clip level
    (:attr:`~scanrig.laser.image.LaserImage.seed_floor`): there a clipped pixel is the scene's.
    Measured on the rendered stripes (1-8 x full scale, red and green lasers, with and without
    the laser-off frame) and the Ciclop frames: no right colour's candidate is a core; green
    asked of the red stripe at 8 x finds 269-270 cores among its 272 clipped candidates.

    Parameters
    ----------
    li : LaserImage
        The frame's signal in the candidates' colour (``li.colour`` set).
    table : pyarrow.Table
        Its detections (full-frame ``u``, ``v``; ``saturated``), ``n`` rows.

    Returns
    -------
    ClippedCandidates
    """
    saturated = table["saturated"].to_numpy(zero_copy_only=False)
    own, cores = np.zeros(saturated.size, bool), np.zeros(saturated.size, bool)
    at = np.flatnonzero(saturated)
    if at.size:
        u0, v0 = li.origin
        u = np.rint(table["u"].to_numpy()[at]).astype(np.int64) - u0
        v = np.rint(table["v"].to_numpy()[at]).astype(np.int64) - v0
        if li.seed_floor is not None:  # not where the scene reaches the clip level
            keep = cell_lookup(li.seed_floor, BG_CELL, u, v) == 0
            at, u, v = at[keep], u[keep], v[keep]
        own[at], cores[at] = _on_clipped_runs(li.colour.image, li.colour.clip_level, u, v, li.colour.laser_channel)
    return ClippedCandidates(own, cores)


def _on_clipped_runs(image: np.ndarray, clip_level: np.ndarray, u: np.ndarray, v: np.ndarray,
                     channel: int) -> tuple[np.ndarray, np.ndarray]:
    """For the pixels ``u``, ``v`` ``(m,)`` of ``image`` ``(H, W, 3)`` whose ``channel`` is clipped
    (at ``clip_level`` ``(3,)`` DN or above), across the beam: whether every other channel
    clipped there has a run that ``channel``'s reaches beyond on both sides (own light), and
    whether one reaches beyond ``channel``'s on both sides (a white core), ``(m,)`` bool each;
    neither where the runs end alike (a glint of white light, a scene clipped in every channel).
    The runs are read only where another channel is clipped at the pixel too (none on a right
    colour's beam short of its white core)."""
    on = _clipped_at(image, clip_level, u, v)  # (m, 3)
    clipped = on[:, channel]
    own, cores = clipped.copy(), np.zeros_like(clipped)
    white = clipped & (np.count_nonzero(on, axis=1) > 1)
    if white.any():
        reach = _run_reach(image, clip_level, u[white], v[white])  # (w, axis, side, 3)
        across = np.argmin(reach[..., channel].sum(axis=2), axis=1)  # the axis of the shorter run
        sides = reach[np.arange(across.size), across]  # (w, side, 3)
        mine = sides[:, :, [channel]]
        others = on[white] & (np.arange(3) != channel)
        cores[white] = (others & np.all(sides > mine, axis=1)).any(axis=1)
        own[white] = ~(others & ~np.all(sides < mine, axis=1)).any(axis=1)
    return own, cores


def _clipped_at(image: np.ndarray, clip_level: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Whether each channel is clipped at the pixels ``u``, ``v`` (any shape ``S``), ``S + (3,)``
    bool; False outside the frame."""
    h, w = image.shape[:2]
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return (image[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)] >= clip_level) & inside[..., None]


def _run_reach(image: np.ndarray, clip_level: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """How many pixels past ``u``, ``v`` ``(m,)`` each channel stays clipped without a break, up to
    ``CORE_REACH_PX``, along the row (left, right) and the column (up, down): ``(m, 2, 2, 3)`` ints."""
    steps = np.arange(1, CORE_REACH_PX + 1)
    du = np.concatenate([-steps, steps, 0 * steps, 0 * steps])  # row left, right; column up, down
    dv = np.concatenate([0 * steps, 0 * steps, -steps, steps])
    clipped = _clipped_at(image, clip_level, u[:, None] + du, v[:, None] + dv).reshape(u.size, 2, 2, -1, 3)
    # the first pixel not clipped (a sentinel after the last) is each run's reach
    ends = np.concatenate([clipped, np.zeros_like(clipped[:, :, :, :1])], axis=3)
    return np.argmin(ends, axis=3)


def dips_more_than_rises(li, k_detect: float) -> bool:
    """Whether the laser signal holds more light below its background than above it.

    A laser of another colour than the signal's is a dip: channel ``k`` minus the mean of the
    others loses half of what the laser adds to one of them. On every ``_DIP_LINE_STEP``-th row
    and column, the 3 x 3 box sums' highest and lowest (the detectors' matched filter) count where
    they pass the detection test, above or below the background; the dips' excess summed over the
    lines is compared with the rises'. 1-2 ms of CPU on a 1920 x 1080 frame (reading the sampled
    columns costs most), so asked only where no bright laser was found.

    Parameters
    ----------
    li : LaserImage
        A colour laser's signal.
    k_detect : float
        The detection threshold, in noise σ of the box sum.

    Returns
    -------
    bool
    """
    light = {1.0: 0.0, -1.0: 0.0}  # rises, dips
    for along_rows in (True, False):
        lines, where_high, where_low = _box_extremes(li.signal, _DIP_LINE_STEP, along_rows)
        for (pos, box), sign in ((where_high, 1.0), (where_low, -1.0)):
            u, v = (pos, lines) if along_rows else (lines, pos)
            excess = sign * (box - 9.0 * li.background_at(u, v))
            noise = 3.0 * np.maximum(li.noise_at(u, v), li.clutter_at(u, v))
            light[sign] += float(excess[excess > k_detect * noise].sum())
    return light[-1.0] > light[1.0]


def _box_extremes(signal: np.ndarray, step: int, along_rows: bool):
    """The highest and lowest 3 x 3 box sum along every ``step``-th row (or column) of ``signal``.

    Parameters
    ----------
    signal : (H, W) array
        DN.
    step : int
    along_rows : bool
        Rows (else columns).

    Returns
    -------
    lines : (n,) int array
        The rows (columns): the box sums' centre lines, ``1, 1 + step, ...``.
    (pos, box), (pos, box) : pairs of (n,) arrays
        Position along the line (int, the box's centre) and value (DN) of each line's highest, then
        lowest box sum.
    """
    lines = np.arange(1, signal.shape[0 if along_rows else 1] - 1, step)
    three = lines[:, None] + np.arange(-1, 2)  # each line and its neighbours
    if along_rows:
        sums = signal[three].sum(axis=1, dtype=np.float32)  # (n, W)
    else:  # the columns picked from each row: contiguous reads, not one cache line per pixel
        sums = signal[:, three.ravel()].reshape(signal.shape[0], lines.size, 3).sum(axis=2, dtype=np.float32).T
    box = sums[:, :-2] + sums[:, 1:-1] + sums[:, 2:]
    index = np.arange(lines.size)
    high, low = box.argmax(axis=1), box.argmin(axis=1)
    return lines, (high + 1, box[index, high]), (low + 1, box[index, low])
