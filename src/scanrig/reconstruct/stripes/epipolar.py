"""Epipolar matching of stripe points: crossings of a detection's epipolar line with other stripes."""

from __future__ import annotations

import numpy as np

from scanrig.reconstruct.stripes.views import StripeView

#: Crossings of one epipolar line with one camera's stripe closer than this (pixels) belong to
#: the same piece of stripe (overlapping segments between neighbours cross the line together).
MERGE_PX = 3.0
#: At most this many distinct crossings (branches) per reference detection and camera.
MAX_BRANCHES = 4


def _essential(cam_i, cam_j) -> np.ndarray:
    """``E`` with ``x_jᵀ E x_i = 0`` for normalised coordinates of cameras i and j."""
    j_from_i = cam_j.cam_from_world @ cam_i.cam_from_world.inverse()
    t = j_from_i.t
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return tx @ j_from_i.R


def _crossings(cam_i, view_i: StripeView, cam_j, view_j: StripeView):
    """Where each point of view i's epipolar line crosses view j's stripe, one row per branch.

    Returns
    -------
    a : ndarray of shape (M,), int
        Index of the reference point in view i.
    b : ndarray of shape (M,), int
        Detection of view j that represents the branch: the segment end nearest to the line.
    """
    empty = np.zeros((0,), int)
    if len(view_i.q) == 0 or len(view_j.segments) == 0:
        return empty, empty
    essential = _essential(cam_i, cam_j)
    lines = view_i.xh @ essential.T  # (n_i, 3): line in j's normalised plane
    seg, a = near_crossings(essential, view_i.xh, view_j.xh, view_j.segments)
    i1, i2 = view_j.segments[seg, 0], view_j.segments[seg, 1]
    # signed (unnormalised) distances of the segments' ends to the lines
    s1 = np.einsum("ij,ij->i", view_j.xh[i1], lines[a])
    s2 = np.einsum("ij,ij->i", view_j.xh[i2], lines[a])
    cross = crossing(s1, s2)
    if not cross.any():
        return empty, empty
    a, i1, i2, s1, s2 = a[cross], i1[cross], i2[cross], s1[cross], s2[cross]
    t = s1 / (s1 - s2)
    qc = view_j.q[i1] + t[:, None] * (view_j.q[i2] - view_j.q[i1])
    b = np.where(t <= 0.5, i1, i2)
    offset = np.linalg.norm(qc - view_j.q[b], axis=1)
    keep = view_j.has_tangent[b]
    a, b, qc, offset = a[keep], b[keep], qc[keep], offset[keep]
    return _branches(a, b, qc, offset)


#: Angular margin of :func:`near_crossings`, rad: far above the rounding of its angles, so that
#: every pair the sign test finds crossing is among its candidates.
PENCIL_MARGIN_RAD = 1e-9
#: Points within this of their camera's epipole (relative, in normalised coordinates) have no angle
#: to that margin: they, and the lines of such points of camera i, pair with everything.
NEAR_EPIPOLE = 1e-6


def near_crossings(essential: np.ndarray, xh_i: np.ndarray, xh_j: np.ndarray, segments: np.ndarray):
    """The (segment, line) pairs that cross or nearly do: candidates for :func:`crossing`.

    Every epipolar line of camera j passes through its epipole, so the lines form a pencil, one
    angle each, and a segment crosses the lines whose angle lies between those of its two ends
    seen from the epipole (mod π). Sorting the lines by angle turns the test of every segment
    against every line (a dense ``(segments, lines)`` array: 100 MB at 3 500 detections a camera)
    into one range of lines per segment. The margin :data:`PENCIL_MARGIN_RAD` covers the angles'
    rounding, so the sign test on the candidates finds what it would find on every pair.

    Parameters
    ----------
    essential : (3, 3) float array
        ``E`` with ``x_jᵀ E x_i = 0`` (rank 2).
    xh_i, xh_j : (n_i, 3), (n_j, 3) float arrays
        Homogeneous normalised coordinates of cameras i and j (NaN rows never cross).
    segments : (K, 2) int array
        Pairs of detections of camera j.

    Returns
    -------
    seg, line : (M,) int arrays
        Index into ``segments`` and into ``xh_i`` (the line ``E x_i``), sorted by segment, then line.
    """
    lines = xh_i @ essential.T
    # the pencil's coordinates: two lines m0, m1 through the epipole (E's range); a line is
    # c0 m0 + c1 m1 and its signed distance to a point x is c · d, d = (m0 · x, m1 · x)
    basis = np.linalg.svd(essential)[0][:, :2]
    c, d = lines @ basis, xh_j @ basis
    # a line's zero set among the d: the direction perpendicular to c, mod π
    gamma = np.remainder(np.arctan2(c[:, 1], c[:, 0]) + 0.5 * np.pi, np.pi)
    beta = np.arctan2(d[:, 1], d[:, 0])
    with np.errstate(invalid="ignore"):  # NaN rows: neither test holds, they are left out
        # a line's rounding is that of E x_i, not of the line itself (small near the epipole)
        line_any = np.hypot(c[:, 0], c[:, 1]) < NEAR_EPIPOLE * np.linalg.norm(essential) * np.linalg.norm(xh_i, axis=1)
        point_any = np.hypot(d[:, 0], d[:, 1]) < NEAR_EPIPOLE * np.linalg.norm(xh_j, axis=1)
    beta1, beta2 = beta[segments[:, 0]], beta[segments[:, 1]]
    # the arc of directions the segment sweeps seen from the epipole: from lo over width, mod π
    delta = np.remainder(beta2 - beta1 + np.pi, 2.0 * np.pi) - np.pi
    lo = np.remainder(np.minimum(beta1, beta1 + delta) - PENCIL_MARGIN_RAD, np.pi)
    width = np.abs(delta) + 2.0 * PENCIL_MARGIN_RAD
    seg_ok = np.isfinite(lo)
    whole = seg_ok & ((width >= np.pi) | point_any[segments[:, 0]] | point_any[segments[:, 1]])
    part = seg_ok & ~whole
    lo, end = np.where(part, lo, 0.0), np.where(part, lo + width, 0.0)
    ranked = np.flatnonzero(np.isfinite(gamma) & ~line_any)
    ranked = ranked[np.argsort(gamma[ranked], kind="stable")]
    gamma_sorted = gamma[ranked]
    start = np.searchsorted(gamma_sorted, lo, "left")
    stop = np.where(whole, ranked.size, np.searchsorted(gamma_sorted, end, "right"))
    start[~part] = 0
    stop[~seg_ok] = 0
    # an arc past π goes on from 0
    wrap_stop = np.where(part & (end > np.pi), np.searchsorted(gamma_sorted, end - np.pi, "right"), 0)
    owner, pos = _ranges(np.r_[start, np.zeros_like(wrap_stop)], np.r_[stop, wrap_stop])
    seg, line = owner % len(segments), ranked[pos]
    anywhere = np.flatnonzero(line_any)  # lines without an angle: with every segment
    if anywhere.size:
        ok = np.flatnonzero(seg_ok)
        seg = np.r_[seg, np.repeat(ok, anywhere.size)]
        line = np.r_[line, np.tile(anywhere, ok.size)]
    by = np.lexsort((line, seg))
    return seg[by], line[by]


def _ranges(start: np.ndarray, stop: np.ndarray):
    """``(k, i)`` for every ``i`` in ``range(start[k], stop[k])`` and every ``k``, by ``k``."""
    count = np.maximum(stop - start, 0)
    owner = np.repeat(np.arange(start.size), count)
    first = np.repeat(start - (np.cumsum(count) - count), count)
    return owner, np.arange(owner.size) + first


def crossing(s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """Whether segments cross lines, from the signed distances ``s1, s2`` of their two ends to
    the lines: ``s1 · s2 <= 0`` and not both zero (no NaN end), same shape.

    The test runs on the signs, so no product can underflow. A NaN distance counts as above,
    below and on the line at once, so that a segment with a NaN end never crosses.
    """
    above1, below1 = ~(s1 <= 0.0), ~(s1 >= 0.0)
    above2, below2 = ~(s2 <= 0.0), ~(s2 >= 0.0)
    same_side = (above1 & above2) | (below1 & below2)
    return ~same_side & ~((above1 == below1) & (above2 == below2))


def _branches(a, b, qc, offset):
    """Merge the crossings of each reference point that lie within :data:`MERGE_PX` of each other."""
    order = np.lexsort((offset, a))
    a, b, qc = a[order], b[order], qc[order]
    keep = np.zeros(a.size, bool)
    alive = np.ones(a.size, bool)
    for _ in range(MAX_BRANCHES):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        first = idx[np.r_[True, a[idx][1:] != a[idx][:-1]]]
        keep[first] = True
        alive[first] = False
        idx = np.flatnonzero(alive)
        rep = first[np.searchsorted(a[first], a[idx])]
        alive[idx[np.linalg.norm(qc[idx] - qc[rep], axis=1) < MERGE_PX]] = False
    return a[keep], b[keep]



def hypotheses(n_cams: int, ref: int, n_ref: int, branches: dict):
    """Every choice of at most one branch per other camera for each reference detection.

    Returns ``choice (H, n_cams)``: the detection index per camera (``-1`` unused), at least one
    other camera used; column ``ref`` holds the reference detection.
    """
    refs = np.unique(np.concatenate([a for a, _ in branches.values()] or [np.zeros(0, int)]))
    choice = np.full((refs.size, n_cams), -1, np.int64)
    choice[:, ref] = refs
    for c, (a_c, b_c) in branches.items():
        order = np.argsort(a_c, kind="stable")
        a_c, b_c = a_c[order], b_c[order]
        rows, pos = _ranges(np.searchsorted(a_c, choice[:, ref], "left"),
                            np.searchsorted(a_c, choice[:, ref], "right"))
        extended = choice[rows].copy()
        extended[:, c] = b_c[pos]
        choice = np.concatenate([choice, extended])
    return choice[(choice >= 0).sum(axis=1) >= 2]



def frame_branches(rig, views) -> dict:
    """``(i, j) -> (a, b)``: the branches of every reference camera ``i`` in every other ``j``."""
    cams = rig.cameras
    return {(i, j): _crossings(cams[i], views[i], cams[j], views[j])
            for i in range(len(cams)) for j in range(len(cams)) if i != j}

