"""Stripe candidates where the laser's own channel no longer measures the laser.

A laser far past full scale saturates the sensor, and some cameras' processing then turns the
pixel towards white: on the Ciclop webcam's chessboard frames, on the rows of a specular glint,
red reads 90-120 DN on the beam (less than beside it) while green and blue rise from 0 to 100-130
DN, so the laser-on minus laser-off colour difference dips where the beam is. Elsewhere the
laser channel is clipped in the laser-on frame, or in the laser-off frame on a bright surface of
the laser's colour. In all these pixels the laser channel is unknown, never zero signal, and the
rise of the two other channels (laser-on minus laser-off) holds the beam.

The laser channel counts as unknown at a pixel where it is clipped in either frame, or where the
other channels each rise by more than ``MAX_CROSSTALK_SHARE`` of its own rise (colour filters pass a few
per cent of a laser's light into the other channels, never half of it). Each run of such pixels
along a scan line on which the other channels rise well above their noise is one more candidate,
centred on the midpoint of the run's edges in the other channels (:func:`fit_unknown_runs`). A
glint that clips every channel in both frames adds nothing to the other channels' difference and
yields none.

Only with a laser-off frame: without one a white surface is "white" in every channel. The pixels
are found on the whole frame with a few vectorised passes and kept as a sparse list; the runs are
built from that list.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from scanrig.laser.noise import NOISE_CELL
from scanrig.laser.pixels import cell_lookup

#: Largest share of the laser channel's rise that the other channels (their mean) take up while
#: the laser channel still measures the light; above it the laser channel is unknown.
MAX_CROSSTALK_SHARE = 0.5
#: The other channels' mean rise must exceed this share of the laser channel's clip level: a
#: camera whitens a pixel saturated in its sensor, so they rise by a good part of full scale (100-130
#: DN of a 180-255 DN clip on the Ciclop webcam), while light that changes between the two
#: exposures moves every channel alike by a few DN...
MIN_RISE_SHARE = 0.2
#: ... and this many of the laser signal's noise σ there.
RISE_SIGMAS = 6.0
#: Distance between two photosites of one colour of a Bayer mosaic along a row or column, px.
BAYER_PERIOD_PX = 2.0
#: Variance of a position known only to lie within one pixel (uniform), px².
_PIXEL_VAR = 1.0 / 12.0
#: Runs longer than this along a scan line follow a stripe lengthwise, px (as a clipped run's
#: reach, :mod:`scanrig.laser.stripe_candidates`).
MAX_RUN_PX = 65


class UnknownPixels(NamedTuple):
    """Pixels where the laser channel is unknown and the other channels rise, in row-major order.

    Attributes
    ----------
    v, u : (m,) int arrays
        Row and column (signal coordinates).
    rise : (m,) float array
        The other channels' mean rise (laser-on minus laser-off), DN.
    whitened : (m,) bool array
        The laser channel is clipped in neither frame (it is unknown because the other channels
        rose too far).
    """

    v: np.ndarray
    u: np.ndarray
    rise: np.ndarray
    whitened: np.ndarray


class Runs(NamedTuple):
    """Runs of :class:`UnknownPixels` along scan lines, sorted by (line, first).

    Attributes
    ----------
    line, first, length : (n,) int arrays
        Scan line, first position on it and length of each run, px.
    level : (n,) float array
        The other channels' mean rise over the run, DN.
    """

    line: np.ndarray
    first: np.ndarray
    length: np.ndarray
    level: np.ndarray


def fit_unknown_runs(li, rows: bool, pixels: UnknownPixels | None = None) -> dict[str, np.ndarray] | None:
    """Centres on the runs along one scan direction where the laser channel is unknown, in the
    columns of :func:`scanrig.laser.stripes.detect_stripe`'s fits; None without a laser-off frame
    or such runs.

    Each run's centre is the midpoint of its two edges, where the other channels' mean rise
    crosses half its mean over the run, interpolated linearly between the run's end pixel and the
    one beyond (as :func:`scanrig.laser.colour_fit.plateau_midpoint` does for the laser channel).
    An edge's variance propagates the other channels' noise through the interpolation, at most a
    uniform pixel's, 1/12 px², however flat the step (the run ends within it); the centre's adds ``BAYER_PERIOD_PX² / 12``: the camera whitens the pixels around the laser
    channel's saturated photosites, which lie ``BAYER_PERIOD_PX`` apart, so the run is centred on
    the photosite nearest the beam (on the Ciclop board's glint rows every run, 3, 5 or 7 px wide,
    is centred on one column while the beam moves by 0.2 px). ``peak`` is the laser channel's clip level less its laser-off value at the run's
    middle (a lower bound: the laser is past the clip there), ``prominence`` that peak's 3 × 3 box
    sum in its noise σ (the unit of the other candidates'), ``width_px`` half the distance
    between the edges.

    Parameters
    ----------
    li : LaserImage
        The prepared frame (:func:`scanrig.laser.image.prepare_image`).
    rows : bool
        Scan lines are rows (else columns).
    pixels : UnknownPixels, optional
        :func:`unknown_laser` of ``li``, which the two scan directions share; found when omitted.

    Returns
    -------
    dict of (n,) arrays or None
        ``line``, ``centre`` (px along the line), ``var`` (px²), ``sigma_px``, ``peak`` (DN),
        ``width_px``, ``snr``, ``saturated`` (all True), ``prominence``; signal coordinates.
    """
    colour = li.colour
    if colour is None or colour.dark is None:
        return None
    runs = unknown_runs(unknown_laser(li) if pixels is None else pixels, rows)
    if runs.line.size == 0:
        return None
    k = colour.laser_channel
    others = [c for c in range(3) if c != k]
    first, last = runs.first, runs.first + runs.length - 1
    n_pos = colour.image.shape[1] if rows else colour.image.shape[0]
    at = np.clip(np.stack([first - 1, first, last, last + 1]), 0, n_pos - 1)  # outer, inner pixel of each edge
    v, u = (runs.line, at) if rows else (at, runs.line)
    rise = 0.5 * (colour.image[v, u][..., others].astype(np.float64) - colour.dark[v, u][..., others]).sum(-1)
    level = 0.5 * runs.level
    sigma = 0.5 * float(np.hypot(*colour.channel_noise[others]))
    edges, var = [], np.zeros(runs.line.size)
    for outer, inner, end, sign in ((rise[0], rise[1], first, -1), (rise[3], rise[2], last, 1)):
        step = np.maximum(inner - outer, 1e-9)
        edges.append(end + sign * np.clip((inner - level) / step, 0.0, 1.0))
        # the run ends there, so its edge lies within that pixel step whatever the noise: at most
        # the variance of a uniform pixel
        var += np.minimum(sigma**2 * ((level - outer) ** 2 + (inner - level) ** 2) / step**4, _PIXEL_VAR)
    middle = runs.first + (runs.length - 1) // 2
    v, u = (runs.line, middle) if rows else (middle, runs.line)
    peak = colour.clip_level[k] - colour.dark[v, u, k]
    prominence = 3.0 * peak / li.noise_at(u, v)
    var = 0.25 * var + BAYER_PERIOD_PX**2 / 12.0
    return {"line": runs.line, "centre": 0.5 * (edges[0] + edges[1]), "var": var, "sigma_px": np.sqrt(var),
            "peak": peak, "width_px": 0.5 * (edges[1] - edges[0]), "snr": peak / colour.laser_noise,
            "saturated": np.ones(runs.line.size, bool), "prominence": prominence}


def unknown_laser(li) -> UnknownPixels:
    """Pixels where the laser channel is unknown and each other channel's rise (laser-on minus
    laser-off, usable in both frames) exceeds ``MIN_RISE_SHARE`` of the laser channel's clip level
    and ``RISE_SIGMAS`` of the laser signal's noise σ in its cell
    (:attr:`scanrig.laser.image.LaserImage.noise`).

    The whitened pixels are searched on the whole frame with the planes the detector has built:
    where the laser channel is not clipped, the other channels' mean rise is the laser channel's
    (``colour.laser_plane``) less the colour difference (``signal``). Only where some are found,
    the pixels clipped in the frame (``saturated``) near them are added (a run of a saturated beam
    may hold both). The few found are checked on the raw frames.

    Parameters
    ----------
    li : LaserImage
        A colour frame with a laser-off frame (``li.colour.dark`` set).
    """
    import cv2

    colour = li.colour
    floor = MIN_RISE_SHARE * float(colour.clip_level[colour.laser_channel])
    rise = cv2.subtract(colour.laser_plane, li.signal)  # float32 planes; OpenCV's pass is the faster
    v, u = np.divmod(np.flatnonzero(rise > floor), rise.shape[1])  # a flat search: few pixels, fast
    whitened = _checked(li, v, u, floor)
    v, u = v[whitened.keep], u[whitened.keep]
    if v.size == 0 or li.saturated is None:
        return UnknownPixels(v, u, whitened.rise, whitened.whitened)
    reach = MAX_RUN_PX
    box = (slice(max(v.min() - reach, 0), v.max() + reach + 1), slice(max(u.min() - reach, 0), u.max() + reach + 1))
    sv, su = np.nonzero(li.saturated[box])
    sv, su = sv + box[0].start, su + box[1].start
    clipped = _checked(li, sv, su, floor)
    sv, su = sv[clipped.keep], su[clipped.keep]
    both_v, both_u = np.r_[v, sv], np.r_[u, su]
    order = np.lexsort((both_u, both_v))
    first = np.r_[True, (np.diff(both_v[order]) != 0) | (np.diff(both_u[order]) != 0)]  # a pixel once
    order = order[first]
    return UnknownPixels(both_v[order], both_u[order], np.r_[whitened.rise, clipped.rise][order],
                         np.r_[whitened.whitened, clipped.whitened][order])


class _Checked(NamedTuple):
    keep: np.ndarray
    rise: np.ndarray
    whitened: np.ndarray


def _checked(li, v: np.ndarray, u: np.ndarray, floor: float) -> _Checked:
    """Which of the pixels ``v, u`` have the laser channel unknown (clipped in either frame, or
    whitened) and the other channels usable and each risen above ``floor`` and ``RISE_SIGMAS`` of
    the noise (a camera whitens a saturated pixel; light of a third colour raises one channel only);
    their mean rise (DN) and whether whitened (not clipped)."""
    colour = li.colour
    k = colour.laser_channel
    others = [c for c in range(3) if c != k]
    px_on, px_off = colour.image[v, u].astype(np.float64), colour.dark[v, u]
    each = px_on[:, others] - px_off[:, others]
    rise = each.mean(axis=1)
    # a pixel turned white has every other channel risen: a light of another colour raises one
    least = each.min(axis=1)
    clip = colour.clip_level
    usable = np.all((px_on[:, others] < clip[others]) & (px_off[:, others] < clip[others]), axis=1)
    clipped = (px_on[:, k] >= clip[k]) | (px_off[:, k] >= clip[k])
    whitened = ~clipped & (least > MAX_CROSSTALK_SHARE * (px_on[:, k] - px_off[:, k]))
    keep = (usable & (clipped | whitened) & (least > floor)
            & (least > RISE_SIGMAS * cell_lookup(li.noise, NOISE_CELL, u, v)))
    return _Checked(keep, rise[keep], whitened[keep])


def unknown_runs(pixels: UnknownPixels, rows: bool) -> Runs:
    """The runs of ``pixels`` along rows (else columns) of at most ``MAX_RUN_PX`` and no longer than
    the run across them through their middle (a run along rows wins a tie: the lines that cross a
    stripe more steeply take it), with at least one whitened pixel (runs only clipped are the
    clipped stripe candidates', :mod:`scanrig.laser.stripe_candidates`).

    Parameters
    ----------
    pixels : UnknownPixels
        From :func:`unknown_laser`.
    rows : bool
        Scan lines are rows (else columns).
    """
    by_rows = np.arange(pixels.v.size)
    by_columns = np.lexsort((pixels.v, pixels.u))
    order, other = (by_rows, by_columns) if rows else (by_columns, by_rows)
    line, pos = (pixels.v, pixels.u) if rows else (pixels.u, pixels.v)
    start, length = _runs(line[order], pos[order])
    _, across_length = _runs(pos[other], line[other])
    across = np.empty(pixels.v.size, np.int64)  # length of the run across through each pixel
    across[other] = np.repeat(across_length, across_length)
    middle = order[start + (length - 1) // 2]
    keep = (length <= MAX_RUN_PX) & ((length <= across[middle]) if rows else (length < across[middle]))
    if start.size:
        keep &= np.add.reduceat(pixels.whitened[order], start) > 0
        level = np.add.reduceat(pixels.rise[order], start) / length
    else:
        level = np.zeros(0)
    first = order[start]
    return Runs(line[first][keep].astype(np.int64), pos[first][keep].astype(np.int64), length[keep].astype(np.int64),
                level[keep])


def _runs(line: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Runs of consecutive positions on one line in pixels sorted by (line, pos): the index of each
    run's first pixel and its length."""
    n = line.size
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    first = np.flatnonzero(np.r_[True, (line[1:] != line[:-1]) | (pos[1:] != pos[:-1] + 1)])
    return first, np.diff(np.r_[first, n])
