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
    lines = view_i.xh @ _essential(cam_i, cam_j).T  # (n_i, 3): line in j's normalised plane
    S = view_j.xh @ lines.T  # (n_j, n_i) signed (unnormalised) distances
    b1, b2 = view_j.segments[:, 0], view_j.segments[:, 1]
    seg, a = np.nonzero(crossing(S, b1, b2))
    if a.size == 0:
        return empty, empty
    i1, i2 = b1[seg], b2[seg]
    s1, s2 = S[i1, a], S[i2, a]
    t = s1 / (s1 - s2)
    qc = view_j.q[i1] + t[:, None] * (view_j.q[i2] - view_j.q[i1])
    b = np.where(t <= 0.5, i1, i2)
    offset = np.linalg.norm(qc - view_j.q[b], axis=1)
    keep = view_j.has_tangent[b]
    a, b, qc, offset = a[keep], b[keep], qc[keep], offset[keep]
    return _branches(a, b, qc, offset)


def crossing(S: np.ndarray, b1: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """Whether the segments ``b1[k] → b2[k]`` cross each line, from the signed distances ``S (n_j, n_i)``
    of the points to the lines: ``S[b1] · S[b2] <= 0`` and not both zero (no NaN end), ``(K, n_i)``.

    The test runs on the signs, gathered per segment as booleans (an eighth of the float rows'
    bytes). A NaN distance counts as above, below and on the line at once, so that a segment with
    a NaN end never crosses.
    """
    above, below = ~(S <= 0.0), ~(S >= 0.0)
    on_line = above == below
    same_side = (above[b1] & above[b2]) | (below[b1] & below[b2])
    return ~same_side & ~(on_line[b1] & on_line[b2])


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
        start = np.searchsorted(a_c, choice[:, ref], "left")
        count = np.searchsorted(a_c, choice[:, ref], "right") - start
        rows = np.repeat(np.arange(len(choice)), count)
        within = np.arange(rows.size) - np.repeat(np.cumsum(count) - count, count)
        extended = choice[rows].copy()
        extended[:, c] = b_c[np.repeat(start, count) + within]
        choice = np.concatenate([choice, extended])
    return choice[(choice >= 0).sum(axis=1) >= 2]



def frame_branches(rig, views) -> dict:
    """``(i, j) -> (a, b)``: the branches of every reference camera ``i`` in every other ``j``."""
    cams = rig.cameras
    return {(i, j): _crossings(cams[i], views[i], cams[j], views[j])
            for i in range(len(cams)) for j in range(len(cams)) if i != j}

