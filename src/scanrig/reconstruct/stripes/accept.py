"""Accepting stripe hypotheses: contradiction by an unused camera, one detection per point."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

#: A camera that a two-view point does not use, but whose stripe passes within this many pixels
#: of the point's projection without meeting it (χ² gate), contradicts the point.
NEAR_MISS_PX = 10.0


def contradicted(cams, views, choice, p, cov, gate: float) -> np.ndarray:
    """Points that a camera they do not use contradicts (see :data:`NEAR_MISS_PX`).

    For every camera ``k`` not in a point's hypothesis, the detection of ``k`` nearest to the
    point's projection is taken; if it lies within :data:`NEAR_MISS_PX` but the projection is off
    its stripe by more than the χ² ``gate`` allows (its across-stripe variance plus the point's
    projected covariance), the point is contradicted.
    """
    out = np.zeros(len(choice), bool)
    for k, (cam, view) in enumerate(zip(cams, views)):
        sel = np.flatnonzero(choice[:, k] < 0)
        if sel.size == 0 or not view.has_tangent.any():
            continue
        q, J = cam.project_with_point_jacobian(p[sel])
        size = np.array([cam.width, cam.height]) - 0.5
        inside = np.all(np.isfinite(q), axis=1) & np.all((q >= -0.5) & (q <= size), axis=1)
        sel, q, J = sel[inside], q[inside], J[inside]
        if sel.size == 0:
            continue
        idx = np.flatnonzero(view.has_tangent)
        dist, nearest = cKDTree(view.q[idx]).query(q, distance_upper_bound=NEAR_MISS_PX)
        near = np.isfinite(dist)
        sel, q, J, b = sel[near], q[near], J[near], idx[nearest[near]]
        nrm = view.normal[b]
        across = np.einsum("ni,ni->n", nrm, q - view.q[b])
        g = np.einsum("ni,nij->nj", nrm, J)
        var = view.var_perp[b] + np.einsum("ni,nij,nj->n", g, cov[sel], g)
        out[sel[across**2 > gate * var]] = True
    return out


def greedy_unique(det_ids: np.ndarray, priority: np.ndarray) -> np.ndarray:
    """Accept rows in ``priority`` order unless one of their detections is already taken.

    ``det_ids (H, k)`` holds frame-wide detection ids (``-1`` unused). Vectorised in rounds: a row
    is accepted when it is the best remaining row of every detection it uses, then every row
    sharing a detection with it is removed — the same result as the sequential greedy loop.
    """
    H = det_ids.shape[0]
    accepted = np.zeros(H, bool)
    alive = np.ones(H, bool)
    n_det = int(det_ids.max()) + 1 if det_ids.size else 0
    rank = np.empty(H, np.int64)
    rank[np.argsort(priority, kind="stable")] = np.arange(H)
    while alive.any():
        rows = np.flatnonzero(alive)
        ids = det_ids[rows]
        best = np.full(n_det + 1, H, np.int64)  # last slot collects unused (-1) entries
        np.minimum.at(best, np.where(ids >= 0, ids, n_det), np.repeat(rank[rows][:, None], ids.shape[1], axis=1))
        mine = np.where(ids >= 0, best[np.where(ids >= 0, ids, n_det)] == rank[rows][:, None], True)
        win = rows[np.all(mine, axis=1)]
        accepted[win] = True
        taken = np.zeros(n_det + 1, bool)
        taken[det_ids[win].ravel()] = True
        taken[n_det] = False
        alive[rows[np.any(taken[np.where(ids >= 0, ids, n_det)], axis=1)]] = False
        alive[win] = False
    return accepted

