"""Stripe candidates along scan lines: prominent peaks, each stripe crossed steeply.

On every scan line (rows, or columns) every local maximum of the 3 × 3 box sum that passes the
detection test (:func:`scanrig.laser.peaks.find_candidates`) is a candidate when it also rises
above *both* flanks (:func:`scanrig.laser.peaks.line_prominence`): texture edges are steps, not
stripes. Candidates on a clipped run are moved to its middle. Where both directions are scanned,
each stripe is kept in the direction that crosses it steeply, and in both where it runs at about
45° to rows and columns (:func:`crossed_steeply`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.laser.peaks import BLOCK, find_candidates, line_prominence, suppress_on_lines
from scanrig.laser.pixels import pixel_blocks

#: A stripe that moves at most this far along the scan lines from one line to the next (px) is
#: crossed at 45° or more from lengthwise (see :func:`crossed_steeply`).
_STEEP_STEP_PX = 1.0
#: Prominence (noise σ of the box sum) of a candidate kept outside its block's direction.
_CHAIN_MIN_PROMINENCE = 50.0
#: Blocks whose rows' share of the evidence (:func:`~scanrig.laser.peaks.direction_map`) lies within
#: this of ½ hold a stripe at about 45° to rows and columns, which both cross it steeply (on a
#: rendered 45° stripe the share is 0.47-0.54 on 90 % of its blocks; a 0.5 px/row stripe's 0.66-0.79).
_EQUALLY_STEEP = 0.05
#: Error of a seed's position along its line, px: an integer maximum, or the middle of a clipped
#: run rounded down, lies within a pixel of the stripe's crossing. A step between two seeds carries
#: twice that.
_SEED_ERROR_PX = 1.0


@dataclass(frozen=True)
class LineCandidates:
    """Prominent candidates of one scan direction, in signal coordinates, sorted by (line, pos).

    Attributes
    ----------
    line, pos : (n,) int arrays
        Scan line and position along it (the middle of the clipped run for a clipped seed).
    run_half : (n,) int array
        Half-length of the clipped run the candidate sits on, pixels (0 if not clipped).
    prominence : (n,) float array
        :func:`~scanrig.laser.peaks.line_prominence` in noise σ of the box sum.
    noise : (n,) float array
        Noise σ at the candidate, DN.
    maxima : (m,) int64 array, sorted
        :func:`line_keys` of every local maximum on these lines that rises above the noise: the
        candidates and those the clutter test rejected. Not fitted, they still bound the fit
        windows of their neighbours (:func:`neighbour_gaps`). Shared by every :meth:`take`.
    """

    line: np.ndarray
    pos: np.ndarray
    run_half: np.ndarray
    prominence: np.ndarray
    noise: np.ndarray
    maxima: np.ndarray

    def take(self, index) -> LineCandidates:
        return LineCandidates(*(a[index] for a in (self.line, self.pos, self.run_half, self.prominence, self.noise)),
                              self.maxima)

    def block_index(self, rows: bool) -> tuple[np.ndarray, np.ndarray]:
        """``(block row, block column)`` of each candidate (4 × 4 pixel blocks)."""
        u, v = (self.pos, self.line) if rows else (self.line, self.pos)
        return v // BLOCK, u // BLOCK

    def block_weights(self, rows: bool, shape) -> np.ndarray:
        """Evidence per block that its scan lines cross a stripe, ``shape`` (the pre-scan's), float32:
        the summed prominence, each divided by the length of its clipped run (a clipped stripe
        followed lengthwise is a long plateau that still falls at both ends)."""
        out = np.zeros(shape, np.float32)
        np.add.at(out, self.block_index(rows), (self.prominence / (1 + 2 * self.run_half)).astype(np.float32))
        return out


def crossed_steeply(cand: LineCandidates, row_share: np.ndarray, rows: bool, max_width_px: float) -> np.ndarray:
    """Keep-mask of the candidates whose scan lines cross their stripe steeply.

    A candidate in a block of its direction (:func:`~scanrig.laser.peaks.direction_map`) stays.
    So does a strong one (``_CHAIN_MIN_PROMINENCE``) whose stripe these lines follow steeply for
    five lines, whatever its block: neighbours on the two previous and the two next lines within
    ``_STEEP_STEP_PX`` per line (a stripe crossed at 45° or more from lengthwise). That follows a
    kink (a shoulder, a chin) pixel by pixel where a block holds both the steep and the flat part.
    Noise bumps on a stripe's flank, which one noisy pixel repeats in three neighbouring box sums,
    do line up now and then, but not strongly.

    Where the stripe runs at about 45° to both directions (``_EQUALLY_STEEP``), both cross it
    steeply and both keep it, at any prominence: a candidate there stays when its stripe runs on
    over the same five lines, each step allowed the rounding of two seeds (``_SEED_ERROR_PX``; at
    exactly one pixel per line the rounded seeds alone step by 0 to 2). Blocks there flip between
    the two directions with the noise in their evidence, and each direction would otherwise lose
    the stripe's crossings in the other's blocks. Texture does not run on over five lines, and a
    clipped run longer than the window a beam of ``max_width_px`` is fitted in (±3 widths) is no
    stripe's core but a clipped patch of the scene, whose midpoints on neighbouring lines do.

    Parameters
    ----------
    cand : LineCandidates
        One direction's candidates.
    row_share : (hb, wb) float array
        :func:`~scanrig.laser.peaks.direction_map`.
    rows : bool
        Whether ``cand`` were found along rows.
    max_width_px : float
        Largest beam width fitted, px.

    Returns
    -------
    (n,) bool array
    """
    share = row_share[cand.block_index(rows)]
    keep = (share >= 0.5) == rows
    strong = np.flatnonzero(~keep & (cand.prominence >= _CHAIN_MIN_PROMINENCE))
    keep[strong] = _runs_on(cand, strong, 0.0)
    thin = cand.run_half <= np.ceil(3.0 * max_width_px)
    tied = np.flatnonzero(~keep & (np.abs(share - 0.5) <= _EQUALLY_STEEP) & thin)
    keep[tied] = _runs_on(cand, tied, 2.0 * _SEED_ERROR_PX)
    return keep


def _runs_on(cand: LineCandidates, at: np.ndarray, slack_px: float) -> np.ndarray:
    """Whether each candidate ``at`` (indices) has one on each of the two previous and the two next
    lines within ``_STEEP_STEP_PX`` per line plus ``slack_px`` along them (candidates sorted by
    line, then position)."""
    ok = np.ones(at.size, bool)
    if at.size == 0:
        return ok
    key = line_keys(cand.line, cand.pos)
    pos = cand.pos[at]
    for step in (-2, -1, 1, 2):
        reach = int(np.floor(_STEEP_STEP_PX * abs(step) + slack_px))
        line = (cand.line[at].astype(np.int64) + step) << _POS_BITS
        first = np.searchsorted(key, line | np.maximum(pos - reach, 0))
        ok &= (first < key.size) & (key[np.minimum(first, key.size - 1)] <= line | (pos + reach))
    return ok


#: Bits of a :func:`line_keys` key that hold the position along the line.
_POS_BITS = 32
#: :func:`neighbour_gaps` where a line has no maximum on that side, px.
NO_NEIGHBOUR_PX = 1 << 30


def line_keys(line: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """One int64 key per ``(line, pos)`` (non-negative ints, pixels) that sorts by line, then
    position, ``(n,)``."""
    return line.astype(np.int64) << _POS_BITS | pos.astype(np.int64)


def neighbour_gaps(line: np.ndarray, pos: np.ndarray, maxima: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each ``(line, pos)`` to the nearest of ``maxima`` before it and after it on
    its line, pixels (``NO_NEIGHBOUR_PX`` where there is none; a maximum at ``pos`` itself is
    neither).

    Parameters
    ----------
    line, pos : (n,) int arrays, pixels
    maxima : (m,) int64 array
        Sorted :func:`line_keys`.

    Returns
    -------
    before, after : (n,) int64 arrays, pixels
    """
    bounds = np.r_[np.int64(-1), maxima, np.iinfo(np.int64).max]  # sentinels on no line
    key = line_keys(line, pos)
    prev = bounds[np.searchsorted(bounds, key, "left") - 1]
    succ = bounds[np.searchsorted(bounds, key, "right")]
    on_pos = (1 << _POS_BITS) - 1
    before = np.where(prev >> _POS_BITS == line, pos - (prev & on_pos), NO_NEIGHBOUR_PX)
    after = np.where(succ >> _POS_BITS == line, (succ & on_pos) - pos, NO_NEIGHBOUR_PX)
    return before, after


#: A peak must rise above its higher flank by at least this fraction of its height above the local
#: background: a laser crossing falls to the background on both sides, a bump of noise riding on
#: a bright plateau (shot noise along a stripe followed lengthwise, bright texture) does not.
_MIN_RELATIVE_PROMINENCE = 0.25


def prominent(li, along, excess, k_detect, min_separation_px, max_width_px) -> LineCandidates:
    """Local maxima along rows or columns that pass the detection test, are not suppressed by a
    stronger neighbour, rise above both flanks by ``k_detect`` σ of the box sum (of the noise or,
    where larger, of the frame's structured clutter, :attr:`~scanrig.laser.image.LaserImage.clutter`)
    and by ``_MIN_RELATIVE_PROMINENCE`` of their height, and in a colour frame rise in the laser's own
    channel too (:func:`_seen_in_laser_channel`, asked first: the tests are independent, and on
    a textured frame it keeps one maximum in ten, so the rest runs on few). Those that pass all
    but the clutter test are kept as :attr:`LineCandidates.maxima` with the candidates."""
    cand = find_candidates(li, along, excess, k_detect=k_detect)
    rows = along == "rows"
    line, pos, score = (cand.v, cand.u, cand.score) if rows else (cand.u, cand.v, cand.score)
    reach = int(np.ceil(3.0 * max_width_px)) + 1  # of an unclipped candidate
    saturated = None if li.saturated is None else (li.saturated if rows else li.saturated.T)
    # the pixel tests while the candidates are in the frame's order (by row, then column): the
    # gathers then walk the frame's memory forwards, for columns too (in their scan order each
    # step jumps a row: four times slower on a textured frame's tens of thousands)
    clipped = np.zeros(line.size, bool) if saturated is None else saturated[line, pos]
    seen = (np.ones(line.size, bool) if li.colour is None
            else _seen_in_laser_channel(li.colour, rows, line, pos, clipped, reach, k_detect))
    if not rows:  # sorted by row, then column: now by column, then row (a stable radix sort by column)
        order = np.argsort(line.astype(np.min_scalar_type(li.signal.shape[1] - 1)), kind="stable")
        line, pos, score, clipped, seen = line[order], pos[order], score[order], clipped[order], seen[order]
    # every maximum suppresses its weaker neighbours, seen in the laser's channel or not
    keep = suppress_on_lines(line, pos, score, min_separation_px) & seen
    line, pos, clipped = line[keep], pos[keep], clipped[keep]
    run_half = np.zeros(line.size, np.int64)
    if clipped.any():
        pos, run_half = _centre_of_saturated_run(saturated, line, pos, clipped, _MAX_RUN_HALF_PX)
    uv = (pos, line) if rows else (line, pos)
    noise = li.noise_at(*uv).astype(np.float64)
    reach = reach + run_half
    signal = li.signal if rows else li.signal.T

    def box_sums():
        return li.box_sums if rows else li.box_sums.T

    prominence_dn, height_dn = line_prominence(signal, line, pos, reach,
                                               box_sums() if li.box_sums_computed() else box_sums)
    height_dn -= 9.0 * li.background_at(*uv)
    prominence = prominence_dn / (3.0 * noise)
    above_noise = (prominence >= k_detect) & (prominence_dn >= _MIN_RELATIVE_PROMINENCE * height_dn)
    # the detection test against the larger of the noise and the frame's structured clutter; the
    # maxima it rejects still bound their neighbours' fit windows
    keep = above_noise & (prominence_dn / (3.0 * np.maximum(noise, li.clutter_at(*uv))) >= k_detect)
    maxima = np.sort(line_keys(line[above_noise], pos[above_noise]))
    return LineCandidates(line, pos, run_half, prominence, noise, maxima).take(keep)


def _seen_in_laser_channel(colour, rows, line, pos, clipped, reach, k_detect) -> np.ndarray:
    """Whether each candidate of a colour frame is a peak of the laser's own channel too.

    A colour difference such as ``red − (green + blue)/2`` has bumps of its own at strong edges of
    grey texture (JPEG stores colour at half resolution and rings there) that the laser channel
    does not show: a red laser must rise in red above both flanks (within ``reach`` pixels) by
    ``k_detect`` of that channel's noise. Candidates on a ``clipped`` pixel are seen by their
    clipping.
    """
    seen = clipped.copy()
    asked = np.flatnonzero(~seen)
    plane = colour.laser_plane if rows else colour.laser_plane.T
    prominence_dn, _ = line_prominence(plane, line[asked], pos[asked], np.full(asked.size, reach),
                                       lambda: colour.laser_box_sums if rows else colour.laser_box_sums.T)
    seen[asked] = prominence_dn >= k_detect * 3.0 * colour.laser_noise
    return seen


#: Longest half clipped run followed from a seed, pixels (an over-exposed stripe with its halo
#: clips over a few tens of pixels at most; a clipped glint or window beyond is no stripe).
_MAX_RUN_HALF_PX = 32


def _centre_of_saturated_run(saturated, line, pos, clipped, reach) -> tuple[np.ndarray, np.ndarray]:
    """Seeds that sit on a clipped plateau (``clipped``, found at its end) moved to the plateau's
    middle, and the plateau's half-length (0 for seeds that are not clipped), followed at most
    ``reach`` pixels and not beyond the frame."""
    pos, run_half = pos.copy(), np.zeros(pos.size, np.int64)
    clipped = np.flatnonzero(clipped)
    idx = pos[clipped, None] + np.arange(-reach, reach + 1)
    sat = pixel_blocks(saturated, line[clipped], pos[clipped] - reach, 1, 2 * reach + 1)[:, 0]
    sat &= (idx >= 0) & (idx < saturated.shape[1])
    right = leading_true(sat[:, reach:])
    left = leading_true(sat[:, reach::-1])
    pos[clipped] += (right - left) // 2
    run_half[clipped] = (right + left) // 2
    return pos, run_half


def leading_true(a: np.ndarray) -> np.ndarray:
    """Length of the run of True at the start of each row of ``a`` ``(n, m)`` bool: ``(n,)`` int
    (where the first False is; ten times faster than a cumulative product)."""
    first_false = np.argmin(a, axis=1)
    return np.where(a[np.arange(a.shape[0]), first_false], a.shape[1], first_false)


def strongest_per_line(line, score, max_per_line) -> np.ndarray:
    """Keep-mask: the ``max_per_line`` highest scores of each line."""
    return rank_on_lines(line, score) < max_per_line


def rank_on_lines(line, peak) -> np.ndarray:
    """0 for the brightest peak of each line, 1 for the next, ... (int32)."""
    if np.all(line[1:] > line[:-1]):  # the usual case: one peak per line, lines in order
        return np.zeros(line.size, np.int32)
    order = np.lexsort((-peak, line))
    sorted_lines = line[order]
    start = np.r_[0, np.flatnonzero(sorted_lines[1:] != sorted_lines[:-1]) + 1]
    first = np.repeat(start, np.diff(np.r_[start, line.size]))
    rank = np.empty(line.size, np.int32)
    rank[order] = np.arange(line.size) - first
    return rank
