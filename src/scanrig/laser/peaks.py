"""Candidate finding: where to fit, at frame rate.

1. *Pre-scan*: the maximum of every 4 × 4 block (OpenCV maxima of row-strided views, then a
   1 × 4 dilation read at stride 4) is compared with the block's background plus ``k_seed``
   noise σ. A trace of SNR ≥ 10 has a pixel well above that; a frame of pure noise flags a few
   dozen blocks. Flagged blocks and their 8 neighbours are the only places looked at further.
2. *Local maxima* in 8 × 8 patches around the flagged blocks of the 3 × 3 box sum (a cheap
   matched filter that gains up to 3× in SNR on wide traces): 2-D maxima for spots, maxima along
   the scan line for stripes. The patches are stacked candidate-minor, ``(8, 8, n)``, so that
   each NumPy step runs over ``n`` contiguous values rather than over many 8-pixel rows. Where
   many blocks are flagged (texture in a colour frame), whole-frame OpenCV filters find the same
   maxima faster.
3. *Detection test*: the box sum above 9 × background must exceed ``k_detect`` times its noise
   (3σ). At ``k_detect = 6`` pure noise gives about 1e-9 false candidates per pixel.
4. *Suppression*: of candidates closer than ``min_separation_px``, the stronger one stays.
5. *Prominence* (stripes): a laser profile rises and falls within a few widths, a step in
   reflectance (a printed dot, a square, a board's edge, wood grain) has one flank only. The box
   sum at a candidate is compared with the lowest box sum on *each* side within reach, and the
   higher of the two lows is its base: :func:`line_prominence`. A step has no base on its bright
   side and gets no prominence. Many candidates read the lows from one erosion of the whole
   frame's box sums along the lines.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scanrig.laser.background import BG_CELL
from scanrig.laser.image import LaserImage
from scanrig.laser.noise import NOISE_CELL
from scanrig.laser.pixels import padded_box_sums, pixel_blocks

_BLOCK_BITS = 2
BLOCK = 1 << _BLOCK_BITS  # 4
_PATCH_MARGIN = 2
_PATCH = BLOCK + 2 * _PATCH_MARGIN


@dataclass(frozen=True)
class Candidates:
    """Integer positions of candidates in signal coordinates.

    Attributes
    ----------
    u, v : (n,) int arrays, pixels
        Column and row of the box-sum maximum.
    score : (n,) float array
        Box-sum SNR: (3 × 3 sum − 9 × background) / (3 σ).
    """

    u: np.ndarray
    v: np.ndarray
    score: np.ndarray

    def take(self, index) -> Candidates:
        return Candidates(self.u[index], self.v[index], self.score[index])


def prescan(li: LaserImage, k_seed: float = 4.5) -> np.ndarray:
    """Excess of each 4 × 4 block's maximum over background + ``k_seed`` σ, DN.

    σ is the noise or, in a colour frame where it is larger, the frame's structured clutter
    (:attr:`~scanrig.laser.image.LaserImage.clutter`), which a stripe's peak must clear in the
    detection test as well: a block of JPEG texture alone seeds no search and adds no structure
    to :func:`worth_scanning`. Where the scene itself reaches the clip level, the threshold is at
    least :attr:`~scanrig.laser.image.LaserImage.seed_floor`.

    Returns
    -------
    (ceil(H/4), ceil(W/4)) float32 array
        Positive where a block holds a pixel above the seed threshold.
    """

    block_max = _block_max(li.signal)
    shape = block_max.shape
    # the threshold on the background's cells (noise cells are whole multiples of them), then
    # repeated to blocks: the same float32 values as computed block by block, 16× fewer
    noise = _upsample(np.maximum(li.noise, li.clutter), NOISE_CELL // BG_CELL, li.background.shape)
    cells = li.background + np.float32(k_seed) * noise
    if li.seed_floor is not None:  # a scene at the clip level: only a laser core it shows seeds there
        cells = np.maximum(cells, li.seed_floor)
    threshold = _upsample(cells, BG_CELL // BLOCK, shape)
    return np.subtract(block_max, threshold, dtype=np.float32)


def _block_max(sig: np.ndarray) -> np.ndarray:
    """Maximum of every ``BLOCK`` × ``BLOCK`` block (the last ones may be partial), ``(hb, wb)``.

    The maximum over each block's rows first, from ``BLOCK`` row-strided views (OpenCV reads them
    without copies), then a ``1 × BLOCK`` dilation read at stride: one pass over the frame and a
    quarter-size intermediate, instead of a full-size dilated copy.
    """
    import cv2

    hb = -(-sig.shape[0] // BLOCK)
    rows = [sig[k::BLOCK] for k in range(BLOCK)]
    # a short last block: repeat its last row (which it already holds) in the missing views
    rows = [r if r.shape[0] == hb else np.concatenate([r, sig[-1:]]) for r in rows]
    row_max = rows[0]
    for r in rows[1:]:
        row_max = cv2.max(row_max, r)
    return cv2.dilate(row_max, np.ones((1, BLOCK), np.uint8), anchor=(0, 0))[:, ::BLOCK]


def _upsample(cells: np.ndarray, factor: int, shape) -> np.ndarray:
    """Each cell repeated ``factor`` × ``factor`` times, cropped to ``shape``."""
    # along rows first, while the array is small; then whole rows are copied
    return np.repeat(np.repeat(cells, factor, 1), factor, 0)[: shape[0], : shape[1]]


#: A scan direction is worth running in a block when the pre-scan's structure across its lines is
#: at least this fraction of the structure across the other direction's lines.
_WORTH_SCANNING = 0.1


def worth_scanning(excess: np.ndarray, tile_blocks: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """The blocks to search from along rows, and along columns: those of positive excess where a
    scan in that direction may cross a stripe steeply.

    A coarse structure tensor of the pre-scan: squared differences of the positive block excess
    across columns and across rows, summed over ``tile_blocks`` × ``tile_blocks`` blocks. A stripe
    that runs along columns changes across columns and hardly across rows there, so a column scan
    would follow it lengthwise: where one sum is below ``_WORTH_SCANNING`` of the other, only the
    other direction runs (a clean straight stripe is scanned once). Texture and curves make both
    sums comparable: both run, and the candidates decide (:func:`direction_map`). The sums are
    needed at the blocks of positive excess alone: read there from integral images (OpenCV's box
    filter of the whole block map costs twice as much).

    Parameters
    ----------
    excess : (hb, wb) float32 array
        Result of :func:`prescan`.
    tile_blocks : int
        Side of the summing window, blocks (odd).

    Returns
    -------
    rows, columns : (hb, wb) bool arrays
        False wherever the excess is not positive.
    """
    e = np.maximum(excess, 0.0, dtype=np.float32)
    across_cols, across_rows = np.empty_like(e), np.empty_like(e)  # squared differences, 0 at the end
    np.subtract(e[:, 1:], e[:, :-1], out=across_cols[:, :-1])
    across_cols[:, -1] = 0.0
    np.subtract(e[1:], e[:-1], out=across_rows[:-1])
    across_rows[-1] = 0.0
    np.square(across_cols, out=across_cols)
    np.square(across_rows, out=across_rows)
    flagged = excess > 0.0
    at = np.flatnonzero(flagged)  # (NumPy's nonzero of a 2-D mask is ten times slower)
    i, j = np.divmod(at, e.shape[1])
    sxx, syy = (_window_sums(a, i, j, tile_blocks // 2) for a in (across_cols, across_rows))
    rows, columns = np.zeros_like(flagged), np.zeros_like(flagged)
    rows.ravel()[at] = sxx >= _WORTH_SCANNING * syy
    columns.ravel()[at] = syy >= _WORTH_SCANNING * sxx
    return rows, columns


def _window_sums(a: np.ndarray, i: np.ndarray, j: np.ndarray, radius: int) -> np.ndarray:
    """Sums of ``a (H, W)`` over the squares of ``2 radius + 1`` centred on ``(i, j)`` (``(n,)``
    ints), the image reflected beyond its edges as by OpenCV's box filter (``BORDER_REFLECT_101``),
    from its float64 integral image: ``(n,)`` float64."""
    import cv2

    side = 2 * radius + 1
    total = cv2.integral(cv2.copyMakeBorder(a, radius, radius, radius, radius, cv2.BORDER_REFLECT_101),
                         sdepth=cv2.CV_64F)
    corner, down = i * total.shape[1] + j, side * total.shape[1]  # flat indices: one gather per corner
    total = total.ravel()
    return total[corner + down + side] - total[corner + side] - total[corner + down] + total[corner]


def direction_map(rows_weight: np.ndarray, columns_weight: np.ndarray, tile_blocks: int = 9) -> np.ndarray:
    """Per 4 × 4 block, the share of the evidence that rows cross the stripe there steeply: it is
    best crossed by rows where the share is at least ½, by columns where it is below.

    A stripe crossed at a steep angle has prominent maxima along the crossing lines; crossed
    lengthwise it has none (its profile along the line is flat). The summed prominence of the
    candidates found along rows and along columns, each summed over ``tile_blocks`` ×
    ``tile_blocks`` blocks, decides: a curved stripe gets rows where it is steep and columns where
    it is flat, and a share near ½ where it runs at 45° to both, which cross it equally steeply
    (:func:`~scanrig.laser.stripe_candidates.crossed_steeply`). Every candidate's own block has
    evidence; blocks without candidates near them read 1.

    Parameters
    ----------
    rows_weight, columns_weight : (hb, wb) float32 arrays
        Summed prominence of the candidates of each block, found along rows and along columns.
    tile_blocks : int
        Side of the summing window, blocks (odd).

    Returns
    -------
    (hb, wb) float64 array
        Rows' share, 0 to 1 (at least ½ exactly where the rows' sum is at least the columns').
    """
    import cv2

    size = (tile_blocks, tile_blocks)
    along_rows = cv2.boxFilter(rows_weight, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    along_cols = cv2.boxFilter(columns_weight, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    # in float64 the share of two float32 sums is >= 1/2 exactly where along_rows >= along_cols
    total = along_rows.astype(np.float64) + along_cols
    return np.divide(along_rows, total, out=np.ones_like(total), where=total > 0)


def find_candidates(li: LaserImage, along: str, excess: np.ndarray | None = None, k_seed: float = 4.5,
                    k_detect: float = 6.0) -> Candidates:
    """Local maxima of the 3 × 3 box sum that pass the detection test.

    Parameters
    ----------
    li : LaserImage
        The prepared frame.
    along : {"2d", "rows", "columns"}
        ``"2d"``: maxima over the 8-neighbourhood (spots). ``"rows"``: maxima along each row
        (a stripe crossing the rows); ``"columns"``: along each column.
    excess : array, optional
        Result of :func:`prescan` (computed when omitted), or any array positive (True) on the
        blocks to search from.
    k_seed, k_detect : float
        Pre-scan and detection thresholds, in noise σ.

    Returns
    -------
    Candidates
        Sorted by row, then column.
    """
    import cv2

    sig = li.signal
    if excess is None:
        excess = prescan(li, k_seed)
    flagged = (excess if excess.dtype == bool else excess > 0).view(np.uint8)
    if not flagged.any():
        return _empty()
    flagged = cv2.dilate(flagged, np.ones((3, 3), np.uint8))
    if np.count_nonzero(flagged) >= _WHOLE_FRAME_SHARE * flagged.size:
        v, u, box = _maxima_of_frame(li.box_sums, flagged, along)
    else:
        v, u, box = _maxima_in_patches(sig, flagged, along)
    above = box - 9.0 * li.background_at(u, v)
    # the noise looked up only where the frame's lowest could pass (its margin covers rounding)
    hopeful = np.flatnonzero(above >= _HOPEFUL * 3.0 * k_detect * li.noise_floor())
    u, v = u[hopeful], v[hopeful]
    score = above[hopeful] / (3.0 * li.noise_at(u, v))
    keep = score >= k_detect
    return Candidates(u[keep], v[keep], score[keep])


#: Margin of the test against the frame's lowest noise in :func:`find_candidates` (a candidate
#: rejected there would fail the exact test by far more than rounding).
_HOPEFUL = 0.999


#: Share of the blocks flagged (with their neighbours) from which the maxima are searched with
#: whole-frame filters rather than in patches around the flagged blocks: they cost about the same
#: there (measured on 1920 x 1080 colour and 1280 x 1024 grey frames: 7-17 %).
_WHOLE_FRAME_SHARE = 0.15


def _maxima_in_patches(sig: np.ndarray, flagged: np.ndarray, along: str):
    """Maxima of the 3 × 3 box sum (see :func:`find_candidates`) in the flagged blocks, searched in
    ``_PATCH``-pixel patches around them: rows ``v``, columns ``u`` and the box sums there, sorted
    by row, then column."""
    import cv2

    h, w = sig.shape
    # 0/1 bytes seen as bool: NumPy's nonzero is many times faster on bool than on uint8
    bi, bj = np.divmod(np.flatnonzero(flagged.view(bool)), flagged.shape[1])
    n = bi.size

    # Patches candidate-minor, (8, 8, n): every elementwise step below runs over n contiguous values.
    patch, bi, bj = _patches(sig, bi, bj)
    three = patch[:-2] + patch[1:-1] + patch[2:]
    box = three[:, :-2] + three[:, 1:-1] + three[:, 2:]  # (6, 6, n): offsets -1 .. 4
    core = box[1:-1, 1:-1]  # offsets 0 .. 3 (the block itself)
    if along == "2d":
        is_max = np.ones(core.shape, bool)
        for dv in (-1, 0, 1):
            for du in (-1, 0, 1):
                if dv or du:
                    is_max &= core >= box[1 + dv : 5 + dv, 1 + du : 5 + du]
    elif along == "rows":  # along the scan line: >= left, > right
        is_max = (core >= box[1:-1, :-2]) & (core > box[1:-1, 2:])
    else:  # columns: >= above, > below
        is_max = (core >= box[:-2, 1:-1]) & (core > box[2:, 1:-1])
    # candidate-major for the flat indices, so that they split by shifts (integer division is slow)
    flat = np.flatnonzero(cv2.transpose(is_max.reshape(BLOCK * BLOCK, n).view(np.uint8)).view(bool))
    k, dv, du = flat >> 2 * _BLOCK_BITS, (flat >> _BLOCK_BITS) & (BLOCK - 1), flat & (BLOCK - 1)
    v = bi[k] * BLOCK + dv
    u = bj[k] * BLOCK + du
    if h % BLOCK or w % BLOCK:  # the last blocks reach beyond the frame
        inside = (v < h) & (u < w)
        k, dv, du, v, u = k[inside], dv[inside], du[inside], v[inside], u[inside]
    # one integer key sorts faster than two, and a stable sort (a merge of the sorted runs that
    # the blocks of one row give) faster than the default; the keys are distinct
    order = np.argsort(v * w + u, kind="stable")
    # the box sum at core[dv, du, k], one index into the flat box sums
    at = ((dv[order] + 1) * box.shape[1] + du[order] + 1) * n + k[order]
    return v[order], u[order], box.ravel().take(at)


def _maxima_of_frame(box: np.ndarray, flagged: np.ndarray, along: str):
    """:func:`_maxima_in_patches` from whole-frame OpenCV filters, for frames flagged over a large
    part (texture in a colour frame): the frame's box sums ``box``
    (:func:`~scanrig.laser.pixels.padded_box_sums`) compared with their shifted views."""
    import cv2

    h, w = box.shape[0] - 2, box.shape[1] - 2
    core = box[1:-1, 1:-1]
    if along == "2d":
        shifts = [(dv, du) for dv in (-1, 0, 1) for du in (-1, 0, 1) if dv or du]
    else:
        shifts = [(0, -1), (0, 1)] if along == "rows" else [(-1, 0), (1, 0)]
    is_max = np.ascontiguousarray(_upsample(flagged, BLOCK, (h, w)))  # in a flagged block
    for dv, du in shifts:
        # along a scan line the later neighbour must be strictly lower (ties go to the first)
        test = cv2.CMP_GT if along != "2d" and dv + du > 0 else cv2.CMP_GE
        cv2.bitwise_and(is_max, cv2.compare(core, box[1 + dv : 1 + dv + h, 1 + du : 1 + du + w], test), dst=is_max)
    v, u = np.divmod(np.flatnonzero(is_max.view(bool)), w)
    return v, u, core[v, u]


def _patches(sig: np.ndarray, bi: np.ndarray, bj: np.ndarray):
    """The ``_PATCH``-pixel squares around blocks ``(bi, bj)``, uint16 (8-bit data) or float32,
    candidate-minor ``(_PATCH, _PATCH, n)``; pixels outside the frame repeat the nearest edge pixel.

    Returns the patches and the blocks ``bi, bj`` in the patches' order (blocks at the frame's
    edge last).
    """
    import cv2
    from numpy.lib.stride_tricks import as_strided, sliding_window_view

    h, w = sig.shape
    n_tops = (h - _PATCH_MARGIN - _PATCH) // BLOCK + 1  # patches inside the frame's rows: bi = 1 .. n_tops
    left = bj * BLOCK - _PATCH_MARGIN
    inside = (bi >= 1) & (bi <= n_tops) & (left >= 0) & (left + _PATCH <= w)
    if sig.strides[1] != sig.itemsize:
        inside[:] = False
    parts = []
    if not inside.all():  # blocks at the edge: pixel by pixel
        edge = ~inside
        bi, bj, left = (np.concatenate([a[inside], a[edge]]) for a in (bi, bj, left))
        n_edge = int(edge.sum())
        offsets = np.arange(_PATCH)
        rows = np.minimum(np.maximum(bi[-n_edge:, None] * BLOCK + (offsets - _PATCH_MARGIN), 0), h - 1)
        cols = np.minimum(np.maximum(left[-n_edge:, None] + offsets, 0), w - 1)
        parts.append(sig[rows[:, :, None], cols[:, None, :]].reshape(n_edge, -1))
    n_inside = bi.size - sum(p.shape[0] for p in parts)
    if n_inside:
        # each run of _PATCH pixels of a row as one opaque element, and the runs of a patch as one
        # strided axis: 8 copies per patch, not 64
        run = np.dtype((np.void, _PATCH * sig.itemsize))
        runs = sliding_window_view(sig, _PATCH, axis=1).view(run)[..., 0]
        stacks = as_strided(runs[_PATCH_MARGIN:], (n_tops, runs.shape[1], _PATCH),
                            (BLOCK * runs.strides[0], runs.strides[1], runs.strides[0]), writeable=False)
        whole = stacks[bi[:n_inside] - 1, left[:n_inside]]
        parts.insert(0, whole.view(sig.dtype).reshape(n_inside, -1))
    patch = parts[0] if len(parts) == 1 else np.concatenate(parts)
    work = np.uint16 if sig.dtype == np.uint8 else np.float32  # box sums of bytes: exact in 16 bits
    return cv2.transpose(patch).astype(work).reshape(_PATCH, _PATCH, bi.size), bi, bj


def suppress_2d(u: np.ndarray, v: np.ndarray, score: np.ndarray, radius_px: float) -> np.ndarray:
    """Keep-mask: drop every candidate with a stronger one (ties: the earlier one) within ``radius_px``.

    Parameters
    ----------
    u, v : (n,) arrays, pixels
    score : (n,) float array
    radius_px : float

    Returns
    -------
    (n,) bool array
    """
    keep = np.ones(u.size, bool)
    if u.size < 2:
        return keep
    from scipy.spatial import cKDTree

    pairs = cKDTree(np.stack([u, v], axis=1).astype(float)).query_pairs(radius_px, output_type="ndarray")
    if pairs.size:
        i, j = pairs[:, 0], pairs[:, 1]
        i_wins = (score[i] > score[j]) | ((score[i] == score[j]) & (i < j))
        keep[np.where(i_wins, j, i)] = False
    return keep


def suppress_on_lines(line: np.ndarray, pos: np.ndarray, score: np.ndarray, radius_px: float) -> np.ndarray:
    """Keep-mask for 1-D suppression: candidates sorted by ``(line, pos)`` lose to a stronger
    neighbour on the same line closer than ``radius_px``."""
    keep = np.ones(line.size, bool)
    if line.size < 2:
        return keep
    close = (line[1:] == line[:-1]) & (np.abs(pos[1:] - pos[:-1]) < radius_px)
    right_wins = score[1:] > score[:-1]
    keep[:-1] &= ~(close & right_wins)
    keep[1:] &= ~(close & ~right_wins)
    return keep


#: Cost of one value gathered into a candidate's window relative to one entry of the running-minimum
#: table (measured on 1920 x 1080 colour frames: about 30 ns against 5 ns).
_GATHER_COST = 6
#: Cost of :func:`_prominence_from_erosion` per pixel of the frame, in the same units (a 3 × 3 box
#: filter and one erosion in OpenCV: about 2 ns a pixel on one core), and of 8-bit data, whose box
#: sums are 16-bit integers (measured on 960 x 1280 colour frames: as costly as the windows of
#: 2,000 candidates).
_EROSION_COST = 2
_EROSION_COST_8BIT = 0.7


def line_prominence(signal: np.ndarray, line: np.ndarray, pos: np.ndarray, reach: np.ndarray,
                    box_sums: np.ndarray | Callable[[], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Prominence of candidates along their scan lines (axis 1 of ``signal``), DN of the 3 × 3 box sum.

    The box sum at ``pos`` minus the higher of the two lowest box sums on its left and on its
    right within ``reach`` pixels: both flanks must fall for a candidate to be prominent.
    Positions beyond the frame repeat its edge.

    A few candidates (a stripe's one crossing per line) read their windows directly; many (a
    textured colour frame has tens of thousands) read the running minima of the whole frame's box
    sums (:func:`_prominence_from_erosion`), whose cost does not grow with their number.

    Parameters
    ----------
    signal : (n_lines, n_pos) array, DN
    line, pos : (n,) int arrays
    reach : (n,) int array
        Pixels searched on each side, at least 1.
    box_sums : array or callable, optional
        The box sums of ``signal`` (:func:`~scanrig.laser.pixels.padded_box_sums`, transposed with
        it) when already computed (the windows are read from them, a third of the gathers), or a
        function returning them, called only when the whole frame's are needed.

    Returns
    -------
    prominence : (n,) float32 array
    box : (n,) float32 array
        The box sum at each candidate.
    """
    if line.size == 0:
        return np.zeros(0, np.float32), np.zeros(0, np.float32)
    known = box_sums if isinstance(box_sums, np.ndarray) else None
    if _windows_cost(reach, known is not None) <= (_EROSION_COST_8BIT if signal.dtype == np.uint8
                                                   else _EROSION_COST) * signal.size:
        return _prominence_from_windows(signal, line, pos, reach, known)
    if known is None:
        known = _box_sums_along(signal) if box_sums is None else box_sums()
    return _prominence_from_erosion(known, line, pos, reach)


def _windows_cost(reach: np.ndarray, from_box: bool) -> int:
    """Cost of :func:`_prominence_from_windows` for candidates of ``reach``, in table entries."""
    cost = 0
    for batch in _reach_batches(reach):
        far = int(reach[batch].max())
        cost += _GATHER_COST * reach[batch].size * ((2 * far + 1) if from_box else 3 * (2 * far + 3))
    return cost


def _reach_batches(reach: np.ndarray) -> list[np.ndarray]:
    """Masks of the candidates within the most common reach (all those not on a clipped run) and
    of the others, if any: read in two batches, a few long windows do not widen all."""
    common = reach <= np.bincount(reach).argmax()
    return [common] if common.all() else [common, ~common]


def _box_sums_along(signal: np.ndarray) -> np.ndarray:
    """:func:`~scanrig.laser.pixels.padded_box_sums` of ``signal`` in its orientation, computed on
    its base array when it is a transposed view (columns scanned)."""
    if signal.strides[1] == signal.itemsize or signal.strides[0] != signal.itemsize:
        return padded_box_sums(signal)
    return padded_box_sums(signal.T).T


def _prominence_from_erosion(box, line, pos, reach) -> tuple[np.ndarray, np.ndarray]:
    """:func:`line_prominence` from the whole frame's box sums ``box`` eroded along the lines.

    The candidates at the most common reach ``r`` (all those not on a clipped run) and at least
    ``r`` pixels from both ends of their line read the lowest box sum of ``pos − r .. pos − 1`` and
    of ``pos + 1 .. pos + r`` from one OpenCV erosion by ``r`` pixels. The others (another reach,
    or a window beyond the frame) read their own windows or, when they are many,
    :func:`_prominence_from_table`.
    """
    import cv2

    n_pos = box.shape[1] - 2
    r = int(np.bincount(reach).argmax())
    inside = (reach == r) & (pos >= r) & (pos < n_pos - r)
    easy = np.flatnonzero(inside)
    along_rows = box.strides[1] == box.itemsize
    # a transposed view (columns scanned) is eroded as its base, across the base's rows
    core = box[1:-1, 1:-1]
    lowest = cv2.erode(core if along_rows else core.T, np.ones((1, r) if along_rows else (r, 1), np.uint8),
                       anchor=(0, 0))  # of x .. x + r - 1
    step = 1 if along_rows else lowest.shape[1]  # from one position to the next along a line, flat
    at = line[easy] * (lowest.shape[1] if along_rows else 1) + pos[easy] * step
    prominence, centre = np.empty(line.size, np.float32), np.empty(line.size, np.float32)
    centre[easy] = box[line[easy] + 1, pos[easy] + 1]
    lowest = lowest.ravel()
    prominence[easy] = centre[easy] - np.maximum(lowest.take(at - r * step), lowest.take(at + step))
    rest = np.flatnonzero(~inside)
    if rest.size:
        n_levels = int(reach[rest].max()).bit_length()
        by = (_prominence_from_windows if _windows_cost(reach[rest], True) <= (n_levels + 3) * core.size
              else _prominence_from_table)
        prominence[rest], centre[rest] = by(None, line[rest], pos[rest], reach[rest], box)
    return prominence, centre


def _prominence_from_windows(signal, line, pos, reach, box=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`line_prominence` from each candidate's own window of box sums: read from ``box``
    when given, else summed from the ``3 × (2 reach + 3)`` pixels of ``signal`` around it; in
    the batches of :func:`_reach_batches`."""
    prominence, centre = np.empty(line.size, np.float32), np.empty(line.size, np.float32)
    for batch in _reach_batches(reach):
        prominence[batch], centre[batch] = _windows_batch(signal, line[batch], pos[batch], reach[batch], box)
    return prominence, centre


def _windows_batch(signal, line, pos, reach, box) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_prominence_from_windows` of one batch, in windows as wide as its longest reach,
    stacked candidate-minor (each step, and each lowest over a flank, runs over all candidates at
    once rather than over many short rows)."""
    import cv2

    far = int(reach.max())
    n = line.size
    if box is not None:  # (2 far + 1, n): offsets -far .. far (box has the ring: positions + 1)
        window = cv2.transpose(pixel_blocks(box, line + 1, pos + 1 - far, 1, 2 * far + 1).reshape(n, -1))
        window = window.astype(np.float32, copy=False)
    else:
        rows = cv2.transpose(pixel_blocks(signal, line - 1, pos - far - 1, 3, 2 * far + 3).reshape(n, -1))
        rows = rows.reshape(3, 2 * far + 3, n)
        col3 = rows[0].astype(np.float32)
        col3 += rows[1]
        col3 += rows[2]
        window = col3[:-2] + col3[1:-1]
        window += col3[2:]
    masked = window
    if reach.min() < far:
        masked = np.where(np.abs(np.arange(-far, far + 1))[:, None] > reach, np.float32(np.inf), window)
    left = masked[:far].min(axis=0)
    right = masked[far + 1 :].min(axis=0)
    return window[far] - np.maximum(left, right), window[far]


def _prominence_from_table(signal, line, pos, reach, box) -> tuple[np.ndarray, np.ndarray]:
    """:func:`line_prominence` from a sparse table of running minima of the box sums ``box`` along
    the lines (``signal`` is not read).

    ``minima[k][l, x]`` is the lowest box sum of ``x .. x + 2**k - 1`` on line ``l``; the lowest
    of any window is that of two overlapping power-of-two windows (a range-minimum query). Beyond
    the frame the pixels repeat its edge, so every box sum there is that of the ring of ``box``.
    """
    n_pos = box.shape[1] - 2
    minima = np.empty((int(reach.max()).bit_length(), box.shape[0] - 2, n_pos), np.float32)
    minima[0] = box[1:-1, 1:-1]
    for k in range(1, minima.shape[0]):
        half = 1 << (k - 1)
        np.minimum(minima[k - 1, :, : n_pos - half], minima[k - 1, :, half:], out=minima[k, :, : n_pos - half])
        minima[k, :, n_pos - half :] = minima[k - 1, :, n_pos - half :]

    def lowest(lo, hi, beyond_box):
        """Lowest box sum of ``lo .. hi`` on each candidate's line, the part beyond the frame
        counting as ``beyond_box``."""
        inside = np.clip([lo, hi], 0, n_pos - 1)
        level = np.log2(inside[1] - inside[0] + 1).astype(np.int64)  # exact for these small integers
        low = np.minimum(minima[level, line, inside[0]], minima[level, line, inside[1] + 1 - (1 << level)])
        low = np.where(hi < 0, np.inf, np.where(lo >= n_pos, np.inf, low))  # the window lies outside
        return np.where((lo < 0) | (hi >= n_pos), np.minimum(low, beyond_box), low)

    left = lowest(pos - reach, pos - 1, box[line + 1, 0])
    right = lowest(pos + 1, pos + reach, box[line + 1, n_pos + 1])
    centre = box[line + 1, pos + 1]
    return (centre - np.maximum(left, right)).astype(np.float32), centre


def _empty() -> Candidates:
    z = np.zeros(0, np.int64)
    return Candidates(z, z, np.zeros(0))
