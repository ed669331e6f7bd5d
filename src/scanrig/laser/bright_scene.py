"""A scene that itself comes near the laser channel's clip level: the warning, and its clipped pixels.

A scene near the clip level (white paper under auto exposure) leaves the laser no room: noise and
JPEG's ringing around print flag its pixels as clipped, and each would read full scale and be
fitted as a stripe (a thousand blobs a frame: ten times a frame's time). Where the scene (the
laser-off frame, else the frame; :func:`scene_level_cells`) is within ``SCENE_MARGINS`` ×
``CLIP_MARGIN`` of the clip level (:func:`scene_reaches_clip`) on more than ``BRIGHT_SCENE_SHARE``
of the frame, :func:`~scanrig.laser.image.prepare_image` warns (:func:`warn_if_bright`,
:class:`BrightSceneWarning`), and in a colour frame the pixels flagged where the scene is that
bright are unknown and read 0 (:func:`hide_clipped_scene`), unless a laser's core shows
(:func:`show_cores`): with a laser-off frame, by its crosstalk raising both other channels; without
one, by its width. Only such a core seeds a search there
(:attr:`~scanrig.laser.image.LaserImage.seed_floor`, :func:`_seed_floor`): without a laser-off
frame in every cell, with one in the cells whose scene reaches the clip level and around those
whose pixels are mostly flagged as clipped.
"""

from __future__ import annotations

import warnings

import numpy as np

from scanrig.geometry.uncertainty import MAD_TO_SIGMA
from scanrig.laser.background import BG_CELL, BG_STRIDE, strided_cell_medians
from scanrig.laser.channels import CHANNEL, CLIP_MARGIN
from scanrig.laser.colour_frames import ColourFrames
from scanrig.laser.noise import QUANTIZATION_SIGMA
from scanrig.laser.pixels import cell_lookup

#: A ``BG_CELL`` cell's scene reaches the clip level where its level (:func:`scene_level_cells`) is
#: within this many ``CLIP_MARGIN`` of it: JPEG's ringing overshoots the edges of print there by
#: about as much again. On the rendered paper of ``benchmarks/bench_colour_sweep.py`` the pixels
#: flagged away from the stripe lie along the printed dots' edges from a paper level of 0.92 of full
#: scale (3-6 times a frame's time); the share of the frame this bright is 0 up to 0.88, 0.15-0.35
#: at 0.9 and 0.88-0.94 from 0.92 on; on the real Ciclop board frame, whose dark red clips at 180
#: DN over a part of the scene, 6 % (under ``BRIGHT_SCENE_SHARE``: its detections do not change).
SCENE_MARGINS = 3.0
#: Rise of each non-laser channel, in its noise σ, that shows a laser's core where the scene
#: reaches the clip level (:func:`_crosstalk_raised`).
_RISE_SIGMAS = 4.0
#: Without a laser-off frame, a laser's clipped core where the scene reaches the clip level is a
#: band at least this wide, px (:func:`_wide_cores`; a beam of σ 1.2 px 8 times past full scale
#: clips over 7 px, one of σ 0.6 px over 3.5 px, which is lost there).
_CORE_WIDTH_PX = 5
#: ... in cells where noise alone flags at most this share of the pixels (0.46-0.72 of the cells'
#: at a paper level of 0.96 of full scale, none at 0.94 but along the stripe, up to 0.17 there).
_NOISE_CLIPPED_SHARE = 0.3
#: A core's flanks, px: clipped in the laser channel where the scene reaches the clip level, the
#: other channels risen too little to show the core (at a paper level of 0.94 of full scale, with
#: the laser-off frame: rank 0 within 0.5 px on 0.69 of the rows, against 0.49 with none).
_FLANK_PX = 2
#: :func:`~scanrig.laser.image.prepare_image` warns where the scene reaches the clip level on more
#: than this share of the frame.
BRIGHT_SCENE_SHARE = 0.1


class BrightSceneWarning(UserWarning):
    """The scene itself reaches the laser channel's clip level on a large part of a frame, where
    the laser cannot show (:func:`~scanrig.laser.image.prepare_image`): the exposure or the gain
    is too high."""


def scene_level_cells(scene: np.ndarray, color: str) -> np.ndarray:
    """The scene's level in the laser's channel (the brightest channel for a grey laser), DN, per
    ``BG_CELL`` cell: :func:`~scanrig.laser.background.background_cells`, which a stripe does not
    reach.

    Parameters
    ----------
    scene : (H, W) or (H, W, 3) uint8 or uint16 array
        The laser-off frame, or the frame itself without one, DN.
    color : {"grey", "red", "green", "blue"}
        The laser's colour.

    Returns
    -------
    (ceil(H / BG_CELL), ceil(W / BG_CELL)) float32 array
    """
    sub = scene[::BG_STRIDE, ::BG_STRIDE]
    if sub.ndim == 3:
        sub = sub.max(axis=2) if color == "grey" else sub[:, :, CHANNEL[color]]
    return strided_cell_medians(sub, scene.shape[:2])


def scene_reaches_clip(level: np.ndarray, saturation_level: float) -> np.ndarray:
    """Whether the scene's ``level`` (any shape, DN: per cell, or the laser-off frame's pixels) is
    within ``SCENE_MARGINS`` × ``CLIP_MARGIN`` of the clip level ``saturation_level``, DN: bool,
    shape of ``level``."""
    return level >= (1.0 - SCENE_MARGINS * CLIP_MARGIN) * saturation_level


def warn_if_bright(scene_clipped: np.ndarray, color: str, saturation_level: float) -> bool:
    """Whether the cells ``scene_clipped`` ``(Hc, Wc)`` (where the scene reaches the clip level,
    :func:`scene_reaches_clip`) are more than ``BRIGHT_SCENE_SHARE`` of the frame; if so,
    :class:`BrightSceneWarning`, issued for the caller of
    :func:`~scanrig.laser.image.prepare_image`. ``color``: the laser's; ``saturation_level``: its
    channel's clip level, DN."""
    share = float(scene_clipped.mean())
    bright = share > BRIGHT_SCENE_SHARE
    if bright:
        channel = "frame's" if color == "grey" else f"{color} channel's"
        warnings.warn(BrightSceneWarning(
            f"the scene itself is within {SCENE_MARGINS * CLIP_MARGIN:.0%} of the {channel} clip level ({saturation_level:g} DN) "
            f"on {share:.0%} of the frame, where the laser cannot show: lower the exposure or the gain"),
            stacklevel=3)
    return bright


def hide_clipped_scene(signal: np.ndarray, unknown: np.ndarray | None, saturated: np.ndarray, at: np.ndarray,
                       scene_clipped: np.ndarray, dark: np.ndarray | None, channel: int,
                       saturation_level: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read 0 in ``signal`` the clipped pixels where the scene itself reaches the clip level, in
    place, until a laser's core shows there (:func:`show_cores`), and take them out of ``unknown``.

    Parameters
    ----------
    signal : (H, W) float32 array, DN
        The laser signal, its clipped pixels at full scale.
    unknown : (H, W) bool array or None
        Pixels clipped in the laser-off frame too.
    saturated : (H, W) bool array
        The clipped pixels (``at`` their flat indices).
    at, scene_clipped, dark, channel, saturation_level
        As :func:`_clipped_scene`.

    Returns
    -------
    scene_at : (m,) int array
        Flat indices of the pixels set to 0.
    near : (Hc, Wc) bool array
        The ``BG_CELL`` cells searched as the scene's.
    seed_floor : (Hc, Wc) float32 array, DN
        :func:`_seed_floor` (:attr:`~scanrig.laser.image.LaserImage.seed_floor`).
    """
    scene_at, near = _clipped_scene(at, signal.shape[1], scene_clipped, dark, channel, saturation_level)
    np.put(signal, scene_at, 0.0)
    if unknown is not None:
        np.put(unknown, scene_at, False)
    return scene_at, near, _seed_floor(saturated, scene_clipped, dark is not None, saturation_level)


def _seed_floor(saturated: np.ndarray, scene_clipped: np.ndarray, with_dark: bool,
                saturation_level: float) -> np.ndarray:
    """The level a pixel must reach to seed a search, per ``BG_CELL`` cell, where the scene reaches
    the clip level: ``(Hc, Wc)`` float32, DN; half of ``saturation_level`` (only a laser's core, at
    full scale, seeds there) or 0.

    Without a laser-off frame the floor is in every cell: on paper near the clip level, within a
    few pixels of its flagged pixels, the signal peaks up to about 45 DN, which take rank 0 where
    the beam's core is hidden (on the rendered paper at 0.9 of full scale, floored only as below:
    26 more rows of 1392 with a rank 0 over 3 px off). The laser-off frame, which holds them too,
    takes them out (no more such rows); with it the floor is in the cells ``scene_clipped``
    (``(Hc, Wc)`` bool, :func:`scene_reaches_clip`) and within two cells of those whose pixels are
    mostly flagged as clipped (``saturated``, ``(H, W)`` bool; :func:`_flagged_share`): where the
    paper itself clips, print bordering it seeds blobs along the edge, and where only some cells of
    paper just below the clip level reach it (15-35 % at 0.9 of full scale) the print between them
    is far from it and the beam on it seeds as in a normal frame (33-58 noise σ above it).
    """
    if not with_dark:
        return np.full(scene_clipped.shape, np.float32(0.5 * saturation_level))
    cells = scene_clipped | _around(_flagged_share(saturated) > 0.5)
    return np.where(cells, np.float32(0.5 * saturation_level), np.float32(0.0))


def _flagged_share(flagged: np.ndarray) -> np.ndarray:
    """The share of the pixels ``flagged`` ``(H, W)`` (bool) per ``BG_CELL`` cell, from every
    ``BG_STRIDE``-th pixel, 5 × 5 median over cells (which a stripe does not reach): ``(Hc, Wc)``
    float32."""
    return strided_cell_medians(flagged.view(np.uint8)[::BG_STRIDE, ::BG_STRIDE], flagged.shape)


def _clipped_scene(at: np.ndarray, width: int, scene_clipped: np.ndarray, dark: np.ndarray | None,
                   channel: int, saturation_level: float) -> tuple[np.ndarray, np.ndarray]:
    """The clipped pixels where the scene itself reaches the clip level, and the cells searched as
    such.

    Parameters
    ----------
    at : (n,) int array
        Flat indices of the clipped pixels, in rows of ``width``.
    scene_clipped : (Hc, Wc) bool array
        ``BG_CELL`` cells whose scene reaches the clip level (:func:`scene_reaches_clip`).
    dark : (H, W, 3) array or None
        The laser-off frame.
    channel : int
        The laser's channel.
    saturation_level : float
        Its clip level, DN.

    Returns
    -------
    scene_at : (m,) int array
        The pixels of ``at`` in the cells ``near`` or, with ``dark``, where its laser ``channel``
        reaches ``saturation_level`` (:func:`scene_reaches_clip`).
    near : (Hc, Wc) bool array
        With ``dark``, ``scene_clipped`` and the two cells around each (print darkens its cells,
        and JPEG rings around it); without one, every cell: the scene is known per cell only.
    """
    near = _around(scene_clipped) if dark is not None else np.ones_like(scene_clipped)
    v, u = np.divmod(at, width)
    inside = cell_lookup(near, BG_CELL, u, v)
    if dark is not None:
        inside |= scene_reaches_clip(dark[v, u, channel], saturation_level)
    return at[inside], near


def show_cores(signal: np.ndarray, saturated: np.ndarray, scene_at: np.ndarray, colour: ColourFrames,
               near: np.ndarray, scene_level: np.ndarray, saturation_level: float) -> None:
    """Of the clipped pixels ``scene_at`` where the scene reaches the clip level (read 0 in
    ``signal``), set those of a laser's core to full scale, in place, and leave clipped
    (``saturated``, unknown) only the core and its flanks (``_FLANK_PX`` around: the beam's laser
    channel clips beyond the core, where the other channels rise too little).

    A core is told by :func:`_crosstalk_raised` with the laser-off frame (the other channels'
    noise from the cells ``near``), else by :func:`_wide_cores`.

    Parameters
    ----------
    signal : (H, W) float32 array, DN
        The laser signal, 0 at ``scene_at`` (:func:`hide_clipped_scene`).
    saturated : (H, W) bool array
        The clipped pixels.
    scene_at : (m,) int array
        Flat indices of the clipped pixels where the scene reaches the clip level.
    colour : ColourFrames
        The frame, its laser-off frame (or None) and the channels' clip levels.
    near : (Hc, Wc) bool array
        The ``BG_CELL`` cells searched as the scene's.
    scene_level : (Hc, Wc) float32 array, DN
        The scene's level per cell (:func:`scene_level_cells`).
    saturation_level : float
        Full scale of the signal, DN.
    """
    import cv2

    if colour.dark is not None:
        core = _crosstalk_raised(colour, scene_at, near)
    else:
        core = _wide_cores(saturated, scene_at, scene_level, float(colour.clip_level[colour.laser_channel]))
    np.put(signal, scene_at[core], saturation_level)
    cores = np.zeros(saturated.shape, np.uint8)
    np.put(cores, scene_at[core], 1)
    side = 2 * _FLANK_PX + 1
    flank = cv2.dilate(cores, np.ones((side, side), np.uint8)).view(bool).ravel()[scene_at]
    np.put(saturated, scene_at[~flank], False)


def _around(cells: np.ndarray) -> np.ndarray:
    """The cells ``cells`` and the two around each (5 × 5 dilation)."""
    import cv2

    return cv2.dilate(cells.view(np.uint8), np.ones((5, 5), np.uint8)).view(bool)


def _wide_cores(saturated: np.ndarray, at: np.ndarray, scene_level: np.ndarray, clip_level: float) -> np.ndarray:
    """Which of the clipped pixels ``at`` (flat indices of ``saturated`` ``(H, W)``) belong to a
    laser's core, told without a laser-off frame: ``(n,)`` bool.

    A beam clips a band several pixels wide across; JPEG's ringing around print flags rings a pixel
    or two thick, which an opening of ``_CORE_WIDTH_PX`` removes. Where noise alone flags more than
    ``_NOISE_CLIPPED_SHARE`` of the pixels (their share per ``BG_CELL`` cell, 5 × 5 median over
    cells, which a stripe does not reach) they merge into wide bands of their own, and where the
    scene within two cells (``scene_level`` (Hc, Wc), DN, per cell) reaches the laser channel's
    ``clip_level`` (DN from which a pixel is flagged) its clipped paper is as wide as a core: no
    core is told there.
    """
    import cv2

    opened = cv2.morphologyEx(saturated.view(np.uint8), cv2.MORPH_OPEN,
                              np.ones((_CORE_WIDTH_PX, _CORE_WIDTH_PX), np.uint8)).view(bool)
    share = _flagged_share(saturated)
    highest_around = cv2.dilate(scene_level, np.ones((5, 5), np.uint8))
    v, u = np.divmod(at, saturated.shape[1])
    return (opened.ravel()[at] & (cell_lookup(share, BG_CELL, u, v) <= _NOISE_CLIPPED_SHARE)
            & (cell_lookup(highest_around, BG_CELL, u, v) < clip_level))


def _crosstalk_raised(colour: ColourFrames, at: np.ndarray, scene_clipped: np.ndarray) -> np.ndarray:
    """Whether the laser's crosstalk raises the non-laser channels above the laser-off frame at the
    pixels ``at`` (flat indices, where the scene reaches the laser channel's clip level): ``(n,)``
    bool.

    Each of the two must rise by more than ``_RISE_SIGMAS`` of its own noise (a laser raises both;
    JPEG's ringing, alike in both frames, neither) from a level below its clip level (where the
    scene clips them too, they cannot show the laser). Their noise is :func:`_change_noise` in the
    cells ``scene_clipped``: the laser signal's noise estimate does not serve, as a scene clipped in
    every channel reads exactly 0 there.
    """
    others = colour.other_channels
    v, u = np.divmod(at, colour.image.shape[1])
    off = colour.dark[v, u][:, others].astype(np.float32)
    room = np.flatnonzero(np.all(off < colour.clip_level[others], axis=1))
    rise = colour.image[v[room], u[room]][:, others].astype(np.float32) - off[room]
    seen = np.zeros(at.size, bool)
    seen[room] = np.all(rise > _RISE_SIGMAS * _change_noise(colour, others, scene_clipped), axis=1)
    return seen


def _change_noise(colour: ColourFrames, others: list[int], cells: np.ndarray) -> np.ndarray:
    """Robust σ ``(2,)``, DN, of the change of the channels ``others`` from the laser-off frame to
    the frame, over every ``BG_STRIDE``-th pixel of the ``BG_CELL`` cells ``cells`` where neither
    is clipped in the laser-off frame (the laser misses most of them); at least the quantisation's."""
    sub = (slice(None, None, BG_STRIDE), slice(None, None, BG_STRIDE))
    on, off = (f[sub][:, :, others].astype(np.float32) for f in (colour.image, colour.dark))
    v, u = np.mgrid[: on.shape[0], : on.shape[1]] * BG_STRIDE
    use = cell_lookup(cells, BG_CELL, u, v) & np.all(off < colour.clip_level[others], axis=2)
    floor = np.float32(QUANTIZATION_SIGMA * np.sqrt(2.0))  # of a difference of two frames
    if not use.any():
        return np.full(len(others), floor)
    change = on[use] - off[use]
    return np.maximum(MAD_TO_SIGMA * np.median(np.abs(change - np.median(change, axis=0)), axis=0), floor)

