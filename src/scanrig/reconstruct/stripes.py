"""Stripe mode: stripe points matched along epipolar lines, the frame's light plane, single views.

A stripe detection measures one number: where the stripe crosses its scan line. Its position
*along* the stripe is not a measurement. Matching a reference detection ``a`` of camera ``i``
with camera ``j`` therefore adds one constraint, not two: the point must project onto ``j``'s
stripe. The classic epipolar "crossing" hides this — the crossing is exactly on ``a``'s epipolar
line by construction, so a two-view point has a zero residual whatever the error, and where the
epipolar line runs nearly along ``j``'s stripe (cameras that see the light sheet edge-on, common
when the laser head and the cameras sit at similar heights) a 0.1 px error across the stripe, or
of the calibration, moves the crossing by pixels and the point by millimetres, while a
covariance interpolated from the detections still predicts a tenth of a millimetre. So:

1. **Stripes.** Each camera's detections are joined into segments between neighbours (closer
   than :data:`NEIGHBOUR_PX`, not on the same scan line) and into connected *pieces*; the local
   tangent of a detection is the principal direction of its neighbours, and its variance
   *across* the stripe is ``nᵀ Σ n`` (detection covariance plus the calibration floor).
2. **Crossings.** ``a``'s epipolar line is intersected with ``j``'s segments (in undistorted
   normalised coordinates); crossings closer than :data:`MERGE_PX` are one *branch* (the same
   piece of stripe), represented by the detection ``b`` nearest to the line. Reflections, other
   parts of a curved stripe and the far side of occlusions give further branches.
3. **Hypotheses.** Every choice of at most one branch per other camera is a hypothesis, solved
   by maximum likelihood (Gauss–Newton on pixels): ``a`` constrains the point with its full 2×2
   covariance, each ``b`` only across its stripe (weight ``n nᵀ / σ⊥²``). The covariance
   ``H⁻¹`` is then honest about the epipolar geometry, and the χ² has ``m − 1`` degrees of
   freedom for ``m`` other cameras: three views test each other, two do not. A hypothesis is
   void where the reference ray crosses a matched camera's stripe plane at less than
   ``min_angle_rad`` (no depth), or where the solution projects farther than :data:`MERGE_PX`
   along ``b``'s stripe from ``b`` (the line constraint is local).
4. **Calibration floor.** Before the frames are solved, the unambiguous three-view hypotheses of
   the whole session estimate how much pixel noise the calibration adds, per camera and ring of
   image radius (:func:`estimate_calibration_floor`): a calibration whose target never reached
   the image borders is off by pixels there, which the fixed ``sigma_floor_px`` cannot know.
5. **Light plane.** The frame's plane is fitted robustly (RANSAC with each point's variance
   along the candidate normal, errors-in-variables correction of its extent, weighted least
   squares, block-jackknife uncertainty) to the three-view hypotheses that pass their χ² gate —
   a reflection seen by one camera cannot be among them — or, with two cameras, to the two-view
   ones. Where the reference ray crosses it at ``min_angle_rad`` or more, the plane, with its
   own position uncertainty at the point, is one more measurement: the hypothesis is re-solved
   with it and its χ² (now ``m`` degrees of freedom) must pass the gate. Two-view points are
   tested by the plane only; a secondary reflection, even one every camera sees consistently,
   and a wrong branch are off it. Without a usable plane only three-view points are kept.
6. **One detection, one point.** Consistent hypotheses are accepted greedily — smallest sigma
   first, then most views — and a hypothesis is dropped when one of its detections already
   belongs to an accepted point: no detection supports two points, and a surface point is not
   written once per reference camera.
7. **Single views.** Brightest-on-their-line detections without any crossing in another camera
   (seen by that camera only), on a piece of stripe that other cameras confirm elsewhere (not an
   isolated noise peak or a reflection only this camera sees), are intersected with the plane
   (flag ``PLANE_SINGLE_VIEW``) unless their sigma exceeds :data:`SINGLE_VIEW_SIGMA_RATIO` times
   the frame's median multi-view sigma.
8. **Precision.** Points whose sigma exceeds :data:`MAX_SIGMA_RATIO` times the median sigma of
   the session's three-view points are left out (``max_sigma_m`` overrides).

A stripe that is a straight line in space leaves the plane's tilt about that line undetermined;
the plane's position uncertainty (lever arm from its inliers' true extent) grows away from the
line, which widens the gate and the sigma there.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.stats import chi2 as chi2_dist

from scanrig.errors import InputError
from scanrig.geometry.triangulation import MIN_TRIANGULATION_ANGLE_RAD
from scanrig.geometry.uncertainty import inv_sym3, pixel_weights, sigma_from_covariance
from scanrig.reconstruct.correspondence import GATE_PROBABILITY, SIGMA_FLOOR_PX
from scanrig.reconstruct.flags import Flag
from scanrig.reconstruct.light_plane import (
    MIN_PLANE_POINTS,
    fit_plane_robust,
    intersect_plane,
    ray_plane_covariance,
    with_block_uncertainty,
)
from scanrig.reconstruct.points import PointCloud

#: Two detections of one camera closer than this (pixels), and not on the same scan line, are
#: neighbours on a stripe: samples are one pixel apart along the scan direction, sqrt(2) on a 45°
#: stripe, and up to ~2.7 px for a stripe at 70° to its scan lines.
NEIGHBOUR_PX = 3.0
#: Crossings of one epipolar line with one camera's stripe closer than this (pixels) belong to
#: the same piece of stripe (overlapping segments between neighbours cross the line together).
MERGE_PX = 3.0
#: At most this many distinct crossings (branches) per reference detection and camera.
MAX_BRANCHES = 4
#: Half-length (pixels) of the piece of tangent used to back-project a stripe's local line.
TANGENT_STEP_PX = 2.0
#: Gauss–Newton steps after the linear start (the start is within the noise; two steps reach the
#: optimum to well below it, the third makes the covariance and χ² those of the optimum).
GN_STEPS = 3
#: A camera that a two-view point does not use, but whose stripe passes within this many pixels
#: of the point's projection without meeting it (χ² gate), contradicts the point.
NEAR_MISS_PX = 10.0
#: A two-view point is kept only if the plane makes it at most this many times more precise than
#: its two views do: the plane test sees errors at the scale of the views' own sigma.
PLANE_GAIN_MAX = 4.0
#: Points whose sigma exceeds this multiple of the median sigma of the session's three-view points
#: (the rig's typical self-checked precision) are left out: with honest covariances they are not
#: wrong, but they are too imprecise to help a surface that the other points pin down better.
MAX_SIGMA_RATIO = 1.5
#: Rings of image radius (px) on which the calibration floor is estimated.
FLOOR_BIN_PX = 50.0
#: Fewest unambiguous three-view points for the floor to be estimated (else the fixed floor).
FLOOR_MIN_SAMPLES = 200
#: A ring of a camera has its own floor only with this many samples, significantly (in standard
#: errors of a sign test) more of them above their χ² median than the noise model allows.
FLOOR_MIN_RING = 10
FLOOR_SIGNIFICANCE = 3.0
#: Robust re-fits of the floor, and the first (wide) gate, in multiples of the χ² gate.
FLOOR_ITERATIONS = 8
FLOOR_FIRST_GATE = 1000.0
#: A single-view point is kept only if its sigma is at most this multiple of the median sigma of
#: the frame's multi-view points: rays that meet the light plane at a grazing angle add nothing.
SINGLE_VIEW_SIGMA_RATIO = 3.0


class _View:
    """One camera's stripe detections in one frame: rays, segments, tangents and across-noise."""

    def __init__(self, cam, q, cov, rank, saturated, line=None, rows=None):
        n = len(q)
        self.cam = cam
        self.q, self.cov, self.rank, self.saturated = q, cov, rank, saturated
        line = np.arange(n) if line is None else np.asarray(line)
        rows = np.ones(n, bool) if rows is None else np.asarray(rows, bool)
        xy, _ = cam.unproject(q) if n else (np.zeros((0, 2)), None)
        R = cam.cam_from_world.R
        d_cam = np.c_[xy, np.ones(n)]
        d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
        self.xh = np.c_[xy, np.ones(n)]  # homogeneous normalised coordinates
        self.dirs = d_cam @ R  # world directions (R.T applied to row vectors)
        finite = np.all(np.isfinite(xy), axis=1)
        pairs = (cKDTree(q).query_pairs(NEIGHBOUR_PX, output_type="ndarray") if n > 1
                 else np.zeros((0, 2), int))
        same_line = (line[pairs[:, 0]] == line[pairs[:, 1]]) & (rows[pairs[:, 0]] == rows[pairs[:, 1]])
        self.segments = pairs[~same_line & finite[pairs[:, 0]] & finite[pairs[:, 1]]]
        # Local tangent: principal direction of the differences to the neighbours.
        s0, s1 = self.segments[:, 0], self.segments[:, 1]
        diff = q[s1] - q[s0]
        outer = diff[:, :, None] * diff[:, None, :]
        M = np.zeros((n, 2, 2))
        np.add.at(M, s0, outer)
        np.add.at(M, s1, outer)
        angle = 0.5 * np.arctan2(2.0 * M[:, 0, 1], M[:, 0, 0] - M[:, 1, 1])
        self.tangent = np.c_[np.cos(angle), np.sin(angle)]
        self.normal = np.c_[-self.tangent[:, 1], self.tangent[:, 0]]
        self.has_tangent = finite & (np.bincount(self.segments.ravel(), minlength=n) > 0)
        self.var_perp = np.einsum("ni,nij,nj->n", self.normal, cov, self.normal)
        self._lines = None
        # pieces of stripe: connected components of the neighbour graph
        graph = coo_matrix((np.ones(len(self.segments)), (self.segments[:, 0], self.segments[:, 1])), shape=(n, n))
        _, self.piece = connected_components(graph, directed=False) if n else (0, np.zeros(0, int))

    def inflate(self, extra_var_px2: np.ndarray) -> None:
        """Add an isotropic variance (px², one per detection) to the covariances, in place."""
        self.cov = self.cov + extra_var_px2[:, None, None] * np.eye(2)
        self.var_perp = self.var_perp + extra_var_px2

    def lines(self) -> np.ndarray:
        """``(n, 3)`` back-projected local stripe lines in normalised coordinates, ``|l[:2]| = 1``."""
        if self._lines is None:
            step = TANGENT_STEP_PX * self.tangent
            xa, _ = self.cam.unproject(self.q - step) if len(self.q) else (np.zeros((0, 2)), None)
            xb, _ = self.cam.unproject(self.q + step) if len(self.q) else (np.zeros((0, 2)), None)
            lines = np.cross(np.c_[xa, np.ones(len(xa))], np.c_[xb, np.ones(len(xb))])
            with np.errstate(invalid="ignore", divide="ignore"):
                self._lines = lines / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
        return self._lines


def _essential(cam_i, cam_j) -> np.ndarray:
    """``E`` with ``x_jᵀ E x_i = 0`` for normalised coordinates of cameras i and j."""
    j_from_i = cam_j.cam_from_world @ cam_i.cam_from_world.inverse()
    t = j_from_i.t
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return tx @ j_from_i.R


def _crossings(cam_i, view_i: _View, cam_j, view_j: _View):
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
    s1, s2 = S[b1], S[b2]
    seg, a = np.nonzero((s1 * s2 <= 0.0) & (s1 != s2))
    if a.size == 0:
        return empty, empty
    t = s1[seg, a] / (s1[seg, a] - s2[seg, a])
    i1, i2 = b1[seg], b2[seg]
    qc = view_j.q[i1] + t[:, None] * (view_j.q[i2] - view_j.q[i1])
    b = np.where(t <= 0.5, i1, i2)
    offset = np.linalg.norm(qc - view_j.q[b], axis=1)
    keep = view_j.has_tangent[b]
    a, b, qc, offset = a[keep], b[keep], qc[keep], offset[keep]
    return _branches(a, b, qc, offset)


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


def _frame_views(rig, table_frame: pa.Table, floor_cov):
    views = []
    for cam in rig.cameras:
        rows = table_frame.filter(pc.equal(table_frame.column("camera"), cam.name))

        def col(name, rows=rows):
            return rows.column(name).to_numpy()

        n = rows.num_rows
        q = np.c_[col("u"), col("v")] if n else np.zeros((0, 2))
        cov = np.zeros((n, 2, 2))
        if n:
            cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1] = col("cov_uu"), col("cov_uv"), col("cov_vv")
            cov[:, 1, 0] = cov[:, 0, 1]
        line = col("line") if n else np.zeros(0, int)
        scan_rows = cov[:, 1, 1] <= cov[:, 0, 0]  # rows scanned: v exact (cov_vv = 0)
        views.append(_View(cam, q, cov + floor_cov, col("rank") if n else np.zeros(0, int),
                           col("saturated") if n else np.zeros(0, bool), line, scan_rows))
    return views


def _hypotheses(n_cams: int, ref: int, n_ref: int, branches: dict):
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


class _Observations:
    """Per-camera pixel observations of hypotheses: ``q (n_cams, H, 2)``, weights ``W (n_cams, H, 2, 2)``.

    The reference detection has its full inverse covariance; a matched detection only the
    weight across its stripe, ``n nᵀ / σ⊥²``. Also the normalised-coordinate rows of the linear
    start and the ray directions.
    """

    def __init__(self, views, ref: int, choice: np.ndarray):
        n_cams, H = len(views), len(choice)
        self.used = choice.T >= 0  # (n_cams, H)
        self.q = np.zeros((n_cams, H, 2))
        self.W = np.zeros((n_cams, H, 2, 2))
        self.D = np.zeros((n_cams, H, 2, 2))  # rᵀ D r: squared residual distance (px²)
        self.T = np.zeros((n_cams, H, 2))  # stripe tangent of matched detections (0 for the reference)
        self.dirs = np.full((n_cams, H, 3), np.nan)
        self.rows = []  # (camera, a (H, k, 3) normalised rows, sigma_norm (H,))
        for c, view in enumerate(views):
            pick = np.maximum(choice[:, c], 0)
            use = self.used[c]
            if not use.any():
                continue
            q = view.q[pick]
            self.q[c] = np.where(use[:, None], q, 0.0)
            self.dirs[c] = np.where(use[:, None], view.dirs[pick], np.nan)
            focal = np.sqrt(view.cam.params[0] * view.cam.params[1])
            if c == ref:
                W = pixel_weights(view.cov[pick])
                x = view.xh[pick]
                r1 = np.c_[np.ones(H), np.zeros(H), -x[:, 0]]
                r2 = np.c_[np.zeros(H), np.ones(H), -x[:, 1]]
                rows = np.stack([r1, r2], axis=1)
                sig = np.sqrt(0.5 * np.trace(view.cov[pick], axis1=1, axis2=2)) / focal
                D = np.broadcast_to(np.eye(2), (H, 2, 2))
            else:
                nrm = view.normal[pick]
                W = nrm[:, :, None] * nrm[:, None, :] / view.var_perp[pick][:, None, None]
                rows = view.lines()[pick][:, None, :]
                sig = np.sqrt(view.var_perp[pick]) / focal
                D = nrm[:, :, None] * nrm[:, None, :]
                self.T[c] = np.where(use[:, None], view.tangent[pick], 0.0)
            self.W[c] = np.where(use[:, None, None], W, 0.0)
            self.D[c] = np.where(use[:, None, None], D, 0.0)
            self.rows.append((c, rows, np.where(use, sig, np.nan)))


def _solve(cams, obs: _Observations, plane=None, start=None):
    """Maximum-likelihood points of hypotheses (Gauss–Newton on pixels, optional plane term).

    Returns
    -------
    p : (H, 3), cov : (H, 3, 3), chi2 : (H,), residual_px : (H,), ok : (H,) bool
    """
    H = obs.q.shape[1]
    p = _linear_start(cams, obs) if start is None else start.copy()
    if plane is not None:
        w_plane = 1.0 / np.maximum(plane.offset_sigma(np.nan_to_num(p)), 1e-9) ** 2
    with np.errstate(invalid="ignore", over="ignore"):  # diverged hypotheses end as not ok
        for it in range(GN_STEPS + 1):
            A = np.zeros((H, 3, 3))
            g = np.zeros((H, 3))
            chi2 = np.zeros(H)
            rsum = np.zeros(H)
            along = np.zeros(H)
            front = np.ones(H, bool)
            for c, cam in enumerate(cams):
                use = obs.used[c]
                if not use.any():
                    continue
                q_hat, J = cam.project_with_point_jacobian(np.nan_to_num(p))
                front &= ~use | np.all(np.isfinite(q_hat), axis=1)
                r = np.where(use[:, None], obs.q[c] - np.nan_to_num(q_hat), 0.0)
                J = np.where(use[:, None, None], np.nan_to_num(J), 0.0)
                Wr = np.einsum("nij,nj->ni", obs.W[c], r)
                A += np.einsum("nki,nkl,nlj->nij", J, obs.W[c], J)
                g += np.einsum("nki,nk->ni", J, Wr)
                chi2 += np.einsum("ni,ni->n", r, Wr)
                # residual as a distance: full for the reference, across the stripe for the others
                rsum += np.einsum("ni,nij,nj->n", r, obs.D[c], r)
                along = np.fmax(along, np.abs(np.einsum("ni,ni->n", obs.T[c], r)))
            if plane is not None:
                rp = plane.offset - np.nan_to_num(p) @ plane.normal
                A += w_plane[:, None, None] * plane.normal[None, :, None] * plane.normal[None, None, :]
                g += (w_plane * rp)[:, None] * plane.normal
                chi2 += w_plane * rp**2
            cov, singular = inv_sym3(A)
            if it == GN_STEPS:
                break
            p = p + np.einsum("nij,nj->ni", cov, g)
        n_views = obs.used.sum(axis=0)
        residual_px = np.sqrt(np.maximum(rsum, 0.0) / np.maximum(n_views, 1))
    ok = front & ~singular & np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(cov), axis=(1, 2))
    ok &= np.isfinite(chi2)
    # the point must project onto the piece of stripe that was matched (the line constraint is
    # local: far along the stripe from the matched detection it says nothing)
    ok &= along <= MERGE_PX
    return p, cov, chi2, residual_px, ok


def _linear_start(cams, obs: _Observations):
    """Weighted linear least squares in normalised coordinates (two passes: depths, then weights)."""
    H = obs.q.shape[1]
    p = np.zeros((H, 3))
    depth = {c: np.ones(H) for c, _, _ in obs.rows}
    for _ in range(2):
        A = np.zeros((H, 3, 3))
        g = np.zeros((H, 3))
        for c, rows, sig in obs.rows:
            R, t = cams[c].cam_from_world.R, cams[c].cam_from_world.t
            a = rows @ R  # (H, k, 3)
            rhs = -(rows @ t)  # (H, k)
            w = np.nan_to_num(1.0 / (sig * depth[c]) ** 2)  # NaN (unused) -> 0
            A += np.einsum("n,nki,nkj->nij", w, a, a)
            g += np.einsum("n,nki,nk->ni", w, a, rhs)
        inv, _ = inv_sym3(A)
        p = np.einsum("nij,nj->ni", inv, g)
        for c, _, _ in obs.rows:
            z = p @ cams[c].cam_from_world.R[2] + cams[c].cam_from_world.t[2]
            depth[c] = np.where(np.isfinite(z) & (z > 0), z, 1.0)
    return p


def _min_crossing_angle(cams, obs: _Observations, ref: int) -> np.ndarray:
    """Smallest angle between the reference ray and the stripe planes of the matched cameras, rad.

    A matched detection constrains the point to the plane through its camera's centre and its
    stripe's local line; where the reference ray runs within a small angle of that plane (the
    epipolar line along the stripe, as for two cameras that both see the light sheet edge-on),
    the depth it gives is unusable, like two nearly parallel rays.
    """
    d_ref = obs.dirs[ref]
    worst = np.full(d_ref.shape[0], np.inf)
    for c, rows, _ in obs.rows:
        if c == ref:
            continue
        normal = rows[:, 0, :] @ cams[c].cam_from_world.R  # plane normal in the world frame
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        angle = np.arcsin(np.clip(np.abs(np.einsum("ni,ni->n", normal, d_ref)), 0.0, 1.0))
        worst = np.where(obs.used[c], np.fmin(worst, angle), worst)
    return worst


def _contradicted(cams, views, choice, p, cov, gate: float) -> np.ndarray:
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


def _greedy_unique(det_ids: np.ndarray, priority: np.ndarray) -> np.ndarray:
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


def _frame_branches(rig, views) -> dict:
    """``(i, j) -> (a, b)``: the branches of every reference camera ``i`` in every other ``j``."""
    cams = rig.cameras
    return {(i, j): _crossings(cams[i], views[i], cams[j], views[j])
            for i in range(len(cams)) for j in range(len(cams)) if i != j}


def _floor_samples(rig, views, branches=None):
    """Three-view (or more) hypotheses of one frame for :func:`estimate_calibration_floor`.

    Only unambiguous matches are used: every detection of the hypothesis has exactly one branch
    in each other camera of the hypothesis (so a reflection seen by one camera, which gives the
    other cameras' detections a second branch there, cannot enter), with all the reference's
    branches. Returns ``h (H, n_cams)`` — how much one px² of extra isotropic noise in each
    camera raises the expected χ² (``tr(R_cᵀ W R_c)`` with ``R = I − J H⁻¹ Jᵀ W`` the residual
    operator) — the χ², its degrees of freedom and each detection's radius (px) from its
    camera's principal point (NaN where unused).
    """
    cams = rig.cameras
    n_cams = len(cams)
    branches = _frame_branches(rig, views) if branches is None else branches
    n_branches = {(i, j): np.bincount(a, minlength=len(views[i].q)) for (i, j), (a, _) in branches.items()}
    out = []
    for i in range(n_cams):
        mine = {j: branches[i, j] for j in range(n_cams) if j != i and branches[i, j][0].size}
        if len(mine) < 2:
            continue
        choice = _hypotheses(n_cams, i, len(views[i].q), mine)
        used = (choice >= 0).sum(axis=1)
        most = np.zeros(len(views[i].q), int)
        np.maximum.at(most, choice[:, i], used)
        sel = (used == most[choice[:, i]]) & (used >= 3)
        for c1 in range(n_cams):
            for c2 in range(n_cams):
                if c1 != c2:
                    both = (choice[:, c1] >= 0) & (choice[:, c2] >= 0)
                    sel &= ~both | (n_branches[c1, c2][np.maximum(choice[:, c1], 0)] == 1)
        choice, used = choice[sel], used[sel]
        if len(choice) == 0:
            continue
        obs = _Observations(views, i, choice)
        p, cov, chi2, _, ok = _solve(cams, obs)
        H = len(choice)
        J = np.zeros((H, 2 * n_cams, 3))
        W = np.zeros((H, 2 * n_cams, 2 * n_cams))
        for c, cam in enumerate(cams):
            _, Jc = cam.project_with_point_jacobian(np.nan_to_num(p))
            J[:, 2 * c:2 * c + 2] = np.where(obs.used[c][:, None, None], np.nan_to_num(Jc), 0.0)
            W[:, 2 * c:2 * c + 2, 2 * c:2 * c + 2] = obs.W[c]
        R = np.eye(2 * n_cams) - J @ np.nan_to_num(cov) @ J.transpose(0, 2, 1) @ W
        h = np.stack([np.einsum("nki,nkl,nli->n", R[:, :, 2 * c:2 * c + 2], W, R[:, :, 2 * c:2 * c + 2])
                      for c in range(n_cams)], axis=1)
        radius = np.stack([np.where(obs.used[c], np.linalg.norm(obs.q[c] - cam.params[2:4], axis=1), np.nan)
                           for c, cam in enumerate(cams)], axis=1)
        ok &= np.all(np.isfinite(h), axis=1)
        out.append((h[ok], chi2[ok], (used[ok] - 2).astype(float), radius[ok]))
    return out


def estimate_calibration_floor(samples, n_cams: int, gate_probability: float = GATE_PROBABILITY,
                               bin_px: float = FLOOR_BIN_PX, max_radius_px: float = 2000.0):
    """Extra pixel noise per camera and image radius that makes the three-view χ² consistent.

    The calibration floor (``sigma_floor_px``) assumes the calibration is equally good everywhere.
    A calibration from target views that did not reach the image borders extrapolates its
    distortion there; stripes on the whole scene then meet errors of pixels, which two-view
    stripe points turn into millimetres. Points seen by three cameras reveal it: their χ² grows
    with the radius of their detections. The model is an isotropic variance ``s_c(r)²`` per
    camera ``c``, non-decreasing in the radius ``r`` (piecewise constant on ``bin_px`` rings), so
    ``E[χ²] = dof + Σ_c s_c(r_c)² h_c`` (:func:`_floor_samples`) is linear in the non-negative ring
    increments: a non-negative least-squares fit, repeated with the hypotheses whose χ² fails the
    gate scaled by their predicted excess left out (wrong matches).

    Returns
    -------
    edges : ndarray of shape (n_bins,)
        Inner radius of each ring, px.
    s2 : ndarray of shape (n_cams, n_bins)
        Extra variance, px² (zeros when there are fewer than :data:`FLOOR_MIN_SAMPLES` samples).
    """
    from scipy.optimize import nnls

    edges = np.arange(0.0, max_radius_px, bin_px)
    n_bins = len(edges)
    s2 = np.zeros((n_cams, n_bins))
    if not samples:
        return edges, s2
    h = np.concatenate([x[0] for x in samples])
    chi2 = np.concatenate([x[1] for x in samples])
    dof = np.concatenate([x[2] for x in samples])
    radius = np.concatenate([x[3] for x in samples])
    if len(chi2) < FLOOR_MIN_SAMPLES:
        return edges, s2
    ring = np.minimum(np.searchsorted(edges, np.nan_to_num(radius, nan=-1.0), "right") - 1, n_bins - 1)
    A = np.zeros((len(chi2), n_cams * n_bins))
    for c in range(n_cams):
        for b in range(n_bins):
            A[:, c * n_bins + b] = np.where(ring[:, c] >= b, h[:, c], 0.0)
    # A ring gets its own increment only where its samples are significantly worse than the noise
    # model (sign test: under it half the χ² are below their median); else it keeps the inner
    # ring's value, so a few unlucky samples cannot raise the floor.
    above = chi2 > chi2_dist.ppf(0.5, dof)
    live_ring = np.zeros((n_cams, n_bins), bool)
    for c in range(n_cams):
        seen = np.isfinite(radius[:, c])
        n = np.bincount(ring[seen, c], minlength=n_bins)[:n_bins]
        k = np.bincount(ring[seen, c], weights=above[seen], minlength=n_bins)[:n_bins]
        with np.errstate(invalid="ignore", divide="ignore"):
            z = (k - 0.5 * n) / (0.5 * np.sqrt(n))
        live_ring[c] = (n >= FLOOR_MIN_RING) & (z >= FLOOR_SIGNIFICANCE)
    live = np.flatnonzero(A.any(axis=0) & live_ring.ravel())
    if live.size == 0:
        return edges, s2
    gate = chi2_dist.ppf(gate_probability, dof)
    keep = chi2 <= FLOOR_FIRST_GATE * gate
    for _ in range(FLOOR_ITERATIONS):
        if keep.sum() < FLOOR_MIN_SAMPLES:
            break
        t = np.zeros(A.shape[1])
        t[live], _ = nnls(A[keep][:, live], chi2[keep] - dof[keep])
        keep = chi2 <= gate * (1.0 + (A @ t) / dof)
        s2 = np.cumsum(t.reshape(n_cams, n_bins), axis=1)
    return edges, s2


def reconstruct_stripe_frame(rig, views, frame_index: int, rng, gate_probability: float,
                             min_angle_rad: float, single_view: bool, branches=None):
    """Points of one stripe frame (see the module notes); returns a PointCloud and counts.

    ``branches`` are the frame's crossings (:func:`_frame_branches`), computed when not given.
    """
    cams = rig.cameras
    n_cams = len(cams)
    counts = dict(multi_view=0, single_view=0, off_plane_pairs=0, pairs=0, plane=0)
    branches = _frame_branches(rig, views) if branches is None else branches
    # hypotheses of every reference camera, solved without the plane
    hyps = []  # (ref, choice, obs, p, cov, chi2, residual, ok)
    crossed = [np.zeros(len(v.q), bool) for v in views]
    for i in range(n_cams):
        mine = {j: branches[i, j] for j in range(n_cams) if j != i and branches[i, j][0].size}
        for a, _ in mine.values():
            crossed[i][a] = True
            counts["pairs"] += int(a.size)
        if not mine:
            continue
        choice = _hypotheses(n_cams, i, len(views[i].q), mine)
        if len(choice) == 0:
            continue
        obs = _Observations(views, i, choice)
        p, cov, chi2, resid, ok = _solve(cams, obs)
        ok &= _min_crossing_angle(cams, obs, i) >= min_angle_rad
        hyps.append([i, choice, obs, p, cov, chi2, resid, ok])
    if not hyps:
        return PointCloud.empty(), counts

    # light plane from the consistent three-view hypotheses (or all pairs with two cameras)
    def geometric_pass(h):
        m = (h[1] >= 0).sum(axis=1) - 1
        dof = np.maximum(m - 1, 1)
        return h[7] & (m >= 2) & (h[5] <= chi2_dist.ppf(gate_probability, dof))

    multi = [geometric_pass(h) for h in hyps]
    p_fit = np.concatenate([h[3][s] for h, s in zip(hyps, multi)])
    cov_fit = np.concatenate([h[4][s] for h, s in zip(hyps, multi)])
    if len(p_fit) < MIN_PLANE_POINTS:
        pairs = [h[7] & ((h[1] >= 0).sum(axis=1) == 2) for h in hyps]
        p_fit = np.concatenate([h[3][s] for h, s in zip(hyps, pairs)])
        cov_fit = np.concatenate([h[4][s] for h, s in zip(hyps, pairs)])
    plane, inliers = (fit_plane_robust(p_fit, None, rng, cov_m=cov_fit) if len(p_fit) >= MIN_PLANE_POINTS
                      else (None, None))
    if plane is not None:
        w = 1.0 / np.maximum(np.einsum("i,nij,j->n", plane.normal, cov_fit[inliers], plane.normal), 1e-24)
        plane = with_block_uncertainty(plane, p_fit[inliers], w)

    # with the plane: re-solve every hypothesis with it as one more measurement, gate m dof
    cand = []
    for h, s_multi in zip(hyps, multi):
        i, choice, obs, p, cov, chi2, resid, ok = h
        m = (choice >= 0).sum(axis=1) - 1
        if plane is not None:
            # the plane measures depth only where the reference ray crosses it at an angle
            crossing = np.arcsin(np.clip(np.abs(obs.dirs[i] @ plane.normal), 0.0, 1.0)) >= min_angle_rad
            p2, cov2, chi2_2, resid2, ok2 = _solve(cams, obs, plane, start=p)
            with_plane = ok & ok2 & crossing
            passed = with_plane & (chi2_2 <= chi2_dist.ppf(gate_probability, m))
            # a two-view point must be located by its own views, the plane only checking and
            # sharpening it: where the views leave it loose, the plane test cannot see errors
            # (a reflection's ray meets the plane somewhere) that the plane-made sigma would hide
            with np.errstate(invalid="ignore"):  # failed solutions have NaN covariances
                loose = (m == 1) & ~(sigma_from_covariance(cov) <= PLANE_GAIN_MAX * sigma_from_covariance(cov2))
            passed &= ~loose
            p, cov, resid = (np.where(with_plane[:, None], p2, p), np.where(with_plane[:, None, None], cov2, cov),
                             np.where(with_plane, resid2, resid))
            passed |= ~crossing & s_multi
        else:
            passed = s_multi
        counts["off_plane_pairs"] += int(((m == 1) & ~passed).sum())
        cand.append((i, choice[passed], p[passed], cov[passed], resid[passed], m[passed]))
    counts["plane"] = int(plane is not None)

    # one detection, one point: the most precise consistent hypotheses first, then most views
    offsets = np.cumsum([0] + [len(v.q) for v in views])
    choice = np.concatenate([c[1] for c in cand])
    if len(choice) == 0 and plane is None:
        return PointCloud.empty(), counts
    p = np.concatenate([c[2] for c in cand])
    cov = np.concatenate([c[3] for c in cand])
    resid = np.concatenate([c[4] for c in cand])
    m = np.concatenate([c[5] for c in cand])
    ref = np.concatenate([np.full(len(c[1]), c[0]) for c in cand])
    # two-view points that a third camera contradicts: it sees the stripe right beside the point
    # but not through it (a third view that sees the stripe far away may be occluded there)
    clash = np.zeros(len(choice), bool)
    two = np.flatnonzero(m == 1)
    clash[two] = _contradicted(cams, views, choice[two], p[two], cov[two], chi2_dist.ppf(gate_probability, 1))
    counts["off_plane_pairs"] += int(clash.sum())
    choice, p, cov, resid, m, ref = (x[~clash] for x in (choice, p, cov, resid, m, ref))
    sigma = sigma_from_covariance(cov) if len(cov) else np.zeros(0)
    det_ids = np.where(choice >= 0, choice + offsets[:-1][None, :], -1)
    priority = np.lexsort((-m, sigma))
    order_rank = np.empty(len(priority), np.int64)
    order_rank[priority] = np.arange(len(priority))
    accepted = _greedy_unique(det_ids, order_rank)
    choice, p, cov, resid, m, ref, sigma = (x[accepted] for x in (choice, p, cov, resid, m, ref, sigma))
    flags = np.zeros(len(choice), np.uint16)
    for c, view in enumerate(views):
        use = choice[:, c] >= 0
        pick = np.maximum(choice[:, c], 0)
        if len(view.q):
            flags[use & (view.rank[pick] > 0)] |= np.uint16(Flag.REJECTED_CANDIDATES)
            flags[use & view.saturated[pick]] |= np.uint16(Flag.SATURATED)
    # a camera in which the reference had crossings but that the accepted point does not use
    for i in range(n_cams):
        sel = ref == i
        for h in hyps:
            if h[0] != i:
                continue
            had = np.zeros((len(views[i].q), n_cams), bool)
            np.logical_or.at(had, h[1][:, i], h[1] >= 0)
            dropped = had[choice[sel, i]] & (choice[sel] < 0)
            flags[np.flatnonzero(sel)[dropped.any(axis=1)]] |= np.uint16(Flag.DROPPED_VIEW)
    clouds = [PointCloud(p, sigma, m + 1, resid, np.full(len(p), frame_index), flags)]
    counts["multi_view"] = len(p)

    # single views: brightest on their line, no crossing in any other camera, on the plane
    if single_view and plane is not None:
        sigma_ref = np.median(sigma) if len(sigma) else 0.0
        used = np.zeros(offsets[-1], bool)
        used[det_ids[accepted][det_ids[accepted] >= 0]] = True
        for i, view in enumerate(views):
            n_i = len(view.q)
            if n_i == 0:
                continue
            # a piece of stripe that other cameras confirm elsewhere (an isolated noise peak, or
            # a reflection seen by this camera only, is not part of one)
            mine = used[offsets[i]:offsets[i + 1]]
            confirmed = np.zeros(n_i, bool)
            confirmed[np.unique(view.piece[mine])] = True
            lone = (~crossed[i] & (view.rank == 0) & ~mine & confirmed[view.piece]
                    & np.all(np.isfinite(view.dirs), axis=1))
            if not lone.any():
                continue
            centers = np.repeat(cams[i].center_world[None], lone.sum(), axis=0)
            p1, t1 = intersect_plane(centers, view.dirs[lone], plane)
            fin = np.all(np.isfinite(p1), axis=1)
            focal = np.sqrt(cams[i].params[0] * cams[i].params[1])
            sig_px = np.sqrt(0.5 * np.trace(view.cov[lone], axis1=1, axis2=2))
            cov1 = ray_plane_covariance(view.dirs[lone][fin], t1[fin], sig_px[fin] / focal, plane, p1[fin])
            sigma1 = sigma_from_covariance(cov1)
            sharp = sigma1 <= SINGLE_VIEW_SIGMA_RATIO * sigma_ref
            flags1 = np.full(sharp.sum(), Flag.PLANE_SINGLE_VIEW, np.uint16)
            flags1[view.saturated[lone][fin][sharp]] |= np.uint16(Flag.SATURATED)
            clouds.append(PointCloud(p1[fin][sharp], sigma1[sharp], np.ones(sharp.sum()),
                                     np.full(sharp.sum(), np.nan), np.full(sharp.sum(), frame_index), flags1))
            counts["single_view"] += int(sharp.sum())
    return PointCloud.concatenate(clouds), counts


def reconstruct_stripes(
    rig,
    table: pa.Table,
    frames: list[str],
    rng: np.random.Generator,
    sigma_floor_px: float = SIGMA_FLOOR_PX,
    gate_probability: float = GATE_PROBABILITY,
    min_angle_rad: float = MIN_TRIANGULATION_ANGLE_RAD,
    single_view: bool = True,
    progress=None,
    estimate_floor: bool = True,
    max_sigma_m: float | None = None,
):
    """Points of every stripe frame of a traces table.

    Parameters
    ----------
    rig : Rig
        At least two calibrated cameras.
    table : pyarrow.Table
        Traces; ``kind == "stripe"`` rows are used.
    frames : list of str
        Frame stems in natural order (defines the ``frame`` index).
    rng : numpy.random.Generator
        For the robust plane fits.
    sigma_floor_px, gate_probability, min_angle_rad
        As in spot mode.
    single_view : bool
        Add the points seen by one camera only, intersected with the frame's plane.
    progress : callable, optional
        ``progress(done, total)`` after each frame.
    estimate_floor : bool
        Raise the calibration floor per camera and image radius where the three-view points show
        the calibration to be worse than ``sigma_floor_px`` (:func:`estimate_calibration_floor`).
    max_sigma_m : float, optional
        Points with a larger sigma are left out; default :data:`MAX_SIGMA_RATIO` times the median
        sigma of the three-view points (``numpy.inf`` keeps every point that passed its tests).

    Returns
    -------
    cloud : PointCloud
    summary : dict
        Frames, frames with a plane, multi-view and single-view points, two-view pairs (branches
        of epipolar crossings) and those rejected (off the plane, no plane to test them, located
        by the plane only, contradicted by a third camera), points left out as imprecise and the
        sigma limit (``max_sigma_mm``), and the largest estimated extra calibration noise
        (``floor_extra_px``).
    """
    if len(rig) < 2:
        raise InputError(f"multi-view reconstruction needs at least 2 cameras, the rig has {len(rig)}")
    stripes = table.filter(pc.equal(table.column("kind"), "stripe"))
    unknown = sorted(set(stripes.column("camera").unique().to_pylist()) - set(rig.names))
    if unknown:
        raise InputError(f"traces name cameras {unknown} that are not in the rig (cameras: {rig.names})")
    floor = np.eye(2) * sigma_floor_px**2
    frame_idx = pc.index_in(stripes.column("frame"), value_set=pa.array(frames, pa.string())).to_numpy(
        zero_copy_only=False)
    order = np.argsort(frame_idx, kind="stable")
    bounds = np.searchsorted(frame_idx[order], np.arange(len(frames) + 1))
    views_of, branches_of = {}, {}
    for f in range(len(frames)):
        rows = order[bounds[f]:bounds[f + 1]]
        if rows.size:
            views_of[f] = _frame_views(rig, stripes.take(pa.array(rows)), floor)
            branches_of[f] = _frame_branches(rig, views_of[f])  # geometry only: kept across the floor
    extra_px = 0.0
    if estimate_floor:
        samples = [x for f, views in views_of.items() for x in _floor_samples(rig, views, branches_of[f])]
        edges, s2 = estimate_calibration_floor(samples, len(rig), gate_probability)
        extra_px = float(np.sqrt(s2.max()))
        if s2.any():
            for views in views_of.values():
                for c, (cam, view) in enumerate(zip(rig.cameras, views)):
                    if len(view.q):
                        r = np.linalg.norm(view.q - cam.params[2:4], axis=1)
                        view.inflate(s2[c][np.minimum(np.searchsorted(edges, r, "right") - 1, len(edges) - 1)])
    totals = dict(multi_view=0, single_view=0, off_plane_pairs=0, pairs=0, plane=0)
    clouds = []
    for f in range(len(frames)):
        if f in views_of:
            cloud, counts = reconstruct_stripe_frame(rig, views_of[f], f, rng, gate_probability, min_angle_rad,
                                                     single_view, branches_of[f])
            clouds.append(cloud)
            for k, v in counts.items():
                totals[k] += v
        if progress is not None:
            progress(f + 1, len(frames))
    cloud = PointCloud.concatenate(clouds)
    if max_sigma_m is None:
        reference = cloud.sigma[cloud.n_views >= 3]
        if reference.size < MIN_PLANE_POINTS:
            reference = cloud.sigma[cloud.n_views >= 2]
        max_sigma_m = MAX_SIGMA_RATIO * float(np.median(reference)) if reference.size else np.inf
    precise = cloud.sigma <= max_sigma_m
    imprecise = int((~precise).sum())
    totals["multi_view"] -= int((~precise & (cloud.n_views >= 2)).sum())
    totals["single_view"] -= int((~precise & (cloud.n_views == 1)).sum())
    cloud = cloud.select(precise)
    summary = dict(frames=len(frames), points=len(cloud), frames_with_plane=totals["plane"],
                   points_multi_view=totals["multi_view"], points_single_view=totals["single_view"],
                   points_imprecise=imprecise, max_sigma_mm=round(1e3 * max_sigma_m, 4),
                   pairs=totals["pairs"], pairs_off_plane=totals["off_plane_pairs"],
                   floor_extra_px=round(extra_px, 3))
    return cloud, summary
