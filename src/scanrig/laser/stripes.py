"""Laser stripes: on every scan line across the stripe, every peak above the noise, fitted in 1-D.

The scan lines are the image rows where the stripe runs mostly vertically and the columns where it
runs mostly horizontally, decided per 4 × 4 pixel block from the pre-scan's structure, so a stripe
curving over a surface is crossed at a steep angle everywhere (or forced by ``direction``). On
each line every local maximum that passes the detection test is a candidate, not only the
brightest, so a secondary reflection never hides the true stripe; each is fitted with a
pixel-integrated Gaussian along the line, vectorised over all (line, peak) pairs of the frame.

The centre is the stripe's crossing with the scan line: for rows ``v`` is exactly the row index
and only ``u`` is uncertain (``cov_vv = cov_uv = 0``), and vice versa for columns. On a tilted
stripe the profile along the line is wider by 1/cos(tilt); ``width_px`` is that width along the
line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError
from scanrig.laser.fit import MIN_PEAK_DN, MIN_WIDTH_PX, fit_batch, minor_model_1d, parameter_covariance
from scanrig.laser.colour_fit import fit_clipped
from scanrig.laser.image import prepare_image
from scanrig.laser.peaks import (BLOCK, direction_map, find_candidates, line_prominence, prescan, suppress_on_lines,
                                 worth_scanning)
from scanrig.laser.traces import empty_table, make_table

DIRECTIONS = ("auto", "rows", "columns")
#: A stripe that moves at most this far along the scan lines from one line to the next (px) is
#: crossed at 45° or more from lengthwise (see :func:`_crossed_steeply`).
_STEEP_STEP_PX = 1.0
#: Prominence (noise σ of the box sum) of a candidate kept outside its block's direction.
_CHAIN_MIN_PROMINENCE = 50.0
#: A fitted centre further than this from its seed pixel has converged onto another peak.
MAX_SHIFT_PX = 2.0


def detect_stripe(
    image: np.ndarray,
    *,
    color: str = "grey",
    dark: np.ndarray | None = None,
    roi: tuple[int, int, int, int] | None = None,
    direction: str = "auto",
    noise_sigma: float | None = None,
    saturation_level: float | None = None,
    k_detect: float = 6.0,
    min_separation_px: float = 3.0,
    max_width_px: float = 3.0,
    max_per_line: int = 8,
    camera: str = "",
    frame: str = "",
):
    """All laser-stripe candidates of one frame: every peak on every scan line.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 or uint16 array
        The frame (RGB for colour), DN.
    color : {"grey", "red", "green", "blue"}
        Laser colour (see :mod:`scanrig.laser.image`).
    dark : array like ``image``, optional
        Laser-off frame to subtract.
    roi : (u0, v0, u1, v1) ints, optional
        Region of interest, pixels, end-exclusive; output coordinates stay full-frame.
    direction : {"auto", "rows", "columns"}
        Scan lines: rows (for a near-vertical stripe), columns, or decided locally from the frame.
    noise_sigma : float, optional
        Known noise σ of the signal, DN; estimated robustly from the frame when omitted.
    saturation_level : float, optional
        DN at which pixels clip (default: dtype maximum). Clipped pixels are left out of the fit.
    k_detect : float
        Detection threshold: the 3 × 3 box sum above background, in units of its noise.
    min_separation_px : float
        Peaks on one line closer than this are merged (the stronger stays).
    max_width_px : float
        Largest Gaussian σ fitted, along the line; the window is ±ceil(3 · max_width_px) pixels.
    max_per_line : int
        At most this many peaks per line (the strongest) are fitted.
    camera, frame : str
        Written into every row.

    Returns
    -------
    pyarrow.Table
        One row per (line, peak) with the columns of ``traces.parquet`` (``kind = "stripe"``;
        ``line`` = full-frame row index where rows were scanned (then ``cov_vv = 0``) or column index
        where columns were (then ``cov_uu = 0``); rank 0 = brightest peak of its line). Empty for a
        dark frame.

    Raises
    ------
    ShapeError, InputError
        On an image of the wrong type or shape, or invalid options.

    Examples
    --------
    >>> import numpy as np, scanrig
    >>> img = np.full((64, 64), 10, np.uint8); img[:, 20:23] = 200
    >>> t = scanrig.detect_stripe(img, noise_sigma=2.0)
    >>> len(t), round(t["u"][0].as_py(), 2)
    (64, 21.0)
    """
    if direction not in DIRECTIONS:
        raise InputError(f"direction must be one of {DIRECTIONS}, got {direction!r}")
    li = prepare_image(image, color, dark, roi, saturation_level, noise_sigma)
    excess = prescan(li)
    if direction == "auto":
        scan = dict(zip(("rows", "columns"), worth_scanning(excess)))
    else:
        scan = {direction: np.ones(excess.shape, bool)}
    found = {along: _prominent(li, along, np.where(blocks, excess, -1.0), k_detect, min_separation_px, max_width_px)
             for along, blocks in scan.items() if blocks.any()}
    for along in ("rows", "columns") if direction == "auto" else ():
        found.setdefault(along, _LineCandidates.empty())
    if direction == "auto":
        by_rows = direction_map(found["rows"].block_weights(True, excess.shape),
                                found["columns"].block_weights(False, excess.shape))
        found = {along: c.take(_crossed_steeply(c, by_rows, along == "rows")) for along, c in found.items()}
    parts = [_fit_along(li, along, c.take(_strongest_per_line(c.line, c.prominence, max_per_line)), max_width_px)
             for along, c in found.items()]
    parts = [p for p in parts if p is not None]
    if not parts:
        return empty_table()
    return make_table("stripe", {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, camera, frame)


@dataclass(frozen=True)
class _LineCandidates:
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
    """

    line: np.ndarray
    pos: np.ndarray
    run_half: np.ndarray
    prominence: np.ndarray
    noise: np.ndarray

    @classmethod
    def empty(cls) -> _LineCandidates:
        z = np.zeros(0, np.int64)
        return cls(z, z, z, np.zeros(0), np.zeros(0))

    def take(self, index) -> _LineCandidates:
        return _LineCandidates(*(a[index] for a in (self.line, self.pos, self.run_half, self.prominence, self.noise)))

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


def _crossed_steeply(cand: _LineCandidates, by_rows: np.ndarray, rows: bool) -> np.ndarray:
    """Keep-mask of the candidates whose scan lines cross their stripe steeply.

    A candidate in a block of its direction (:func:`~scanrig.laser.peaks.direction_map`) stays.
    So does a strong one (``_CHAIN_MIN_PROMINENCE``) whose stripe these lines follow steeply for
    five lines, whatever its block: neighbours on the two previous and the two next lines within
    ``_STEEP_STEP_PX`` per line (a stripe crossed at 45° or more from lengthwise). That follows a
    kink (a shoulder, a chin) pixel by pixel where a block holds both the steep and the flat part.
    Noise bumps on a stripe's flank, which one noisy pixel repeats in three neighbouring box sums,
    do line up now and then, but not strongly.
    """
    chained = cand.prominence >= _CHAIN_MIN_PROMINENCE
    for step in (-2, -1, 1, 2):
        chained &= _has_neighbour(cand, _STEEP_STEP_PX * abs(step), step)
    return chained | (by_rows[cand.block_index(rows)] == rows)


def _has_neighbour(cand: _LineCandidates, reach_px: float, step: int) -> np.ndarray:
    """Whether each candidate has one on the line ``step`` away within ``reach_px`` along it
    (candidates sorted by line, then position)."""
    key = cand.line.astype(np.int64) << 32 | cand.pos.astype(np.int64)
    reach = int(np.floor(reach_px))
    line = (cand.line.astype(np.int64) + step) << 32
    first = np.searchsorted(key, line | np.maximum(cand.pos - reach, 0))
    return (first < key.size) & (key[np.minimum(first, key.size - 1)] <= line | (cand.pos + reach))


#: A peak must rise above its higher flank by at least this fraction of its height above the local
#: background: a laser crossing falls to the background on both sides, a bump of noise riding on
#: a bright plateau (shot noise along a stripe followed lengthwise, bright texture) does not.
_MIN_RELATIVE_PROMINENCE = 0.25


def _prominent(li, along, excess, k_detect, min_separation_px, max_width_px) -> _LineCandidates:
    """Local maxima along rows or columns that pass the detection test, rise above both flanks by
    ``k_detect`` noise σ of the box sum and by ``_MIN_RELATIVE_PROMINENCE`` of their height, and
    are not suppressed by a stronger neighbour."""
    cand = find_candidates(li, along, excess, k_detect=k_detect)
    rows = along == "rows"
    line, pos = (cand.v, cand.u) if rows else (cand.u, cand.v)
    order = np.lexsort((pos, line))
    line, pos, score = line[order], pos[order], cand.score[order]
    keep = suppress_on_lines(line, pos, score, min_separation_px)
    line, pos = line[keep], pos[keep]
    signal = li.signal if rows else li.signal.T
    run_half = np.zeros(line.size, np.int64)
    if li.saturated is not None:
        pos, run_half = _centre_of_saturated_run(li.saturated if rows else li.saturated.T, line, pos,
                                                 _MAX_RUN_HALF_PX)
    uv = (pos, line) if rows else (line, pos)
    noise = li.noise_at(*uv).astype(np.float64)
    reach = int(np.ceil(3.0 * max_width_px)) + 1 + run_half
    prominence_dn, height_dn = line_prominence(signal, line, pos, reach)
    height_dn -= 9.0 * li.background_at(*uv)
    prominence = prominence_dn / (3.0 * noise)
    keep = (prominence >= k_detect) & (prominence_dn >= _MIN_RELATIVE_PROMINENCE * height_dn)
    if li.colour is not None:
        keep &= _seen_in_laser_channel(li.colour, rows, line, pos, reach, run_half, k_detect)
    return _LineCandidates(line, pos, run_half, prominence, noise).take(keep)


def _seen_in_laser_channel(colour, rows, line, pos, reach, run_half, k_detect) -> np.ndarray:
    """Whether each candidate of a colour frame is a peak of the laser's own channel too.

    A colour difference such as ``red − (green + blue)/2`` has bumps of its own at strong edges of
    grey texture (JPEG stores colour at half resolution and rings there) that the laser channel
    does not show: a red laser must rise in red above both flanks by ``k_detect`` of that
    channel's noise. Clipped candidates are seen by their clipping.
    """
    plane = colour.laser_plane if rows else colour.laser_plane.T
    prominence_dn, _ = line_prominence(plane, line, pos, reach)
    return (run_half > 0) | (prominence_dn >= k_detect * 3.0 * colour.laser_noise)


def _fit_along(li, along, cand: _LineCandidates, max_width_px) -> dict[str, np.ndarray] | None:
    """Sub-pixel centres of the candidates of one scan direction (full-frame columns of the traces
    table, ranked by prominence); None when there are none."""
    if cand.line.size == 0:
        return None
    rows = along == "rows"
    signal = li.signal if rows else li.signal.T
    saturated = None if li.saturated is None else (li.saturated if rows else li.saturated.T)
    clipped = cand.run_half > 0 if li.colour is not None else np.zeros(cand.line.size, bool)
    parts = []
    if not clipped.all():
        plain = cand.take(~clipped)
        uv = (plain.pos, plain.line) if rows else (plain.line, plain.pos)
        parts.append(_fit_lines(signal, saturated, plain.line, plain.pos, li.background_at(*uv), plain.noise,
                                max_width_px, plain.prominence))
    if clipped.any():
        wide = cand.take(clipped)
        fit = fit_clipped(li.colour, rows, wide.line, wide.pos,
                          int(np.ceil(3.0 * max_width_px)) + int(wide.run_half.max()),
                          MAX_SHIFT_PX + wide.run_half / 2.0)
        index = fit.pop("index")
        fit.update(line=wide.line[index], sigma_px=np.sqrt(fit["var"]), saturated=np.ones(index.size, bool),
                   prominence=wide.prominence[index])
        parts.append(fit)
    cols = {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}
    centre = cols.pop("centre")
    var = cols.pop("var")
    zero = np.zeros_like(var)
    if rows:
        cols.update(u=centre + li.origin[0], v=cols["line"] + float(li.origin[1]), cov_uu=var, cov_vv=zero)
        cols["line"] = cols["line"] + li.origin[1]
    else:
        cols.update(u=cols["line"] + float(li.origin[0]), v=centre + li.origin[1], cov_uu=zero, cov_vv=var)
        cols["line"] = cols["line"] + li.origin[0]
    cols["cov_uv"] = zero
    cols["rank"] = _rank_on_lines(cols["line"], cols.pop("prominence"))
    cols["line"] = cols["line"].astype(np.int32)
    return cols


def _fit_lines(signal, saturated, line, pos, background, noise, max_width_px, prominence) -> dict[str, np.ndarray]:
    """Fit every (line, pos) candidate along its line (axis 1 of ``signal``); failed fits dropped.
    The windows are stacked candidate-minor, ``(W, n)`` (see :mod:`scanrig.laser.fit`)."""
    half = int(np.ceil(3.0 * max_width_px))
    offs = np.arange(-half, half + 1)
    n_pos = signal.shape[1]
    idx = offs[:, None] + pos
    inside = (idx >= 0) & (idx < n_pos)
    np.clip(idx, 0, n_pos - 1, out=idx)
    y = signal[line, idx].astype(np.float64)
    mask = inside & _nearest_on_line(line, pos, offs)
    sat = None if saturated is None else saturated[line, idx]
    if sat is not None:
        mask &= ~sat
    p0 = _start(y, background.astype(np.float64), half, max_width_px, sat)
    lower = np.array([MIN_PEAK_DN, -half, MIN_WIDTH_PX, -np.inf])
    upper = np.array([np.inf, half, max_width_px, np.inf])
    res = fit_batch(minor_model_1d(offs.astype(float)), y, mask, p0, lower, upper, minor=True)
    p = res.params
    var = parameter_covariance(res, noise)[:, 1, 1]
    ok = np.isfinite(var) & (np.abs(p[:, 1]) <= MAX_SHIFT_PX) & (res.dof > 0)
    out = {
        "line": line, "centre": pos + p[:, 1], "var": var, "sigma_px": np.sqrt(np.abs(var)),
        "peak": p[:, 0], "width_px": p[:, 2], "snr": p[:, 0] / noise,
        "saturated": np.zeros(line.size, bool) if sat is None else sat[half - 1 : half + 2].any(axis=0),
        "prominence": prominence,
    }
    return {k: a[ok] for k, a in out.items()}


#: Longest half clipped run followed from a seed, pixels (an over-exposed stripe with its halo
#: clips over a few tens of pixels at most; a clipped glint or window beyond is no stripe).
_MAX_RUN_HALF_PX = 32


def _centre_of_saturated_run(saturated, line, pos, reach) -> tuple[np.ndarray, np.ndarray]:
    """Seeds that sit on a clipped plateau (found at its end) moved to the plateau's middle, and the
    plateau's half-length (0 for seeds that are not clipped), followed at most ``reach`` pixels."""
    offs = np.arange(-reach, reach + 1)
    idx = np.clip(pos[:, None] + offs, 0, saturated.shape[1] - 1)
    sat = saturated[line[:, None], idx]
    right = np.cumprod(sat[:, reach:], axis=1).sum(axis=1)
    left = np.cumprod(sat[:, reach::-1], axis=1).sum(axis=1)
    clipped = sat[:, reach]
    return np.where(clipped, pos + (right - left) // 2, pos), np.where(clipped, (right + left) // 2, 0)


def _nearest_on_line(line, pos, offs) -> np.ndarray:
    """(W, n) True where a window pixel is nearer its own peak than the neighbouring peaks on the
    same line (candidates sorted by line, then position)."""
    if line.size == 0:
        return np.ones((offs.size, 0), bool)
    big = 10 * offs.size
    same_prev = np.r_[False, line[1:] == line[:-1]]
    same_next = np.r_[line[1:] == line[:-1], False]
    gap_prev = np.where(same_prev, np.r_[big, pos[1:] - pos[:-1]], big)
    gap_next = np.where(same_next, np.r_[pos[1:] - pos[:-1], big], big)
    twice = 2 * offs[:, None]
    return (twice > -gap_prev) & (twice < gap_next)


#: Widths tried for the start of a fit whose core is clipped, pixels.
_CLIPPED_START_WIDTHS = np.array([0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0])


def _start(y, background, half, max_width_px, saturated) -> np.ndarray:
    """Start values ``(n, 4)`` from windows ``y (W, n)``: peak, centroid and width from the excess
    area of the ±2 px core.

    A clipped core has no usable peak or area; there the centre starts at the middle of the
    clipped run and the width at the best of a few trial widths, each with peak and background
    solved linearly from the unclipped pixels.
    """
    core = y[half - 2 : half + 3] - background
    excess = np.clip(core, 0.0, None)
    peak = np.maximum(core.max(axis=0), 1e-3)
    total = np.maximum(excess.sum(axis=0), 1e-9)
    x0 = (excess * np.arange(-2.0, 3.0)[:, None]).sum(axis=0) / total
    width = total / (np.sqrt(2 * np.pi) * peak)
    start = np.stack([peak, x0, np.clip(width, 0.5, max_width_px), background], axis=1)
    if saturated is not None:
        clipped = saturated[half]
        if clipped.any():
            start[clipped] = _clipped_start(y[:, clipped].T, saturated[:, clipped].T, half, max_width_px)
    return start


def _clipped_start(y, saturated, half, max_width_px) -> np.ndarray:
    """Start values (peak, x0, width, background) for windows whose centre pixel is clipped."""
    right = np.cumprod(saturated[:, half:], axis=1).sum(axis=1)
    left = np.cumprod(saturated[:, half::-1], axis=1).sum(axis=1)
    x0 = (right - left) / 2.0
    widths = _CLIPPED_START_WIDTHS[_CLIPPED_START_WIDTHS <= max_width_px]
    x = np.arange(-half, half + 1, dtype=float)
    g = np.exp(-0.5 * ((x[None, None, :] - x0[:, None, None]) / widths[None, :, None]) ** 2)  # (n, k, W)
    w = (~saturated)[:, None, :].astype(float)
    # weighted linear least squares of y ≈ A g + b per (candidate, width)
    s_w, s_g, s_y = w.sum(-1), (w * g).sum(-1), (w * y[:, None, :]).sum(-1)
    s_gg, s_gy = (w * g * g).sum(-1), (w * g * y[:, None, :]).sum(-1)
    det = s_w * s_gg - s_g**2
    with np.errstate(divide="ignore", invalid="ignore"):  # all pixels clipped: no solution, NaN
        amp = (s_w * s_gy - s_g * s_y) / det
        bg = (s_y - amp * s_g) / s_w
        resid = (w * (y[:, None, :] - amp[..., None] * g - bg[..., None]) ** 2).sum(-1)
    resid = np.where(np.isfinite(resid) & (amp > 0), resid, np.inf)
    best = np.argmin(resid, axis=1)
    pick = np.arange(y.shape[0])
    return np.stack([np.nan_to_num(amp[pick, best], nan=1.0), x0, widths[best],
                     np.nan_to_num(bg[pick, best])], axis=1)


def _strongest_per_line(line, score, max_per_line) -> np.ndarray:
    """Keep-mask: the ``max_per_line`` highest scores of each line."""
    return _rank_on_lines(line, score) < max_per_line


def _rank_on_lines(line, peak) -> np.ndarray:
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
